"""What the continuous sidewalk's geometry allows, measured: exploration, reward balance and room to pass.

SPEC §1 (revised 2026-11-23) chose the continuous geometry for three properties; this section measures each at the
config's defaults (or at any ``--override``, e.g. the first geometry ``env.length_m=10 env.width_m=1.5
env.dt_s=0.1``):

- ``untrained``: success of each learner's *untrained* collection policy (sampling, as the collector runs it) in
  ``EPISODES`` episodes per opponent. A learner that never sees the goal learns the cheapest ending instead
  (crashing at once); learning appeared only where this is ≥ ~0.5 % (issue 9).
- ``scripted``: the ego's mean return and success of fixed policies per opponent (drive straight at full speed;
  turn into the side wall at full speed; stand still): walking must pay more than crashing.
- ``prm_passes``: the PRM agent against an ego that stands still on the centre line midway, and against an ego
  driving straight along the centre line at full speed, one world per seed (the seed fixes the roadmap): how
  often the PRM agent reaches its goal, and both do. The continuous form of "the Dijkstra agent yields".

    python runners/bench.py geometry
    python -m sidewalk.bench.geometry --override env.length_m=10 env.width_m=1.5 env.dt_s=0.1
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import replace

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tqdm import tqdm

from sidewalk.bench.common import format_table, torch_threads
from sidewalk.compose import compose_experiment

EPISODES = 1024
PRM_SEEDS = 1000
OPPONENTS = ("random", "prm", "centralized")
LEARNERS = ("trpo", "ppo")


class FixedAction(TensorDictModuleBase):
    """A policy that writes the same ``action`` in every world: (acceleration, turn) per agent controlled."""

    def __init__(self, action: Sequence[float], n_agents: int = 1) -> None:
        super().__init__()
        self.in_keys, self.out_keys = [], ["action"]
        self.action = torch.tensor(list(action) * n_agents, dtype=torch.float32)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        shape = (*tensordict.batch_size, *self.action.shape)
        action = self.action.expand(shape).reshape(*tensordict.batch_size, -1, 2).squeeze(-2)
        tensordict.set("action", action.clone())
        return tensordict


def _experiment(opponent: str, algo: str, overrides: Sequence[str]):
    # The geometry of the scenario's own starts: what these figures measure (eval=nominal: no jitter).
    return compose_experiment(["env=continuous", f"opponent={opponent}", f"algo={algo}", "eval=nominal", *overrides])


def _outcome(metrics: dict[str, float], opponent: str) -> dict[str, float]:
    """Success and return of the learner's side: the ego, or the team when it plays every agent."""
    if opponent == "centralized":
        returns = [v for k, v in metrics.items() if k.startswith("agent") and k.endswith("/return")]
        return {"success": metrics["team/success_rate"], "return": sum(returns) / len(returns)}
    return {"success": metrics["ego/success_rate"], "return": metrics["ego/return"]}


def untrained(
    overrides: Sequence[str],
    episodes: int = EPISODES,
    seed: int = 0,
    learners: Sequence[str] = LEARNERS,
    opponents: Sequence[str] = OPPONENTS,
) -> list[dict]:
    """Ego (or team) success of each learner's untrained sampling policy, per opponent."""
    from sidewalk.evaluate import evaluate
    from sidewalk.registry import LEARNERS

    rows = []
    for algo_name in learners:
        for opponent in opponents:
            experiment = _experiment(opponent, algo_name, overrides)
            torch.manual_seed(seed)
            view = experiment.world.make(episodes, seed, experiment.device)
            algo = LEARNERS[algo_name](experiment.algo, view)
            metrics = evaluate(view, algo.collection_policy(), seed=seed, deterministic=False)  # it samples
            outcome = _outcome(metrics, opponent)
            rows.append(
                {"learner": algo_name, "opponent": opponent, "episodes": episodes,
                 "untrained_success": outcome["success"], "return": outcome["return"]}
            )
    return rows


SCRIPTED = {
    "straight": (1.0, 0.0),  # full acceleration along the heading: the shortest walk
    "wall": (1.0, math.pi / 8),  # full acceleration, turning left as fast as allowed: the side wall
    "still": (0.0, 0.0),
}


def scripted(
    overrides: Sequence[str], episodes: int = 256, seed: int = 0, opponents: Sequence[str] = OPPONENTS
) -> list[dict]:
    """Ego (team) return and success of fixed policies, per opponent: walking must pay more than crashing."""
    from sidewalk.evaluate import evaluate

    rows = []
    for opponent in opponents:
        experiment = _experiment(opponent, "trpo", overrides)
        view = experiment.world.make(episodes, seed, experiment.device)
        for name, action in SCRIPTED.items():
            policy = FixedAction(action, n_agents=view.n_agents if opponent == "centralized" else 1)
            outcome = _outcome(evaluate(view, policy, seed=seed), opponent)
            rows.append({"opponent": opponent, "ego_policy": name, "success": outcome["success"],
                         "return": outcome["return"]})
    return rows


def prm_passes(overrides: Sequence[str], seeds: int = PRM_SEEDS) -> list[dict]:
    """The PRM agent against a still ego midway on the centre line and a straight-driving ego, one world per seed."""
    from sidewalk.envs import ContinuousSidewalkEnv, crashed
    from sidewalk.views import EgoView

    experiment = _experiment("prm", "trpo", [*overrides, "noise=0"])
    params = experiment.world.env_params
    base = ContinuousSidewalkEnv(1, params=params).layout
    midway = (base.length_m / 2, base.width_m / 2)
    still_layout = replace(base, starts=(midway, base.starts[1]))
    cases = {
        "still ego midway": (still_layout, SCRIPTED["still"]),
        "straight ego": (base, SCRIPTED["straight"]),
    }
    rows = []
    for case, (layout, action) in cases.items():
        other_arrived = both_arrived = 0
        steps_other = []
        for seed in tqdm(range(seeds), desc=case, leave=False, file=sys.stderr):
            core = ContinuousSidewalkEnv(1, seed=seed, params=replace(params, layout=layout))
            view = EgoView(core, opponent="prm", opponent_kwargs=experiment.world.opponent_params)
            policy = FixedAction(action)
            td = view.reset()
            for step in range(params.max_steps):
                td = view.step(policy(td))["next"]
                info = td.get(("world", "info"))
                if bool((info["reached_goal"] | crashed(info))[0, 1]):
                    break
            other = bool(info["reached_goal"][0, 1])
            other_arrived += other
            steps_other.append(step + 1)
            both_arrived += other and bool(info["reached_goal"][0, 0])
        rows.append(
            {"case": case, "worlds": seeds, "prm_arrives": other_arrived / seeds, "both_arrive": both_arrived / seeds,
             "prm_steps_mean": sum(steps_other) / len(steps_other)}
        )
    return rows


def run(overrides: Sequence[str] = (), threads: Sequence[int] = (1,), **_ignored) -> list[dict]:
    """Every table of the section, as rows with a ``table`` column (for ``runners/bench.py``)."""
    with torch_threads(threads[0]):
        rows = [{"table": "untrained", **row} for row in untrained(overrides)]
        rows += [{"table": "scripted", **row} for row in scripted(overrides)]
        rows += [{"table": "prm_passes", **row} for row in prm_passes(overrides)]
    return rows


def format_rows(rows: list[dict]) -> str:
    """``run``'s rows as one table per ``table``."""
    parts = []
    for table in dict.fromkeys(row["table"] for row in rows):
        part = [{k: v for k, v in row.items() if k != "table"} for row in rows if row["table"] == table]
        parts.append(f"{table}:\n{format_table(part)}")
    return "\n\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--override", nargs="*", default=[], help="Hydra overrides, e.g. env.length_m=10")
    parser.add_argument("--tables", nargs="+", default=["untrained", "scripted", "prm_passes"],
                        choices=["untrained", "scripted", "prm_passes"])
    parser.add_argument("--prm-seeds", type=int, default=PRM_SEEDS)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    for table in args.tables:
        if table == "prm_passes":
            rows = prm_passes(args.override, seeds=args.prm_seeds)
        else:
            rows = {"untrained": untrained, "scripted": scripted}[table](args.override)
        print(f"\n## {table}\n{format_table(rows)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
