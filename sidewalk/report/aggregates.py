"""Aggregates over a paper figure's panels, the rliable way (Agarwal et al., "Deep RL at the Edge of the Statistical
Precipice", 2021): each panel is a *task* (a domain, say) and the conditions at one rank of every panel are one
*compared setting* (``conditions.compared_settings``). A setting's row pools the learner's final values of its
conditions: mean ± SE over every pooled run, and the IQM with a stratified-bootstrap interval (each panel's runs
resampled on their own) and, for a rate whose target is 1 (``GAP_METRICS``), the optimality gap with its interval.
After the table, the probability of improvement P(A > B) of every ordered pair of settings, with its interval and
whether that separates them (excludes 0.5). Where the figure compares learners (``PaperFigure.profile``), a
performance profile too: the fraction of the pooled runs scoring above each threshold, with its bootstrap band."""

from __future__ import annotations

import itertools
import logging
import math
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
from sidewalk.report.tables import (
    Final,
    NumberLog,
    Settings,
    interval_text,
    iqm_text,
    mean_se_text,
    summary_values,
)
from sidewalk.stats import (
    Interval,
    Profile,
    holm_adjusted,
    interval_estimate,
    mean_se,
    performance_profile,
    probability_of_improvement,
    separation_text,
)

log = logging.getLogger(__name__)

# The thresholds of a profile: rates lie in [0, 1], drawn in steps of 0.01.
PROFILE_TAUS = np.linspace(0.0, 1.0, 101)
# The metrics whose optimality gap (``stats.STATISTICS``, against 1) the table shows: rates where 1 is the target. A
# collision rate's target is 0, and its gap from 0 would be its mean, already shown.
GAP_METRICS = ("success_rate",)
IMPROVEMENT_NULL = 0.5  # P(A > B) of two settings that do not differ


@dataclass
class Aggregate:
    """A compared setting's learner scores, (runs, tasks) padded with NaN where a panel has fewer runs, their pooled
    final value and, for a metric of ``GAP_METRICS``, their optimality gap (else None)."""

    setting: ComparedSetting
    scores: np.ndarray
    final: Final
    gap: Interval | None = None

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
    stratified-bootstrap interval at ``settings``' confidence, resamples and seed), and their optimality gap with
    the same bootstrap's interval where ``metric`` is one of ``GAP_METRICS``."""
    scores = learner_scores(setting.conditions, metric)
    mean, se, _ = mean_se(scores.ravel())
    bootstrap = {
        "confidence": settings.confidence,
        "n_resamples": settings.n_resamples,
        "seed": settings.seed,
    }
    interval = interval_estimate(scores, "iqm", **bootstrap)
    gap = interval_estimate(scores, "optimality_gap", **bootstrap) if metric in GAP_METRICS else None
    final = Final(learner_of(setting), metric, scores.ravel(), float(mean), float(se), interval)
    return Aggregate(setting, scores, final, gap)


def aggregate_table(aggregates: Sequence[Aggregate], confidence: float) -> list[str]:
    """Markdown rows: setting, conditions, learner, metric, tasks, runs, mean ± SE, IQM [CI] and, where the
    aggregates have one, the optimality gap [CI]."""
    level = f"{confidence:.0%}"
    gap = any(item.gap is not None for item in aggregates)
    lines = [
        f"| setting | conditions | learner | metric | tasks | runs | mean ± SE | IQM [{level} CI] |"
        + (f" optimality gap [{level} CI] |" if gap else ""),
        "| --- | --- | --- | --- | ---: | ---: | --- | --- |" + (" --- |" if gap else ""),
    ]
    for item in aggregates:
        final = item.final
        ids = ", ".join(condition.ident for condition in item.setting.conditions)
        gap_cell = f" {interval_text(item.gap, final.metric) if item.gap else '–'} |" if gap else ""
        lines.append(
            f"| {item.setting.label} | {ids} | {final.agent} | {final.metric} | {item.tasks} | {item.runs} | "
            f"{mean_se_text(final)} | {iqm_text(final)} |{gap_cell}"
        )
    return lines


def improvements(
    aggregates: Sequence[Aggregate], settings: Settings
) -> list[tuple[Aggregate, Aggregate, Interval]]:
    """(A, B, P(A > B)) for every pair of ``aggregates``, each pair once (P(B > A) is 1 − P(A > B)), with the
    stratified-bootstrap interval at ``settings``' confidence, resamples and seed, and the stratified Mann-Whitney
    test of the pair's runs (``stats.permutation_p``), Holm-adjusted over the pairs as one family."""
    pairs = [
        (a, b, probability_of_improvement(
            a.scores, b.scores, confidence=settings.confidence, n_resamples=settings.n_resamples, seed=settings.seed,
        ))
        for a, b in itertools.combinations(aggregates, 2)
    ]
    adjusted = holm_adjusted([interval for _, _, interval in pairs])
    return [(a, b, interval) for (a, b, _), interval in zip(pairs, adjusted)]


def improvement_section(
    section: str, aggregates: Sequence[Aggregate], settings: Settings, numbers: NumberLog
) -> list[str]:
    """``report.md`` lines of the probability of improvement of every ordered pair of ``aggregates`` (a sentence
    saying what it is, and a table: P(A > B) [CI] and whether the interval separates A from B); its numbers go to
    ``numbers`` under ``section``."""
    level = f"{settings.confidence:.0%}"
    metric = aggregates[0].final.metric
    md = [
        (
            f"Probability of improvement (rliable): P(A > B) is the chance that a run of A ends with a higher {metric} "
            "than a run of B in the same panel, ties counting half (the normalised Mann-Whitney U), averaged over the "
            f"panels; 0.5 is no difference; each pair once (P(B > A) is 1 − P(A > B)). Its {level} CI is a stratified "
            "bootstrap of both settings' runs of each panel. A pair separates when the stratified Mann-Whitney test "
            "(each panel's runs split at random between the two settings, the statistic P(A > B); the run is the "
            f"unit) gives p ≤ {1 - settings.confidence:.2g} after Holm's adjustment over the table's pairs."
        ),
        "",
        f"| A | B | P(A > B) [{level} CI] | separation |",
        "| --- | --- | --- | --- |",
    ]
    for a, b, interval in improvements(aggregates, settings):
        words = separation_text(interval, IMPROVEMENT_NULL, settings.confidence)
        md.append(f"| {a.setting.label} | {b.setting.label} | {interval_text(interval)} | {words} |")
        agent = a.final.agent if a.final.agent == b.final.agent else f"{a.final.agent} > {b.final.agent}"
        coarse = "" if math.isnan(interval.low) or not interval.note else f"; {interval.note}"  # 2 runs
        numbers.add_interval_row(
            section,
            f"{a.setting.ident} > {b.setting.ident}",
            f"{a.setting.label} > {b.setting.label}",
            agent,
            metric,
            "probability_of_improvement",
            interval,
            a.runs + b.runs,
            words + coarse,
        )
    return md + [""]


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
    of its compared settings, their probabilities of improvement and, for a figure that compares learners, their
    performance profile, drawn into ``figures_dir`` and appended to ``figures``; numbers go to ``numbers`` (sections
    ``<figure>/aggregate`` and ``<figure>/probability_of_improvement``) and the profile's points to
    ``curves_rows``."""
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
        if item.gap is not None:
            numbers.add_interval_row(
                section, ident, label, final.agent, final.metric, "optimality_gap", item.gap, item.runs
            )
    gap = (
        f" The optimality gap is the runs' mean shortfall of final {spec.metric} below 1 (lower is better), with "
        "the same bootstrap's CI."
        if spec.metric in GAP_METRICS
        else ""
    )
    md = [
        (
            f"Aggregate over the figure's {len(panels)} panel{'s' if len(panels) > 1 else ''} as tasks (rliable, "
            "Agarwal et al. 2021): each row "
            f"pools the learner's final {spec.metric} of the conditions at one rank of every panel; the IQM's "
            f"{settings.confidence:.0%} CI is a stratified bootstrap (each panel's runs resampled on their own)."
            + gap
        ),
        "",
        *aggregate_table(aggregates, settings.confidence),
        "",
    ]
    if left_out:
        md += [
            "Not at their rank in every panel (or a middle value, where panels compare different numbers of values "
            "and only each panel's first and last are matched), so left out of the aggregate: "
            + "; ".join(f"{c.ident} ({c.label})" for c in left_out)
            + ".",
            "",
        ]
    if len(aggregates) > 1:
        md += improvement_section(f"{spec.name}/probability_of_improvement", aggregates, settings, numbers)
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
