"""Microseconds per plan per world of the scripted planners, beside scipy's Dijkstra on the same grid costmaps;
optionally the planners' milliseconds per call beside another checkout or revision of this repository.

    python runners/bench.py planning                                  # this checkout, 1, 64 and 1024 worlds
    python runners/bench.py planning --num-envs 128 1024 --baseline /path/to/other/checkout
    python runners/bench.py planning --baseline HEAD~3 --repeats 5    # a revision: timed in a git worktree

Each planner is timed on states recorded from its own rollout against a uniformly random ego (auto-reset on),
replayed in turn; one plan is the opponent's whole ``act`` (costmap or edge costs, the batched shortest-path
solve, the move or the controller), for all worlds at once. The scipy column plans the costmaps our Dijkstra
built for those states, one world at a time: per world it writes the costs into a prebuilt 4-neighbour graph and
runs ``scipy.sparse.csgraph.dijkstra`` from the goal -- scipy's best case, with no graph construction timed.

With ``--baseline`` the Dijkstra and PRM opponents of both trees are timed the same way, each tree's in fresh
processes that import its own ``sidewalk`` (this file's timing code, the tree's planners), taking turns
``--repeats`` times; a row gives the fastest of each tree's turns in CPU milliseconds of the one timing thread
per call, so other work on the machine slows both sides less than it would their wall-clock, and the ratio
this ÷ baseline.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse
import torch
from scipy.sparse.csgraph import dijkstra

# Only names that older revisions have too: a baseline tree runs this file against its own package.
from sidewalk.bench.common import format_table, seconds_per_call, torch_threads
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.grid import MOVES
from sidewalk.opponents.base import DONE_KEY, GOAL_KEY, STATE_KEY, Opponent
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.opponents.prm import PRMOpponent
from sidewalk.opponents.random import RandomOpponent

NUM_ENVS = (1, 64, 1024)
RECORDED_STEPS = 50  # states recorded per measurement, replayed in turn
EGO, PLANNER = 0, 1
REPEATS = 3  # turns each tree takes with --baseline

PlanInputs = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


def recorded_states(env, planner: Opponent, steps: int = RECORDED_STEPS, seed: int = 0) -> list[PlanInputs]:
    """(state, goal, done) of ``steps`` consecutive steps of ``planner`` against a uniformly random ego."""
    env.set_seed(seed)
    ego = RandomOpponent(env, controlled=(EGO,), ego=None)
    tensordict, states = env.reset(), []
    for _ in range(steps):
        states.append(tuple(tensordict.get(key).clone() for key in (STATE_KEY, GOAL_KEY, DONE_KEY)))
        _, tensordict = env.step_and_maybe_reset(ego(planner(tensordict)))
    return states


def scipy_grid_planner(rows: int, cols: int) -> Callable[[np.ndarray, int], np.ndarray]:
    """A function (costmap (rows, cols), goal cell) -> distance-to-goal field, by scipy's Dijkstra.

    The graph's structure (4-neighbour edges, reversed so that one search from the goal gives every cell's
    distance to it) is built once; each call writes the entry costs of the edges' target cells and searches.
    """
    cells = np.arange(rows * cols).reshape(rows, cols)
    sources, targets = [], []
    for d_row, d_col in MOVES:
        row_from, row_to = max(0, -d_row), rows - max(0, d_row)
        col_from, col_to = max(0, -d_col), cols - max(0, d_col)
        here = cells[row_from:row_to, col_from:col_to]
        there = cells[row_from + d_row : row_to + d_row, col_from + d_col : col_to + d_col]
        sources.append(there.ravel())  # reversed: from the cell entered back to the cell left
        targets.append(here.ravel())
    sources, targets = np.concatenate(sources), np.concatenate(targets)
    graph = scipy.sparse.csr_matrix(
        (np.ones(len(sources)), (sources, targets)), shape=(rows * cols, rows * cols)
    )
    entered = np.repeat(np.arange(rows * cols), np.diff(graph.indptr))  # the cell each stored edge enters

    def plan(costmap: np.ndarray, goal_cell: int) -> np.ndarray:
        graph.data[:] = costmap.ravel()[entered]
        return dijkstra(graph, directed=True, indices=goal_cell)

    return plan


def _time_planner(planner: Opponent, states: list[PlanInputs], seconds: float) -> float:
    replay = itertools.cycle(states)
    return seconds_per_call(lambda: planner.act(*next(replay)), min_seconds=seconds)


def _time_scipy(planner: DijkstraOpponent, states: list[PlanInputs], seconds: float) -> float:
    """Seconds per recorded state for scipy to plan every (world, controlled agent) costmap of it."""
    layout = planner.env.layout
    plan_one = scipy_grid_planner(layout.rows, layout.cols)
    problems = []
    for state, goal, done in states:
        costmap = planner.plan(state, goal, done).costmap.double().numpy()  # (B, C, rows, cols)
        goal_cell = (goal[:, planner.controlled, 0] * layout.cols + goal[:, planner.controlled, 1]).numpy()
        problems.append((costmap, goal_cell))
    replay = itertools.cycle(problems)

    def plan_all() -> None:
        costmap, goal_cell = next(replay)
        for world in range(costmap.shape[0]):
            for k in range(costmap.shape[1]):
                plan_one(costmap[world, k], int(goal_cell[world, k]))

    return seconds_per_call(plan_all, min_seconds=seconds)


def _mean_rounds(planner: Opponent, states: list[PlanInputs]) -> float:
    rounds = []
    for inputs in states:
        planner.act(*inputs)
        rounds.append(planner.last_rounds)
    return sum(rounds) / len(rounds)


def _planners(n: int) -> dict[str, tuple[Opponent, list[PlanInputs]]]:
    """Dijkstra on the grid and the PRM in the plane, ``n`` worlds each, with their recorded states."""
    grid_planner = DijkstraOpponent(DiscreteSidewalkEnv(num_envs=n, seed=0, observation="vector"))
    plane_planner = PRMOpponent(ContinuousSidewalkEnv(num_envs=n, seed=0))
    return {
        "dijkstra": (grid_planner, recorded_states(grid_planner.env, grid_planner)),
        "prm": (plane_planner, recorded_states(plane_planner.env, plane_planner)),
    }


def run(
    num_envs: Sequence[int] = NUM_ENVS,
    threads: int | Sequence[int] = 1,
    seconds: float = 0.5,
    baseline: str | None = None,
    repeats: int = REPEATS,
) -> list[dict]:
    """One row per (threads, num_envs): µs per plan per world of Dijkstra, of scipy on the same costmaps, and of
    the PRM, with the mean number of solver rounds per plan; with ``baseline`` (a checkout directory or a
    revision), ms per call of Dijkstra and the PRM in both trees instead (see the module's docstring)."""
    threads = [threads] if isinstance(threads, int) else list(threads)
    if baseline is not None:
        return _compare(baseline, list(num_envs), threads, seconds, repeats)
    rows = []
    for n_threads in threads:
        with torch_threads(n_threads):
            for n in num_envs:
                planners = _planners(n)
                grid_planner, grid_states = planners["dijkstra"]
                plane_planner, plane_states = planners["prm"]
                dijkstra_us = _time_planner(grid_planner, grid_states, seconds) / n * 1e6
                scipy_us = _time_scipy(grid_planner, grid_states, seconds) / n * 1e6
                rows.append(
                    {
                        "threads": n_threads,
                        "num_envs": n,
                        "dijkstra µs/plan/world": dijkstra_us,
                        "scipy µs/plan/world": scipy_us,
                        "scipy/dijkstra": scipy_us / dijkstra_us,
                        "dijkstra rounds": _mean_rounds(grid_planner, grid_states),
                        "prm µs/plan/world": _time_planner(plane_planner, plane_states, seconds) / n * 1e6,
                        "prm rounds": _mean_rounds(plane_planner, plane_states),
                        "prm nodes": len(plane_planner.roadmap.nodes),
                    }
                )
    return rows


# ---- one checkout beside another ------------------------------------------------------------------------------


def _cpu_ms_per_call(planner: Opponent, states: list[PlanInputs], seconds: float) -> float:
    """CPU milliseconds of this thread per ``act`` on the replayed ``states``, over at least ``seconds``."""
    replay = itertools.cycle(states)
    for _ in range(3):
        planner.act(*next(replay))
    calls, start = 0, time.thread_time()
    while time.thread_time() - start < seconds:
        planner.act(*next(replay))
        calls += 1
    return (time.thread_time() - start) / calls * 1e3


def _worker(num_envs: Sequence[int], threads: Sequence[int], seconds: float) -> list[dict]:
    """What one turn of one tree measures: (threads, num_envs, planner, ms per call, solver rounds)."""
    rows = []
    for n_threads in threads:
        with torch_threads(n_threads):
            for n in num_envs:
                for name, (planner, states) in _planners(n).items():
                    rows.append({"threads": n_threads, "num_envs": n, "planner": name,
                                 "ms": _cpu_ms_per_call(planner, states, seconds),
                                 "rounds": _mean_rounds(planner, states)})  # fmt: skip
    return rows


@contextmanager
def _trees(baseline: str, tmp: str) -> Iterator[dict[str, Path]]:
    """{"baseline": its tree, "this": this checkout}; a revision is checked out into a git worktree under tmp."""
    from sidewalk.bench.common import REPO_ROOT, revision_trees

    if Path(baseline, "sidewalk").is_dir():
        yield {"baseline": Path(baseline).resolve(), "this": REPO_ROOT}
        return
    with revision_trees(baseline, tmp) as trees:
        yield dict(zip(("baseline", "this"), trees.values()))


def _turn(tree: Path, num_envs: Sequence[int], threads: Sequence[int], seconds: float) -> list[dict]:
    """One worker process timing ``tree``'s planners: this file, run with ``tree`` first on the import path."""
    command = [sys.executable, "-P", __file__, "--worker", "--num-envs", *map(str, num_envs),
               "--threads", *map(str, threads), "--seconds", str(seconds)]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(tree)}
    result = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"timing the planners of {tree} failed:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.splitlines()[-1])


def _compare(
    baseline: str, num_envs: Sequence[int], threads: Sequence[int], seconds: float, repeats: int
) -> list[dict]:
    """Rows of ms per call of each planner in both trees (the fastest of ``repeats`` turns) and their ratio."""
    fastest: dict[tuple[str, int, int, str], float] = {}
    rounds: dict[tuple[str, int, int, str], float] = {}
    with tempfile.TemporaryDirectory(prefix="sidewalk-planning-") as tmp, _trees(baseline, tmp) as trees:
        for turn in range(repeats):
            for side, tree in trees.items():
                print(f"planning: turn {turn + 1} of {repeats}, {side} ({tree})", file=sys.stderr, flush=True)
                for row in _turn(tree, num_envs, threads, seconds):
                    key = (side, row["threads"], row["num_envs"], row["planner"])
                    fastest[key] = min(fastest.get(key, float("inf")), row["ms"])
                    rounds[key] = row["rounds"]
    rows = []
    for n_threads, n, planner in itertools.product(threads, num_envs, ("prm", "dijkstra")):
        before, after = fastest[("baseline", n_threads, n, planner)], fastest[("this", n_threads, n, planner)]
        rows.append({"threads": n_threads, "num_envs": n, "planner": planner,
                     "baseline ms/call": before, "this ms/call": after, "this ÷ baseline": after / before,
                     "baseline rounds": rounds[("baseline", n_threads, n, planner)],
                     "this rounds": rounds[("this", n_threads, n, planner)]})  # fmt: skip
    return rows


def parse_options(argv: Sequence[str]) -> dict[str, Any]:
    """This section's own flags (``runners/bench.py planning ...``)."""
    parser = argparse.ArgumentParser(prog="runners/bench.py planning", description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", help="a checkout directory or git revision to time beside this one")
    parser.add_argument("--repeats", type=int, default=REPEATS, help=f"turns per tree, --baseline ({REPEATS})")
    parser.add_argument("--seconds", type=float, default=0.5, help="timed seconds per measurement (0.5)")
    args = parser.parse_args(list(argv))
    if args.repeats < 1:
        parser.error(f"--repeats={args.repeats} must be ≥ 1")
    if args.baseline is not None and not Path(args.baseline, "sidewalk").is_dir():
        from sidewalk.bench.common import is_commit

        if not is_commit(args.baseline):
            parser.error(f"--baseline={args.baseline!r} is neither a checkout directory nor a commit")
    return {"baseline": args.baseline, "repeats": args.repeats, "seconds": args.seconds}


def format_rows(rows: list[dict]) -> str:
    if rows and "planner" in rows[0]:
        header = "CPU ms per call of the timing thread, the fastest of each tree's turns; rounds as each tree's "
        return header + "planner counts them (its last_rounds).\n" + format_table(rows)
    return "One plan covers all of a row's worlds at once; scipy loops over them.\n" + format_table(rows)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=list(NUM_ENVS))
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args, rest = parser.parse_known_args(argv)
    options = parse_options(rest)
    if args.worker:
        print(json.dumps(_worker(args.num_envs, args.threads, options["seconds"])))
        return
    print(format_rows(run(args.num_envs, args.threads, **options)))


if __name__ == "__main__":
    main()
