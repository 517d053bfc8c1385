"""Several seeds in one trial (``replicas=R``): a run is the same for the same seed and R, a replica's update is its
lone learner's, a learner without a replica axis trains each replica as its lone run, every replica's folder is an
ordinary run folder, a command that needs one run names a group folder's seeds' folders, and a killed or pre-empted
group resumes to the same numbers."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

from sidewalk.algos.replicas import replica_state
from sidewalk.compose import compose as compose_config
from sidewalk.config import validate
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.experiment import Trial
from sidewalk.partners.policy import read_partner
from sidewalk.registry import LEARNERS
from sidewalk.report.document import write_report
from sidewalk.report.runs import find_run_folders, load_run
from sidewalk.report.tables import Settings
from sidewalk.run_folder import GROUP_DIR, read_torch_file, replica_dir
from sidewalk.schema import register_schemas

ROOT = Path(__file__).resolve().parents[1]
WALL_CLOCK = ["time_s", "frames_per_s"]
register_schemas()

SHORT = ["logger=none", "iterations=4", "eval_every=2", "eval_episodes=8", "checkpoint_every=2"]
DQN_GRID = ["num_envs=4", "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=2000",
            "algo.learning_starts=0", "noise=0.1"]
TRPO_CONTINUOUS = ["env=continuous", "opponent=prm", "num_envs=8", "algo.frames_per_batch=64",
                   "algo.vf_batch_size=16", "noise=0.5"]
SETUPS = {
    "dqn-grid": DQN_GRID,
    "trpo-continuous": TRPO_CONTINUOUS,  # the configured roadmap: one PRM plans every replica's worlds
    "trpo-continuous-roadmap-per-seed": [*TRPO_CONTINUOUS, "opponent.params.roadmap_seed=null"],  # a PRM per replica
    "ppo-continuous-random": ["env=continuous", "opponent=random", "algo=ppo", "num_envs=8",
                              "algo.frames_per_batch=64", "algo.minibatch_size=32", "noise=0.5"],
    "ppo-lagrangian-continuous": ["env=continuous", "opponent=prm", "algo=ppo_lagrangian", "num_envs=8",
                                  "algo.frames_per_batch=64", "algo.minibatch_size=32", "noise=0.5"],
    "centralized-dqn": ["opponent=centralized", *DQN_GRID],
    "iql-selfplay": ["+experiment=selfplay_discrete", "num_envs=4", "algo.frames_per_batch=16",
                     "algo.batch_size=16", "algo.learning_starts=0"],
}


def experiment(*overrides: str):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return validate(compose(config_name="config", overrides=[*SHORT, *overrides]))


def metrics(run_dir: Path) -> pd.DataFrame:
    return pd.read_csv(run_dir / "metrics.csv").drop(columns=WALL_CLOCK)


@pytest.mark.parametrize("setup", ["dqn-grid", "trpo-continuous", "ppo-continuous-random"])
def test_a_group_is_the_same_for_the_same_seed_and_replicas(tmp_path, setup):
    exp = experiment(*SETUPS[setup], "seed=3", "replicas=2")
    for name in ("first", "second"):  # their metrics compared: no absolute metric
        Trial(exp, tmp_path / name).run(progress=False, absolute_metric=False)
    for seed in (3, 4):
        pd.testing.assert_frame_equal(metrics(replica_dir(tmp_path / "first", seed)),
                                      metrics(replica_dir(tmp_path / "second", seed)), check_exact=True)
    assert not metrics(replica_dir(tmp_path / "first", 3)).equals(metrics(replica_dir(tmp_path / "first", 4)))


@pytest.mark.parametrize("setup", ["iql-selfplay", "ppo-lagrangian-continuous"])
def test_without_a_replica_axis_a_replica_is_its_lone_run(tmp_path, setup):
    """Learners that train their replicas one after another (each on its own stream): replica seed 4 of the group
    of seeds 3, 4, 5 is the lone run of seed 4, metric for metric."""
    for overrides, folder in ((["seed=3", "replicas=3"], "three"), (["seed=4"], "lone")):  # their metrics compared
        Trial(experiment(*SETUPS[setup], *overrides), tmp_path / folder).run(progress=False, absolute_metric=False)
    pd.testing.assert_frame_equal(metrics(replica_dir(tmp_path / "three", 4)), metrics(tmp_path / "lone"))


LEARNER_WORLDS = {
    "dqn": (DiscreteSidewalkEnv, {"learning_starts": 0, "batch_size": 32, "buffer_size": 1000}),
    "trpo": (ContinuousSidewalkEnv, {}),
    "ppo": (ContinuousSidewalkEnv, {"minibatch_size": 32}),
}


def _replay_buffer() -> TensorDictReplayBuffer:
    return TensorDictReplayBuffer(storage=LazyTensorStorage(1000), batch_size=32)


def _updated(algo, batch) -> dict:
    """``algo``'s policy state after one update on ``batch`` with the random draws of seed 7."""
    torch.manual_seed(7)
    algo.update(batch, _replay_buffer())
    return algo.policy_state_dict()


@pytest.mark.parametrize("name", list(LEARNER_WORLDS))
def test_a_replica_updates_as_its_lone_learner(name):
    """One update of a learner with a replica axis (R = 3) against a lone learner holding replica 1's networks, on
    replica 1's batch with the same random draws: the same networks after it (up to float rounding); and replica 1
    ends exactly where it did when another replica's batch is changed."""
    from sidewalk.views import make_view

    cls = LEARNERS[name]
    core_cls, settings = LEARNER_WORLDS[name]
    config = cls.Config(frames_per_batch=64, **settings)
    env = make_view("ego", core_cls(8, seed=0), opponent="random")

    def replicated():
        torch.manual_seed(0)
        return cls(config, env, replicas=3)

    lone = cls(config, env)
    lone.load_state_dict(replica_state(replicated().state_dict(), lone.state_dict(), 1))
    collector = Collector(env, lone.collection_policy(), frames_per_batch=64, total_frames=-1,
                          auto_register_policy_transforms=False)
    batches = [next(iter(collector)).clone() for _ in range(3)]
    collector.shutdown()
    layout = lone.policy_state_dict()
    together = replica_state(_updated(replicated(), torch.stack(batches)), layout, 1)
    alone = _updated(lone, batches[1].clone())
    for module, state in alone["modules"].items():
        for key, value in state.items():
            torch.testing.assert_close(together["modules"][module][key], value, rtol=1e-4, atol=1e-5,
                                       msg=f"{name}: {module}.{key}")
    changed = replica_state(_updated(replicated(), torch.stack([batches[0], batches[1], batches[0]])), layout, 1)
    for module, state in together["modules"].items():
        for key, value in state.items():
            assert torch.equal(changed["modules"][module][key], value), f"{name}: {module}.{key}"


@pytest.mark.parametrize("unit", ["conv", "mlp"])
def test_the_accelerator_map_equals_the_cpu_loop(unit):
    """A replicated unit's vmap forward (the path taken on an accelerator, which no CI machine here has) and, for an
    MLP, its batched matmuls (the path it takes everywhere) give the loop's outputs and gradients, replica by
    replica, and replica r is the lone unit holding its slice."""
    from torch import nn
    from torchrl.modules import MLP, ConvNet

    from sidewalk.algos.networks import PAPER_CONV
    from sidewalk.algos.replicas import replicate_

    torch.manual_seed(0)
    if unit == "conv":
        build, x = (lambda: ConvNet(in_features=1, activation_class=nn.ReLU, **PAPER_CONV)), torch.rand(3, 4, 1, 14, 30)
    else:
        build, x = (lambda: MLP(in_features=6, out_features=2, num_cells=[8, 8])), torch.randn(3, 5, 6)
    network = replicate_(build(), 3)
    gradients = {}
    ways = ("forward_vmapped", "forward_looped", *(("forward_batched", "__call__") if unit == "mlp" else ()))
    for way in ways:
        network.zero_grad()
        output = getattr(network, way)(x)
        output.square().sum().backward()
        gradients[way] = (output.detach(), [p.grad.clone() for p in network.parameters()])
    for way in ways:
        torch.testing.assert_close(gradients[way][0], gradients["forward_looped"][0])
        for mapped, looped in zip(gradients[way][1], gradients["forward_looped"][1]):
            torch.testing.assert_close(mapped, looped)
    assert network.__dict__.get("linear_only", False) == (unit == "mlp")  # the conv stack stays mapped
    lone = build()
    lone.load_state_dict({name: value[2] for name, value in network.state_dict().items()})
    torch.testing.assert_close(lone(x[2]), gradients["forward_looped"][0][2])


def main_py(processes, *overrides: str, timeout: float = 600, check: bool = True) -> subprocess.CompletedProcess:
    """``python runners/main.py *overrides`` in a process of its own (forked after the imports: conftest.py)."""
    result = processes.run("runners/main.py", *overrides, timeout=timeout)  # the caller decides what a failure means
    if check and result.returncode != 0:
        raise AssertionError(f"main.py failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


def test_replica_folders_are_ordinary_run_folders(tmp_path, processes):
    group, lone = tmp_path / "group", tmp_path / "lone"
    main_py(processes, *SHORT, *DQN_GRID, "seed=1", "replicas=2", f"hydra.run.dir={group}")
    cfg = compose_config([*SHORT, *DQN_GRID, "seed=2"])  # the lone run, trained in this process as main.py would
    Trial(validate(cfg), lone, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    assert (group / GROUP_DIR / "config.yaml").exists() and not (group / GROUP_DIR / "checkpoint.pt").exists()
    assert find_run_folders([group]) == [replica_dir(group, 1), replica_dir(group, 2)]
    replica, alone = load_run(replica_dir(group, 2)), load_run(lone)
    assert replica.config == alone.config  # the replica's config.yaml is the lone run's, seed 2 and all
    assert list(replica.metrics.columns) == list(alone.metrics.columns)
    assert {p.name for p in replica_dir(group, 2).iterdir()} >= {"config.yaml", "history.jsonl", "metrics.csv",
                                                                 "summary.json", "policy.pt"}
    summary = json.loads((replica_dir(group, 2) / "summary.json").read_text())
    assert summary["seed"] == 2 and summary["iterations"] == 4
    assert (group / "report" / "report.md").exists()  # the group ended with one report over its replicas
    # A partner is one run: the group folder names its seeds' folders, either of which plays.
    with pytest.raises(ValueError, match=f"{replica_dir(group, 1)}, {replica_dir(group, 2)}"):
        read_partner(group)
    assert read_partner(replica_dir(group, 2)).algo_name == "dqn"
    result = write_report([tmp_path], tmp_path / "report", Settings(n_resamples=200))
    assert not result.skipped
    # To the report, the lone run of seed 2 is the same condition as the group and the same run as its replica 2.
    (condition,) = result.conditions
    assert sorted(run.seed for run in condition.runs) == [1, 2]
    assert [seed for seed, _, _ in condition.duplicates] == [2]


def written_group(folder: Path, seeds: tuple[int, ...] = (3, 4)) -> Path:
    """A group folder laid out as a finished group of ``seeds`` leaves it (its files' contents are not read here):
    ``.group/`` and one run folder per seed, beside the group's report."""
    (folder / GROUP_DIR).mkdir(parents=True)
    (folder / GROUP_DIR / "config.yaml").write_text(f"seed: {seeds[0]}\nreplicas: {len(seeds)}\n")
    (folder / "report").mkdir()
    for seed in seeds:
        replica_dir(folder, seed).mkdir()
        for name in ("config.yaml", "policy.pt", "summary.json"):
            (replica_dir(folder, seed) / name).write_text("")
    return folder


def test_a_command_that_needs_one_run_names_a_group_folders_seeds(tmp_path, capsys):
    group = written_group(tmp_path / "group")
    seeds = f"{replica_dir(group, 3)}, {replica_dir(group, 4)}"
    assert find_run_folders([group]) == [replica_dir(group, 3), replica_dir(group, 4)]  # as reports and cross-play
    with pytest.raises(ValueError, match=f"opponent.path='{group}' is a group folder .*: give one of its 2 seeds' run "
                                         f"folders: {seeds}"):
        read_partner(group)
    spec = importlib.util.spec_from_file_location("render_runner", ROOT / "runners" / "render.py")
    render = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(render)
    assert render.main([str(group)]) == 2
    assert capsys.readouterr().err == f"error: {group} is a group folder (several seeds trained together, replicas=R) " \
                                      f"and one run is needed here: give one of its 2 seeds' run folders: {seeds}\n"


@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGTERM], ids=["killed", "preempted"])
def test_a_stopped_group_resumes_to_the_same_metrics(tmp_path, finished_run, processes, stop):
    overrides = [*SHORT, *TRPO_CONTINUOUS, "iterations=12", "checkpoint_every=3", "eval_every=6", "replicas=2",
                 "plots=false"]
    whole = finished_run(overrides)
    stopped = tmp_path / "stopped"
    process = processes.start("runners/main.py", *overrides, f"hydra.run.dir={stopped}")
    deadline = time.time() + 300
    while not (stopped / GROUP_DIR / "checkpoint.pt").exists() and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)  # into the next iterations, past the checkpoint
    os.kill(process.pid, stop)
    returncode = process.wait()
    assert not (replica_dir(stopped, 0) / "summary.json").exists(), "the group finished before it could be stopped"
    if stop == signal.SIGTERM:
        assert returncode == 128 + signal.SIGTERM
        at = read_torch_file(stopped / GROUP_DIR / "checkpoint.pt")["iteration"]
        assert len(pd.read_csv(replica_dir(stopped, 1) / "metrics.csv")) == at
    main_py(processes, *overrides, f"hydra.run.dir={stopped}", "resume=true")
    for seed in (0, 1):
        pd.testing.assert_frame_equal(metrics(replica_dir(stopped, seed)), metrics(replica_dir(whole, seed)))


def test_bad_replicas_is_one_error_line(tmp_path, processes):
    result = main_py(processes, *SHORT, "replicas=0", f"hydra.run.dir={tmp_path / 'run'}", check=False)
    assert result.returncode == 2 and result.stderr.strip().startswith("error: replicas=0")
    assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "run" / "seed0").exists()
