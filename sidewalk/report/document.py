"""``report.md`` assembled from its sections, and the report's files written: ``report.md``, ``report.csv`` (every
number in it), ``curves.csv`` (every plotted point) and ``marl_eval/*.json`` (the runs as marl-eval files, one per
comparable set, ``sidewalk.report.marl_eval``); the figures come from ``sidewalk.report.figures`` and, for a
cross-play matrix found under the paths, ``sidewalk.report.crossplay``."""

from __future__ import annotations

import datetime
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from sidewalk.report.aggregates import aggregate_section
from sidewalk.report.claims import claims_section
from sidewalk.report.conditions import (
    BOOKKEEPING_KEYS,
    PAPER_FIGURES,
    Condition,
    describe,
    group_conditions,
    peer_keys,
)
from sidewalk.report.crossplay import crossplay_sections, find_crossplay
from sidewalk.report.figures import family_sections, paper_figure_section, trajectory_section
from sidewalk.report.marl_eval import MarlEvalSet, write_marl_eval
from sidewalk.report.runs import (
    Run,
    RunFolderError,
    Skipped,
    find_run_folders,
    load_run,
    readable_path,
    shown_path,
)
from sidewalk.report.tables import NumberLog, Settings, distinct_range, records_safety
from sidewalk.report.who_yields import who_yields_section
from sidewalk.run_folder import CONFIG, METRICS

log = logging.getLogger(__name__)


@dataclass
class ReportResult:
    """What ``write_report`` wrote and what it left out."""

    out: Path
    report_md: Path
    figures: list[Path]
    skipped: list[Skipped]
    notes: list[str]
    conditions: list[Condition]
    crossplay: list[Path] = field(default_factory=list)  # cross-play folders whose matrix the report includes


# The columns of curves.csv: every plotted point of the report's figures; ci_low/ci_high only where the band is a
# bootstrap interval (a performance profile), not ± SE.
CURVES_COLUMNS = (
    "figure",
    "condition_id",
    "condition",
    "agent",
    "metric",
    "x_axis",
    "x",
    "mean",
    "se",
    "seeds",
    "ci_low",
    "ci_high",
)


def write_report(
    paths: Sequence[str | Path],
    out: str | Path | None = None,
    settings: Settings | None = None,
    preamble: str | Path | None = None,
) -> ReportResult:
    """Read every run folder under ``paths`` and write the report (see the ``sidewalk.report`` docstring) into ``out``
    (default: ``report/`` inside the single path given, or inside the paths' common folder); PNG files
    already in ``out/figures`` are replaced. ``preamble``: a Markdown file placed under the title (how the runs
    were made, say), read before any work starts.

    Unusable run folders are listed in ``report.md`` with the reason and left out; a paper figure without its runs
    is skipped with a note. Raises ``FileNotFoundError`` for a missing path and ``ValueError`` when no run
    folder is found at all.
    """
    settings = settings or Settings()
    preamble_text = _read_preamble(preamble)
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("give at least one run folder or sweep folder")
    folders = find_run_folders(paths)
    crossplay = find_crossplay(paths)
    if not folders and not crossplay:
        raise ValueError(
            f"no run folder (a folder with {CONFIG} and {METRICS}) or cross-play matrix under "
            f"{', '.join(map(str, paths))}"
        )
    out = _clean_output_folder(paths, out)
    figures_dir = out / "figures"
    log.info("reading %d run folder(s)", len(folders))
    runs, skipped = _load_runs(folders)
    conditions = group_conditions(runs)
    log.info("%d usable run(s) in %d condition(s); %d skipped", len(runs), len(conditions), len(skipped))

    numbers = NumberLog()
    curves_rows: list[dict[str, Any]] = []
    figures: list[Path] = []
    notes: list[str] = []
    md: list[str] = [
        "# Sidewalk report",
        "",
        f"Generated {datetime.datetime.now().isoformat(timespec='seconds')} from "
        + ", ".join(f"`{readable_path(p)}`" for p in paths)
        + f": {len(folders)} run folder(s), {len(runs)} used in {len(conditions)} condition(s), "
        f"{len(skipped)} skipped.",
        "",
    ]
    if preamble_text:
        md += [preamble_text, ""]
    md += _runs_section(conditions, numbers, out)
    md += _skipped_section(skipped)
    md += claims_section(conditions, numbers)
    md += ["## Paper figures", ""]
    for spec in PAPER_FIGURES:
        md += paper_figure_section(spec, conditions, settings, figures_dir, figures, numbers, curves_rows, notes)
        md += aggregate_section(spec, conditions, settings, figures_dir, figures, numbers, curves_rows)
    md += trajectory_section(conditions, settings, figures_dir, figures, notes)
    md += family_sections(conditions, settings, figures_dir, figures, numbers, curves_rows)
    md += who_yields_section(conditions, settings, numbers)
    md += crossplay_sections(crossplay, figures_dir, out, figures, numbers)
    md += _statistics_section(settings, safety=any(records_safety(c) for c in conditions))
    md += _marl_eval_section(write_marl_eval(conditions, out), out)

    report_md = _write_files(out, md, numbers, curves_rows)
    log.info("wrote %s (%d figure(s))", report_md, len(figures))
    return ReportResult(out, report_md, figures, skipped, notes, conditions, crossplay)


def _read_preamble(preamble: str | Path | None) -> str:
    """The preamble's text ("" without one); raises ``FileNotFoundError`` if it is not a file."""
    if preamble is None:
        return ""
    if not Path(preamble).is_file():
        raise FileNotFoundError(f"preamble {preamble} is not a file; give a Markdown file")
    return Path(preamble).read_text().strip()


def _clean_output_folder(paths: Sequence[Path], out: str | Path | None) -> Path:
    """The report's folder (``out``, or ``report/`` in the paths' folder), with an empty ``figures/`` in it."""
    if out is None:
        base = paths[0] if len(paths) == 1 else Path(os.path.commonpath([p.resolve() for p in paths]))
        out = base / "report"
    out = Path(out)
    figures_dir = out / "figures"
    figures_dir.mkdir(parents=True, exist_ok=True)
    for stale in figures_dir.glob("*.png"):  # figures of an earlier report that this one may not redraw
        stale.unlink()
    return out


def _load_runs(folders: Sequence[Path]) -> tuple[list[Run], list[Skipped]]:
    """The run folders that load, and those that do not with the reason."""
    runs: list[Run] = []
    skipped: list[Skipped] = []
    for folder in folders:
        try:
            runs.append(load_run(folder))
        except RunFolderError as error:
            skipped.append(Skipped(folder, str(error)))
            log.warning("skipped %s: %s", folder, error)
    return runs, skipped


def _write_files(out: Path, md: list[str], numbers: NumberLog, curves_rows: list[dict[str, Any]]) -> Path:
    """Write ``report.md``, ``report.csv`` and ``curves.csv`` into ``out``; returns the path of ``report.md``."""
    report_md = out / "report.md"
    report_md.write_text("\n".join(md) + "\n")
    numbers.frame().to_csv(out / "report.csv", index=False)
    # Objects, not a float column: frames stay integers beside a profile's thresholds, each value written as it came.
    pd.DataFrame(curves_rows, columns=list(CURVES_COLUMNS), dtype=object).to_csv(out / "curves.csv", index=False)
    return report_md


def _runs_section(conditions: Sequence[Condition], numbers: NumberLog, out: Path) -> list[str]:
    md = [
        "## Conditions",
        "",
        f"Runs are grouped by their config without the seed and bookkeeping keys ({', '.join(BOOKKEEPING_KEYS)}).",
        "",
        "| id | condition | family | seeds | iterations | frames | evaluation protocol | distinct episodes |",
        "| --- | --- | --- | --- | ---: | ---: | --- | --- |",
    ]
    for condition in conditions:
        iterations = int(condition.runs[0].metrics["iteration"].iloc[-1])
        frames = int(condition.runs[0].metrics["frames"].iloc[-1])
        md.append(
            f"| {condition.ident} | {condition.label} | {', '.join(condition.families)} | "
            f"{', '.join(map(str, condition.seeds))} | {iterations} | {frames} | {protocol_text(condition.flat)} | "
            f"{_distinct_episodes(condition)} |"
        )
        numbers.add("conditions", condition, "", "", "seeds", len(condition.runs), len(condition.runs))
        numbers.add("conditions", condition, "", "", "iterations", iterations, len(condition.runs))
        numbers.add("conditions", condition, "", "", "frames", frames, len(condition.runs))
    md.append("")
    for condition in conditions:
        if "+" in condition.label and " more" in condition.label:
            md.append(
                f"- {condition.ident} differs from the other {condition.domain} {condition.algo.upper()} "
                f"{condition.opponent} conditions in: {describe(condition, peer_keys(condition, conditions), None)}"
            )
        for seed, kept, left_out in condition.duplicates:
            md.append(
                f"- {condition.ident}: seed {seed} was run twice (the same config, e.g. by two presets); "
                f"used `{shown_path(kept, out)}`, left out `{shown_path(left_out, out)}`"
            )
    return md + [""]


def protocol_text(flat: dict[str, Any]) -> str:
    """A run's evaluation protocol as the Conditions table names it: ``perturbed (starts ±1, goals ±1 rows)``,
    ``perturbed (starts ±1, goals ±1 cells)``,
    ``nominal``; ``, trained on fixed starts`` where training did not draw its worlds alike; ``; ε-greedy at 0.01``
    where the learner acted ε-greedily in evaluation (``eval.epsilon``)."""
    name = str(flat.get("eval.name", "nominal"))
    if flat.get("env.domain") == "discrete":
        by_unit = []  # "starts ±1, goals ±1 rows", "starts ±1, goals ±1 cells"
        for unit in ("rows", "cells"):
            parts = [f"{what}s ±{value}" for what in ("start", "goal") if (value := flat.get(f"eval.{what}_jitter_{unit}", 0))]
            by_unit += [f"{', '.join(parts)} {unit}"] if parts else []
        text = "; ".join(by_unit)
    else:
        bounds = [(what, flat.get(f"eval.{key}", 0.0), unit) for what, key, unit in
                  (("starts", "start_jitter_m", "m"), ("goals", "goal_jitter_m", "m"),
                   ("headings", "heading_jitter_rad", "rad"))]
        text = ", ".join(f"{what} ±{float(value):g} {unit}" for what, value, unit in bounds if value)
    if text and not flat.get("eval.train_alike", True):
        text += "; trained on the scenario's own starts"
    if epsilon := float(flat.get("eval.epsilon", 0.0) or 0.0):
        text += ("; " if text else "") + f"ε-greedy at {epsilon:g}"
    return f"{name} ({text})" if text else name


def _distinct_episodes(condition: Condition) -> str:
    """How many different episodes the seeds' final evaluations played, of how many worlds ("–": not recorded)."""
    counts = [run.summary.get("distinct_episodes") for run in condition.runs]
    if any(count is None for count in counts):
        return "–"
    worlds = int(max(run.summary.get("episodes", 0) for run in condition.runs))
    return f"{distinct_range(counts)} of {worlds}"


def _skipped_section(skipped: Sequence[Skipped]) -> list[str]:
    if not skipped:
        return ["No run folder was skipped.", ""]
    md = ["## Skipped run folders", "", "| run folder | reason |", "| --- | --- |"]
    md += [
        f"| `{item.path}` | {item.reason} |" for item in skipped
    ]  # absolute: the folder must be found to fix it
    return md + [""]


def _marl_eval_section(written: Sequence[tuple[Path, MarlEvalSet]], out: Path) -> list[str]:
    """Where the runs are as marl-eval files, and which conditions each file holds."""
    if not written:
        return []
    md = [
        "## marl-eval files",
        "",
        ("The runs as marl-eval files, laid out as BenchMARL writes its runs: one file per set that marl-eval loads whole "
        "(the same algorithms in every task, the same seeds and evaluations in every run). Each metric is a "
        "one-element list with the evaluation's `episodes` and `distinct_episodes` beside it; `absolute_metrics` is "
        "the best policy re-evaluated on ten times the episodes, where BenchMARL's is a maximum over episodes "
        "(`sidewalk.report.marl_eval`, docs/guide/evaluation.md)."),
        "",
        "| file | tasks | conditions | seeds | evaluations | frames |",
        "| --- | --- | --- | --- | ---: | ---: |",
    ]
    for path, marl_set in written:
        relative = path.relative_to(out).as_posix()
        md.append(
            f"| [`{relative}`]({relative}) | {', '.join(marl_set.tasks)} | "
            f"{', '.join(c.ident for c in marl_set.conditions)} | {', '.join(map(str, marl_set.seeds))} | "
            f"{len(marl_set.frames)} | {marl_set.frames[-1] if marl_set.frames else 0} |"
        )
    return md + [""]


def _statistics_section(settings: Settings, safety: bool) -> list[str]:
    level = f"{settings.confidence:.0%}"
    md = [
        "## How the numbers are computed",
        "",
        (
            "- Curves: the evaluation metrics logged during training (`eval/<agent>/<metric>` in `metrics.csv`), "
            "mean over seeds, shaded ± one standard error (SE = sample standard deviation / √n, as in the paper)."
        ),
        (
            "- Final values: `summary.json` of each seed (the last evaluation). IQM is the interquartile mean (the mean "
            "of the middle 50 % of the seeds' values; with fewer than 4 seeds nothing is trimmed and it is the mean)."
        ),
        (
            "- Distinct episodes (Conditions): how many different trajectories the worlds of a final evaluation "
            "played. At noise 0 in a fixed layout every world plays the same episode (1 of 256): each seed's rate is "
            "then one episode's 0 or 1, and the spread shown is the seeds' alone."
        ),
        (
            f"- {level} CI: percentile interval of the IQM under the stratified bootstrap (rliable's method), "
            f"{settings.n_resamples} resamples, seed {settings.seed}, computed with `scipy.stats.bootstrap`."
        ),
        (
            "- With 1 seed there is no SE and no CI (shown as – / 'no CI'); with 2 seeds the CI is marked coarse "
            "(a bootstrap of two values can take only three values). The paper used 3 seeds."
        ),
        (
            "- Aggregates (rliable: Agarwal et al. 2021, \"Deep RL at the Edge of the Statistical Precipice\"): under "
            "each paper figure, its panels are tasks and the conditions at one rank of every panel one compared "
            "setting; a row pools the learner's final values of a setting's conditions (mean ± SE over all its runs, "
            f"IQM with the {level} CI of a stratified bootstrap: each panel's runs resampled on their own). For Fig. 5, "
            "which compares learners, the performance profile: the fraction of a setting's runs whose final value is "
            f"above each threshold τ (strictly, as rliable), with the same bootstrap's {level} band."
        ),
    ]
    if safety:  # a report of runs written before the safety accounting has none of it to explain
        md.append(
            "- Safety: a step costs 1 where an agent hits a wall or another agent (`env.cost=near_miss` adds "
            "steps ending too close to another agent). The cost figures draw `train/cumulative_cost` of "
            "`metrics.csv`, the cost the learner's agents (the ego against a scripted opponent, every agent "
            "otherwise) paid since training began, mean over seeds, ± one SE shaded. The safety tables give the "
            'three numbers of Safety Gym (Ray, Achiam & Amodei 2019, "Benchmarking Safe Exploration in Deep '
            "Reinforcement Learning\"): final return and final cost, the learner's mean episode return and episode "
            "cost in the last evaluation (`ego/return`, `ego/cost` where the learner plays the ego, else `return`, "
            "`cost`: means over agents), which say what the learned policy achieves and how safely; and the "
            "training cost rate (`cost_rate`: all the cost paid in training over the frames collected), which says "
            "how safely it learned. Shield rate: the mean over training of `train/shield_rate`, the share of the "
            "learner's steps where the safety shield replaced its action. — marks a number a run did not record "
            "(written before the safety accounting, or without the shield)."
        )
    return md + [""]
