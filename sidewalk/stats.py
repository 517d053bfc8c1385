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
and the difference of a statistic between two independent samples (``difference_interval``). An interval separates
a comparison when it excludes the value of no difference (``separates``): 0 for a difference, 0.5 for a probability
of improvement.

Few runs: with one run per task there is nothing to resample, so the interval is NaN and ``Interval.note`` says so
(and it separates nothing); with two runs a task's resamples take only three distinct values, so the interval is
computed but flagged coarse.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

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
) -> Interval:
    """``statistic`` of ``scores`` (runs,) or (runs, tasks) with a stratified-bootstrap percentile interval.

    ``statistic`` is ``"iqm"``, ``"mean"``, ``"median"``, ``"optimality_gap"`` (against 1) or a function
    ``f(values, axis)`` reducing ``axis`` of the pooled scores of all tasks. The same ``seed`` gives the same
    interval. NaN scores (a metric undefined in a run, e.g. path efficiency with no arrival) are dropped per task
    first.
    """
    reduce = _reducer(statistic)
    _check_bootstrap(confidence, n_resamples)
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


ONE_RUN_NOTE = "1 run: no interval (a bootstrap needs ≥ 2 runs per task)"


def _reducer(
    statistic: str | Callable[[np.ndarray, int], np.ndarray],
) -> Callable[[np.ndarray, int], np.ndarray]:
    if isinstance(statistic, str):
        check_choice("statistic", statistic, STATISTICS)
        return STATISTICS[statistic]
    return statistic


def _few_runs_note(runs: int) -> str:
    return "2 runs: coarse interval (few distinct resamples)" if runs == 2 else ""


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
) -> Interval:
    """rliable's probability of improvement P(X > Y): the chance that a run of ``x`` scores above a run of ``y`` in
    the same task, ties counting half, averaged over the tasks. Per task it is the Mann-Whitney U statistic of ``x``
    over ``y`` divided by the number of pairs: the mean over every pair (x_i, y_j) of 1 if x_i > y_j, 0.5 if equal
    and 0 otherwise. P(X > Y) + P(Y > X) = 1, and 0.5 is no difference.

    ``x`` and ``y`` are (runs,) or (runs, tasks) with the same tasks, NaN-padded where a task has fewer runs (NaN is
    dropped per task). The interval is a stratified percentile bootstrap at ``confidence`` that resamples the runs
    of ``x`` and those of ``y`` independently within each task, as rliable's ``get_interval_estimates`` does for a
    pair; the same ``seed`` gives the same interval. With fewer than 2 runs of either in some task: the point, a
    NaN interval and ``ONE_RUN_NOTE``.
    """
    _check_bootstrap(confidence, n_resamples)
    x_tasks, y_tasks = finite_tasks(x), finite_tasks(y)
    if len(x_tasks) != len(y_tasks):
        raise ValueError(
            f"x has {len(x_tasks)} tasks and y has {len(y_tasks)}; valid: scores of the same tasks, "
            f"(runs,) or (runs, tasks) with one column per task"
        )
    samples = x_tasks + y_tasks  # x's tasks, then y's in the same order: the form _mean_improvement reads
    runs = min(len(sample) for sample in samples)
    if runs == 0:
        return Interval(math.nan, math.nan, math.nan, 0, "no finite score")
    point = float(_mean_improvement(*samples))
    if runs < 2:
        return Interval(point, math.nan, math.nan, runs, ONE_RUN_NOTE)
    low, high = _independent_bootstrap(samples, _mean_improvement, confidence, n_resamples, seed)
    return Interval(point, float(low), float(high), runs, _few_runs_note(runs))


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
    its own. ``statistic`` is as for ``interval_estimate``; the same ``seed`` gives the same interval. NaN values
    are dropped first; with fewer than 2 values in either sample: the point, a NaN interval and ``ONE_RUN_NOTE``.
    """
    reduce = _reducer(statistic)
    _check_bootstrap(confidence, n_resamples)
    samples = [_finite_sample(name, values) for name, values in (("a", a), ("b", b))]
    runs = min(len(sample) for sample in samples)
    if runs == 0:
        return Interval(math.nan, math.nan, math.nan, 0, "no finite score")
    point = float(reduce(samples[0], -1) - reduce(samples[1], -1))
    if runs < 2:
        return Interval(point, math.nan, math.nan, runs, ONE_RUN_NOTE)

    def difference(first: np.ndarray, second: np.ndarray, axis: int = -1) -> np.ndarray:
        return reduce(first, axis) - reduce(second, axis)

    low, high = _independent_bootstrap(samples, difference, confidence, n_resamples, seed)
    return Interval(point, float(low), float(high), runs, _few_runs_note(runs))


def _finite_sample(name: str, values: np.ndarray | list) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1 or array.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-d array, one value per run; got shape {array.shape}")
    return array[~np.isnan(array)]


def separates(interval: Interval, null: float) -> bool:
    """Whether ``interval`` excludes ``null``, the value of no difference (0 for a ``difference_interval``, 0.5 for a
    ``probability_of_improvement``): the comparison is decided at the interval's confidence. An interval that does
    not exist (NaN: one run, or none) separates nothing."""
    return not (math.isnan(interval.low) or math.isnan(interval.high)) and (
        interval.low > null or interval.high < null
    )


def separation_text(interval: Interval, null: float, confidence: float = 0.95) -> str:
    """Whether ``interval`` separates its comparison (``separates``), in the report's words: "separates at 95%",
    "does not separate at 95%", or "no interval (1 run)" (or "no interval (no finite score)")."""
    if math.isnan(interval.low) or math.isnan(interval.high):
        return (
            "no interval (1 run)"
            if interval.runs == 1
            else f"no interval ({interval.note or 'no finite score'})"
        )
    level = f"{confidence:.0%}"
    return f"separates at {level}" if separates(interval, null) else f"does not separate at {level}"
