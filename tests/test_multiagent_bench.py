"""The multi-agent training benchmark runs at a tiny size: both learners train an iteration, the rows have positive
frames/s and the ratio, and the peer's batch, epochs, minibatches and networks are ours."""

from __future__ import annotations

import importlib.util
import math

import pytest

from sidewalk.bench import multiagent

HAS_VMAS = importlib.util.find_spec("vmas") is not None
needs_vmas = pytest.mark.skipif(not HAS_VMAS, reason="VMAS (the 'bench' extra) is not installed: no peer to run")


@pytest.fixture(scope="module")
def rows():
    return multiagent.run(num_envs=[64], threads=[1], steps=2, iterations=1, warmup=0)


def test_rows_have_every_column_and_positive_rates(rows):
    assert [row["learner"] for row in rows] == (["TorchRL example IPPO"] if HAS_VMAS else []) + ["ours IPPO"]
    for row in rows:
        assert tuple(row) == multiagent.COLUMNS
        assert (row["threads"], row["worlds"], row["frames/it"]) == (1, 64, 128)
        for column in ("collect s", "update s", "frames/s", "frames/cpu-s", "cpu %"):
            assert math.isfinite(row[column]) and row[column] > 0, (row["learner"], column)
        assert row["frames/s"] <= row["frames/it"] / (row["collect s"] + row["update s"]) * (1 + 1e-9)
    ours = rows[-1]
    if HAS_VMAS:
        assert ours["ours/peer"] == pytest.approx(ours["frames/s"] / rows[0]["frames/s"])
        assert ours["ours/peer cpu"] == pytest.approx(ours["frames/cpu-s"] / rows[0]["frames/cpu-s"])
    else:
        assert ours["ours/peer"] is None and ours["ours/peer cpu"] is None
    text = multiagent.format_rows(rows)
    assert all(column in text for column in ("frames/s", "ours/peer", "frames/cpu-s", "minibatches/it"))
    assert "OMP_WAIT_POLICY" in text
    assert ("ours ÷ peer frames/s at 1 thread(s), 64 worlds" in text) == HAS_VMAS


@needs_vmas
def test_peer_matches_our_batch_epochs_minibatches_and_networks(rows):
    peer, ours = rows
    # 128 frames in minibatches of 64, 10 epochs: IPPO's defaults for both
    assert peer["minibatches/it"] == ours["minibatches/it"] == 10 * 128 // 64
    assert (peer["obs/agent"], ours["obs/agent"]) == (18, 12)

    def mlp(inputs: int, outputs: int) -> int:  # [64, 64] tanh hidden layers, shared by the agents
        return (inputs * 64 + 64) + (64 * 64 + 64) + (64 * outputs + outputs)

    # The example's policy outputs loc and scale (4); ours loc (2) and a state-independent log-std (2).
    assert peer["parameters"] == mlp(18, 4) + mlp(18, 1)
    assert ours["parameters"] == mlp(12, 2) + 2 + mlp(12, 1)


def test_options_are_checked():
    options = multiagent.parse_options([])
    assert options == {"steps": multiagent.STEPS, "iterations": multiagent.ITERATIONS, "warmup": multiagent.WARMUP,
                       "learners": list(multiagent.LEARNERS)}
    assert multiagent.parse_options(["--ma-steps", "16", "--ma-warmup", "0", "--ma-learners", "ours"]) == {
        "steps": 16, "iterations": multiagent.ITERATIONS, "warmup": 0, "learners": ["ours"]}
    for bad in (["--ma-steps", "0"], ["--ma-iterations", "0"], ["--ma-warmup", "-1"], ["--ma-learners", "mappo"],
                ["--ma-iteratons", "2"]):
        with pytest.raises(SystemExit):
            multiagent.parse_options(bad)


def test_a_batch_smaller_than_a_minibatch_fails_before_compute():
    with pytest.raises(ValueError, match="minibatch size 64"):
        multiagent.run(num_envs=[16], threads=[1], steps=2, iterations=1, warmup=0)
