"""The scenarios benchmark runs at a tiny size: positive finite rates under the expected columns, sizes that construct."""

from __future__ import annotations

import importlib.util
import math

import pytest

from sidewalk.bench import scenarios
from sidewalk.envs import ContinuousSidewalkEnv

HAS_VMAS = importlib.util.find_spec("vmas") is not None


@pytest.fixture(scope="module")
def rows():
    return scenarios.run(agents=[2, 4], num_envs=[64], threads=[1], seconds=0.02, repeats=1)


def test_rows_have_every_column_and_positive_finite_rates(rows):
    assert [(r["domain"], r["N"]) for r in rows] == [(d, n) for d in scenarios.DOMAINS for n in (2, 4)]
    measured = ["ours steps/s", "ours µs/agent-step", "ours cost ÷ min N", "ours reset %", "ours cpu %"]
    if HAS_VMAS:
        measured += ["vmas steps/s", "ours/vmas", "vmas µs/agent-step", "vmas cost ÷ min N", "vmas reset %",
                     "vmas cpu %"]
    for row in rows:
        assert tuple(row) == scenarios.COLUMNS
        assert row["num_envs"] == 64 and row["threads"] == 1
        for column in measured:
            assert math.isfinite(row[column]) and row[column] >= 0, (row["domain"], row["N"], column)
        for column in ("ours steps/s", "ours µs/agent-step") + (("vmas steps/s", "ours/vmas") if HAS_VMAS else ()):
            assert row[column] > 0, (row["domain"], row["N"], column)
        assert row["ours µs/agent-step"] == pytest.approx(1e6 / (row["ours steps/s"] * row["N"]))
        if row["N"] == 2:
            assert row["ours cost ÷ min N"] == 1.0
    if not HAS_VMAS:
        assert all(row["vmas steps/s"] is None for row in rows)


def test_table_prints_every_row_and_the_targets(rows):
    text = scenarios.format_rows(rows)
    assert all(column in text for column in ("ours steps/s", "ours/vmas", "ours cost ÷ min N"))
    for domain in scenarios.DOMAINS:
        assert f"{domain} (1 thread(s), 64 worlds): cost per agent-step N=4 ÷ N=2" in text


def test_world_sizes_grow_with_n_and_construct_at_16_agents():
    assert scenarios.grid_room(2) == scenarios.grid_room(4) == (7, 15)
    assert scenarios.grid_room(16) == (14, 29)
    assert [scenarios.plane_side_m(n) for n in (2, 4, 8, 16)] == [4.5, 6.0, 8.1, 11.2]
    for domain in scenarios.DOMAINS:
        env, _ = scenarios.make_ours(domain, 1, 16)
        assert env.n_agents == 16
    with pytest.raises(ValueError, match="crowd"):  # the rule of thumb sqrt(N·2.2) + 1 m is too small at N = 16
        side = math.sqrt(16 * 2.2) + 1
        ContinuousSidewalkEnv(num_envs=1, layout="random", n_agents=16, length_m=side, width_m=side)


def test_options_are_checked():
    assert scenarios.parse_options([])["agents"] == list(scenarios.AGENTS)
    assert scenarios.parse_options(["--agents", "2", "8", "--repeats", "1"])["agents"] == [2, 8]
    for bad in (["--agents", "0"], ["--seconds", "0"], ["--domains", "hex"], ["--agnets", "2"]):
        with pytest.raises(SystemExit):
            scenarios.parse_options(bad)
