"""The cross-play matrix drawn and told: heatmaps of every run with every partner and of conditions (mean over
seeds), and the ``report.md`` section, from a folder that ``runners/crossplay.py`` wrote (``crossplay.csv``, one row
per pairing, see ``sidewalk.crossplay``; ``crossplay.json``, how it was made; ``notes.md``, optional, what it
shows, written by hand). Reads files only: no learner, no torch."""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from sidewalk.report.figures import _save, slug
from sidewalk.report.runs import shown_path
from sidewalk.report.tables import NumberLog, distinct_range, fmt, interval_text
from sidewalk.stats import (
    Interval,
    holm_adjusted,
    interval_estimate,
    probability_of_improvement,
    separation_text,
)

log = logging.getLogger(__name__)

CROSSPLAY_CSV = "crossplay.csv"
CROSSPLAY_JSON = "crossplay.json"
CONVENTIONS_CSV = "conventions.csv"  # the convention each row's policy follows with itself (sidewalk.crossplay.conventions.convention)
NOTES = "notes.md"  # what the matrix shows, written by hand beside the CSV
ADHOC_CSV = "adhoc.csv"  # the ad-hoc score of each condition (adhoc_table), beside the matrix
ADHOC_COLUMNS = ("condition", "runs", "partners", "iqm", "low", "high", "mean", "distinct_low", "distinct_high",
                 "note", "br_prox_partners", "br_prox_iqm", "br_prox_low", "br_prox_high")
# Beside a matrix: each held-out partner's best response (columns member, success, ...), ZSC-Eval's BR-Prox.
BEST_RESPONSES_CSV = "best_responses.csv"
# A best response that gets through with its own partner in fewer of its worlds is no yardstick: every condition's
# score over it reaches BR-Prox's cap of 1.
WEAK_BEST_RESPONSE = 0.5
REPORT = "report.md"
# Heatmaps: CSV column -> (title, colour map); every value is a rate in [0, 1].
HEATMAP_METRICS = {
    "success": ("success of the row's agent", "viridis"),
    "collision_rate": ("collision rate of the row's agent", "magma_r"),
    "team_success": ("team success (every agent arrived)", "viridis"),
    "deadlock_rate": ("deadlock rate (the pair stuck in front of each other to the time limit)", "magma_r"),
}
ANNOTATE_MAX_CELLS = 600  # beyond this many cells, a heatmap's numbers are unreadable: colours only


def find_crossplay(paths: Sequence[str | Path]) -> list[Path]:
    """Every folder under ``paths`` (searched recursively, hidden folders not) that holds a ``crossplay.csv``."""
    found: set[Path] = set()
    for path in map(Path, paths):
        if not path.is_dir():
            continue
        for root, dirs, files in os.walk(path):
            if CROSSPLAY_CSV in files:
                found.add(Path(root))
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
    return sorted(found)


def read_crossplay(folder: str | Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A cross-play folder's table and how it was made (``{}`` when ``crossplay.json`` is missing)."""
    folder = Path(folder)
    frame = pd.read_csv(folder / CROSSPLAY_CSV, dtype={"skipped": str, "partner": str, "row_run": str})
    frame["skipped"] = frame["skipped"].fillna("")
    meta_path = folder / CROSSPLAY_JSON
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    conventions = folder / CONVENTIONS_CSV
    if conventions.exists():
        meta["conventions"] = pd.read_csv(conventions).to_dict("records")
    notes = folder / NOTES
    if notes.exists():
        meta["notes"] = notes.read_text().strip()
    return frame, meta


def _run_names(frame: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """Each row's run and each partner shown: its condition's label and seed (a scripted partner by name)."""
    def shown(label: pd.Series, seed: pd.Series, path: pd.Series) -> pd.Series:
        return pd.Series(
            [f"{lab} s{int(s)}" if pd.notna(s) else f"{lab} ({Path(p).name})" for lab, s, p in zip(label, seed, path)],
            index=frame.index,
        )

    rows = shown(frame["row_label"], frame["row_seed"], frame["row_run"])
    learned = frame["partner_kind"] == "learned"
    partners = frame["partner"].astype(str).copy()
    partners[learned] = shown(frame["partner_label"], frame["partner_seed"], frame["partner"])[learned]
    return rows, partners


def _ordered(values: pd.Series) -> list[str]:
    return list(dict.fromkeys(values))


def _partner_order(names: pd.Series, kinds: pd.Series) -> list[str]:
    """Partners in the CSV's order, the scripted ones first."""
    scripted = _ordered(names[kinds == "scripted"])
    return scripted + [name for name in _ordered(names) if name not in scripted]


def scripted_count(frame: pd.DataFrame) -> int:
    """How many of the matrix's partners are scripted (its first columns)."""
    return len(set(frame.loc[frame["partner_kind"] == "scripted", "partner"]))


def run_table(frame: pd.DataFrame, metric: str) -> pd.DataFrame:
    """Runs (rows) × partners (columns) of ``metric``, in the CSV's order; NaN where a cell was skipped."""
    rows, partners = _run_names(frame)
    table = pd.DataFrame({"row": rows, "partner": partners, "value": frame[metric].astype(float)})
    pivot = table.pivot_table(index="row", columns="partner", values="value", aggfunc="mean", dropna=False)
    return pivot.reindex(index=_ordered(rows), columns=_partner_order(partners, frame["partner_kind"]))


def self_pairs(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(row, partner) names of the cells where a run plays with itself."""
    rows, partners = _run_names(frame)
    mask = frame["self_pair"].astype(bool)
    return list(zip(rows[mask], partners[mask]))


def condition_table(frame: pd.DataFrame, metric: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(mean, pairs): conditions (rows) × partners (columns: scripted opponents by name, learned ones by
    condition) of ``metric``, the mean over every pair of runs of the two conditions, self-pairs (a run with
    itself) left out, so a condition's cell with itself is the mean over pairs of different seeds; ``pairs``
    counts the cells averaged (0 and NaN where there are none, e.g. a condition of one seed with itself)."""
    used = frame[~frame["self_pair"].astype(bool) & (frame["skipped"] == "")]
    rows, columns = _ordered(frame["row_label"]), _partner_order(frame["partner_label"], frame["partner_kind"])
    grouped = used.groupby(["row_label", "partner_label"], sort=False)[metric]
    mean = grouped.mean().unstack().reindex(index=rows, columns=columns)
    pairs = grouped.count().unstack().reindex(index=rows, columns=columns).fillna(0).astype(int)
    return mean.astype(float), pairs


def adhoc_table(frame: pd.DataFrame, best: dict[str, float] | None = None) -> pd.DataFrame | None:
    """The ad-hoc score of each condition (``ADHOC_COLUMNS``): the team success of its runs (seeds) with every
    held-out partner (``heldout`` cells), as the interquartile mean of those runs × partners scores with a 95 %
    bootstrap interval that resamples whole runs (``sidewalk.stats.interval_estimate``, ``clustered``: one policy
    played every partner, so the seed is the unit); ``mean`` the plain mean.
    With ``best`` (a held-out member's name → its best response's team success), BR-Prox beside it
    (``br_prox_scores``), over the partners that have a best response. None when the matrix has no held-out partner
    (``--partners heldout``)."""
    if "heldout" not in frame or not frame["heldout"].astype(bool).any():
        return None
    records = []
    used = _heldout(frame)
    for label, scores in adhoc_scores(frame).items():
        normalised = _br_prox(scores, best or {})
        interval = interval_estimate(scores.to_numpy(dtype=float), "iqm", clustered=True)
        # A matrix made before distinct episodes were recorded has no such column.
        distinct = used.loc[used["row_label"] == label].get("distinct_episodes")
        known = distinct.dropna() if distinct is not None else pd.Series(dtype=float)
        record = {
            "condition": label, "runs": len(scores), "partners": scores.shape[1], "iqm": interval.point,
            "low": interval.low, "high": interval.high, "mean": float(np.nanmean(scores.to_numpy(dtype=float))),
            "distinct_low": int(known.min()) if len(known) else None,
            "distinct_high": int(known.max()) if len(known) else None, "note": interval.note,
            "br_prox_partners": normalised.shape[1],
        }
        if normalised.shape[1]:
            prox = interval_estimate(normalised.to_numpy(dtype=float), "iqm", clustered=True)
            record |= {"br_prox_iqm": prox.point, "br_prox_low": prox.low, "br_prox_high": prox.high}
        records.append(record)
    return pd.DataFrame(records, columns=list(ADHOC_COLUMNS))


def br_prox_scores(frame: pd.DataFrame, best: dict[str, float]) -> dict[str, pd.DataFrame]:
    """Each condition's runs × partners BR-Prox (ZSC-Eval): min(1, its team success / the partner's best response's),
    so that a partner no one plays well with weighs as much as an easy one. A partner without a best response, or
    whose best response never succeeds (the ratio is undefined), is left out."""
    return {label: _br_prox(scores, best) for label, scores in adhoc_scores(frame).items()}


def _br_prox(scores: pd.DataFrame, best: dict[str, float]) -> pd.DataFrame:
    """One condition's runs × partners scores over the partners' best responses (``br_prox_scores``)."""
    members = [partner.removeprefix("heldout:") for partner in scores.columns]
    denominators = np.array([best.get(member, math.nan) for member in members], dtype=float)
    denominators[~(denominators > 0)] = math.nan
    return (scores / denominators).clip(upper=1.0).loc[:, ~np.isnan(denominators)]


def best_response_table(folder: Path) -> pd.DataFrame:
    """``folder/best_responses.csv`` (``sidewalk.best_responses.BEST_RESPONSE_COLUMNS``), empty where there is none;
    a file without the columns member and success is an error naming them."""
    path = Path(folder) / BEST_RESPONSES_CSV
    if not path.exists():
        return pd.DataFrame(columns=["member", "success"])
    table = pd.read_csv(path)
    missing = {"member", "success"} - set(table.columns)
    if missing:
        raise ValueError(f"{path} lacks the column(s) {sorted(missing)}; it needs member and success")
    return table.astype({"member": str, "success": float})


def read_best_responses(folder: Path) -> dict[str, float]:
    """``folder/best_responses.csv`` as member → its best response's team success; empty where there is none."""
    return _successes(best_response_table(folder))


def _successes(table: pd.DataFrame) -> dict[str, float]:
    return dict(zip(table["member"].astype(str), table["success"].astype(float)))


def best_response_warning(table: pd.DataFrame, members: Sequence[str] | None = None) -> str:
    """One line naming each best response of ``table`` (``best_responses.csv``; of ``members`` where given) that
    BR-Prox should not rest on: trained for fewer iterations than its recipe's reference budget (``budget`` below
    ``reference_budget``, where the file has both) or getting through with its own partner in fewer than
    ``WEAK_BEST_RESPONSE`` of its worlds; "" when there is none."""
    weak = []
    for row in table.to_dict("records"):
        if members is not None and row["member"] not in members:
            continue
        budget, reference = row.get("budget", math.nan), row.get("reference_budget", math.nan)
        if budget < reference or row["success"] < WEAK_BEST_RESPONSE:  # an unknown (NaN) budget compares False
            trained = "budget unknown" if math.isnan(budget) else f"{budget:.0f} iterations"
            trained += "" if math.isnan(reference) else f", reference {reference:.0f}"
            weak.append(f"`{row['member']}` ({trained}; team success {row['success']:.2f})")
    if not weak:
        return ""
    return (f"Warning: best responses below their reference budget or weak with their own partner: {', '.join(weak)}. "
            "BR-Prox over a weak best response reads high (every condition reaches its cap of 1): retrain them, at "
            "least at the reference budget (`--train-best-responses` without `--iterations`), before reading it.")


def _br_prox_text(members: Sequence[str], best: dict[str, float]) -> str:
    """What BR-Prox rests on: which held-out ``members`` have a best response (``best``), which are left out, why."""
    if not best:
        return (f"BR-Prox (each partner's score over its best response's, ZSC-Eval) needs `{BEST_RESPONSES_CSV}` "
                "beside the matrix: no partner here has a best response yet, so only the raw score is given.")
    missing = [f"`{name}`" for name in members if name not in best]
    never = [f"`{name}`" for name in members if name in best and not best[name] > 0]
    scores = ", ".join(f"`{name}` {best[name]:.2f}" for name in members if name in best)
    text = (f"BR-Prox: each partner's team success over that of a best response trained against it "
            f"(`{BEST_RESPONSES_CSV}`: {scores}), capped at 1, then the same IQM over runs × partners.")
    if missing:
        text += f" No best response cached for {', '.join(missing)}: left out of BR-Prox, kept in the raw score."
    if never:
        text += f" The best response to {', '.join(never)} never succeeds (the ratio is undefined): left out too."
    return text


def _heldout(frame: pd.DataFrame) -> pd.DataFrame:
    """The held-out cells played with a partner the row never met in training (a matrix made before that was known
    has no ``met_in_training`` column: every cell counts)."""
    return frame[frame["heldout"].astype(bool) & (frame["skipped"] == "") & ~_met(frame)]


def _met(frame: pd.DataFrame) -> pd.Series:
    return frame.get("met_in_training", pd.Series(False, index=frame.index)).fillna(False).astype(bool)


def _met_text(frame: pd.DataFrame) -> str:
    """Which held-out partners some row met in training, left out of the score for that row."""
    met = frame[frame["heldout"].astype(bool) & _met(frame)]
    if met.empty:
        return "none of which any learner met in training"
    named = "; ".join(f"`{partner}` by {', '.join(_ordered(cells['row_label']))}"
                      for partner, cells in met.groupby("partner_label", sort=False))
    return (f"left out where a row trained with one ({named}: {len(met)} of "
            f"{int(frame['heldout'].astype(bool).sum())} cells)")


def adhoc_scores(frame: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """Each condition's team success with the held-out partners: runs × partners (a partner is a task)."""
    used = _heldout(frame)
    return {
        label: used[used["row_label"] == label].pivot_table(index="row_run", columns="partner",
                                                             values="team_success", aggfunc="mean")
        for label in _ordered(used["row_label"])
    }


def adhoc_comparisons(frame: pd.DataFrame) -> list[tuple[str, str, Interval]]:
    """P(A > B) of every pair of conditions, each pair once, over their held-out scores (``probability_of_improvement``
    with the partners as tasks, ``clustered``: a run played every partner, so whole runs are resampled and the exact
    Mann-Whitney test splits whole seeds), for the partners both were played with; the tests' p-values Holm-adjusted
    as one family (``stats.holm_adjusted``)."""
    scores = adhoc_scores(frame)
    pairs = []
    for first, second in itertools.combinations(scores, 2):
        shared = [partner for partner in scores[first].columns if partner in scores[second].columns]
        pairs.append((first, second, probability_of_improvement(scores[first][shared].to_numpy(dtype=float),
                                                                scores[second][shared].to_numpy(dtype=float),
                                                                clustered=True)))
    adjusted = holm_adjusted([interval for _, _, interval in pairs])
    return [(first, second, interval) for (first, second, _), interval in zip(pairs, adjusted)]


def _adhoc_lines(frame: pd.DataFrame, sub: str, numbers: NumberLog | None, responses: pd.DataFrame) -> list[str]:
    """The ad-hoc score's table, where the matrix has held-out partners; BR-Prox beside it where ``responses``
    (``best_response_table``) has the partners' best responses, with ``best_response_warning`` (also logged) where
    BR-Prox rests on weak ones."""
    best = _successes(responses)
    table = adhoc_table(frame, best)
    if table is None:
        return []
    heldout = [name.removeprefix("heldout:") for name in _ordered(_heldout(frame)["partner"])]
    # Only those BR-Prox rests on: one that never succeeds is left out of it (and named by _br_prox_text).
    warning = best_response_warning(responses, [name for name in heldout if best.get(name, 0) > 0])
    if warning:
        log.warning(warning)
    partners = ", ".join(f"`{name}`" for name in _ordered(frame.loc[frame["heldout"].astype(bool), "partner_label"]))
    md = [
        f"{sub} Ad-hoc score: partners never met",
        "",
        (
            f"Team success with every partner of the held-out population ({partners}), {_met_text(frame)}: the "
            "interquartile mean over each condition's runs × partners, with its 95 % stratified-bootstrap interval "
            "over runs (seeds)."
        ),
        "",
        _br_prox_text(heldout, best),
        "",
        *([f"**{warning}**", ""] if warning else []),
        "| condition | runs | partners | IQM | 95 % interval | mean | distinct episodes a cell | BR-Prox IQM [95 %] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in table.itertuples():
        interval = f"[{fmt(r.low)}, {fmt(r.high)}]" if not math.isnan(r.low) else r.note
        prox = ("–" if not r.br_prox_partners or math.isnan(r.br_prox_iqm) else
                f"{fmt(r.br_prox_iqm)} [{fmt(r.br_prox_low)}, {fmt(r.br_prox_high)}] ({r.br_prox_partners} partners)"
                + (" **over weak best responses: see the warning**" if warning else ""))
        md.append(f"| {r.condition} | {r.runs} | {r.partners} | {fmt(r.iqm)} | {interval} | {fmt(r.mean)} | "
                  f"{distinct_range([r.distinct_low, r.distinct_high])} | {prox} |")
        if numbers is not None:
            numbers.add("crossplay", None, f"row: {r.condition}; partners: held-out population", "team_success",
                        "iqm", float(r.iqm), int(r.runs), "ad-hoc score: IQM over runs × held-out partners")
    comparisons = adhoc_comparisons(frame)
    if comparisons:
        md += [
            "",
            ("Which condition plays better with partners never met: P(A > B), the chance that a run of A ends a "
             "held-out partner's cell with higher team success than a run of B with the same partner (ties half; "
             "rliable's probability of improvement, the partners as tasks), each pair once (P(B > A) is 1 − P(A > B)), "
             "with its 95 % bootstrap interval over whole runs. The seed is the unit: one policy played every "
             "partner, so partners are not independent samples. A pair separates when the exact Mann-Whitney test "
             "of the two conditions' seeds (every split of the seeds, the statistic P(A > B)) gives p ≤ 0.05 after "
             "Holm's adjustment over the table's pairs; 3 seeds against 3 cannot (the smallest p is 0.1)."),
            "",
            "| A | B | P(A > B) [95 % interval] | separation |",
            "| --- | --- | --- | --- |",
        ]
        for first, second, interval in comparisons:
            md.append(f"| {first} | {second} | {interval_text(interval)} | {separation_text(interval, 0.5)} |")
    return md + [""]


def draw_heatmap(
    table: pd.DataFrame,
    title: str,
    path: Path,
    cmap: str = "viridis",
    pairs: pd.DataFrame | None = None,
    outlined: Sequence[tuple[str, str]] = (),
    scripted: int = 0,
) -> None:
    """``table`` as a heatmap on [0, 1], each cell annotated with its value (and its number of pairs); NaN
    cells grey, the ``outlined`` (row, column) cells boxed, a line after the first ``scripted`` columns."""
    n_rows, n_cols = table.shape
    width = min(2.5 + 0.62 * n_cols + 0.06 * max(len(str(r)) for r in table.index), 40.0)
    height = min(1.8 + 0.42 * n_rows + 0.05 * max(len(str(c)) for c in table.columns), 40.0)
    figure = Figure(figsize=(width, height))
    ax = figure.add_subplot()
    values = table.to_numpy(float)
    colour_map = matplotlib.colormaps[cmap].with_extremes(bad="#dddddd")  # a skipped cell, or no pair: grey
    colours = ax.imshow(np.ma.masked_invalid(values), vmin=0.0, vmax=1.0, cmap=colour_map, aspect="auto")
    ax.set_xticks(range(n_cols), [str(c) for c in table.columns], rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(n_rows), [str(r) for r in table.index], fontsize=8)
    ax.set_xlabel("partner (plays every other agent)")
    ax.set_ylabel("row (plays the agent it trained as)")
    ax.set_title(title, fontsize=10)
    if n_rows * n_cols <= ANNOTATE_MAX_CELLS:
        size = 7 if n_cols <= 12 else 5.5
        for i in range(n_rows):
            for j in range(n_cols):
                value = values[i, j]
                text = "–" if math.isnan(value) else f"{value:.2f}"
                if pairs is not None and not math.isnan(value):
                    text += f"\n({int(pairs.iat[i, j])})"
                red, green, blue = colours.cmap(colours.norm(value))[:3] if not math.isnan(value) else (1, 1, 1)
                dark = 0.299 * red + 0.587 * green + 0.114 * blue < 0.5
                ax.text(j, i, text, ha="center", va="center", fontsize=size, color="white" if dark else "black")
    index = {name: i for i, name in enumerate(table.index)}
    column = {name: j for j, name in enumerate(table.columns)}
    for row, partner in outlined:
        if row in index and partner in column:
            corner = (column[partner] - 0.5, index[row] - 0.5)
            ax.add_patch(Rectangle(corner, 1.0, 1.0, fill=False, edgecolor="red", linewidth=1.4))
    if 0 < scripted < n_cols:  # scripted partners | learned ones
        ax.axvline(scripted - 0.5, color="white", linewidth=3)
    figure.colorbar(colours, ax=ax, fraction=0.04, pad=0.02)
    _save(figure, path)


def _markdown_table(mean: pd.DataFrame, pairs: pd.DataFrame | None = None) -> list[str]:
    header = "| row \\ partner | " + " | ".join(str(c) for c in mean.columns) + " |"
    lines = [header, "| --- |" + " ---: |" * len(mean.columns)]
    for name, values in mean.iterrows():
        cells = []
        for j, value in enumerate(values):
            text = fmt(float(value))
            if pairs is not None and not math.isnan(float(value)):
                text += f" ({int(pairs.loc[name].iloc[j])})"
            cells.append(text)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def crossplay_section(
    frame: pd.DataFrame,
    meta: dict[str, Any],
    figures_dir: Path,
    out: Path,
    figures: list[Path] | None = None,
    numbers: NumberLog | None = None,
    prefix: str = "crossplay",
    heading: str = "## Cross-play",
    folder: Path | None = None,
) -> list[str]:
    """The matrix's ``report.md`` lines: how it was made, per metric the conditions' table and heatmap and every
    run's heatmap (figures drawn into ``figures_dir`` as ``<prefix>_*.png`` and linked relative to ``out``), the
    skipped cells, and what it shows (``notes.md``, or a place for it). Numbers of the tables go to ``numbers``;
    ``folder``: where the matrix's ``crossplay.csv`` is (linked for every cell's numbers)."""
    figures = figures if figures is not None else []
    sub = heading.split(" ", 1)[0] + "#"
    responses = best_response_table(folder) if folder is not None else pd.DataFrame(columns=["member", "success"])
    md = [heading, ""] + _how_it_was_made(frame, meta, out, folder) + _adhoc_lines(frame, sub, numbers, responses)
    md += _conventions_lines(meta, sub)
    for metric, (title, cmap) in HEATMAP_METRICS.items():
        if metric not in frame or frame[metric].isna().all():
            continue  # a matrix made before the metric existed
        md += _metric_lines(frame, metric, title, cmap, figures_dir, prefix, out, figures, numbers, sub)
    return md + _skipped_lines(frame, sub) + _notes_lines(meta, sub)


def _how_it_was_made(frame: pd.DataFrame, meta: dict[str, Any], out: Path, folder: Path | None) -> list[str]:
    """The command, the matrix's size and world, and how to read its cells."""
    rows = _ordered(frame["row_run"])
    partners = _ordered(frame["partner"])
    episodes = meta.get("episodes", frame["episodes"].dropna().max() if frame["episodes"].notna().any() else "?")
    md = []
    if meta.get("command"):
        md += ["Made by:", "", "```", meta["command"], "```", ""]
    world = ", ".join(
        [f"{key} {meta[key]}" for key in ("domain", "layout", "noise") if key in meta]
        + [f"{key} ±{value:g}" for key, value in meta.get("jitter", {}).items() if value]
    )
    md += [
        (
            f"{len(rows)} run(s) × {len(partners)} partner(s) = {len(frame)} cells"
            + (f", made {meta['created']}" if meta.get("created") else "")
            + f". Every cell plays one episode in each of the same {episodes} seeded worlds"
            + (f" (seed {meta['seed']}: worlds seeded {meta['world_seed']}, the stream a run of seed {meta['seed']} "
               "is evaluated on)" if "seed" in meta and "world_seed" in meta else "")
            + (f"; world: {world}" if world else "")
            + (f", the training world of `{meta['world_of']}`" if meta.get("world_of") else "")
            + "."
        ),
        "",
        (
            "- Rows: a learned policy playing the agent it trained as (agent 0 for a centralized or self-play "
            "learner); columns: the partner playing every other agent, a scripted opponent or a learned policy. "
            "Both act greedily (their evaluation policies)."
        ),
        "- Success and collisions are the row's agent's; team success: every agent reached its goal.",
        (
            "- By condition: the mean over every pair of runs of the two conditions (the number of pairs in "
            "parentheses). Self-pairs (a run with itself) are left out, so a condition's cell with itself is the "
            "mean over pairs of *different* seeds (cross-seed play); every run's figure shows the self-pairs, "
            "boxed in red."
        ),
    ]
    if folder is not None:
        md.append(f"- Every cell's numbers: [`{CROSSPLAY_CSV}`]({shown_path(folder / CROSSPLAY_CSV, out)}).")
    return md + [""]


def _conventions_lines(meta: dict[str, Any], sub: str) -> list[str]:
    """The convention each run's policy follows with itself, where the matrix recorded them."""
    if not meta.get("conventions"):
        return []
    md = [
        f"{sub} Conventions",
        "",
        (
            "Each run's policy playing every agent on the same worlds: the side the agents pass on (\"left\": both "
            "keep to their own left) and its share of the episodes, and who swerves most "
            "(`sidewalk.crossplay.conventions.convention`)."
        ),
        "",
        "| run | seed | passing side | share | yielder |",
        "| --- | --- | --- | --- | --- |",
    ]
    md += [
        f"| {c['row_label']} | {c['row_seed']} | {c['passing_side']} | {c['passing_fraction']:.2f} | {c['yielder']} |"
        for c in meta["conventions"]
    ]
    return md + [""]


def _metric_lines(
    frame: pd.DataFrame,
    metric: str,
    title: str,
    cmap: str,
    figures_dir: Path,
    prefix: str,
    out: Path,
    figures: list[Path],
    numbers: NumberLog | None,
    sub: str,
) -> list[str]:
    """One metric's subsection: the conditions' table, its heatmap and every run's (drawn into ``figures_dir`` as
    ``<prefix>_*.png`` and appended to ``figures``); the table's numbers go to ``numbers``."""
    mean, pairs = condition_table(frame, metric)
    by_condition = figures_dir / f"{prefix}_by_condition_{metric}.png"
    by_run = figures_dir / f"{prefix}_{metric}.png"
    draw_heatmap(mean, f"Cross-play by condition: {title}", by_condition, cmap, pairs=pairs,
                 scripted=scripted_count(frame))
    draw_heatmap(run_table(frame, metric), f"Cross-play, every run: {title}", by_run, cmap,
                 outlined=self_pairs(frame), scripted=scripted_count(frame))
    figures += [by_condition, by_run]
    md = [f"{sub} {title[0].upper()}{title[1:]}", ""]
    md += _markdown_table(mean, pairs) + [""]
    md += [
        f"![cross-play by condition: {title}]({shown_path(by_condition, out)})",
        "",
        f"![cross-play, every run: {title}]({shown_path(by_run, out)})",
        "",
    ]
    if numbers is not None:
        for row_label, values in mean.iterrows():
            for partner_label, value in values.items():
                numbers.add(
                    "crossplay", None, f"row: {row_label}; partner: {partner_label}", metric, "mean",
                    float(value), int(pairs.loc[row_label, partner_label]),
                    "mean over pairs of runs, self-pairs left out",
                )
    return md


def _skipped_lines(frame: pd.DataFrame, sub: str) -> list[str]:
    """The cells not played, with the reason each was skipped."""
    skipped = frame[frame["skipped"] != ""]
    if skipped.empty:
        return []
    md = [f"{sub} Cells not played", "", "| row | partner | reason |", "| --- | --- | --- |"]
    md += [f"| `{r.row_run}` | `{r.partner}` | {r.skipped} |" for r in skipped.itertuples()]
    return md + [""]


def _notes_lines(meta: dict[str, Any], sub: str) -> list[str]:
    """What the matrix shows: its ``notes.md``, or where to write them."""
    notes = meta.get("notes", "").strip()
    return [
        f"{sub} What it shows",
        "",
        notes
        or "_Not written yet: write what the matrix shows (do policies trained with a scripted partner coordinate "
        f"with a learned one? do self-play seeds coordinate with each other?) into `{NOTES}` beside "
        f"`{CROSSPLAY_CSV}` and redraw (`python runners/crossplay.py --redraw DIR`)._",
        "",
    ]


def write_crossplay_report(folder: str | Path) -> Path:
    """Draw the figures of the cross-play folder ``folder`` into ``folder/figures`` and write its
    ``report.md`` (the section under a title) and, with held-out partners, ``adhoc.csv``; returns the report's path."""
    from sidewalk.run_folder import atomic_write

    folder = Path(folder)
    frame, meta = read_crossplay(folder)
    figures_dir = folder / "figures"
    figures_dir.mkdir(parents=True, exist_ok=True)
    md = ["# Sidewalk cross-play", ""]
    md += crossplay_section(frame, meta, figures_dir, folder, folder=folder)
    adhoc = adhoc_table(frame, read_best_responses(folder))
    if adhoc is not None:
        atomic_write(folder / ADHOC_CSV, lambda tmp: adhoc.to_csv(tmp, index=False))
    report = folder / REPORT
    atomic_write(report, lambda tmp: tmp.write_text("\n".join(md) + "\n"))
    log.info("wrote %s", report)
    return report


def crossplay_sections(
    folders: Sequence[Path], figures_dir: Path, out: Path, figures: list[Path], numbers: NumberLog
) -> list[str]:
    """The cross-play sections of a report over runs (``sidewalk.report.document``), one per folder found."""
    md: list[str] = []
    for number, folder in enumerate(folders, 1):
        frame, meta = read_crossplay(folder)
        heading = "## Cross-play" if len(folders) == 1 else f"## Cross-play: `{shown_path(folder, out)}`"
        md += crossplay_section(
            frame, meta, figures_dir, out, figures, numbers,
            prefix=f"crossplay{number}_{slug(folder.name)}" if len(folders) > 1 else "crossplay", heading=heading,
            folder=folder,
        )
    return md
