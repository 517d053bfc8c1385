"""The reproduction estimate reads a probe's costs apart correctly, packs runs onto workers, and prices the sweeps
that runners/reproduce.sh runs."""

from __future__ import annotations

import pandas as pd
import pytest

from sidewalk.bench.common import REPO_ROOT
from sidewalk.bench.reproduce_wall_clock import (
    POOL,
    WARMUP,
    costs_from_metrics,
    in_order,
    makespan,
    revision_jobs,
    run_seconds,
    sweep,
)


def test_probe_costs_are_read_apart_from_metrics_csv():
    # 40 iterations of 0.1 s; an evaluation every 20 costs 2 s more, the iteration after a checkpoint 0.5 s more;
    # the first WARMUP iterations are cheap (no gradient steps yet); the process ran 7 s outside the loop.
    period, seconds = 20, []
    for iteration in range(1, 41):
        cost = 0.02 if iteration <= WARMUP else 0.1
        cost += 2.0 if iteration % period == 0 else 0.0
        cost += 0.5 if iteration == 21 else 0.0
        seconds.append(cost)
    times = pd.Series(seconds).cumsum()
    rows = pd.DataFrame({"iteration": range(1, 41), "time_s": times})
    costs = costs_from_metrics(rows, wall_s=float(times.iloc[-1]) + 7.0, period=period)
    assert costs == pytest.approx({"ms_per_iteration": 100.0, "eval_s": 2.0, "checkpoint_s": 0.5, "fixed_s": 7.0})
    # A run of 5000 iterations at periods of 50: 100 evaluations, 99 checkpoints (none after the last iteration).
    assert run_seconds(costs, 5000, 50, 50) == pytest.approx(7.0 + 500.0 + 200.0 + 49.5)


def test_runs_are_packed_longest_first_onto_the_workers():
    assert makespan([2.0, 2.0, 1.0, 5.0, 2.0], 2) == 6.0  # 5+1 | 2+2+2
    assert makespan([3.0, 3.0, 2.0, 2.0, 2.0], 2) == 7.0  # greedy, as a launcher hands out jobs: 3+2+2 | 3+2
    assert makespan([5.0, 1.0], 1) == 6.0
    assert makespan([4.0], 3) == 4.0
    assert in_order([1.0, 5.0, 2.0], 2) == 5.0  # the pool's order, not the longest first: 1+2 | 5
    assert in_order([1.0, 1.0, 5.0], 2) == 6.0


def test_the_estimate_prices_every_job_of_the_pool():
    model, jobs = revision_jobs(REPO_ROOT)
    assert model == POOL
    presets = list(dict.fromkeys(job["preset"] for job in jobs))
    assert sorted(presets) == ["fig5_continuous", "fig5_discrete", "fig6_continuous", "fig6_discrete", "fig8"]
    assert len(jobs) == 13  # 5 presets x 3 points, Fig. 8's explicit reward once (it is Fig. 6's noise 0.01)
    fig5 = [job for job in jobs if job["preset"] == "fig5_discrete"]
    assert [job["overrides"][1] for job in fig5] == ["opponent=random", "opponent=dijkstra", "opponent=centralized"]
    assert all(job["replicas"] == 3 for job in jobs)  # each job trains seeds 0, 1, 2 in one process
    assert (fig5[0]["iterations"], fig5[0]["eval_every"], fig5[0]["checkpoint_every"]) == (5000, 50, 250)
    assert all(job["iterations"] == 5000 for job in jobs if "continuous" in job["preset"] or job["preset"] == "fig8")
    sizes = [job["size"] for job in jobs]
    assert sizes == sorted(sizes, reverse=True)  # the largest first


def test_a_preset_sweep_expands_as_hydra_would():
    fig5 = sweep("fig5_discrete")
    assert fig5["runs"] == [["opponent=random"], ["opponent=dijkstra"], ["opponent=centralized"]]
    assert (fig5["replicas"], fig5["iterations"]) == (3, 5000)
