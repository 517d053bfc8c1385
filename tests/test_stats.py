"""Performance profiles (``sidewalk.stats.performance_profile``) against hand-computed fractions: strictly above each
threshold as rliable counts, pooled over tasks with NaN runs dropped, and a stratified-bootstrap band that a seed
fixes and that keeps each task's number of runs. The comparisons of methods against hand counts and rliable: the
optimality gap, the probability of improvement P(X > Y) with its stratified bootstrap of both samples, the difference
of two independent samples, and whether an interval separates a comparison."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.stats

from sidewalk.stats import (
    FEW_RUNS,
    ONE_RUN_NOTE,
    difference_interval,
    fraction_above,
    holm,
    holm_adjusted,
    interval_estimate,
    optimality_gap,
    paired_difference_interval,
    performance_profile,
    permutation_p,
    probability_of_improvement,
    separates,
    separation_text,
)


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


# ---- comparisons -----------------------------------------------------------------------------------------------------


def test_the_optimality_gap_is_the_mean_shortfall_below_the_threshold():
    assert optimality_gap([1.0, 1.0, 0.5, 0.0]) == pytest.approx(0.375)  # (0 + 0 + 0.5 + 1) / 4
    assert optimality_gap([1.0, 0.9, 0.4], threshold=0.5) == pytest.approx(0.1 / 3)  # scores above it count 0
    # Pooled over tasks, the NaN padding dropped: shortfalls 0.8, 0.5 | 0.0, 0.3, 0.2 -> 1.8 / 5.
    assert optimality_gap([[0.2, 1.0], [0.5, 0.7], [np.nan, 0.8]]) == pytest.approx(1.8 / 5)
    gap = interval_estimate([1.0, 1.0, 0.5, 0.0], "optimality_gap", n_resamples=1000, seed=2)
    assert gap.point == pytest.approx(0.375) and gap.low < gap.point < gap.high
    assert 0.0 <= gap.low and gap.high <= 1.0  # every resample's gap is a mean shortfall of rates in [0, 1]
    assert interval_estimate([1.0, 1.0, 0.5, 0.0], "optimality_gap", n_resamples=1000, seed=2) == gap
    metrics = pytest.importorskip("rliable.metrics")
    scores = np.random.default_rng(5).uniform(0.0, 1.2, (7, 3))
    assert optimality_gap(scores) == pytest.approx(metrics.aggregate_optimality_gap(scores))
    with pytest.raises(ValueError, match="threshold=nan"):
        optimality_gap([0.5], threshold=math.nan)


def pairs_above(x, y) -> float:
    """P(X > Y) of one task counted pair by pair: 1 where x_i > y_j, 0.5 where equal."""
    return np.mean([[1.0 if a > b else 0.5 if a == b else 0.0 for b in y] for a in x])


def test_the_probability_of_improvement_counts_the_pairs_ties_half():
    x, y = [1.0, 2.0, 3.0], [2.0, 2.0, 0.0]
    # x = 1 beats only 0; x = 2 ties both 2s and beats 0; x = 3 beats all: (1 + 2 + 3) / 9.
    assert probability_of_improvement(x, y, n_resamples=200).point == pytest.approx(6 / 9)
    # P(Y > X) = 1 − P(X > Y): a tie counts half each way.
    assert probability_of_improvement(y, x, n_resamples=200).point == pytest.approx(3 / 9)
    same = probability_of_improvement(x, x, n_resamples=200)
    assert same.point == 0.5 and same.low < 0.5 < same.high and not separates(same, 0.5)
    # Two tasks, the second NaN-padded: the mean of the tasks' probabilities, each over its own runs.
    x2 = np.array([[0.1, 0.9], [0.5, 0.3], [0.7, np.nan]])
    y2 = np.array([[0.4, 0.3], [0.4, 0.8], [0.6, 0.1]])
    expected = (pairs_above([0.1, 0.5, 0.7], [0.4, 0.4, 0.6]) + pairs_above([0.9, 0.3], [0.3, 0.8, 0.1])) / 2
    assert probability_of_improvement(x2, y2, n_resamples=200).point == pytest.approx(expected)
    metrics = pytest.importorskip("rliable.metrics")
    rng = np.random.default_rng(6)
    xs, ys = rng.integers(0, 4, (6, 3)) / 4, rng.integers(0, 4, (5, 3)) / 4  # ties aplenty
    assert probability_of_improvement(xs, ys, n_resamples=200).point == pytest.approx(
        metrics.probability_of_improvement(xs, ys)
    )


def test_the_probability_of_improvement_resamples_both_samples_within_each_task():
    rng = np.random.default_rng(8)
    x, y = rng.normal(0.6, 0.2, (5, 2)), rng.normal(0.4, 0.2, (4, 2))
    got = probability_of_improvement(x, y, n_resamples=500, seed=4)
    # The same resampling by hand, pair by pair: x's and y's runs of each task resampled on their own.

    def by_pairs(x0, x1, y0, y1, axis=-1):
        return np.array(
            [(pairs_above(*t0) + pairs_above(*t1)) / 2 for t0, t1 in zip(zip(x0, y0), zip(x1, y1))]
        )

    expected = scipy.stats.bootstrap(
        (x[:, 0], x[:, 1], y[:, 0], y[:, 1]),
        by_pairs,
        n_resamples=500,
        method="percentile",
        paired=False,
        vectorized=True,
        rng=np.random.default_rng(4),
    ).confidence_interval
    assert (got.low, got.high) == (pytest.approx(expected.low), pytest.approx(expected.high))
    assert probability_of_improvement(x, y, n_resamples=500, seed=4) == got  # a seed fixes the interval


def test_a_clearly_better_sample_separates_and_one_run_has_no_interval():
    better = probability_of_improvement([0.8, 0.9, 0.85, 0.95], [0.1, 0.3, 0.2, 0.25], n_resamples=500)
    assert better.point == 1.0 and better.low > 0.5 and separates(better, 0.5)
    # 4 against 4 seeds: 70 splits, the two most extreme of which give p = 2/70.
    assert better.p == pytest.approx(2 / 70) and better.smallest_p == pytest.approx(2 / 70)
    assert separation_text(better, 0.5) == "separates at 95% (p 0.029, exact Mann-Whitney, 4 v 4 seeds)"
    one = probability_of_improvement([[0.9, 0.2], [np.nan, 0.4]], [[0.1, 0.3], [0.2, 0.5]], n_resamples=200)
    assert one.point == pytest.approx((1.0 + 0.25) / 2) and math.isnan(one.low) and one.note == ONE_RUN_NOTE
    # 1 v 2 and 2 v 2 runs split 3 × 6 ways: no test at 5 %.
    assert not separates(one, 0.5) and one.smallest_p == pytest.approx(2 / 18)
    assert separation_text(one, 0.5).startswith("cannot separate at 95% (smallest p 0.11: stratified Mann-Whitney")
    with pytest.raises(ValueError, match="x has 2 tasks and y has 1"):
        probability_of_improvement([[0.1, 0.2], [0.3, 0.4]], [0.1, 0.2])
    with pytest.raises(ValueError, match="n_resamples=0"):
        probability_of_improvement([0.1, 0.2], [0.1, 0.2], n_resamples=0)


def test_the_difference_of_two_samples_is_an_independent_bootstrap():
    apart = difference_interval([1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0], n_resamples=200)
    assert (apart.point, apart.low, apart.high) == (1.0, 1.0, 1.0) and separates(apart, 0.0)
    # Three seeds a side never separate, however far apart: 20 splits, p ≥ 2/20, though the interval excludes 0.
    three = difference_interval([1.0, 1.0, 1.0], [0.0, 0.0, 0.0], n_resamples=200)
    assert three.low == 1.0 and three.p == pytest.approx(0.1) and not separates(three, 0.0)
    assert separation_text(three, 0.0) == "cannot separate at 95% (smallest p 0.1: exact Mann-Whitney, 3 v 3 seeds)"
    equal = difference_interval([0.2, 0.5, 0.9, 0.4], [0.2, 0.5, 0.9, 0.4], n_resamples=500)
    assert equal.point == 0.0 and equal.low < 0.0 < equal.high and not separates(equal, 0.0)
    assert separation_text(equal, 0.0, confidence=0.9) == "does not separate at 90% (p 1, exact Mann-Whitney, 4 v 4 seeds)"
    a, b = [3.0, 4.0, 6.0, np.nan], [1.0, 2.0, 2.5]
    got = difference_interval(a, b, "median", n_resamples=1000, seed=9)
    expected = scipy.stats.bootstrap(
        ([3.0, 4.0, 6.0], b),
        lambda first, second, axis: np.median(first, axis=axis) - np.median(second, axis=axis),
        n_resamples=1000,
        method="percentile",
        paired=False,
        vectorized=True,
        rng=np.random.default_rng(9),
    ).confidence_interval
    assert got.point == 2.0 and got.runs == 3  # the NaN dropped: medians 4 and 2
    assert (got.low, got.high) == (pytest.approx(expected.low), pytest.approx(expected.high))
    assert difference_interval(a, b, "median", n_resamples=1000, seed=9) == got
    one = difference_interval([5.0], [1.0, 2.0])
    assert one.point == 3.5 and math.isnan(one.high) and one.note == ONE_RUN_NOTE and not separates(one, 0.0)
    with pytest.raises(ValueError, match=r"a must be a non-empty 1-d array.*\(2, 2\)"):
        difference_interval([[1.0, 2.0], [3.0, 4.0]], [1.0, 2.0])
    with pytest.raises(ValueError, match="statistic='mode'"):
        difference_interval([1.0, 2.0], [1.0, 2.0], "mode")
    with pytest.raises(ValueError, match="confidence=0.0"):
        difference_interval([1.0, 2.0], [1.0, 2.0], confidence=0.0)


# ---- tests at the seed level: exact, valid at their n, and adjusted for multiplicity ---------------------------------


def test_the_rank_test_is_scipys_exact_mann_whitney_and_a_censored_seed_ranks_last():
    rng = np.random.default_rng(5)
    a, b = rng.normal(0.0, 1.0, 7), rng.normal(1.0, 1.0, 8)
    p, smallest, how = permutation_p(a, b)
    assert p == pytest.approx(scipy.stats.mannwhitneyu(a, b, method="exact").pvalue)  # no ties: the same test
    assert smallest == pytest.approx(2 / math.comb(15, 7)) and how == "exact Mann-Whitney, 7 v 8 seeds"
    # A seed that never learned (inf frames) is the slowest of all: three learners against three that never did.
    assert permutation_p([1e4, 2e4, 3e4], [math.inf] * 3)[0] == pytest.approx(0.1)
    assert permutation_p([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])[0] == 1.0  # all tied: nothing to tell apart


def test_the_sign_flip_test_enumerates_every_flip_of_the_paired_differences():
    differences = np.array([0.3, 0.1, 0.2, -0.05, 0.25])
    p, smallest, how = permutation_p(differences, None, paired=True)
    flips = np.array(list(itertools.product([-1, 1], repeat=5)))
    expected = np.mean(np.abs(flips @ differences) >= abs(differences.sum()) - 1e-12)
    assert p == pytest.approx(expected) and smallest == pytest.approx(2 / 32) and how == "exact sign-flip, 5 seeds"
    paired = paired_difference_interval([0.9, 0.8, 0.85], [0.6, 0.7, 0.65], n_resamples=200)
    assert paired.point == pytest.approx(0.2) and paired.p == pytest.approx(0.25)  # 3 pairs: 2 of 8 flips as far
    with pytest.raises(ValueError, match="equal length|one shape"):
        paired_difference_interval([1.0, 2.0], [1.0])


def test_a_seed_that_fixes_a_convention_is_one_unit_across_partners():
    # The audit's pattern: each seed of a condition plays all partners; seeds 0 and 1 fail partner A and meet B,
    # seed 2 the other way round. Partners are not samples: the clustered test splits whole seeds.
    x = np.array([[0.0, 1.0, 0.9], [0.0, 1.0, 0.9], [1.0, 0.0, 0.9]])
    y = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]])
    clustered = probability_of_improvement(x, y, clustered=True, n_resamples=2000)
    assert clustered.test == "exact Mann-Whitney, 3 v 3 seeds over 3 tasks" and clustered.smallest_p == 0.1
    assert not separates(clustered, 0.5)
    # Whole rows are resampled: a resample of three copies of seed 2 is possible, of seed 0's first cell with seed
    # 2's second is not, so every resampled P(X > Y) is a mean over whole seeds.
    rows = np.array([[0.0, 1.0], [1.0, 0.0]])
    interval = interval_estimate(rows, "mean", clustered=True, n_resamples=500)
    assert (interval.point, interval.low, interval.high) == (0.5, 0.5, 0.5)  # every row's mean is 0.5
    assert interval_estimate(rows, "mean", n_resamples=500).low < 0.5  # the stratified one mixes cells


def test_holm_adjusts_a_family_step_down_and_names_it():
    assert holm([0.01, 0.04, 0.03, math.nan]) == pytest.approx([0.03, 0.06, 0.06, math.nan], nan_ok=True)
    assert holm([0.5, 0.001]) == pytest.approx([0.5, 0.002])
    tested = [difference_interval([1.0, 2, 3, 4], [6.0, 7, 8, 9], n_resamples=100)] * 3
    adjusted = holm_adjusted(tested)
    assert adjusted[0].p == pytest.approx(3 * tested[0].p) and adjusted[0].test.endswith("; Holm over 3")
    assert not separates(adjusted[0], 0.0) and separates(tested[0], 0.0)  # p 2/70 alone, 3 × that in a family


def test_the_verdicts_error_rate_holds_at_few_seeds_where_the_bootstrap_interval_does_not():
    # Equal conditions, 3 and 5 seeds a side: how often each rule calls a difference. The percentile bootstrap's
    # false separations run far above 5 % (the audit: 19 % at 3, 12 % at 5); the exact test's stay at or below 5 %.
    # 400 draws: a rate near 0.05 has a standard error of 0.011, so the bounds below sit 3 errors away.
    rng = np.random.default_rng(0)
    for seeds, bootstrap_above in ((3, 0.12), (5, 0.08)):
        by_interval = by_test = 0
        for _ in range(400):
            d = difference_interval(rng.normal(size=seeds), rng.normal(size=seeds), n_resamples=400,
                                    seed=int(rng.integers(1 << 30)))
            by_interval += d.low > 0 or d.high < 0
            by_test += separates(d, 0.0)
        assert by_interval / 400 > bootstrap_above and by_test / 400 <= 0.05 + 0.033
    # What FEW_RUNS says: at 3 runs a nominal 95 % interval of a mean covers far less (the audit measured 0.74).
    intervals = [interval_estimate(rng.normal(size=3), "mean", n_resamples=400, seed=k) for k in range(400)]
    covered = sum(interval.low <= 0.0 <= interval.high for interval in intervals)
    assert covered / 400 < 0.85 and FEW_RUNS == 10
