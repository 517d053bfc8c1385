"""Microseconds per plan per world of the scripted planners, beside scipy's Dijkstra on the same grid costmaps.

Each planner is timed on states recorded from its own rollout against a uniformly random ego (auto-reset on),
replayed in turn; one plan is the opponent's whole ``act`` (costmap or edge costs, the batched shortest-path
solve, the move or the controller), for all worlds at once. The scipy column plans the costmaps our Dijkstra
built for those states, one world at a time: per world it writes the costs into a prebuilt 4-neighbour graph and
runs ``scipy.sparse.csgraph.dijkstra`` from the goal -- scipy's best case, with no graph construction timed.
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Callable, Sequence

import numpy as np
import scipy.sparse
import torch
from scipy.sparse.csgraph import dijkstra

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


def run(
    num_envs: Sequence[int] = NUM_ENVS, threads: int | Sequence[int] = 1, seconds: float = 0.5
) -> list[dict]:
    """One row per (threads, num_envs): µs per plan per world of Dijkstra, of scipy on the same costmaps, and of
    the PRM, with the mean number of solver rounds per plan."""
    rows = []
    for n_threads in [threads] if isinstance(threads, int) else threads:
        with torch_threads(n_threads):
            for n in num_envs:
                grid = DiscreteSidewalkEnv(num_envs=n, seed=0, observation="vector")
                grid_planner = DijkstraOpponent(grid)
                grid_states = recorded_states(grid, grid_planner)
                plane = ContinuousSidewalkEnv(num_envs=n, seed=0)
                plane_planner = PRMOpponent(plane)
                plane_states = recorded_states(plane, plane_planner)

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


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=list(NUM_ENVS))
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--seconds", type=float, default=0.5, help="timed seconds per measurement")
    args = parser.parse_args(argv)
    print("One plan covers all of a row's worlds at once; scipy loops over them.")
    print(format_table(run(args.num_envs, args.threads, args.seconds)))


if __name__ == "__main__":
    main()
