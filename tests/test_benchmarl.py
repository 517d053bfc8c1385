"""The sidewalk as BenchMARL tasks (sidewalk.interop.benchmarl): configs that match the self-play presets, specs as
BenchMARL reads them, its command line, BenchMARL's MAPPO (continuous) and IQL / QMIX (grid images, CNN) training two
small iterations, and the dueling Q-value model (layers/dueling_mlp) that the grid's tuned settings choose. The
README's test command installs BenchMARL, so these run in .ci/run."""

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
    ("vdn", "door_discrete", ["experiment.off_policy_n_optimizer_steps=1"]),  # 1 of its 64 optimiser steps
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


def test_the_comparison_table_keeps_runs_of_another_model_apart(tmp_path, monkeypatch):
    """A tuned grid row made with BenchMARL's MLP (before the dueling model; no model column) is not today's tuned
    run, which chooses the dueling model: that run trains, and both rows stay."""
    from sidewalk.bench import benchmarl_tasks

    old = {"algorithm": "iql", "task": "sidewalk_discrete", "observation": "vector", "state": True,
           "protocol": "perturbed", "config": "tuned", "seed": 0, "frames": 245_760, "wall_s": 1.0, "team_success": 0.9,
           "deadlock": 0.1, "agent_success": 0.9, "team_success_sampled": 0.9, "distinct_episodes": 78}
    pd.DataFrame([old]).to_csv(tmp_path / "benchmarl.csv", index=False)
    trained = []

    def fake_training(algorithm, task, seed, *args):
        trained.append((algorithm, task, seed))
        return {**old, "model": "dueling_mlp", "team_success": 1.0}

    monkeypatch.setattr(benchmarl_tasks, "train_and_evaluate", fake_training)
    rows = benchmarl_tasks.run(algorithms=["iql"], tasks=["sidewalk_discrete"], seeds=[0], out=str(tmp_path))
    assert trained == [("iql", "sidewalk_discrete", 0)]
    assert sorted((row["model"], row["team_success"]) for row in rows) == [("dueling_mlp", 1.0), ("mlp", 0.9)]


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
    assert "| mappo | zipper_continuous | vector | no | perturbed | default | mlp | 1 |" in benchmarl_tasks.format_rows(rows)


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
    assert "| nominal | default | mlp | 1 | 6,000 | 1 | 1.00 (1.00) | 1.00 | 0.00 | – |" in table
    assert "| perturbed | default | mlp | 1 | 6,000 | 1 | 0.50 (0.50) | 1.00 | 0.00 | 200 |" in table


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
    (["algorithm=iql", "task=sidewalk/door_continuous", "model=layers/dueling_mpl"],
     ("error: model=layers/dueling_mpl is not a BenchMARL model (did you mean layers/dueling_mlp?); valid: layers/cnn, "
      "layers/deepsets, layers/dueling_mlp, layers/gnn, layers/gru, layers/lstm, layers/mlp, sequence")),
    # A tuned file's model merges over the command line's: layers/mlp would run as the dueling model, silently.
    (["-m", "algorithm=mappo,iql", "task=sidewalk/sidewalk_discrete", "model=layers/mlp"],
     ("error: model=layers/mlp: the tuned settings of sidewalk/sidewalk_discrete and iql choose model "
      "layers/dueling_mlp; add tuned=default to run BenchMARL's defaults with another")),
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
    grid = [(task, algorithm) for task in ("door_discrete", "sidewalk_discrete") for algorithm in ("iql", "qmix", "vdn")]
    assert tuned_pairs() == [("door_continuous", "ippo"), ("door_continuous", "mappo"), *grid]
    for task, algorithm in tuned_pairs():  # the grid's Q-learners take the dueling model, the rest BenchMARL's MLP
        expected = {"model": "dueling_mlp"} if task.endswith("discrete") else {}
        assert SidewalkTask[task.upper()].tuned_models(algorithm) == expected, (task, algorithm)
    assert tuned(SidewalkTask.DOOR_DISCRETE, "qmix") == tuned(SidewalkTask.SIDEWALK_DISCRETE, "qmix")  # the same


def tuned(task, algorithm):
    from omegaconf import OmegaConf

    from sidewalk.interop.benchmarl import TUNED_DIR

    return OmegaConf.to_container(OmegaConf.load(TUNED_DIR / task.name.lower() / f"{algorithm}.yaml"))


@pytest.mark.parametrize(("task", "algorithm"), tuned_pairs())
def test_the_tuned_settings_load_and_apply_in_python_and_on_the_command_line(task, algorithm):
    from benchmarl.algorithms import algorithm_config_registry
    from benchmarl.hydra_config import load_experiment_config_from_hydra, load_model_config_from_hydra
    from benchmarl.models import model_config_registry
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
    chosen = SidewalkTask[task.upper()].tuned_models(algorithm)  # a model the file chooses: its fields, not the MLP's
    for section in ("model", "critic_model"):  # the same model from the command line as from Python
        assert type(configs[fields[section]]) is model_config_registry[chosen.get(section, "mlp")]
        assert load_model_config_from_hydra(cfg[section]) == configs[fields[section]], section
    changed = 0
    for section, values in tuned.items():
        if section == "defaults":
            continue
        for key, value in values.items():
            if section == "task":  # the task's env settings, over its own
                assert configs["task"].config[key] == {**defaults["task"].config[key], **value}
                assert cfg.task[key] == configs["task"].config[key]
                continue
            assert cfg[section][key] == value, (section, key)
            value = _class_from_name(value) if key.endswith("class") else value  # torch.nn.ReLU: a class in Python
            assert getattr(configs[fields[section]], key) == value, (section, key)
            if section in chosen:
                continue
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


def test_a_misspelt_tuned_model_is_an_error_naming_the_valid_ones(tmp_path, monkeypatch):
    from sidewalk.interop import benchmarl

    (tmp_path / "sidewalk_discrete").mkdir()
    tuned_file = tmp_path / "sidewalk_discrete" / "iql.yaml"
    monkeypatch.setattr(benchmarl, "TUNED_DIR", tmp_path)
    tuned_file.write_text("defaults:\n  - /model/layers/dueling_mpl@model\n  - _self_\n")
    valid = "cnn, deepsets, dueling_mlp, gnn, gru, lstm, mlp"
    with pytest.raises(ValueError, match=rf"unknown model 'dueling_mpl' \(did you mean 'dueling_mlp'\?\) for .*iql.yaml; "
                                         rf"valid: {valid}$"):
        benchmarl.experiment_configs(SidewalkTask.SIDEWALK_DISCRETE, "iql")
    # Hydra refuses an override in a file its defaults list reaches through ${task}/${algorithm}: named, not ignored.
    tuned_file.write_text("defaults:\n  - override /model: layers/dueling_mlp\n")
    with pytest.raises(ValueError, match=r"defaults entry \{'override /model': 'layers/dueling_mlp'\} is not one a "
                                         r"tuned file may have; valid: /model/layers/<model>@model, "):
        benchmarl.experiment_configs(SidewalkTask.SIDEWALK_DISCRETE, "iql")


def dueling_model(share_params: bool, input_has_agent_dim: bool = True, centralised: bool = False,
                  num_cells: tuple[int, ...] = (6,)):
    """A dueling model of 3 agents, 5 features each (or a state of 7), 4 actions: as BenchMARL builds a Q-network."""
    from torchrl.data import Categorical, Composite, Unbounded

    from sidewalk.interop.benchmarl import DuelingMlpConfig

    def group(**leaves):
        return Composite({"agents": Composite(leaves, shape=(3,))})

    config = DuelingMlpConfig.get_from_yaml()
    config.num_cells, config.hidden = list(num_cells), 8
    return config.get_model(
        input_spec=group(observation=Unbounded(shape=(3, 5))) if input_has_agent_dim else Composite(
            state=Unbounded(shape=(7,))),
        output_spec=group(action_value=Unbounded(shape=(3, 4))) if not (share_params and centralised) else Composite(
            action_value=Unbounded(shape=(4,))),
        agent_group="agents", input_has_agent_dim=input_has_agent_dim, n_agents=3, centralised=centralised,
        share_params=share_params, device="cpu", action_spec=group(action=Categorical(4, shape=(3,))),
    )


@pytest.mark.parametrize("share_params", [True, False], ids=["shared", "per_agent"])
@pytest.mark.parametrize("num_cells", [(), (6,)], ids=["no_trunk", "trunk"])
def test_the_dueling_model_s_q_is_v_plus_a_minus_the_mean_of_a(share_params, num_cells):
    from tensordict import TensorDict

    torch.manual_seed(0)
    model = dueling_model(share_params, num_cells=num_cells)
    observation = torch.linspace(-2.0, 2.0, 2 * 3 * 5).reshape(2, 3, 5)  # 2 worlds, 3 agents, 5 features
    q = model(TensorDict({"agents": {"observation": observation}}, batch_size=[2]))["agents", "action_value"]
    assert q.shape == (2, 3, 4)
    net = model.mlp.get_stateful_net()  # one agent's DuelingMlpNet; its weights are each agent's slice of params
    for agent in range(3):
        weights = model.mlp.params if share_params else model.mlp.params[agent]
        with weights.to_module(net):
            features = net.trunk(observation[:, agent])
            value, advantage = net.head.value(features), net.head.advantage(features)
        assert value.shape == (2, 1) and advantage.shape == (2, 4)
        torch.testing.assert_close(q[:, agent], value + advantage - advantage.mean(-1, keepdim=True))
    assert not torch.allclose(q[:, 0], q[:, 1])  # the agents' observations differ, so do their values


def test_the_dueling_model_has_one_set_of_weights_shared_or_one_per_agent():
    from tensordict import TensorDict

    from sidewalk.interop.benchmarl.models import DuelingMlpNet

    shared, per_agent = dueling_model(share_params=True), dueling_model(share_params=False)
    one_set = {name: p.shape for name, p in DuelingMlpNet(5, 4, [6], 8, "cpu").named_parameters()}
    assert {name: p.shape for name, p in shared.mlp.params.flatten_keys(".").items()} == one_set
    assert {name: p.shape for name, p in per_agent.mlp.params.flatten_keys(".").items()} == {
        name: (3, *shape) for name, shape in one_set.items()}
    assert sum(p.numel() for p in per_agent.parameters()) == 3 * sum(p.numel() for p in shared.parameters())
    # A centralised model on the state (BenchMARL's critics and mixers): one network, or one per agent, as its MLP.
    state = TensorDict({"state": torch.ones(2, 7)}, batch_size=[2])
    for share_params, networks, shape in [(True, 1, (2, 4)), (False, 3, (2, 3, 4))]:
        model = dueling_model(share_params, input_has_agent_dim=False, centralised=True)
        assert len(model.mlp) == networks and all(isinstance(net, DuelingMlpNet) for net in model.mlp)
        assert model(state.clone())[model.out_key].shape == shape
    # Centralised over the agents' observations, shared: BenchMARL's one output for the group, without the agent axis.
    model = dueling_model(True, centralised=True)
    observation = TensorDict({"agents": {"observation": torch.ones(2, 3, 5)}}, batch_size=[2])
    assert model(observation)["action_value"].shape == (2, 4)


@pytest.mark.parametrize("algorithm", ["iql", "qmix"])
def test_benchmarl_trains_the_tuned_dueling_model_two_iterations_from_python(algorithm, tmp_path):
    from benchmarl.experiment import Experiment

    from sidewalk.interop.benchmarl import experiment_configs
    from sidewalk.interop.benchmarl.models import DuelingMlp

    torch.manual_seed(0)
    configs = experiment_configs(SidewalkTask.SIDEWALK_DISCRETE, algorithm)
    config = configs["config"]  # the tuned settings at a small budget: 2 batches of 64 frames from 4 worlds
    config.max_n_iters, config.max_n_frames = 2, None
    config.loggers, config.render, config.save_folder = ["csv"], False, str(tmp_path)
    config.off_policy_collected_frames_per_batch, config.off_policy_n_envs_per_worker = 64, 4
    config.off_policy_n_optimizer_steps, config.off_policy_train_batch_size = 2, 16
    config.evaluation_interval, config.evaluation_episodes = 64, 2
    experiment = Experiment(**configs, seed=0)
    assert any(isinstance(module, DuelingMlp) for module in experiment.policy.modules())
    before = [p.detach().clone() for p in experiment.policy.parameters()]
    experiment.run()
    assert experiment.n_iters_performed == 2 and experiment.total_frames == 128
    assert any(not torch.equal(a, b) for a, b in zip(before, experiment.policy.parameters(), strict=True))


@pytest.mark.parametrize("algorithm", ["iql", "qmix"])
def test_the_guide_s_command_trains_the_tuned_dueling_model_two_iterations(algorithm, tmp_path):
    # As the guide writes it but for the pair and two batches of the tuned 2,048 frames, one optimiser step each.
    command = guide_command()
    command[command.index("algorithm=mappo")] = f"algorithm={algorithm}"
    command[command.index("task=sidewalk/door_continuous")] = "task=sidewalk/sidewalk_discrete"
    out = subprocess.run(
        [sys.executable, *command[1:], "experiment.max_n_frames=4096", "experiment.off_policy_n_optimizer_steps=1"],
        cwd=tmp_path, check=False, capture_output=True, text=True, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    rows = list(csv.reader(next(tmp_path.rglob("counters_total_frames.csv")).open()))
    assert [float(frames) for _, frames in rows] == [2048, 4096]
    # BenchMARL names a run's folder <algorithm>_<task>_<model class>_...: the tuned file's model ran.
    assert [path.name for path in tmp_path.rglob(f"{algorithm}_sidewalk_discrete_duelingmlp_*") if path.is_dir()]
