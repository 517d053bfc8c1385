"""Configs: every group composes, YAML mirrors the schemas, and bad input fails before compute, named."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from sidewalk.config import validate
from sidewalk.loggers import BACKEND_PACKAGES, check_logger
from sidewalk.registry import LEARNERS
from sidewalk.schema import register_schemas

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
register_schemas()


def composed(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


@pytest.mark.parametrize(
    "overrides",
    [
        [],
        ["env=continuous", "opponent=prm", "noise=0.5", "algo=trpo"],
        ["env=continuous", "opponent=centralized", "algo=ppo", "reward=implicit"],
        ["opponent=random", "algo=ppo", "env.observation=vector", "logger=none"],
        ["opponent=centralized", "reward.shaped_agents=[0]"],
    ],
)
def test_valid_configs_compose_and_validate(overrides):
    experiment = validate(composed(*overrides))
    assert experiment.algo.name == composed(*overrides).algo.name


@pytest.mark.parametrize("name", list(LEARNERS))
def test_algo_yaml_mirrors_its_schema(name):
    # Composed on vectors: a setting that differs on images (${sidewalk.on_images:...}) takes its vector value.
    yaml = OmegaConf.to_container(composed(f"algo={name}", "env=discrete", "env.observation=vector").algo, resolve=True)
    defaults = dataclasses.asdict(LEARNERS[name].Config())
    assert yaml == defaults


@pytest.mark.parametrize("algo", ["ippo", "mappo"])
def test_on_policy_multiagent_learners_take_image_settings_on_grid_images(algo):
    settings = ("epochs", "minibatch_size", "entropy_coef", "share_params")
    images = composed("opponent=self", f"algo={algo}").algo
    assert [images[key] for key in settings] == [4, 512, 0.01, False]
    for vectors in (["env=continuous"], ["env.observation=vector"]):
        assert [composed("opponent=self", f"algo={algo}", *vectors).algo[key] for key in settings] == [10, 64, 0.0, True]
    assert composed("opponent=self", f"algo={algo}", "algo.epochs=7").algo.epochs == 7  # the command line wins


@pytest.mark.parametrize(
    "overrides, expected",
    [
        ([], (128, 400, 25, 512)),  # DQN: 4 steps of 128 worlds an iteration, 400 of them
        (["env=continuous"], (128, 500, 50, 2048)),  # TRPO
        (["iterations=7", "eval_every=3", "num_envs=8"], (8, 7, 3, 512)),  # the command line wins
        (["+experiment=fig5_discrete"], (32, 5000, 50, 128)),  # the reference runs' settings, pinned
        (["+experiment=fig6_discrete", "scale=quick"], (32, 20, 5, 128)),
    ],
)
def test_run_length_and_worlds_come_from_the_learner_unless_given(overrides, expected):
    experiment = validate(composed(*overrides))
    assert (experiment.num_envs, experiment.iterations, experiment.eval_every,
            experiment.algo.frames_per_batch) == expected


@pytest.mark.parametrize(
    "overrides, algo, c_progress",
    [
        (["opponent=self"], "iql", 0.02),  # self-play learns as first asked for: a multi-agent learner, shaped
        (["opponent=self", "env=continuous"], "ippo", 0.1),
        (["opponent=self", "env=continuous", "algo=mappo", "reward=implicit"], "mappo", 0.1),
        (["opponent=self", "reward.c_progress=0"], "iql", 0.0),  # the command line wins
        (["+experiment=selfplay_door_continuous", "algo=mappo"], "mappo", 0.1),
        ([], "dqn", 0.02),  # the grid shapes every view: DQN against Dijkstra held only with it
        (["opponent=centralized"], "dqn", 0.02),
        (["+experiment=fig5_discrete"], "dqn", 0.0),  # the paper's presets keep the paper's reward
        (["env=continuous"], "trpo", 0.0),  # the continuous world's scripted partners keep the paper's reward
        (["env=continuous", "opponent=centralized"], "trpo", 0.0),
    ],
)
def test_self_play_defaults_to_a_multiagent_learner_and_its_shaping(overrides, algo, c_progress):
    cfg = composed(*overrides)
    assert (cfg.algo.name, cfg.reward.c_progress) == (algo, c_progress)


@pytest.mark.parametrize("name", ["random", "dijkstra", "prm", "convention", "population"])
def test_opponent_yaml_mirrors_the_constructor_defaults(name):
    import inspect

    from sidewalk.opponents.base import opponent_class

    yaml = OmegaConf.to_container(OmegaConf.load(CONF / "opponent" / f"{name}.yaml").params)
    parameters = inspect.signature(opponent_class(name).__init__).parameters
    defaults = {k: p.default for k, p in parameters.items() if k not in ("self", "env", "controlled", "ego")}
    assert yaml == defaults


@pytest.mark.parametrize(
    "overrides, named",
    [
        (["env=foo"], "discrete"),  # an unknown option lists the valid ones
        (["opponent=foo"], "dijkstra"),
        (["algo=foo"], "trpo"),
        (["reward=foo"], "implicit"),
        (["logger=foo"], "tensorboard"),
        (["seed=abc"], "abc"),
        (["noise=abc"], "abc"),
        (["foo=1"], "foo"),
        (["algo.lr=fast"], "fast"),
        (["env.width_cells=2.5"], "2.5"),
        (["num_envs=0"], "num_envs=0"),
        (["iterations=0"], "iterations=0"),
        (["eval_episodes=-3"], "eval_episodes=-3"),
        (["noise=1.5"], "noise=1.5"),
        (["env=continuous", "opponent=prm", "algo=trpo", "noise=-0.1"], "noise=-0.1"),
        (["algo.lr=-1"], "algo.lr=-1"),
        (["algo.gamma=1.5"], "algo.gamma=1.5"),
        (["algo.eps_end=2.0"], "algo.eps_end=2.0"),
        (["algo.target_update=sometimes"], "sometimes"),
        (["env.width_cells=0"], "width_cells=0"),
        (["env.observation=rgb"], "observation='rgb'"),
        (["env=continuous", "opponent=prm", "algo=trpo", "env.dt_s=0"], "dt_s=0"),
        (["reward.alpha=2"], "alpha=2"),
        (["reward.shaped_agents=[5]"], "shaped_agents"),
        (["device=tpu"], "device='tpu'"),
        (["opponent=prm"], "opponent=prm does not play env=discrete"),
        (["env=continuous", "opponent=dijkstra", "algo=trpo"], "opponent=dijkstra does not play env=continuous"),
        (["env=continuous", "algo=dqn"], "algo=dqn does not fit env=continuous"),
        (["opponent.ego=3"], "opponent.ego=3"),
        (["env.length_cells=6"], "14 px per side"),
        (["+nosie=0.5"], "unknown key 'nosie' (did you mean 'noise'?)"),
        (["+mystery=1"], "unknown key 'mystery'"),
        (["+env.widht_cells=3"], "unknown key 'widht_cells' (did you mean 'width_cells'?)"),
        (["+algo.lrr=0.1"], "unknown key 'lrr' (did you mean 'lr'?) for algo.* (algo=dqn)"),
        (["keep_checkpoint=some"], "keep_checkpoint='some'"),
    ],
)
def test_bad_overrides_fail_naming_the_value(overrides, named):
    with pytest.raises((ConfigCompositionException, OmegaConfBaseException, ValueError, TypeError)) as error:
        validate(composed(*overrides))
    message = str(error.value) + str(getattr(error.value, "__cause__", "") or "")
    assert named in message


# One interpreter runs every command of CLI_CASES through runners/main.py's cli(), as the shell would (its argv, exit
# status, stdout and stderr): a process per command would add seconds of imports each.
CLI_BATCH = """
import contextlib, io, json, os, runpy, sys
cli = runpy.run_path("runners/main.py")["cli"]
commands, outcomes_file, outcomes = json.loads(sys.argv[1]), sys.argv[2], []
for arguments in commands:
    os.environ.pop("HYDRA_FULL_ERROR", None)  # cli() sets it for Hydra; each command starts as from the shell
    sys.argv = ["runners/main.py", *arguments]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            cli()
            status = 0
        except SystemExit as stop:
            status = stop.code
    outcomes.append([status, out.getvalue(), err.getvalue()])
with open(outcomes_file, "w") as file:  # not stdout: a library's log handler may hold the real one
    json.dump(outcomes, file)
"""

# A logger backend whose package this environment lacks (the dev extras install none of them).
MISSING_LOGGER = next((name for name, package in BACKEND_PACKAGES.items() if importlib.util.find_spec(package) is None),
                      None)
# name: (arguments, exit status, what stderr must hold, what it must not); the run folder is `<tmp>/<name>`.
CLI_CASES = {
    "pairing": (["opponent=prm"], 2, ["does not play env=discrete"], []),
    "unknown_env": (["env=maze"], 2, ["continuous"], []),
    "noise_range": (["noise=2"], 2, ["noise=2"], []),
    "typo_added": (["+nosie=0.5"], 2, ["unknown key 'nosie' (did you mean 'noise'?)"], []),
    # Without "+", Hydra's advice was to add the typo with "+": the schema's nearest key instead.
    "typo": (["nosie=0.5"], 2, ["error: unknown key 'nosie' (did you mean 'noise'?) for the experiment"], ["+nosie"]),
    "typo_nested": (["env.widht_cells=3"], 2, ["unknown key 'widht_cells' (did you mean 'width_cells'?) for env.*"],
                    ["+env"]),
    # An opponent's settings are its constructor's keywords: a typo is named, not a TypeError.
    "opponent_param": (["opponent=convention", "+opponent.params.stlye=keep_right"], 2,
                       ["error: unknown parameter 'stlye' (did you mean 'style'?)",
                        "for opponent.params (opponent=convention); valid: style, lane_fraction"], ["TypeError"]),
    # The layout is named where the user typed it, not in the room side a resolver derives from it.
    "layout": (["env.layout=dor"], 2, ["error: env.layout='dor' is not valid; valid:", "'door'", "'sidewalk'"],
               ["width_cells"]),
    # A device this torch cannot use, named with those it can (no GPU has this index anywhere).
    "device": ([f"device=cuda:{torch.cuda.device_count()}"], 2,
               [f"error: device='cuda:{torch.cuda.device_count()}' is not available on this machine", "'cpu'"],
               ["AssertionError"]),
    # Values only the partner's constructor or the job's start knew were bad: refused as the config's are, by
    # building one world of the experiment before Hydra makes the folder (they exited 1 leaving a main.log).
    "partner_value": (["opponent.params.tie_break=rnd"], 2,
                      ["error: tie_break='rnd' is not valid; valid: 'random', 'progress'"], ["Error executing job"]),
    "partner_value_continuous": (["env=continuous", "opponent=prm", "opponent.params.n_nodes=1"], 2,
                                 ["error: n_nodes=1"], ["Error executing job"]),
    "missing_dataset": (["opponent=proxy", "opponent.params.dataset=sidewalk/none-v0"], 2,
                        ["error: ", "'sidewalk/none-v0'"], ["Error executing job"]),
    **({"logger_package": ([f"logger={MISSING_LOGGER}"], 2,
                           [f"error: logger={MISSING_LOGGER} needs the '{MISSING_LOGGER}' package", "usable here: csv"],
                           ["Error executing job"])} if MISSING_LOGGER else {}),
}


@pytest.fixture(scope="module")
def cli_outcomes(tmp_path_factory):
    """Every command of ``CLI_CASES``, ``scale=quick`` shown with ``--cfg job`` and a sweep, each run once: name →
    (exit status, stdout, stderr, run folder)."""
    tmp = tmp_path_factory.mktemp("cli")
    commands = {name: [*arguments, f"hydra.run.dir={tmp / name}"] for name, (arguments, *_) in CLI_CASES.items()}
    commands["scale"] = ["scale=quick", "--cfg", "job"]
    commands["scale_preset"] = ["+experiment=fig5_discrete", "scale=quick", "--cfg", "job"]  # the preset's group
    # A sweep whose second point is bad: refused before its first (good, short) job, so no sweep folder at all.
    commands["sweep"] = ["-m", "noise=0,-0.1", "iterations=1", "eval_every=0", "eval_episodes=1",
                         f"hydra.sweep.dir={tmp / 'sweep'}"]
    outcomes_file = tmp / "outcomes.json"
    done = subprocess.run([sys.executable, "-c", CLI_BATCH, json.dumps(list(commands.values())), str(outcomes_file)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    outcomes = json.loads(outcomes_file.read_text())
    return {name: (*outcome, tmp / name) for name, outcome in zip(commands, outcomes, strict=True)}


@pytest.mark.parametrize("name", list(CLI_CASES))
def test_cli_refuses_bad_input_in_one_line_before_it_makes_a_folder(cli_outcomes, name):
    _, status, named, unnamed = CLI_CASES[name]
    code, _, stderr, run_dir = cli_outcomes[name]
    assert code == status, stderr
    assert len(stderr.strip().splitlines()) == 1, stderr
    for part in named:
        assert part in stderr, stderr
    for part in unnamed:
        assert part not in stderr, stderr
    assert not run_dir.exists(), sorted(run_dir.rglob("*"))  # Hydra had made it (its .hydra/, main.log) before


@pytest.mark.parametrize("name", ["scale", "scale_preset"])
def test_cli_takes_a_scale_without_plus_on_a_plain_run_and_on_a_preset(cli_outcomes, name):
    code, stdout, stderr, _ = cli_outcomes[name]
    assert code == 0, stderr
    shown = OmegaConf.create(stdout)
    assert (shown.iterations, shown.eval_every, shown.replicas) == (20, 5, 2)


def test_a_sweep_with_a_bad_point_is_refused_before_its_first_job(cli_outcomes):
    code, _, stderr, sweep_dir = cli_outcomes["sweep"]
    assert code == 2, stderr
    assert "error: job 1 (noise=-0.1): noise=-0.1 is out of range; valid: [0.0, 1.0]; no job was started" in stderr
    assert not sweep_dir.exists()



def test_a_logger_whose_package_is_missing_is_refused_naming_the_install(monkeypatch):
    import sidewalk.loggers

    installed = {"wandb"}
    monkeypatch.setattr(sidewalk.loggers.importlib.util, "find_spec", lambda name: name in installed or None)
    check_logger("csv"), check_logger("wandb"), check_logger("none")
    with pytest.raises(ValueError, match=r"logger=mlflow needs the 'mlflow' package, which is not installed here: "
                                         r"pip install mlflow .*; usable here: csv, wandb, none$"):
        check_logger("mlflow")
