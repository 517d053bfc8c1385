"""Performance profiles (``sidewalk.stats.performance_profile``) against hand-computed fractions: strictly above each
threshold as rliable counts, pooled over tasks with NaN runs dropped, and a stratified-bootstrap band that a seed
fixes and that keeps each task's number of runs."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from sidewalk.stats import fraction_above, performance_profile


def test_the_profile_counts_the_runs_strictly_above_each_threshold():
    scores = [0.0, 0.25, 0.5, 0.75, 1.0]
    # At a threshold equal to a score that score does not count (rliable's ``scores > tau``).
    profile = performance_profile(scores, [0.0, 0.25, 0.5, 0.6, 0.99, 1.0], n_resamples=200)
    assert profile.fraction.tolist() == pytest.approx([4 / 5, 3 / 5, 2 / 5, 2 / 5, 1 / 5, 0.0])
    assert profile.taus.tolist() == [0.0, 0.25, 0.5, 0.6, 0.99, 1.0] and profile.runs == 5
    assert np.all(profile.low <= profile.fraction) and np.all(profile.fraction <= profile.high)
    assert (profile.low[-1], profile.high[-1]) == (0.0, 0.0)  # no resample has a score above 1
    assert (profile.low[0], profile.high[0]) != (profile.fraction[0],) * 2  # a real band where runs differ


def test_the_profile_pools_every_run_of_every_task_and_drops_nan_runs():
    # Two tasks of 3 and 2 runs, the shorter one padded with NaN: 5 runs in all, 3 of them above 0.5.
    scores = np.array([[0.2, 0.9], [0.6, np.nan], [1.0, 0.1]])
    profile = performance_profile(scores, [0.5], n_resamples=200)
    assert profile.fraction.tolist() == pytest.approx([3 / 5])  # not 4/6: the NaN is no run
    assert profile.runs == 2 and "coarse" in profile.note  # the fewest runs of a task
    batch = fraction_above(np.array([[0.2, 0.6, 1.0], [0.0, 0.0, 0.7]]), [0.5, 0.1])
    assert batch.tolist() == [
        [pytest.approx(2 / 3), pytest.approx(1 / 3)],
        [1.0, pytest.approx(1 / 3)],
    ]  # (taus, batch)


def test_the_band_is_the_stratified_percentile_bootstrap_a_seed_fixes():
    rng = np.random.default_rng(4)
    tasks = (rng.uniform(0, 1, 6), rng.uniform(0, 1, 4))
    scores = np.full((6, 2), np.nan)
    scores[:, 0], scores[:4, 1] = tasks
    taus = [0.25, 0.5, 0.75]
    profile = performance_profile(scores, taus, n_resamples=1000, seed=3)
    for index, tau in enumerate(taus):  # the same resampling by hand, one threshold at a time
        expected = scipy.stats.bootstrap(
            tasks,
            lambda a, b, axis, tau=tau: np.mean(np.concatenate([a, b], axis=axis) > tau, axis=axis),
            n_resamples=1000,
            method="percentile",
            paired=False,
            vectorized=True,
            rng=np.random.default_rng(3),
        ).confidence_interval
        assert (profile.low[index], profile.high[index]) == (
            pytest.approx(expected.low),
            pytest.approx(expected.high),
        )
    again = performance_profile(scores, taus, n_resamples=1000, seed=3)
    assert np.array_equal(again.low, profile.low) and np.array_equal(again.high, profile.high)


def test_the_band_keeps_each_task_s_number_of_runs():
    # One task all 0, the other all 1: a stratified resample always holds 3 zeros and 3 ones, so the fraction above
    # 0.5 is 1/2 in every resample; an ordinary bootstrap over the 6 pooled runs would spread it.
    scores = np.array([[0.0, 1.0]] * 3)
    profile = performance_profile(scores, [0.5], n_resamples=500, seed=0)
    assert (profile.fraction[0], profile.low[0], profile.high[0]) == (0.5, 0.5, 0.5)


def test_one_run_has_no_band_and_bad_arguments_are_refused():
    one = performance_profile([[0.3, 0.8], [0.5, np.nan]], [0.4], n_resamples=100)
    assert one.fraction.tolist() == [pytest.approx(2 / 3)] and math.isnan(one.low[0]) and "1 run" in one.note
    none = performance_profile([np.nan, np.nan], [0.4])
    assert math.isnan(none.fraction[0]) and none.note == "no finite score"
    with pytest.raises(ValueError, match="confidence=1.0"):
        performance_profile([0.1, 0.2], [0.5], confidence=1.0)
    with pytest.raises(ValueError, match="taus"):
        performance_profile([0.1, 0.2], [])
