"""Aggregates over a paper figure's panels, the rliable way (Agarwal et al., "Deep RL at the Edge of the Statistical
Precipice", 2021): each panel is a *task* (a domain, say) and the conditions at one rank of every panel are one
*compared setting* (``conditions.compared_settings``). A setting's row pools the learner's final values of its
conditions: mean ± SE over every pooled run, and the IQM with a stratified-bootstrap interval (each panel's runs
resampled on their own). Where the figure compares learners (``PaperFigure.profile``), a performance profile too:
the fraction of the pooled runs scoring above each threshold, with its bootstrap band."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from sidewalk.report.conditions import (
    ComparedSetting,
    Condition,
    PaperFigure,
    compared_settings,
    figure_panels,
)
from sidewalk.report.figures import COLOURS, CURVE_METRICS, _save
from sidewalk.report.tables import Final, NumberLog, Settings, iqm_text, mean_se_text, summary_values
from sidewalk.stats import Profile, interval_estimate, mean_se, performance_profile

log = logging.getLogger(__name__)

# The thresholds of a profile: rates lie in [0, 1], drawn in steps of 0.01.
PROFILE_TAUS = np.linspace(0.0, 1.0, 101)


@dataclass
class Aggregate:
    """A compared setting's learner scores, (runs, tasks) padded with NaN where a panel has fewer runs, and their
    pooled final value."""

    setting: ComparedSetting
    scores: np.ndarray
    final: Final

    @property
    def tasks(self) -> int:
        return self.scores.shape[1]

    @property
    def runs(self) -> int:
        return int(np.sum(~np.isnan(self.scores)))


def learner_of(setting: ComparedSetting) -> str:
    """The learner's agent of each of ``setting``'s conditions (``ego``, ``agent0``), once each, joined by " / "."""
    agents: list[str] = []
    for condition in setting.conditions:
        agent = condition.agents()[0][0]
        if agent not in agents:
            agents.append(agent)
    return " / ".join(agents)


def learner_scores(conditions: Sequence[Condition], metric: str) -> np.ndarray:
    """The learner's final ``metric`` (``summary.json``) of each run: (runs, tasks), a column per condition, padded
    with NaN below a condition with fewer runs (the statistics drop NaN per task)."""
    columns = [summary_values(c, f"{c.agents()[0][0]}/{metric}") for c in conditions]
    longest = max(len(column) for column in columns)
    return np.column_stack(
        [np.pad(column, (0, longest - len(column)), constant_values=np.nan) for column in columns]
    )


def aggregate(setting: ComparedSetting, metric: str, settings: Settings) -> Aggregate:
    """``setting``'s learner scores of ``metric`` and their pooled final value (mean ± SE over all runs, IQM with its
    stratified-bootstrap interval at ``settings``' confidence, resamples and seed)."""
    scores = learner_scores(setting.conditions, metric)
    mean, se, _ = mean_se(scores.ravel())
    interval = interval_estimate(
        scores, "iqm", confidence=settings.confidence, n_resamples=settings.n_resamples, seed=settings.seed
    )
    final = Final(learner_of(setting), metric, scores.ravel(), float(mean), float(se), interval)
    return Aggregate(setting, scores, final)


def aggregate_table(aggregates: Sequence[Aggregate], confidence: float) -> list[str]:
    """Markdown rows: setting, conditions, learner, metric, tasks, runs, mean ± SE, IQM [CI]."""
    lines = [
        f"| setting | conditions | learner | metric | tasks | runs | mean ± SE | IQM [{confidence:.0%} CI] |",
        "| --- | --- | --- | --- | ---: | ---: | --- | --- |",
    ]
    for item in aggregates:
        final = item.final
        ids = ", ".join(condition.ident for condition in item.setting.conditions)
        lines.append(
            f"| {item.setting.label} | {ids} | {final.agent} | {final.metric} | {item.tasks} | {item.runs} | "
            f"{mean_se_text(final)} | {iqm_text(final)} |"
        )
    return lines


def aggregate_section(
    spec: PaperFigure,
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    numbers: NumberLog,
    curves_rows: list[dict[str, Any]],
) -> list[str]:
    """``report.md`` lines of ``spec``'s aggregates over its panels (none where the figure has no panel): the table
    of its compared settings and, for a figure that compares learners, their performance profile, drawn into
    ``figures_dir`` and appended to ``figures``; numbers go to ``numbers`` (section ``<figure>/aggregate``) and the
    profile's points to ``curves_rows``."""
    panels = figure_panels(spec, conditions)
    if not panels:
        return []
    compared, left_out = compared_settings(spec, panels)
    if not compared:  # panels with no rank in common: nothing to pool
        return []
    section = f"{spec.name}/aggregate"
    aggregates = [aggregate(setting, spec.metric, settings) for setting in compared]
    for item in aggregates:
        label, ident, final = item.setting.label, item.setting.ident, item.final
        numbers.add_row(section, ident, label, final.agent, final.metric, "tasks", item.tasks, item.runs)
        numbers.add_final_row(section, ident, label, final)
    md = [
        (
            f"Aggregate over the figure's {len(panels)} panel{'s' if len(panels) > 1 else ''} as tasks (rliable, "
            "Agarwal et al. 2021): each row "
            f"pools the learner's final {spec.metric} of the conditions at one rank of every panel; the IQM's "
            f"{settings.confidence:.0%} CI is a stratified bootstrap (each panel's runs resampled on their own)."
        ),
        "",
        *aggregate_table(aggregates, settings.confidence),
        "",
    ]
    if left_out:
        md += [
            "Not at their rank in every panel, so left out of the aggregate: "
            + "; ".join(f"{c.ident} ({c.label})" for c in left_out)
            + ".",
            "",
        ]
    if spec.profile:
        md += _profile_figure(spec, aggregates, settings, figures_dir, figures, curves_rows)
    return md


def profile_name(spec: PaperFigure) -> str:
    """The file name (without ``.png``) of ``spec``'s performance profile: ``fig5_performance_profile``."""
    return f"{spec.name.split('_')[0]}_performance_profile"


def _profile_figure(
    spec: PaperFigure,
    aggregates: Sequence[Aggregate],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    curves_rows: list[dict[str, Any]],
) -> list[str]:
    """``report.md`` lines of the performance profile of ``aggregates`` (a line each, its band shaded), drawn into
    ``figures_dir`` and appended to ``figures``; its points go to ``curves_rows``."""
    name = profile_name(spec)
    figure = Figure(figsize=(7.5, 4.8))
    ax = figure.subplots()
    for index, item in enumerate(aggregates):
        profile = performance_profile(
            item.scores,
            PROFILE_TAUS,
            confidence=settings.confidence,
            n_resamples=settings.n_resamples,
            seed=settings.seed,
        )
        colour = COLOURS[index % len(COLOURS)]
        ax.plot(profile.taus, profile.fraction, color=colour, linewidth=1.8, label=item.setting.label)
        band = np.isfinite(profile.low)
        if band.any():
            ax.fill_between(
                profile.taus, profile.low, profile.high, where=band, color=colour, alpha=0.2, lw=0
            )
        _record_profile(curves_rows, name, item, profile)
    metric_text = CURVE_METRICS.get(spec.metric, spec.metric)
    ax.set_xlabel(f"the learner's final {metric_text} τ")
    ax.set_ylabel(f"fraction of runs with {metric_text} > τ")
    ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
    level = f"{settings.confidence:.0%}"
    ax.set_title(f"{spec.title}: performance profile\npooled over the panels, {level} bootstrap band shaded")
    path = figures_dir / f"{name}.png"
    _save(figure, path)
    figures.append(path)
    log.info("drew %s", path.name)
    return [
        (
            f"Performance profile (rliable's score distribution): the fraction of each setting's runs whose "
            f"learner's final {spec.metric} is above τ, pooled over the panels, with a {level} stratified-bootstrap "
            "band shaded (no band where a panel has 1 run)."
        ),
        "",
        f"![{spec.title}: performance profile](figures/{path.name})",
        "",
    ]


def _record_profile(curves_rows: list[dict[str, Any]], name: str, item: Aggregate, profile: Profile) -> None:
    for tau, fraction, low, high in zip(profile.taus, profile.fraction, profile.low, profile.high):
        curves_rows.append(
            {
                "figure": name,
                "condition_id": item.setting.ident,
                "condition": item.setting.label,
                "agent": item.final.agent,
                "metric": item.final.metric,
                "x_axis": "tau",
                "x": float(tau),
                "mean": float(fraction),
                "se": np.nan,
                "seeds": item.runs,
                "ci_low": float(low),
                "ci_high": float(high),
            }
        )
