"""The sidewalk as BenchMARL tasks (sidewalk.interop.benchmarl): configs that match the self-play presets, specs as
BenchMARL reads them, its command line, and BenchMARL's MAPPO (continuous) and IQL / QMIX (grid images, CNN)
training two small iterations. The README's test command installs BenchMARL, so these run in .ci/run."""

from __future__ import annotations

import csv
import importlib.util
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import check_env_specs

if importlib.util.find_spec("benchmarl") is None:  # not importorskip: BenchMARL imports only after our adapter
    pytest.skip("BenchMARL is installed by the README's test command", allow_module_level=True)

from sidewalk.interop.benchmarl import SidewalkTask, make_core
from sidewalk.schema import env_params_of

PRESET = {task: f"selfplay_{task.name.lower().replace('sidewalk_', '')}"
          if task.name.startswith("SIDEWALK") else "selfplay_" + task.name.lower() for task in SidewalkTask}


@pytest.mark.parametrize("task", list(SidewalkTask), ids=lambda task: task.name.lower())
def test_each_task_is_the_worlds_of_its_self_play_preset(task):
    from sidewalk.compose import compose

    cfg = compose([f"+experiment={PRESET[task]}"])
    config = task.get_from_yaml().config
    assert config["domain"] == cfg.env.domain
    assert make_core(config, 1, 0, "cpu").params == env_params_of(cfg)


def test_a_bad_task_config_names_the_bad_value_and_the_valid_ones():
    with pytest.raises(ValueError, match=r"domain='grid' is not valid; valid: \['discrete', 'continuous'\]"):
        make_core({"domain": "grid"}, 1, 0, "cpu")
    valid = r"\['domain', 'noise', 'env', 'reward', 'state'\]"
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['layout'\]; valid: " + valid):
        make_core({"domain": "discrete", "layout": "door"}, 1, 0, "cpu")


@pytest.mark.parametrize("name", ["door_continuous", "door_discrete"])
def test_specs_as_benchmarl_reads_them(name):
    task = SidewalkTask[name.upper()].get_from_yaml()
    env = task.get_env_fun(num_envs=3, continuous_actions=name.endswith("continuous"), seed=0, device="cpu")()
    env = TransformedEnv(env, Compose(*task.get_env_transforms(env)))
    check_env_specs(env)
    assert task.group_map(env) == {"agents": ["agent_0", "agent_1", "agent_2"]}
    assert task.max_steps(env) == 300
    assert task.has_render(env) == (importlib.util.find_spec("torchcodec") is not None)  # TorchRL 0.14's video writer
    assert set(task.observation_spec(env)["agents"].keys()) == {"observation"}  # the models' only input
    assert {"reached_goal", "cost", "mask"} <= set(task.info_spec(env)["agents", "info"].keys())
    assert task.state_spec(env)["state"].shape == (3 * (8 if name.endswith("continuous") else 5),)
    task.config["state"] = False  # critics and mixers on the agents' observations instead
    assert task.state_spec(env) is None
    observation = env.reset().get(("agents", "observation"))
    if name == "door_discrete":  # images channels last in [0, 1], as BenchMARL's CNN takes them
        assert observation.shape[-1] == 1 and observation.dtype == torch.float32
        assert 0.0 <= float(observation.min()) and float(observation.max()) <= 1.0 and float(observation.max()) > 0


def test_the_adapter_lets_benchmarl_run_on_this_torchrl():
    import benchmarl.algorithms.iql as benchmarl_iql
    from torchrl import collectors

    from sidewalk._torchrl import adapt_benchmarl

    adapt_benchmarl()  # idempotent: a second call changes nothing
    assert collectors.SyncDataCollector is collectors.Collector
    assert benchmarl_iql.QValueModule.keywords == {"strict_shape": False}


def small_experiment(algorithm: str, task: str, model: str, tmp_path: Path):
    from benchmarl import algorithms
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import CnnConfig, MlpConfig

    config = ExperimentConfig.get_from_yaml()
    config.max_n_iters, config.max_n_frames = 2, None
    config.loggers, config.render, config.save_folder = ["csv"], False, str(tmp_path)
    config.on_policy_collected_frames_per_batch = config.off_policy_collected_frames_per_batch = 100
    config.on_policy_minibatch_size, config.on_policy_n_minibatch_iters = 50, 1
    config.off_policy_n_optimizer_steps, config.off_policy_train_batch_size = 2, 16
    config.evaluation_interval, config.evaluation_episodes = 100, 2
    model_config = {"mlp": MlpConfig, "cnn": CnnConfig}[model].get_from_yaml()
    return Experiment(
        task=SidewalkTask[task.upper()].get_from_yaml(),
        algorithm_config=getattr(algorithms, f"{algorithm}Config").get_from_yaml(),
        model_config=model_config, critic_model_config=MlpConfig.get_from_yaml(), seed=0, config=config,
    )


@pytest.mark.parametrize(("algorithm", "task", "model"), [
    ("Mappo", "sidewalk_continuous", "mlp"),
    ("Iql", "sidewalk_discrete", "cnn"),
    ("Qmix", "door_discrete", "cnn"),
])
def test_benchmarl_trains_two_iterations_on_a_sidewalk_task(algorithm, task, model, tmp_path):
    torch.manual_seed(0)
    experiment = small_experiment(algorithm, task, model, tmp_path)
    before = [p.detach().clone() for p in experiment.policy.parameters()]
    experiment.run()
    assert experiment.n_iters_performed == 2 and experiment.total_frames == 200
    assert any(not torch.equal(a, b) for a, b in zip(before, experiment.policy.parameters(), strict=True))
    # BenchMARL's per-group info logging sees the outcome flags and the cost.
    logged = {path.stem for path in Path(experiment.folder_name).rglob("*.csv")}
    assert {"collection_agents_info_reached_goal", "collection_agents_info_cost"} <= logged, sorted(logged)


GUIDE = Path(__file__).resolve().parent.parent / "docs" / "guide" / "benchmarl.md"
FIRST_COMMAND = "python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous "


def guide_command() -> list[str]:
    """The guide's first command, as a user copies it."""
    line = next(line for line in GUIDE.read_text().splitlines() if line.startswith(FIRST_COMMAND))
    return shlex.split(line.partition("#")[0])


@pytest.mark.parametrize(("algorithm", "task", "budget"), [
    ("mappo", "door_continuous", ["experiment.on_policy_n_minibatch_iters=1"]),  # 1 of its 40 minibatch steps
    ("iql", "sidewalk_discrete", ["experiment.off_policy_n_optimizer_steps=1"]),  # 1 of its 64 optimiser steps
], ids=["on_policy", "off_policy"])
def test_the_guide_s_command_starts_each_kind_of_tuned_pair(algorithm, task, budget, tmp_path):
    # As written but for the pair and a small budget (one batch, one optimiser step; nothing of the batch or the
    # evaluation interval): a tuned file BenchMARL refuses at start fails here.
    command = guide_command()
    command[command.index("algorithm=mappo")] = f"algorithm={algorithm}"
    command[command.index("task=sidewalk/door_continuous")] = f"task=sidewalk/{task}"
    assert (task, algorithm) in tuned_pairs()
    out = subprocess.run(
        [sys.executable, *command[1:], "experiment.max_n_frames=2048", *budget], cwd=tmp_path, check=False,
        capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    rows = list(csv.reader(next(tmp_path.rglob("counters_total_frames.csv")).open()))
    assert [float(frames) for _, frames in rows] == [2048]  # one iteration of the tuned batch
    assert next(tmp_path.rglob("eval_reward_episode_reward_mean.csv")).read_text()  # BenchMARL evaluated it
    assert len(list(csv.reader(next(tmp_path.rglob("collection_agents_info_reached_goal.csv")).open()))) == 1


def test_the_comparison_table_writes_a_row_per_run_and_skips_finished_runs(tmp_path, monkeypatch):
    from sidewalk.bench import benchmarl_tasks

    with pytest.raises(SystemExit):
        benchmarl_tasks.parse_options(["--bm-tasks", "hallway"])  # names the valid tasks (argparse error)
    rows = benchmarl_tasks.run(algorithms=["mappo"], tasks=["zipper_continuous"], seeds=[0], frames=6000,
                               out=str(tmp_path), eval_episodes=4)
    assert [(row["algorithm"], row["task"], row["seed"], row["frames"]) for row in rows] == [
        ("mappo", "zipper_continuous", 0, 6000)]
    assert 0.0 <= rows[0]["team_success"] <= 1.0
    assert rows[0]["config"] == "default"  # no tuned settings for the pair: BenchMARL's defaults, and said so
    assert (tmp_path / "runs" / "mappo_zipper_continuous_vector_default_seed0.pt").exists()

    def no_training(*args, **kwargs):
        raise AssertionError("a finished run was trained again")

    monkeypatch.setattr(benchmarl_tasks, "train_and_evaluate", no_training)
    assert benchmarl_tasks.run(algorithms=["mappo"], tasks=["zipper_continuous"], seeds=[0], frames=6000,
                               out=str(tmp_path), eval_episodes=4) == rows
    assert benchmarl_tasks.parse_options(["--bm-no-state"])["state"] is False


def test_the_comparison_table_keeps_runs_without_the_state_apart(tmp_path, monkeypatch):
    from sidewalk.bench import benchmarl_tasks

    # A finished run that saw the state: the same run without it is a new row.
    old = {"algorithm": "mappo", "task": "zipper_continuous", "observation": "vector", "state": True,
           "protocol": "perturbed", "seed": 0, "frames": 6000, "wall_s": 1.0, "team_success": 1.0, "deadlock": 0.0,
           "agent_success": 1.0, "team_success_sampled": 1.0, "distinct_episodes": 4}
    pd.DataFrame([old]).to_csv(tmp_path / "benchmarl.csv", index=False)
    seen = []

    def fake_run(algorithm, task, seed, frames, out, eval_episodes, grid_observation, state, config):
        seen.append(state)
        return {**old, "state": state, "team_success": 0.5}

    monkeypatch.setattr(benchmarl_tasks, "train_and_evaluate", fake_run)
    for state in (True, False):
        rows = benchmarl_tasks.run(algorithms=["mappo"], tasks=["zipper_continuous"], seeds=[0], frames=6000,
                                   out=str(tmp_path), eval_episodes=4, state=state)
    assert seen == [False]
    assert sorted((row["state"], row["team_success"]) for row in rows) == [(False, 0.5), (True, 1.0)]
    assert "| mappo | zipper_continuous | vector | no | perturbed | default | 1 |" in benchmarl_tasks.format_rows(rows)


def test_the_comparison_table_keeps_runs_of_the_paper_s_fixed_starts_apart(tmp_path, monkeypatch):
    from sidewalk.bench import benchmarl_tasks

    # A row of the table made before the protocol (no protocol column): its worlds started from the fixed starts.
    old = {"algorithm": "mappo", "task": "zipper_continuous", "observation": "vector", "state": True, "seed": 0,
           "frames": 6000, "wall_s": 1.0, "team_success": 1.0, "deadlock": 0.0, "agent_success": 1.0,
           "team_success_sampled": 1.0}
    pd.DataFrame([old]).to_csv(tmp_path / "benchmarl.csv", index=False)
    trained = []

    def fake_run(algorithm, task, seed, frames, out, eval_episodes, grid_observation, state, config):
        trained.append(task)
        return {**old, "protocol": "perturbed", "team_success": 0.5, "distinct_episodes": 200}

    monkeypatch.setattr(benchmarl_tasks, "train_and_evaluate", fake_run)
    rows = benchmarl_tasks.run(algorithms=["mappo"], tasks=["zipper_continuous"], seeds=[0], frames=6000,
                               out=str(tmp_path), eval_episodes=4)
    assert trained == ["zipper_continuous"]  # the task's worlds are perturbed now: a new row
    table = benchmarl_tasks.format_rows(rows)
    assert "| nominal | default | 1 | 6,000 | 1 | 1.00 (1.00) | 1.00 | 0.00 | – |" in table
    assert "| perturbed | default | 1 | 6,000 | 1 | 0.50 (0.50) | 1.00 | 0.00 | 200 |" in table


def test_the_command_line_s_help_names_the_tasks_and_the_tuned_settings(capsys):
    from sidewalk.interop.benchmarl.__main__ import main

    assert main(["--help"]) == 0  # Hydra's own --help composed the config first and failed without a task
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m sidewalk.interop.benchmarl algorithm=ALGORITHM task=TASK")
    assert "sidewalk/door_continuous   (tuned: ippo, mappo)" in out and "sidewalk/zipper_discrete\n" in out
    assert "algorithms: iddpg, ippo, iql," in out and "tuned=default" in out


@pytest.mark.parametrize(("args", "error"), [
    (["algorithm=mappo", "task=sidewalk/door_continous"],
     ("error: task=sidewalk/door_continous is not a BenchMARL task (did you mean sidewalk/door_continuous?); "
      "the sidewalk's tasks: sidewalk/sidewalk_continuous, sidewalk/sidewalk_discrete,")),
    (["-m", "algorithm=iql,vdn", "task=sidewalk/sidewalk_discrete,sidewalk/dor_discrete"],  # every value of a sweep
     "error: task=sidewalk/dor_discrete is not a BenchMARL task (did you mean sidewalk/door_discrete?)"),
    (["algorithm=mapo", "task=sidewalk/door_continuous"],
     "error: algorithm=mapo is not a BenchMARL algorithm (did you mean mappo?); valid: iddpg, ippo, iql,"),
])
def test_a_misspelt_task_or_algorithm_is_one_error_naming_the_sidewalk_s_tasks(args, error, capsys):
    from sidewalk.interop.benchmarl.__main__ import main

    assert main(args) == 2  # before Hydra, which listed ~40 VMAS and PettingZoo tasks and none of ours
    err = capsys.readouterr().err
    assert err.startswith(error) and err.count("\n") == 1, err


def tuned_pairs():
    from sidewalk.interop.benchmarl import TUNED_DIR

    return sorted((path.parent.name, path.stem) for path in TUNED_DIR.glob("*/*.yaml"))


def test_tuned_settings_ship_for_the_issue_s_pairs():
    # The continuous sidewalk has none: BenchMARL's defaults learn it (docs/guide/benchmarl.md).
    assert tuned_pairs() == [("door_continuous", "ippo"), ("door_continuous", "mappo"), ("sidewalk_discrete", "iql"),
                             ("sidewalk_discrete", "qmix"), ("sidewalk_discrete", "vdn")]


@pytest.mark.parametrize(("task", "algorithm"), tuned_pairs())
def test_the_tuned_settings_load_and_apply_in_python_and_on_the_command_line(task, algorithm):
    from benchmarl.algorithms import algorithm_config_registry
    from benchmarl.hydra_config import load_experiment_config_from_hydra
    from benchmarl.utils import _class_from_name
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from sidewalk.interop.benchmarl import CONFIG_DIR, TUNED_DIR, experiment_configs

    tuned = OmegaConf.to_container(OmegaConf.load(TUNED_DIR / task / f"{algorithm}.yaml"))
    configs = experiment_configs(SidewalkTask[task.upper()], algorithm)
    defaults = experiment_configs(SidewalkTask[task.upper()], algorithm, tuned=False)
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        cfg = compose("config", overrides=[f"algorithm={algorithm}", f"task=sidewalk/{task}"])
        cfg_default = compose("config", overrides=[f"algorithm={algorithm}", f"task=sidewalk/{task}", "tuned=default"])
    fields = {"experiment": "config", "algorithm": "algorithm_config", "model": "model_config",
              "critic_model": "critic_model_config"}
    changed = 0
    for section, values in tuned.items():
        for key, value in values.items():
            if section == "task":  # the task's env settings, over its own
                assert configs["task"].config[key] == {**defaults["task"].config[key], **value}
                assert cfg.task[key] == configs["task"].config[key]
                continue
            assert cfg[section][key] == value, (section, key)
            value = _class_from_name(value) if key.endswith("class") else value  # torch.nn.ReLU: a class in Python
            assert getattr(configs[fields[section]], key) == value, (section, key)
            changed += getattr(defaults[fields[section]], key) != value
            default = cfg_default[section][key]  # tuned=default: BenchMARL's
            assert (_class_from_name(default) if key.endswith("class") else default) == getattr(
                defaults[fields[section]], key)
    assert changed >= 5  # the tuned file changes BenchMARL's defaults, not restates them
    # BenchMARL's own start checks (the evaluation interval a multiple of the batch), and an evaluation at the end.
    on_policy = algorithm_config_registry[algorithm].on_policy()
    for config in (configs["config"], load_experiment_config_from_hydra(cfg.experiment)):
        config.validate(on_policy)
        assert config.get_max_n_frames(on_policy) % config.evaluation_interval == 0, (task, algorithm)


def test_a_misspelt_tuned_setting_is_an_error_naming_the_valid_ones(tmp_path, monkeypatch):
    from sidewalk.interop import benchmarl

    (tmp_path / "door_continuous").mkdir()
    (tmp_path / "door_continuous" / "mappo.yaml").write_text("experiment:\n  lrr: 0.001\n")
    monkeypatch.setattr(benchmarl, "TUNED_DIR", tmp_path)
    with pytest.raises(TypeError, match=r"unknown parameter 'lrr' \(did you mean 'lr'\?\) for experiment in"):
        benchmarl.experiment_configs(SidewalkTask.DOOR_CONTINUOUS, "mappo")
