"""BenchMARL's algorithms on the sidewalk's BenchMARL tasks (``sidewalk.interop.benchmarl``): each run at
BenchMARL's defaults (its ``base_experiment.yaml``, each algorithm's YAML; the MLP model, the CNN on grid images)
and the tasks' reward (the self-play presets'), for a frame budget, then evaluated as our learners are: one episode
in each of 256 fresh worlds (``sidewalk.evaluate``, the evaluation seed stream ``runners/main.py`` uses), greedy.

    python runners/bench.py benchmarl                                         # the table in docs/guide/benchmarl.md
    python runners/bench.py benchmarl --bm-algorithms mappo --bm-tasks sidewalk_continuous --bm-seeds 0
    python runners/bench.py benchmarl --bm-algorithms mappo --bm-tasks sidewalk_continuous --bm-no-state
    python -m sidewalk.bench.benchmarl_tasks --bm-out results/benchmarl       # the same, as a module

Each finished run is one row of ``<out>/benchmarl.csv`` (algorithm, task, observation, state, seed, frames,
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
COLUMNS = ["algorithm", "task", "observation", "state", "protocol", "seed", "frames", "wall_s", "team_success",
           "deadlock", "agent_success", "team_success_sampled", "distinct_episodes"]
JITTER_KEYS = ("start_jitter_rows", "goal_jitter_rows", "start_jitter_m", "goal_jitter_m", "heading_jitter_rad")


def task_protocol(task_config: dict[str, Any]) -> str:
    """How a task's worlds differ (docs/guide/evaluation.md): ``perturbed`` where its env moves starts or goals (the
    tasks' configs give the perturbed protocol's bounds since 2026-11-28), else ``nominal``. Rows of a table made
    before have no protocol: they were nominal."""
    env = task_config.get("env") or {}
    return "perturbed" if any(env.get(key) for key in JITTER_KEYS) else "nominal"


def parse_options(argv: list[str]) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="runners/bench.py benchmarl", add_help=False)
    parser.add_argument("--bm-algorithms", nargs="+", choices=sorted(ALGORITHM_CONFIGS))
    parser.add_argument("--bm-tasks", nargs="+")
    parser.add_argument("--bm-seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--bm-frames", type=int, default=240_000, help="frames per run (BenchMARL's max_n_frames)")
    parser.add_argument("--bm-out", default="results/benchmarl")
    parser.add_argument("--bm-eval-episodes", type=int, default=256)
    parser.add_argument("--bm-grid-observation", choices=("image", "vector"), default="image",
                        help="what the grid tasks' agents see: images (BenchMARL's CNN) or vectors (its MLP)")
    parser.add_argument("--bm-no-state", action="store_true",
                        help="withhold the tasks' root state (task config state: false): critics and mixers read the "
                             "agents' observations")
    args, _ = parser.parse_known_args(argv)
    from sidewalk.interop.benchmarl import SidewalkTask

    valid = [task.name.lower() for task in SidewalkTask]
    bad = [task for task in args.bm_tasks or [] if task not in valid]
    if bad:
        parser.error(f"--bm-tasks {bad} are not sidewalk tasks; valid: {valid}")
    if args.bm_frames < 1 or args.bm_eval_episodes < 1:
        parser.error("--bm-frames and --bm-eval-episodes must be positive")
    return {"algorithms": args.bm_algorithms, "tasks": args.bm_tasks, "seeds": args.bm_seeds,
            "frames": args.bm_frames, "out": args.bm_out, "eval_episodes": args.bm_eval_episodes,
            "grid_observation": args.bm_grid_observation, "state": not args.bm_no_state}


def planned_runs(algorithms: list[str] | None, tasks: list[str] | None, seeds: list[int]) -> list[tuple[str, str, int]]:
    """(algorithm, task, seed) in the order they run: seed-major, so a partial table has every setting's first seed."""
    from sidewalk.interop.benchmarl import SidewalkTask

    pairs = []
    for domain, (domain_algorithms, domain_tasks) in DEFAULT_RUNS.items():
        for task in tasks or domain_tasks:
            if SidewalkTask[task.upper()].get_from_yaml().config["domain"] != domain:
                continue
            pairs += [(algorithm, task) for algorithm in algorithms or domain_algorithms]
    return [(algorithm, task, seed) for seed in seeds for algorithm, task in pairs]


def train_and_evaluate(algorithm: str, task_name: str, seed: int, frames: int, out: Path, eval_episodes: int,
                       grid_observation: str = "image", state: bool = True) -> dict[str, Any]:
    """One BenchMARL run at its defaults for ``frames`` frames, then our evaluation of its greedy policy."""
    from benchmarl import algorithms
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import CnnConfig, MlpConfig
    from torchrl.envs import Compose, TransformedEnv

    from sidewalk.evaluate import evaluate
    from sidewalk.experiment import EVAL_SEED_OFFSET
    from sidewalk.interop.benchmarl import SidewalkTask

    task = SidewalkTask[task_name.upper()].get_from_yaml()
    if task.config["domain"] == "discrete":
        task.config["env"]["observation"] = grid_observation
    task.config["state"] = state
    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = frames
    config.loggers, config.render, config.evaluation = ["csv"], False, False
    config.checkpoint_at_end, config.keep_checkpoints_num = False, 1
    config.save_folder = str(out / "runs")
    (out / "runs").mkdir(parents=True, exist_ok=True)
    images = task.config["domain"] == "discrete" and grid_observation == "image"
    model = (CnnConfig if images else MlpConfig).get_from_yaml()
    experiment = Experiment(
        task=task, algorithm_config=getattr(algorithms, ALGORITHM_CONFIGS[algorithm]).get_from_yaml(),
        model_config=model, critic_model_config=model, seed=seed, config=config,
    )
    start = time.perf_counter()
    experiment.run()
    wall_s = time.perf_counter() - start
    view = task.get_env_fun(eval_episodes, experiment.continuous_actions, seed + EVAL_SEED_OFFSET, "cpu")()
    env = TransformedEnv(view, Compose(*task.get_env_transforms(view)))
    metrics = evaluate(env, experiment.policy, seed=seed + EVAL_SEED_OFFSET)
    # The same worlds with the policy's actions sampled, as BenchMARL collects: a deterministic policy can fail where
    # its sampling succeeds (and the other way round).
    sampled = evaluate(env, _Sampling(experiment.policy), seed=seed + EVAL_SEED_OFFSET, deterministic=False)
    observation = "image" if images else "vector"
    name = f"{algorithm}_{task_name}_{observation}{'' if state else '_nostate'}_seed{seed}.pt"
    torch.save(experiment.policy.state_dict(), out / "runs" / name)
    return {"algorithm": algorithm, "task": task_name, "observation": observation, "state": state,
            "protocol": task_protocol(task.config), "seed": seed, "frames": experiment.total_frames,
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
        frames: int = 240_000, out: str = "results/benchmarl", eval_episodes: int = 256,
        grid_observation: str = "image", state: bool = True) -> list[dict[str, Any]]:
    from sidewalk.run_folder import atomic_write

    torch.set_num_threads(1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    table_path = out_dir / "benchmarl.csv"
    table = pd.read_csv(table_path) if table_path.exists() else pd.DataFrame(columns=COLUMNS)
    table["protocol"] = table["protocol"].fillna("nominal") if "protocol" in table else "nominal"
    for algorithm, task, seed in planned_runs(algorithms, tasks, list(seeds)):
        from sidewalk.interop.benchmarl import SidewalkTask

        observation = grid_observation if task.endswith("discrete") else "vector"
        protocol = task_protocol(SidewalkTask[task.upper()].get_from_yaml().config)
        same = (table.algorithm == algorithm) & (table.task == task) & (table.seed == seed) & (
            table.observation == observation) & (table.state == state) & (table.protocol == protocol)
        if (table[same].frames >= frames).any():
            continue
        print(f"benchmarl: {algorithm} on sidewalk/{task} ({observation}{'' if state else ', no state'}), seed {seed}, "
              f"{frames:,} frames", flush=True)
        row = train_and_evaluate(algorithm, task, seed, frames, out_dir, eval_episodes, grid_observation, state)
        table = pd.concat([table[~same], pd.DataFrame([row])], ignore_index=True)
        atomic_write(table_path, lambda tmp, rows=table: rows.to_csv(tmp, index=False))
    return table.to_dict("records")


def format_rows(rows: list[dict[str, Any]]) -> str:
    """Mean over seeds of each setting, with the seeds' values: the docs' table."""
    from sidewalk.report.tables import distinct_range

    if not rows:
        return "(no runs)"
    table = pd.DataFrame(rows)
    table["protocol"] = table["protocol"].fillna("nominal") if "protocol" in table else "nominal"
    header = ("algorithm", "task", "observation", "state", "protocol", "seeds", "frames", "wall-clock (s, mean)",
              "team success, greedy (per seed)", "team success, sampled (mean)", "deadlock (mean)",
              "distinct episodes")
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    setting = ["algorithm", "task", "observation", "state", "protocol"]
    for (algorithm, task, observation, state, protocol), group in table.groupby(setting, sort=False):
        per_seed = ", ".join(f"{value:.2f}" for value in group.sort_values("seed").team_success)
        distinct = distinct_range(group.get("distinct_episodes", []))
        lines.append(f"| {algorithm} | {task} | {observation} | {'yes' if state else 'no'} | {protocol} "
                     f"| {len(group)} | {int(group.frames.mean()):,} | {group.wall_s.mean():.0f} "
                     f"| {group.team_success.mean():.2f} ({per_seed}) "
                     f"| {group.team_success_sampled.mean():.2f} | {group.deadlock.mean():.2f} | {distinct} |")
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    print(format_rows(run(**parse_options(sys.argv[1:]))))
