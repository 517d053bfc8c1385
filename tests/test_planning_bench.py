"""The planning section times the scripted planners, and beside another tree, each tree in its own processes."""

from __future__ import annotations

import pytest

from sidewalk.bench import planning
from sidewalk.bench.common import REPO_ROOT


def test_beside_a_baseline_both_trees_are_timed_and_compared():
    rows = planning.run(num_envs=[2], seconds=0.02, baseline=str(REPO_ROOT), repeats=1)
    assert [(row["num_envs"], row["planner"]) for row in rows] == [(2, "prm"), (2, "dijkstra")]
    for row in rows:
        assert row["baseline ms/call"] > 0 and row["this ms/call"] > 0
        assert row["this ÷ baseline"] == pytest.approx(row["this ms/call"] / row["baseline ms/call"])
        assert row["this rounds"] == row["baseline rounds"]  # the same planner, the same recorded states
    assert "this ÷ baseline" in planning.format_rows(rows)


def test_bad_options_are_named():
    assert planning.parse_options(["--baseline", str(REPO_ROOT)])["baseline"] == str(REPO_ROOT)
    with pytest.raises(SystemExit):
        planning.parse_options(["--baseline", "no-such-revision"])
    with pytest.raises(SystemExit):
        planning.parse_options(["--repeats", "0"])
