"""The report's numbers: learning curves (mean and SE over seeds at each x), final values with mean ± SE and the
IQM's bootstrap interval (``sidewalk.stats``), the log of every number behind ``report.csv``, and the Markdown
table of final values."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from sidewalk.report.conditions import Condition
from sidewalk.social import SOCIAL_UNITS
from sidewalk.stats import Interval, interval_estimate, mean_se

X_AXES = {"frames": "frames", "iterations": "iteration"}  # option name -> metrics.csv column


@dataclass
class Settings:
    """How the report computes and draws: x axis, bootstrap, trajectories."""

    x: str = "frames"
    confidence: float = 0.95
    n_resamples: int = 10_000
    seed: int = 0
    trajectory_episodes: int = 3
    max_trajectory_panels: int = 8

    def __post_init__(self) -> None:
        if self.x not in X_AXES:
            raise ValueError(f"x={self.x!r} is not valid; valid: {', '.join(map(repr, X_AXES))}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"confidence={self.confidence!r} is out of range; valid: (0, 1)")
        for name in ("n_resamples", "trajectory_episodes", "max_trajectory_panels"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int)
                or value < (1 if name == "n_resamples" else 0)
            ):
                raise ValueError(f"{name}={value!r} must be an integer ≥ {1 if name == 'n_resamples' else 0}")


def curve(condition: Condition, agent: str, metric: str, x: str) -> pd.DataFrame:
    """Mean, standard error and number of seeds of ``eval/<agent>/<metric>`` at each x (frames or iteration)
    where any seed evaluated; empty when no run evaluated during training."""
    return column_curve(condition, f"eval/{agent}/{metric}", x)


def column_curve(condition: Condition, column: str, x: str) -> pd.DataFrame:
    """Mean, standard error and number of seeds of ``metrics.csv``'s ``column`` at each x (frames or iteration)
    where any seed has a value; empty when no run has the column."""
    x_column = X_AXES[x]
    series = [
        run.metrics.set_index(x_column)[column].dropna().rename(run.seed)
        for run in condition.runs
        if column in run.metrics.columns
    ]
    series = [s for s in series if not s.empty]
    if not series:
        return pd.DataFrame(columns=["x", "mean", "se", "n"])
    table = pd.concat(series, axis=1).sort_index()
    mean, se, count = mean_se(table.to_numpy(), axis=1)
    return pd.DataFrame({"x": table.index.to_numpy(), "mean": mean, "se": se, "n": count})


@dataclass
class Final:
    """Final values of one metric of one agent over a condition's seeds."""

    agent: str
    metric: str
    values: np.ndarray
    mean: float
    se: float
    iqm: Interval


def summary_values(condition: Condition, key: str) -> np.ndarray:
    """``summary.json``'s ``key`` of each seed's run (NaN where a run lacks it or it is undefined)."""
    return np.array([float(run.summary.get(key, math.nan)) for run in condition.runs], dtype=float)


def finals(condition: Condition, agents: Sequence[str], metric: str, settings: Settings) -> list[Final]:
    """``summary.json`` values of ``<agent>/<metric>`` across seeds, with mean, SE and IQM interval."""
    return [final_of(condition, agent, metric, f"{agent}/{metric}", settings) for agent in agents]


def final_of(condition: Condition, agent: str, metric: str, key: str, settings: Settings) -> Final:
    """``summary.json``'s ``key`` across seeds as the final value of ``agent``'s ``metric``."""
    return final_from(agent, metric, summary_values(condition, key), settings)


def final_from(agent: str, metric: str, values: np.ndarray, settings: Settings) -> Final:
    """``values`` (one per seed, NaN where a run has none) as the final value of ``agent``'s ``metric``."""
    mean, se, _ = mean_se(values)
    interval = interval_estimate(
        values, "iqm", confidence=settings.confidence, n_resamples=settings.n_resamples, seed=settings.seed
    )
    return Final(agent, metric, values, float(mean), float(se), interval)


# ---- safety ------------------------------------------------------------------------------------------------------

CUMULATIVE_COST = "train/cumulative_cost"
SHIELD_RATE = "train/shield_rate"
# Safety Gym's triple (Ray, Achiam & Amodei 2019, "Benchmarking Safe Exploration in Deep RL"), after the learner's
# success, then the shield's share of the learner's steps where runs log it: metric -> column header.
SAFETY_COLUMNS = {
    "success_rate": "success",
    "return": "final return",
    "cost": "final cost",
    "cost_rate": "training cost rate",
    "shield_rate": "shield rate",
}
NOT_RECORDED = "—"


def records_safety(condition: Condition) -> bool:
    """Whether any run of ``condition`` has the safety accounting (runs written before it have neither key)."""
    return any("cost_rate" in run.summary or CUMULATIVE_COST in run.metrics.columns for run in condition.runs)


def learner_agent(condition: Condition) -> tuple[str, str]:
    """(agent, display name) whose return and cost measure the learner: ``ego`` where it plays one agent against
    a scripted opponent (``ego/return``, ``ego/cost``), else ``all``, the overall keys (the mean over agents)."""
    agents = condition.agents()
    return agents[0] if agents and agents[0][0] == "ego" else ("all", "all agents")


def safety_finals(condition: Condition, settings: Settings) -> dict[str, Final]:
    """The learner's final success and Safety Gym's triple: final return and final episode cost (the last
    evaluation) and the cost rate over all of training (``cost_rate``, the training cost per frame); plus the mean
    of ``train/shield_rate`` over training where any run logs it. Keyed by ``SAFETY_COLUMNS``' metrics."""
    agent, _ = learner_agent(condition)
    prefix = "ego/" if agent == "ego" else ""
    found = {
        metric: final_of(condition, agent, metric, f"{prefix}{metric}", settings)
        for metric in ("success_rate", "return", "cost")
    }
    found["cost_rate"] = final_of(condition, agent, "cost_rate", "cost_rate", settings)
    if any(SHIELD_RATE in run.metrics.columns for run in condition.runs):
        # Every iteration collects the same frames, so the mean over iterations is the share of all training steps.
        values = np.array(
            [
                run.metrics[SHIELD_RATE].mean() if SHIELD_RATE in run.metrics.columns else math.nan
                for run in condition.runs
            ],
            dtype=float,
        )
        found["shield_rate"] = final_from(agent, "shield_rate", values, settings)
    return found


def recorded(final: Final | None) -> bool:
    """Whether any seed has a value (a NaN-only final is a metric the runs did not record, not a zero)."""
    return final is not None and bool(np.any(~np.isnan(final.values)))


def safety_table(rows: Sequence[tuple[Condition, str, dict[str, Final]]]) -> list[str]:
    """Markdown rows: condition, learner, seeds, then mean ± SE of each of ``SAFETY_COLUMNS`` (shield rate only
    where some row has it); a metric no seed of a condition recorded shows ``NOT_RECORDED``."""
    metrics = [m for m in SAFETY_COLUMNS if m != "shield_rate" or any(recorded(f.get(m)) for _, _, f in rows)]
    lines = [
        "| id | condition | learner | seeds | " + " | ".join(SAFETY_COLUMNS[m] for m in metrics) + " |",
        "| --- | --- | --- | ---: | " + " | ".join("---" for _ in metrics) + " |",
    ]
    for condition, agent_name, by_metric in rows:
        cells = []
        for metric in metrics:
            final = by_metric.get(metric)
            if not recorded(final):
                cells.append(NOT_RECORDED)
                continue
            cells.append(mean_se_text(final))
        lines.append(
            f"| {condition.ident} | {condition.label} | {agent_name} | {len(condition.runs)} | "
            + " | ".join(cells)
            + " |"
        )
    return lines


class NumberLog:
    """Every number that ``report.md`` shows, one per row of ``report.csv``."""

    COLUMNS = (
        "section",
        "condition_id",
        "condition",
        "agent",
        "metric",
        "statistic",
        "value",
        "seeds",
        "note",
    )

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def add(
        self,
        section: str,
        condition: Condition | None,
        agent: str,
        metric: str,
        statistic: str,
        value: float,
        seeds: int,
        note: str = "",
    ) -> None:
        self.add_row(
            section,
            condition.ident if condition else "",
            condition.label if condition else "",
            agent,
            metric,
            statistic,
            value,
            seeds,
            note,
        )

    def add_row(
        self,
        section: str,
        condition_id: str,
        condition: str,
        agent: str,
        metric: str,
        statistic: str,
        value: float,
        seeds: int,
        note: str = "",
    ) -> None:
        """One number of what ``condition_id`` and ``condition`` name: one condition, or several pooled ("C1+C7")."""
        self.rows.append(
            {
                "section": section,
                "condition_id": condition_id,
                "condition": condition,
                "agent": agent,
                "metric": metric,
                "statistic": statistic,
                "value": value,
                "seeds": seeds,
                "note": note,
            }
        )

    def add_final(self, section: str, condition: Condition, final: Final) -> None:
        self.add_final_row(section, condition.ident, condition.label, final)

    def add_final_row(self, section: str, condition_id: str, condition: str, final: Final) -> None:
        """``final``'s mean, SE, IQM and CI bounds, as ``add_row`` names them; seeds: the runs with a value."""
        n = int(np.sum(~np.isnan(final.values)))
        for statistic, value in (
            ("mean", final.mean),
            ("se", final.se),
            ("iqm", final.iqm.point),
            ("ci_low", final.iqm.low),
            ("ci_high", final.iqm.high),
        ):
            self.add_row(
                section,
                condition_id,
                condition,
                final.agent,
                final.metric,
                statistic,
                value,
                n,
                final.iqm.note,
            )

    def add_interval_row(
        self,
        section: str,
        condition_id: str,
        condition: str,
        agent: str,
        metric: str,
        statistic: str,
        interval: Interval,
        seeds: int,
        note: str = "",
    ) -> None:
        """``interval``'s point as ``statistic`` and its bounds as ``<statistic>_ci_low``/``_ci_high``, as
        ``add_row`` names them; ``note`` defaults to the interval's own."""
        for name, value in (
            (statistic, interval.point),
            (f"{statistic}_ci_low", interval.low),
            (f"{statistic}_ci_high", interval.high),
        ):
            self.add_row(
                section, condition_id, condition, agent, metric, name, value, seeds, note or interval.note
            )

    def frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.rows, columns=list(self.COLUMNS))


def fmt(value: float, digits: int = 3) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def distinct_range(counts: Iterable[float | None]) -> str:
    """Several evaluations' distinct episodes as ``N`` where they agree, else ``low–high`` ("–": none recorded)."""
    known = [int(count) for count in counts if count is not None and not math.isnan(count)]
    if not known:
        return "–"
    low, high = min(known), max(known)
    return str(low) if low == high else f"{low}–{high}"


# A learner that rarely collides pays a cost every thousand frames or fewer: fixed decimals would print 0.000.
SIGNIFICANT_DIGITS = {"cost_rate": 3}


def fmt_metric(value: float, metric: str) -> str:
    """``value`` of ``metric`` as ``report.md`` shows it: 3 decimals, or 3 significant digits for a small rate."""
    if metric in SIGNIFICANT_DIGITS and value is not None and not math.isnan(value) and value != 0:
        return f"{value:.{SIGNIFICANT_DIGITS[metric]}g}"
    return fmt(value)


def mean_se_text(final: Final) -> str:
    """``final``'s mean ± SE as ``report.md`` shows it (the mean alone where there is no SE)."""
    se = "" if math.isnan(final.se) else f" ± {fmt_metric(final.se, final.metric)}"
    return fmt_metric(final.mean, final.metric) + se


def iqm_text(final: Final) -> str:
    """``final``'s IQM and its interval as ``report.md`` shows them (``interval_text``)."""
    return interval_text(final.iqm, final.metric)


def interval_text(interval: Interval, metric: str = "") -> str:
    """A point and its interval as ``report.md`` shows them, in ``metric``'s digits (``fmt_metric``):
    "0.400 [0.200, 0.600]", "no CI" without one, "(coarse)" after one of two runs."""
    low, high = fmt_metric(interval.low, metric), fmt_metric(interval.high, metric)
    ci = "no CI" if math.isnan(interval.low) else f"[{low}, {high}]"
    if interval.note.startswith("2 runs"):
        ci += " (coarse)"
    return f"{fmt_metric(interval.point, metric)} {ci}"


def final_table(rows: Sequence[tuple[Condition, str, Final]], confidence: float) -> list[str]:
    """Markdown rows: condition, agent, metric, seeds, mean ± SE, IQM [CI]."""
    level = f"{confidence:.0%}"
    lines = [
        f"| id | condition | agent | metric | seeds | mean ± SE | IQM [{level} CI] |",
        "| --- | --- | --- | --- | ---: | --- | --- |",
    ]
    for condition, agent_name, final in rows:
        n = int(np.sum(~np.isnan(final.values)))
        lines.append(
            f"| {condition.ident} | {condition.label} | {agent_name} | {final.metric} | {n} | "
            f"{mean_se_text(final)} | {iqm_text(final)} |"
        )
    return lines


def social_finals(condition: Condition, settings: Settings) -> list[Final]:
    """The social measures of the pass (``sidewalk.social``) its runs' final evaluations recorded, across seeds."""
    keys = [key for key in SOCIAL_UNITS if any(key in run.summary for run in condition.runs)]
    return [final_of(condition, "team", key, key, settings) for key in keys]


def social_table(rows: Sequence[tuple[Condition, list[Final]]], confidence: float) -> list[str]:
    """Markdown rows, one per condition and social measure: its unit, seeds, the distinct episodes each seed's final
    evaluation played, mean ± SE and IQM [CI] over seeds (``sidewalk.social`` defines the measures)."""
    lines = [
        f"| id | condition | measure | unit | seeds | distinct episodes a seed | mean ± SE | IQM [{confidence:.0%} CI] |",
        "| --- | --- | --- | --- | ---: | ---: | --- | --- |",
    ]
    for condition, finals_of_condition in rows:
        distinct = distinct_range(run.summary.get("distinct_episodes") for run in condition.runs)
        for final in finals_of_condition:
            n = int(np.sum(~np.isnan(final.values)))
            lines.append(
                f"| {condition.ident} | {condition.label} | {final.metric.removeprefix('social/')} | "
                f"{SOCIAL_UNITS[final.metric]} | {n} | {distinct} | {mean_se_text(final)} | {iqm_text(final)} |"
            )
    return lines
