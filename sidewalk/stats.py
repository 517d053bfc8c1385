"""Statistics over seeds: mean and standard error (the paper's curves), interquartile mean and stratified-bootstrap
confidence intervals, and performance profiles with their bootstrap bands (the rliable way: Agarwal et al., "Deep RL
at the Edge of the Statistical Precipice", 2021).

Scores are arrays of shape (runs,) or (runs, tasks): one value per seed (run), optionally for several tasks
(settings aggregated together). A stratified bootstrap resamples the runs of each task separately, with
replacement, so every resample keeps each task's number of runs; with one task it is the ordinary bootstrap over
runs. Intervals are percentile intervals, as rliable computes them.

The resampling is ``scipy.stats.bootstrap``, which resamples each of several samples independently: given one
sample per task, that is exactly rliable's stratified bootstrap. (``rliable.library`` itself does not import next to
pandas 3 with arch 7, and its ``StratifiedBootstrap`` rejects arch 8's ``random_state`` handling; scipy is a
dependency of this package anyway.) The interquartile mean is ``scipy.stats.trim_mean(scores, 0.25, axis=None)``,
which is what ``rliable.metrics.aggregate_iqm`` computes.

Comparisons of methods as Agarwal et al. (2021) make them with rliable, here in numpy and scipy alone: the
optimality gap (``optimality_gap``, the mean shortfall of the scores below a target, also an ``interval_estimate``
statistic), the probability of improvement P(X > Y) of one algorithm over another (``probability_of_improvement``:
per task the normalised Mann-Whitney U, averaged over tasks, with a stratified bootstrap of both algorithms' runs),
and the difference of a statistic between two independent samples (``difference_interval``) or of two measures of
the same runs (``paired_difference_interval``).

Verdicts rest on a test whose error rate holds at the number of seeds, not on the bootstrap interval: a percentile
bootstrap over few seeds covers less than its nominal level (``tests/test_stats.py`` measures it), so at 3 seeds a
side a 95 % interval "separates" equal conditions far more often than 5 % of the time. Every comparison carries the
p-value of an exact permutation test with the seed as the unit (``permutation_p``): the Mann-Whitney rank test of two
conditions' seeds (all splits of the pooled seeds enumerated; a censored value, such as ``inf`` frames for a seed that
never learned, ranks last), the sign-flip test of paired per-seed differences, and for scores over several tasks the
same splits of whole seeds (``clustered``: the tasks are partners one policy played) or of each task's runs on their
own (the tasks are separate experiments). A comparison separates when that p-value is at most 1 − confidence
(``separates``); its smallest attainable p-value (``Interval.smallest_p``) says when the seeds cannot separate anything
(3 against 3: 0.1). ``holm`` adjusts a family of p-values for multiplicity (Holm 1979).

Few runs: with one run per task there is nothing to resample, so the interval is NaN and ``Interval.note`` says so
(and it separates nothing); with two runs a task's resamples take only three distinct values, so the interval is
computed but flagged coarse.
"""

from __future__ import annotations

import functools
import itertools
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.stats

from sidewalk._checks import check_choice, check_int, check_range


def _shortfall(scores: np.ndarray, axis: int, threshold: float) -> np.ndarray:
    return np.mean(np.maximum(threshold - scores, 0.0), axis=axis)


# The statistics an interval can be asked for by name; each maps scores (..., values) to (...).
STATISTICS: dict[str, Callable[[np.ndarray, int], np.ndarray]] = {
    "mean": lambda x, axis: np.mean(x, axis=axis),
    "median": lambda x, axis: np.median(x, axis=axis),
    "iqm": lambda x, axis: scipy.stats.trim_mean(x, 0.25, axis=axis),
    # Against 1: the scores this package aggregates are rates in [0, 1] whose target is 1.
    "optimality_gap": lambda x, axis: _shortfall(x, axis, 1.0),
}


@dataclass(frozen=True)
class Interval:
    """A point estimate with its confidence interval; ``low``/``high`` are NaN where no interval exists, and
    ``note`` says why (or that the interval is coarse)."""

    point: float
    low: float
    high: float
    runs: int  # the fewest runs of any task
    note: str = ""
    # A comparison's test (``permutation_p``): its two-sided p-value (after any multiplicity adjustment), the smallest
    # p-value its seeds allow, and what it was ("exact Mann-Whitney, 5 v 5 seeds"); NaN and "" for an estimate.
    p: float = math.nan
    smallest_p: float = math.nan
    test: str = ""


def as_scores(scores: np.ndarray | list) -> np.ndarray:
    """Scores as a float array (runs, tasks); a 1-d array is one task. Raises on an empty or >2-d array."""
    array = np.asarray(scores, dtype=float)
    if array.ndim == 1:
        array = array[:, None]
    if array.ndim != 2 or array.size == 0:
        raise ValueError(
            f"scores must be a non-empty (runs,) or (runs, tasks) array; got shape {array.shape}"
        )
    return array


def mean_se(values: np.ndarray | list, axis: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, standard error ``std(ddof=1) / sqrt(n)`` and count ``n`` along ``axis``, ignoring NaNs.

    Where fewer than two values are present the standard error is NaN (one seed has no spread to estimate);
    where none are, the mean is NaN too.
    """
    array = np.asarray(values, dtype=float)
    count = np.sum(~np.isnan(array), axis=axis)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: NaN is the intended answer
        mean = np.nanmean(array, axis=axis)
        std = np.nanstd(array, axis=axis, ddof=1)
    se = np.where(count >= 2, std / np.sqrt(np.maximum(count, 1)), np.nan)
    return mean, se, count


def iqm(scores: np.ndarray | list) -> float:
    """Interquartile mean of every score (runs × tasks pooled): the mean of the middle 50 %, as rliable's
    ``aggregate_iqm``. With fewer than four scores nothing is trimmed and it equals the mean."""
    return float(scipy.stats.trim_mean(as_scores(scores), 0.25, axis=None))


def interval_estimate(
    scores: np.ndarray | list,
    statistic: str | Callable[[np.ndarray, int], np.ndarray] = "iqm",
    *,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
    clustered: bool = False,
) -> Interval:
    """``statistic`` of ``scores`` (runs,) or (runs, tasks) with a stratified-bootstrap percentile interval.

    ``statistic`` is ``"iqm"``, ``"mean"``, ``"median"``, ``"optimality_gap"`` (against 1) or a function
    ``f(values, axis)`` reducing ``axis`` of the pooled scores of all tasks. The same ``seed`` gives the same
    interval. NaN scores (a metric undefined in a run, e.g. path efficiency with no arrival) are dropped per task
    first. ``clustered``: a row is one seed across every task (one policy played every partner), and the bootstrap
    resamples whole rows, the seed being the unit (rows with a NaN are dropped).
    """
    reduce = _reducer(statistic)
    _check_bootstrap(confidence, n_resamples)
    if clustered:
        rows = complete_rows(scores)
        if len(rows) == 0:
            return Interval(math.nan, math.nan, math.nan, 0, "no finite score")
        point = float(reduce(rows.ravel(), -1))
        if len(rows) < 2:
            return Interval(point, math.nan, math.nan, len(rows), ONE_RUN_NOTE)
        low, high = _cluster_bootstrap([rows], lambda r: reduce(r.reshape(*r.shape[:-2], -1), -1), confidence,
                                       n_resamples, seed)
        return Interval(point, float(low), float(high), len(rows), _few_runs_note(len(rows)))
    tasks = finite_tasks(scores)
    runs = min(len(task) for task in tasks)
    if runs == 0:
        return Interval(math.nan, math.nan, math.nan, 0, "no finite score")
    pooled = np.concatenate(tasks)
    point = float(reduce(pooled, -1))
    if runs < 2:
        return Interval(point, math.nan, math.nan, runs, ONE_RUN_NOTE)
    low, high = _stratified_bootstrap(tasks, reduce, confidence, n_resamples, seed)
    return Interval(point, float(low), float(high), runs, _few_runs_note(runs))


def complete_rows(scores: np.ndarray | list) -> np.ndarray:
    """The rows (seeds) of ``as_scores(scores)`` with a finite score in every task."""
    array = as_scores(scores)
    return array[~np.isnan(array).any(axis=1)]


def _cluster_bootstrap(
    samples: Sequence[np.ndarray],
    statistic: Callable[..., np.ndarray],
    confidence: float,
    n_resamples: int,
    seed: int,
) -> tuple[float, float]:
    """The percentile interval of ``statistic(*resampled)``, each sample (rows, tasks) resampled by whole rows on its
    own; ``statistic`` maps arrays (resamples, rows, tasks) to (resamples,)."""
    rng = np.random.default_rng(seed)
    resampled = [rows[rng.integers(0, len(rows), size=(n_resamples, len(rows)))] for rows in samples]
    values = statistic(*resampled)
    tail = (1.0 - confidence) / 2
    low, high = np.quantile(values, [tail, 1.0 - tail])
    return float(low), float(high)


ONE_RUN_NOTE = "1 run: no interval (a bootstrap needs ≥ 2 runs per task)"


def _reducer(
    statistic: str | Callable[[np.ndarray, int], np.ndarray],
) -> Callable[[np.ndarray, int], np.ndarray]:
    if isinstance(statistic, str):
        check_choice("statistic", statistic, STATISTICS)
        return STATISTICS[statistic]
    return statistic


def _few_runs_note(runs: int) -> str:
    if runs == 2:
        return "2 runs: coarse interval (few distinct resamples)"
    if runs < FEW_RUNS:
        return f"{runs} runs: the interval covers less than its level (a verdict rests on the exact test)"
    return ""


# Below this many runs a percentile bootstrap interval covers well below its nominal level (measured in
# tests/test_stats.py: about 0.74 of a 95 % interval of a mean at 3 runs, 0.82 at 5, 0.90 at 10).
FEW_RUNS = 10


def finite_tasks(scores: np.ndarray | list) -> list[np.ndarray]:
    """Each task's finite scores (a column of ``as_scores(scores)`` without its NaNs): tasks of unequal numbers of
    runs are given as a (runs, tasks) array padded with NaN."""
    return [column[~np.isnan(column)] for column in as_scores(scores).T]


def _check_bootstrap(confidence: float, n_resamples: int) -> None:
    check_range("confidence", confidence, 0.0, 1.0, low_open=True)
    if confidence == 1.0:  # check_range's upper bound is closed; a 100 % interval is every resample's range
        raise ValueError(f"confidence={confidence!r} is out of range; valid: (0.0, 1.0)")
    check_int("n_resamples", n_resamples, 1)


def _stratified_bootstrap(
    tasks: list[np.ndarray],
    reduce: Callable[[np.ndarray, int], np.ndarray],
    confidence: float,
    n_resamples: int,
    seed: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval (low, high) of ``reduce`` over the pooled runs of all ``tasks``, each task's runs
    resampled on their own; ``reduce`` may return several values (a profile), and so do low and high."""

    def pooled_statistic(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        return reduce(np.concatenate(samples, axis=axis), axis)

    return _independent_bootstrap(tasks, pooled_statistic, confidence, n_resamples, seed)


def _independent_bootstrap(
    samples: Sequence[np.ndarray],
    statistic: Callable[..., np.ndarray],
    confidence: float,
    n_resamples: int,
    seed: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval (low, high) of ``statistic(*samples, axis=-1)``, each sample resampled on its own."""
    with warnings.catch_warnings():
        warnings.simplefilter(
            "ignore"
        )  # identical scores give a degenerate (zero-width) interval: that is fine
        result = scipy.stats.bootstrap(
            tuple(samples),
            statistic,
            n_resamples=n_resamples,
            vectorized=True,
            paired=False,  # each sample resampled on its own: with a sample per task, the stratified bootstrap
            confidence_level=confidence,
            method="percentile",
            rng=np.random.default_rng(seed),
        )
    return result.confidence_interval.low, result.confidence_interval.high


@dataclass(frozen=True)
class Profile:
    """A performance profile: at each threshold of ``taus``, the fraction of runs scoring above it, with its
    confidence band (``low``/``high`` NaN where no band exists, and ``note`` says why, or that it is coarse)."""

    taus: np.ndarray
    fraction: np.ndarray
    low: np.ndarray
    high: np.ndarray
    runs: int  # the fewest runs of any task
    note: str = ""


def fraction_above(scores: np.ndarray, taus: np.ndarray, axis: int = -1) -> np.ndarray:
    """The fraction of ``scores`` along ``axis`` strictly above each of ``taus``: shape (len(taus), rest...)."""
    above = np.expand_dims(np.moveaxis(scores, axis, -1), -2) > np.asarray(taus, dtype=float)[:, None]
    return np.moveaxis(np.mean(above, axis=-1), -1, 0)


def performance_profile(
    scores: np.ndarray | list,
    taus: np.ndarray | list,
    *,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
) -> Profile:
    """The performance profile of ``scores`` (runs,) or (runs, tasks): for each threshold τ of ``taus`` the fraction
    of all runs (pooled over tasks) whose score is strictly above τ, as rliable's ``create_performance_profile``
    (its score distribution), with a stratified-bootstrap percentile band at ``confidence``.

    NaN scores are dropped per task first, so tasks of unequal runs come as a NaN-padded array and every run
    counts once. The same ``seed`` gives the same band; with 1 run in some task there is no band.
    """
    _check_bootstrap(confidence, n_resamples)
    thresholds = np.asarray(taus, dtype=float).ravel()
    if thresholds.size == 0 or np.isnan(thresholds).any():
        raise ValueError(f"taus must be a non-empty list of numbers; got {taus!r}")
    tasks = finite_tasks(scores)
    runs = min(len(task) for task in tasks)
    nothing = np.full(thresholds.shape, math.nan)
    if runs == 0:
        return Profile(thresholds, nothing, nothing, nothing, 0, "no finite score")
    fraction = fraction_above(np.concatenate(tasks), thresholds)
    if runs < 2:
        return Profile(thresholds, fraction, nothing, nothing, runs, ONE_RUN_NOTE)

    def reduce(pooled: np.ndarray, axis: int) -> np.ndarray:
        return fraction_above(pooled, thresholds, axis)

    low, high = _stratified_bootstrap(tasks, reduce, confidence, n_resamples, seed)
    return Profile(thresholds, fraction, np.asarray(low), np.asarray(high), runs, _few_runs_note(runs))


# ---- comparisons ---------------------------------------------------------------------------------------------------


def optimality_gap(scores: np.ndarray | list, threshold: float = 1.0) -> float:
    """rliable's optimality gap of ``scores`` (runs,) or (runs, tasks): the mean over every run of every task of
    ``max(threshold − score, 0)``, how far the scores fall short of ``threshold`` (0 where every run reaches it;
    lower is better). NaN scores are dropped; NaN where none is left."""
    check_range("threshold", threshold)
    pooled = np.concatenate(finite_tasks(scores))
    return float(_shortfall(pooled, -1, threshold)) if pooled.size else math.nan


def probability_of_improvement(
    x: np.ndarray | list,
    y: np.ndarray | list,
    *,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
    clustered: bool = False,
) -> Interval:
    """rliable's probability of improvement P(X > Y): the chance that a run of ``x`` scores above a run of ``y`` in
    the same task, ties counting half, averaged over the tasks. Per task it is the Mann-Whitney U statistic of ``x``
    over ``y`` divided by the number of pairs: the mean over every pair (x_i, y_j) of 1 if x_i > y_j, 0.5 if equal
    and 0 otherwise. P(X > Y) + P(Y > X) = 1, and 0.5 is no difference.

    ``x`` and ``y`` are (runs,) or (runs, tasks) with the same tasks, NaN-padded where a task has fewer runs (NaN is
    dropped per task). The interval is a stratified percentile bootstrap at ``confidence`` that resamples the runs
    of ``x`` and those of ``y`` independently within each task, as rliable's ``get_interval_estimates`` does for a
    pair; the same ``seed`` gives the same interval. ``clustered``: a row is one seed across every task (the same
    policy played every partner), so whole rows are resampled, and tested, together (rows with a NaN are dropped).
    The interval carries the p-value of the exact permutation test with the seed as the unit (``permutation_p``).
    With fewer than 2 runs of either in some task: the point, a NaN interval and ``ONE_RUN_NOTE``.
    """
    _check_bootstrap(confidence, n_resamples)
    x_tasks, y_tasks = finite_tasks(x), finite_tasks(y)
    if len(x_tasks) != len(y_tasks):
        raise ValueError(
            f"x has {len(x_tasks)} tasks and y has {len(y_tasks)}; valid: scores of the same tasks, "
            f"(runs,) or (runs, tasks) with one column per task"
        )
    if clustered:
        x_rows, y_rows = complete_rows(x), complete_rows(y)
        x_tasks, y_tasks = list(x_rows.T), list(y_rows.T)
    samples = x_tasks + y_tasks  # x's tasks, then y's in the same order: the form _mean_improvement reads
    runs = min(len(sample) for sample in samples)
    if runs == 0:
        return Interval(math.nan, math.nan, math.nan, 0, "no finite score")
    point = float(_mean_improvement(*samples))
    test = permutation_p(x, y, clustered=clustered, seed=seed)
    if runs < 2:
        return Interval(point, math.nan, math.nan, runs, ONE_RUN_NOTE, *test)
    if clustered:
        def improvement(x_resampled: np.ndarray, y_resampled: np.ndarray) -> np.ndarray:
            tasks = x_resampled.shape[-1]
            return _mean_improvement(*(x_resampled[..., t] for t in range(tasks)),
                                     *(y_resampled[..., t] for t in range(tasks)))

        low, high = _cluster_bootstrap([x_rows, y_rows], improvement, confidence, n_resamples, seed)
    else:
        low, high = _independent_bootstrap(samples, _mean_improvement, confidence, n_resamples, seed)
    return Interval(point, float(low), float(high), runs, _few_runs_note(runs), *test)


def _mean_improvement(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
    """The mean over tasks of P(X > Y) along ``axis``; ``samples`` are X's tasks, then Y's in the same order."""
    tasks = len(samples) // 2
    return np.mean([_improvement(x, y, axis) for x, y in zip(samples[:tasks], samples[tasks:])], axis=0)


def _improvement(x: np.ndarray, y: np.ndarray, axis: int) -> np.ndarray:
    """P(X > Y) of one task along ``axis``: the Mann-Whitney U of ``x``, from the ranks of x and y pooled (ties at
    their mean rank, so a tie counts half), over the number of pairs; memory linear in the runs, not the pairs."""
    x, y = np.moveaxis(x, axis, -1), np.moveaxis(y, axis, -1)
    m, n = x.shape[-1], y.shape[-1]
    ranks = scipy.stats.rankdata(np.concatenate([x, y], axis=-1), axis=-1)
    return (np.sum(ranks[..., :m], axis=-1) - m * (m + 1) / 2) / (m * n)


def difference_interval(
    a: np.ndarray | list,
    b: np.ndarray | list,
    statistic: str | Callable[[np.ndarray, int], np.ndarray] = "mean",
    *,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
) -> Interval:
    """``statistic`` of ``a`` minus that of ``b``, two independent samples of one value per run (the seeds of two
    conditions, say), with the percentile interval at ``confidence`` of a bootstrap that resamples each sample on
    its own, and the p-value of the exact Mann-Whitney permutation test (``permutation_p``). ``statistic`` is as for
    ``interval_estimate``; the same ``seed`` gives the same interval. NaN values are dropped first; ``inf`` (a
    censored value: a seed that never got there) takes part in the test, ranking last, but leaves no finite point or
    interval. With fewer than 2 values in either sample: the point, a NaN interval and ``ONE_RUN_NOTE``.
    """
    reduce = _reducer(statistic)
    _check_bootstrap(confidence, n_resamples)
    samples = [_finite_sample(name, values) for name, values in (("a", a), ("b", b))]
    runs = min(len(sample) for sample in samples)
    if runs == 0:
        return Interval(math.nan, math.nan, math.nan, 0, "no finite score")
    test = permutation_p(*samples, seed=seed)
    if not all(np.isfinite(sample).all() for sample in samples):
        return Interval(math.nan, math.nan, math.nan, runs, "censored values: no difference of means", *test)
    point = float(reduce(samples[0], -1) - reduce(samples[1], -1))
    if runs < 2:
        return Interval(point, math.nan, math.nan, runs, ONE_RUN_NOTE, *test)

    def difference(first: np.ndarray, second: np.ndarray, axis: int = -1) -> np.ndarray:
        return reduce(first, axis) - reduce(second, axis)

    low, high = _independent_bootstrap(samples, difference, confidence, n_resamples, seed)
    return Interval(point, float(low), float(high), runs, _few_runs_note(runs), *test)


def paired_difference_interval(
    a: np.ndarray | list,
    b: np.ndarray | list,
    *,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
) -> Interval:
    """The mean of ``a − b``, two measures of the same runs (two agents of each seed), with the percentile interval of
    a bootstrap of the per-run differences and the p-value of the exact sign-flip permutation test of their mean
    (``permutation_p(..., paired=True)``). Pairs with a NaN are dropped."""
    first, second = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if first.ndim != 1 or first.shape != second.shape or first.size == 0:
        raise ValueError(f"a and b must be non-empty 1-d arrays of one shape; got {first.shape} and {second.shape}")
    differences = first - second  # interval_estimate and permutation_p drop the NaN pairs
    estimate = interval_estimate(differences, "mean", confidence=confidence, n_resamples=n_resamples, seed=seed)
    if np.isnan(differences).all():
        return estimate
    p, smallest_p, test = permutation_p(differences, None, paired=True, seed=seed)
    return replace(estimate, p=p, smallest_p=smallest_p, test=test)


def _finite_sample(name: str, values: np.ndarray | list) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1 or array.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-d array, one value per run; got shape {array.shape}")
    return array[~np.isnan(array)]


# ---- tests at the seed level ----------------------------------------------------------------------------------------

# Splits of the seeds are all enumerated up to this many; beyond, a Monte Carlo of MONTE_CARLO random ones, whose
# p-value (hits + 1) / (draws + 1) is valid at any number of draws.
EXACT_SPLITS = 200_000
MONTE_CARLO = 20_000


def permutation_p(
    a: np.ndarray | list,
    b: np.ndarray | list | None,
    *,
    paired: bool = False,
    clustered: bool = False,
    seed: int = 0,
) -> tuple[float, float, str]:
    """(p, smallest p, what it was): the two-sided p-value of a permutation test of "``a`` and ``b`` come from one
    distribution", with the seed as the unit, and the smallest p-value as many seeds allow (data without ties, the
    two most extreme splits).

    - ``paired`` (``b`` ignored; ``a`` the per-seed differences): the sign-flip test of their mean.
    - One task, (runs,): the Mann-Whitney rank test, exact over every split of the pooled seeds into groups of
      ``len(a)`` and ``len(b)`` (ties at their mean rank, ``inf`` last, NaN dropped).
    - Several tasks, (runs, tasks): the statistic is rliable's probability of improvement minus 0.5 (the mean over
      tasks of each task's Mann-Whitney U over its pairs). ``clustered``: a row is one seed across every task, and
      whole rows are split (rows with a NaN dropped); otherwise each task's runs are split on their own (the tasks
      are separate experiments), by Monte Carlo.

    Exact wherever the splits number at most ``EXACT_SPLITS``, else a Monte Carlo of ``MONTE_CARLO`` seeded by
    ``seed``."""
    rng = np.random.default_rng(seed)
    if paired:
        differences = np.asarray(a, dtype=float).ravel()
        differences = differences[~np.isnan(differences)]
        n = len(differences)
        if n == 0:
            return math.nan, math.nan, "no finite score"
        if 2**n <= EXACT_SPLITS:
            signs = 1 - 2 * ((np.arange(2**n)[:, None] >> np.arange(n)) & 1)
            how = f"exact sign-flip, {n} seeds"
        else:
            signs = rng.choice([-1, 1], size=(MONTE_CARLO, n))
            how = f"sign-flip, {n} seeds, {MONTE_CARLO:,} random flips"
        null = np.abs(signs @ differences) / n
        return _p_value(null, abs(differences.mean()), exact=2**n <= EXACT_SPLITS), min(1.0, 2 / 2**n), how
    x, y = as_scores(a), as_scores(b)
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"a has {x.shape[1]} tasks and b has {y.shape[1]}; valid: scores of the same tasks")
    if clustered or x.shape[1] == 1:
        x, y = complete_rows(x), complete_rows(y)  # one task: its NaN dropped
        m, n = len(x), len(y)
        if m == 0 or n == 0:
            return math.nan, math.nan, "no finite score"
        # Each task's U is a sum of ranks (ranks of the pooled seeds within the task), so the statistic of a split is
        # a sum over its seeds of their ranks averaged over tasks.
        ranks = scipy.stats.rankdata(np.concatenate([x, y]), axis=0).mean(axis=1)
        splits = math.comb(m + n, m)
        if splits <= EXACT_SPLITS:
            chosen = _all_splits(m + n, m)
        else:
            chosen = np.argsort(rng.random((MONTE_CARLO, m + n)), axis=1)[:, :m]
        statistic = np.abs((ranks[chosen].sum(axis=1) - m * (m + 1) / 2) / (m * n) - 0.5)
        observed = abs((ranks[:m].sum() - m * (m + 1) / 2) / (m * n) - 0.5)
        unit = "seeds" if x.shape[1] == 1 else f"seeds over {x.shape[1]} tasks"
        how = (f"exact Mann-Whitney, {m} v {n} {unit}" if splits <= EXACT_SPLITS
               else f"Mann-Whitney, {m} v {n} {unit}, {MONTE_CARLO:,} random splits")
        return _p_value(statistic, observed, exact=splits <= EXACT_SPLITS), min(1.0, 2 / splits), how
    x_tasks, y_tasks = finite_tasks(x), finite_tasks(y)
    if min(map(len, x_tasks + y_tasks)) == 0:
        return math.nan, math.nan, "no finite score"
    statistic = np.zeros(MONTE_CARLO)
    observed = 0.0
    for first, second in zip(x_tasks, y_tasks):
        m, n = len(first), len(second)
        ranks = scipy.stats.rankdata(np.concatenate([first, second]))
        chosen = np.argsort(rng.random((MONTE_CARLO, m + n)), axis=1)[:, :m]
        statistic += (ranks[chosen].sum(axis=1) - m * (m + 1) / 2) / (m * n) - 0.5
        observed += (ranks[:m].sum() - m * (m + 1) / 2) / (m * n) - 0.5
    tasks = len(x_tasks)
    splits = math.prod(math.comb(len(first) + len(second), len(first)) for first, second in zip(x_tasks, y_tasks))
    return (_p_value(np.abs(statistic / tasks), abs(observed / tasks), exact=False),
            max(2 / splits, 1 / (MONTE_CARLO + 1)), f"stratified Mann-Whitney, {tasks} tasks, {MONTE_CARLO:,} random splits")


@functools.lru_cache(maxsize=8)
def _all_splits(total: int, chosen: int) -> np.ndarray:
    """Every choice of ``chosen`` of ``total`` seeds, (comb(total, chosen), chosen): a report asks for the same sizes
    many times."""
    splits = np.array(list(itertools.combinations(range(total), chosen)), dtype=np.int64)
    return splits.reshape(math.comb(total, chosen), chosen)


def _p_value(null: np.ndarray, observed: float, *, exact: bool) -> float:
    """The p-value of a two-sided test from the null distribution of |statistic| (every split when ``exact``, else
    random ones: then (hits + 1) / (draws + 1))."""
    hits = int(np.sum(null >= observed - 1e-9 * max(1.0, observed)))  # equal splits count as equal through rounding
    return hits / len(null) if exact else (hits + 1) / (len(null) + 1)


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values (Holm 1979): the i-th smallest times the number of
    p-values not below it, made non-decreasing, capped at 1; a NaN stays NaN and does not count. A family whose
    adjusted p-values are compared with α has a family-wise error rate of at most α."""
    values = np.asarray(p_values, dtype=float)
    adjusted = np.full(values.shape, math.nan)
    present = np.flatnonzero(~np.isnan(values))
    order = present[np.argsort(values[present], kind="stable")]
    running = 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * values[index]))
        adjusted[index] = running
    return adjusted.tolist()


def holm_adjusted(intervals: Sequence[Interval]) -> list[Interval]:
    """``intervals`` with their p-values Holm-adjusted as one family (``holm``; their tests say so)."""
    adjusted = holm([interval.p for interval in intervals])
    family = sum(not math.isnan(interval.p) for interval in intervals)
    return [
        interval if math.isnan(p) else replace(interval, p=p, smallest_p=min(1.0, interval.smallest_p * family),
                                               test=f"{interval.test}; Holm over {family}")
        for interval, p in zip(intervals, adjusted)
    ]


def separates(interval: Interval, null: float, confidence: float = 0.95) -> bool:
    """Whether the comparison ``interval`` states is decided at ``confidence``: its test's p-value (``Interval.p``,
    ``permutation_p``) is at most 1 − ``confidence``. An estimate without a test falls back on its interval excluding
    ``null``, the value of no difference (0 for a difference, 0.5 for a probability of improvement); an interval that
    does not exist (NaN: one run, or none) separates nothing."""
    if not math.isnan(interval.p):
        return interval.p <= 1.0 - confidence + 1e-12
    return not (math.isnan(interval.low) or math.isnan(interval.high)) and (
        interval.low > null or interval.high < null
    )


def separation_text(interval: Interval, null: float, confidence: float = 0.95) -> str:
    """Whether ``interval`` separates its comparison (``separates``), in the report's words: "separates at 95% (p
    0.003, exact Mann-Whitney, 10 v 10 seeds)", "does not separate at 95% (p 0.31, ...)", "cannot separate at 95%:
    3 v 3 seeds (smallest p 0.1, ...)", or "no interval (1 run)"."""
    level = f"{confidence:.0%}"
    if not math.isnan(interval.p):
        alpha = 1.0 - confidence
        if interval.smallest_p > alpha + 1e-12:
            return f"cannot separate at {level} (smallest p {interval.smallest_p:.2g}: {interval.test})"
        words = "separates" if separates(interval, null, confidence) else "does not separate"
        return f"{words} at {level} (p {interval.p:.2g}, {interval.test})"
    if math.isnan(interval.low) or math.isnan(interval.high):
        return (
            "no interval (1 run)"
            if interval.runs == 1
            else f"no interval ({interval.note or 'no finite score'})"
        )
    return f"separates at {level}" if separates(interval, null) else f"does not separate at {level}"
