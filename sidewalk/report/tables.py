"""The report's numbers: learning curves (mean and SE over seeds at each x), final values with mean ± SE and the
IQM's bootstrap interval (``sidewalk.stats``), the log of every number behind ``report.csv``, and the Markdown
table of final values."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from sidewalk.report.conditions import Condition
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
    column, x_column = f"eval/{agent}/{metric}", X_AXES[x]
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
    values = summary_values(condition, key)
    mean, se, _ = mean_se(values)
    interval = interval_estimate(
        values, "iqm", confidence=settings.confidence, n_resamples=settings.n_resamples, seed=settings.seed
    )
    return Final(agent, metric, values, float(mean), float(se), interval)


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
        self.rows.append(
            {
                "section": section,
                "condition_id": condition.ident if condition else "",
                "condition": condition.label if condition else "",
                "agent": agent,
                "metric": metric,
                "statistic": statistic,
                "value": value,
                "seeds": seeds,
                "note": note,
            }
        )

    def add_final(self, section: str, condition: Condition, final: Final) -> None:
        n = int(np.sum(~np.isnan(final.values)))
        for statistic, value in (
            ("mean", final.mean),
            ("se", final.se),
            ("iqm", final.iqm.point),
            ("ci_low", final.iqm.low),
            ("ci_high", final.iqm.high),
        ):
            self.add(section, condition, final.agent, final.metric, statistic, value, n, final.iqm.note)

    def frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.rows, columns=list(self.COLUMNS))


def fmt(value: float, digits: int = 3) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def final_table(rows: Sequence[tuple[Condition, str, Final]], confidence: float) -> list[str]:
    """Markdown rows: condition, agent, metric, seeds, mean ± SE, IQM [CI]."""
    level = f"{confidence:.0%}"
    lines = [
        f"| id | condition | agent | metric | seeds | mean ± SE | IQM [{level} CI] |",
        "| --- | --- | --- | --- | ---: | --- | --- |",
    ]
    for condition, agent_name, final in rows:
        n = int(np.sum(~np.isnan(final.values)))
        interval = final.iqm
        ci = "no CI" if math.isnan(interval.low) else f"[{fmt(interval.low)}, {fmt(interval.high)}]"
        if interval.note.startswith("2 runs"):
            ci += " (coarse)"
        mean_text = fmt(final.mean) + ("" if math.isnan(final.se) else f" ± {fmt(final.se)}")
        lines.append(
            f"| {condition.ident} | {condition.label} | {agent_name} | {final.metric} | {n} | {mean_text} | "
            f"{fmt(interval.point)} {ci} |"
        )
    return lines
