"""BenchMARL's algorithms on the sidewalk's BenchMARL tasks (``sidewalk.interop.benchmarl``): each run at the
settings shipped with the tasks (``--bm-config tuned``: BenchMARL's defaults with the pair's
``conf/tuned/sidewalk/<task>/<algorithm>.yaml`` over them, its frame budget) or at BenchMARL's defaults alone
(``--bm-config default``: its ``base_experiment.yaml``, each algorithm's YAML; the MLP model, the CNN on grid images),
the tasks' reward (the self-play presets'), then evaluated as our learners are: one episode in each of 256 fresh
worlds (``sidewalk.evaluate``, the evaluation seed stream ``runners/main.py`` uses), greedy.

    python runners/bench.py benchmarl                                         # the table in docs/guide/benchmarl.md
    python runners/bench.py benchmarl --bm-algorithms mappo --bm-tasks sidewalk_continuous --bm-seeds 0
    python runners/bench.py benchmarl --bm-algorithms mappo --bm-tasks sidewalk_continuous --bm-no-state
    python runners/bench.py benchmarl --bm-config default --bm-frames 240000               # BenchMARL's defaults
    python -m sidewalk.bench.benchmarl_tasks --bm-out results/benchmarl       # the same, as a module

Each finished run is one row of ``<out>/benchmarl.csv`` (algorithm, task, observation, state, config, seed, frames,
wall-clock, final team success greedy, deadlock, agent success, team success with sampled actions), written whole and
renamed after every run; a run already in it is skipped, so an interrupted table resumes where it stopped.
BenchMARL's own logs and checkpoints go to ``<out>/runs``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import pandas as pd
import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

# The grid: on-policy and off-policy continuous learners, and value-decomposition learners on the grid.
DEFAULT_RUNS = {
    "continuous": (("mappo", "ippo", "masac"), ("sidewalk_continuous", "door_continuous")),
    "discrete": (("iql", "vdn", "qmix"), ("sidewalk_discrete", "door_discrete")),
}
ALGORITHM_CONFIGS = {
    "mappo": "MappoConfig", "ippo": "IppoConfig", "masac": "MasacConfig", "isac": "IsacConfig",
    "maddpg": "MaddpgConfig", "iddpg": "IddpgConfig", "iql": "IqlConfig", "vdn": "VdnConfig", "qmix": "QmixConfig",
}
COLUMNS = ["algorithm", "task", "observation", "state", "protocol", "config", "model", "seed", "frames", "wall_s",
           "team_success", "deadlock", "agent_success", "team_success_sampled", "distinct_episodes"]


def task_protocol(task_config: dict[str, Any]) -> str:
    """How a task's worlds differ (docs/guide/evaluation.md): ``perturbed`` where its env moves starts or goals (the
    tasks' configs give the perturbed protocol's bounds since 2026-11-28), else ``nominal``. Rows of a table made
    before have no protocol: they were nominal."""
    from sidewalk.schema import PROTOCOL_ENV_FIELDS  # the env parameters a protocol sets, each domain's

    env = task_config.get("env") or {}
    return "perturbed" if any(env.get(key) for fields in PROTOCOL_ENV_FIELDS.values() for key in fields) else "nominal"


def parse_options(argv: list[str]) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="runners/bench.py benchmarl", add_help=False)
    parser.add_argument("--bm-algorithms", nargs="+", choices=sorted(ALGORITHM_CONFIGS))
    parser.add_argument("--bm-tasks", nargs="+")
    parser.add_argument("--bm-seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--bm-config", choices=("tuned", "default"), default="tuned",
                        help="tuned: the settings shipped with the tasks (conf/tuned/sidewalk/<task>/<algorithm>.yaml) "
                             "over BenchMARL's defaults; default: BenchMARL's defaults alone")
    parser.add_argument("--bm-frames", type=int,
                        help="frames per run (BenchMARL's max_n_frames); default: the tuned config's, or 240,000")
    parser.add_argument("--bm-out", default="results/benchmarl")
    parser.add_argument("--bm-eval-episodes", type=int, default=256)
    parser.add_argument("--bm-grid-observation", choices=("image", "vector"),
                        help="what the grid tasks' agents see: images (BenchMARL's CNN) or vectors (its MLP); "
                             "default: the config's (tuned: vectors, BenchMARL's defaults: images)")
    parser.add_argument("--bm-no-state", action="store_true",
                        help="withhold the tasks' root state (task config state: false): critics and mixers read the "
                             "agents' observations")
    args, _ = parser.parse_known_args(argv)
    from sidewalk.interop.benchmarl import SidewalkTask

    valid = [task.name.lower() for task in SidewalkTask]
    bad = [task for task in args.bm_tasks or [] if task not in valid]
    if bad:
        parser.error(f"--bm-tasks {bad} are not sidewalk tasks; valid: {valid}")
    if (args.bm_frames is not None and args.bm_frames < 1) or args.bm_eval_episodes < 1:
        parser.error("--bm-frames and --bm-eval-episodes must be positive")
    return {"algorithms": args.bm_algorithms, "tasks": args.bm_tasks, "seeds": args.bm_seeds,
            "frames": args.bm_frames, "out": args.bm_out, "eval_episodes": args.bm_eval_episodes,
            "grid_observation": args.bm_grid_observation, "state": not args.bm_no_state, "config": args.bm_config}


def planned_runs(algorithms: list[str] | None, tasks: list[str] | None, seeds: list[int]) -> list[tuple[str, str, int]]:
    """(algorithm, task, seed) in the order they run: seed-major, so a partial table has every setting's first seed.
    An algorithm is paired with the tasks whose actions it supports (BenchMARL's ``supports_*_actions``)."""
    from benchmarl.algorithms import algorithm_config_registry

    from sidewalk.interop.benchmarl import SidewalkTask

    pairs = []
    for domain, (domain_algorithms, domain_tasks) in DEFAULT_RUNS.items():
        for task in tasks or domain_tasks:
            if SidewalkTask[task.upper()].get_from_yaml().config["domain"] != domain:
                continue
            supports = "supports_continuous_actions" if domain == "continuous" else "supports_discrete_actions"
            pairs += [(algorithm, task) for algorithm in algorithms or domain_algorithms
                      if getattr(algorithm_config_registry[algorithm], supports)()]
    return [(algorithm, task, seed) for seed in seeds for algorithm, task in pairs]


def run_settings(algorithm: str, task_name: str, config: str, frames: int | None, grid_observation: str | None,
                 state: bool = True) -> dict[str, Any]:
    """A run's ``Experiment`` arguments (``sidewalk.interop.benchmarl.experiment_configs``) with the table's frame
    budget, grid observation and root state: the config's where not given (BenchMARL's defaults: 240,000 frames,
    images)."""
    from benchmarl.models import CnnConfig

    from sidewalk.interop.benchmarl import SidewalkTask, experiment_configs

    settings = experiment_configs(SidewalkTask[task_name.upper()], algorithm, tuned=config == "tuned")
    task = settings["task"]
    task.config["state"] = state
    if task.config["domain"] == "discrete":
        task.config["env"]["observation"] = grid_observation or task.config["env"].get("observation", "image")
        if task.config["env"]["observation"] == "image":  # BenchMARL's MLP refuses images, its CNN vectors
            settings["model_config"] = CnnConfig.get_from_yaml()
            if not state:  # the critic reads the agents' images, not the state
                settings["critic_model_config"] = CnnConfig.get_from_yaml()
    settings["config"].max_n_frames = frames or (240_000 if config == "default" else settings["config"].max_n_frames)
    return settings


def model_of(settings: dict[str, Any]) -> str:
    """The name BenchMARL's model registry gives the run's (agents') model: ``mlp``, ``cnn``, ``dueling_mlp``, ..."""
    from benchmarl.models import model_config_registry

    names = {config_class: name for name, config_class in model_config_registry.items()}
    return names.get(type(settings["model_config"]), type(settings["model_config"]).__name__)


def observation_of(task_config: dict[str, Any]) -> str:
    return task_config["env"].get("observation", "image") if task_config["domain"] == "discrete" else "vector"


def train_and_evaluate(algorithm: str, task_name: str, seed: int, frames: int | None, out: Path, eval_episodes: int,
                       grid_observation: str | None = None, state: bool = True,
                       config_name: str = "tuned") -> dict[str, Any]:
    """One BenchMARL run at ``config_name``'s settings (``run_settings``), then our evaluation of its greedy
    policy."""
    from benchmarl.experiment import Experiment
    from torchrl.envs import Compose, TransformedEnv

    from sidewalk.evaluate import evaluate
    from sidewalk.experiment import EVAL_SEED_OFFSET

    settings = run_settings(algorithm, task_name, config_name, frames, grid_observation, state)
    task, config = settings["task"], settings["config"]
    config.loggers, config.render, config.evaluation = ["csv"], False, False
    config.checkpoint_at_end, config.keep_checkpoints_num = False, 1
    config.save_folder = str(out / "runs")
    (out / "runs").mkdir(parents=True, exist_ok=True)
    experiment = Experiment(**settings, seed=seed)
    start = time.perf_counter()
    experiment.run()
    wall_s = time.perf_counter() - start
    view = task.get_env_fun(eval_episodes, experiment.continuous_actions, seed + EVAL_SEED_OFFSET, "cpu")()
    env = TransformedEnv(view, Compose(*task.get_env_transforms(view)))
    metrics = evaluate(env, experiment.policy, seed=seed + EVAL_SEED_OFFSET)
    # The same worlds with the policy's actions sampled, as BenchMARL collects: a deterministic policy can fail where
    # its sampling succeeds (and the other way round).
    sampled = evaluate(env, _Sampling(experiment.policy), seed=seed + EVAL_SEED_OFFSET, deterministic=False)
    observation = observation_of(task.config)
    name = f"{algorithm}_{task_name}_{observation}{'' if state else '_nostate'}_{config_name}_seed{seed}.pt"
    torch.save(experiment.policy.state_dict(), out / "runs" / name)
    return {"algorithm": algorithm, "task": task_name, "observation": observation, "state": state,
            "protocol": task_protocol(task.config), "config": config_name, "model": model_of(settings), "seed": seed,
            "frames": experiment.total_frames,
            "wall_s": round(wall_s, 1), "team_success": metrics["team/success_rate"],
            "deadlock": metrics["deadlock_rate"], "agent_success": metrics["success_rate"],
            "team_success_sampled": sampled["team/success_rate"], "distinct_episodes": metrics["distinct_episodes"]}


class _Sampling(TensorDictModuleBase):
    """``policy`` with its actions sampled (TorchRL's RANDOM exploration), whatever the caller's context."""

    def __init__(self, policy: TensorDictModuleBase) -> None:
        super().__init__()
        self.policy, self.in_keys, self.out_keys = policy, policy.in_keys, policy.out_keys

    def forward(self, tensordict):
        with set_exploration_type(ExplorationType.RANDOM):
            return self.policy(tensordict)


def run(algorithms: list[str] | None = None, tasks: list[str] | None = None, seeds: list[int] = (0, 1, 2),
        frames: int | None = None, out: str = "results/benchmarl", eval_episodes: int = 256,
        grid_observation: str | None = None, state: bool = True, config: str = "tuned") -> list[dict[str, Any]]:
    from sidewalk.interop.benchmarl import SidewalkTask
    from sidewalk.run_folder import atomic_write

    torch.set_num_threads(1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    table_path = out_dir / "benchmarl.csv"
    table = pd.read_csv(table_path) if table_path.exists() else pd.DataFrame(columns=COLUMNS)
    table = with_defaults(table).reindex(columns=COLUMNS)  # an old table's columns in today's order
    for algorithm, task, seed in planned_runs(algorithms, tasks, list(seeds)):
        # a pair without tuned settings runs at BenchMARL's defaults, and its row says so
        applied = config if algorithm in SidewalkTask[task.upper()].tuned_algorithms() else "default"
        settings = run_settings(algorithm, task, applied, frames, grid_observation, state)
        observation, budget = observation_of(settings["task"].config), settings["config"].max_n_frames
        same = (table.algorithm == algorithm) & (table.task == task) & (table.seed == seed) & (
            table.observation == observation) & (table.state == state) & (
            table.protocol == task_protocol(settings["task"].config)) & (table.config == applied) & (
            table.model == model_of(settings))
        if (table[same].frames >= budget).any():
            continue
        print(f"benchmarl: {algorithm} on sidewalk/{task} ({observation}{'' if state else ', no state'}, {applied} "
              f"config), seed {seed}, {budget:,} frames", flush=True)
        row = train_and_evaluate(algorithm, task, seed, frames, out_dir, eval_episodes, grid_observation, state,
                                 applied)
        table = pd.concat([table[~same], pd.DataFrame([row])], ignore_index=True)
        atomic_write(table_path, lambda tmp, rows=table: rows.to_csv(tmp, index=False))
    return table.to_dict("records")


def with_defaults(table: pd.DataFrame) -> pd.DataFrame:
    """Rows made before a column existed read as what they were: ``nominal`` before the protocol, BenchMARL's
    ``default`` settings before the tuned configs, BenchMARL's MLP (CNN on images) before the dueling model."""
    for column, old in (("protocol", "nominal"), ("config", "default")):
        table[column] = table[column].fillna(old) if column in table else old
    models = table["observation"].map({"image": "cnn"}).fillna("mlp") if len(table) else pd.Series(dtype=str)
    table["model"] = table["model"].fillna(models) if "model" in table else models
    return table


def format_rows(rows: list[dict[str, Any]]) -> str:
    """Mean over seeds of each setting, with the seeds' values: the docs' table."""
    from sidewalk.report.tables import distinct_range

    if not rows:
        return "(no runs)"
    table = with_defaults(pd.DataFrame(rows))
    header = ("algorithm", "task", "observation", "state", "protocol", "config", "model", "seeds", "frames",
              "wall-clock (s, mean)",
              "team success, greedy (per seed)", "team success, sampled (mean)", "deadlock (mean)",
              "distinct episodes")
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    setting = ["algorithm", "task", "observation", "state", "protocol", "config", "model"]
    for (algorithm, task, observation, state, protocol, config, model), group in table.groupby(setting, sort=False):
        per_seed = ", ".join(f"{value:.2f}" for value in group.sort_values("seed").team_success)
        distinct = distinct_range(group.get("distinct_episodes", []))
        lines.append(f"| {algorithm} | {task} | {observation} | {'yes' if state else 'no'} | {protocol} | {config} "
                     f"| {model} "
                     f"| {len(group)} | {int(group.frames.mean()):,} | {group.wall_s.mean():.0f} "
                     f"| {group.team_success.mean():.2f} ({per_seed}) "
                     f"| {group.team_success_sampled.mean():.2f} | {group.deadlock.mean():.2f} | {distinct} |")
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    print(format_rows(run(**parse_options(sys.argv[1:]))))
