"""Reports over run folders: learning curves, final values with confidence intervals, and the paper's figures.

``write_report(paths, out)`` finds every run folder under ``paths`` (a folder holding ``config.yaml`` and
``metrics.csv``, as ``runners/main.py`` writes it, alone or inside a sweep), groups the runs into *conditions*
(identical configs but for the seed and bookkeeping keys such as the logger), and writes into ``out``:

- ``figures/curves_<family>.png``: success and collision rate of each agent over training, the mean over seeds
  with the standard error shaded (the paper's way); one figure per *family*, i.e. per sweep folder (the folder
  holding Hydra's ``multirun.yaml``), or per parent folder for runs outside a sweep;
- the paper's figures where runs that differ in the figure's variable are present (see ``PAPER_FIGURES``):
  Fig. 5 success and Fig. 7 collisions by opponent, Fig. 6 success under noise, Fig. 8 explicit vs implicit
  reward, and Fig. 10 representative trajectories replayed from the runs' checkpoints; a figure whose runs are
  missing is skipped with a note;
- ``report.md``: the tables (final values of each condition: mean ± standard error over seeds, interquartile mean
  with its 95 % stratified-bootstrap interval, see ``sidewalk.stats``) with the figures embedded by relative path,
  and the run folders that were skipped and why (no ``metrics.csv``, a truncated CSV, no ``summary.json``, a
  failed job...);
- ``report.csv``: every number in ``report.md``, one per row; ``curves.csv``: every plotted point.

Learning curves read the ``eval/<agent>/<metric>`` columns of ``metrics.csv`` (the evaluations during training);
final values read ``summary.json`` (the last evaluation). Agents are ``ego``/``other`` where a learner plays
against a scripted opponent and ``agent0``/``agent1``/... where it plays every agent (centralized).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import logging
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from omegaconf import OmegaConf

from sidewalk.stats import Interval, interval_estimate, mean_se

log = logging.getLogger(__name__)

CONFIG, METRICS, SUMMARY, CHECKPOINT, ERROR = (
    "config.yaml",
    "metrics.csv",
    "summary.json",
    "checkpoint.pt",
    "error.txt",
)
# A folder holding any of these is a run folder, complete or not (".hydra" alone: a job killed while starting).
RUN_MARKERS = (CONFIG, METRICS, SUMMARY, CHECKPOINT, ERROR, ".hydra")
SWEEP_MARKER = "multirun.yaml"
# Keys that change neither what a run learns nor what it measures, so they never split runs into conditions
# (a resumed run's config says resume=true; a run logged to TensorBoard is the same experiment as one logged to CSV).
BOOKKEEPING_KEYS = ("seed", "resume", "device", "torch_threads", "checkpoint_every", "logger")
CURVE_METRICS = {"success_rate": "success rate", "collision_rate": "collision rate"}
X_AXES = {"frames": "frames", "iterations": "iteration"}  # option name -> metrics.csv column
OPPONENT_ORDER = ("random", "dijkstra", "prm", "centralized")
DOMAIN_ORDER = ("discrete", "continuous")
COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f")


class RunFolderError(Exception):
    """A run folder that cannot be used; the message says why."""


# ---- reading run folders ----------------------------------------------------------------------------------------


@dataclass
class Run:
    """One usable run folder: its resolved config (nested and flattened to dotted keys), metrics and summary."""

    path: Path
    family: str
    config: dict[str, Any]
    flat: dict[str, Any]
    metrics: pd.DataFrame
    summary: dict[str, Any]

    @property
    def seed(self) -> int:
        return int(self.flat.get("seed", -1))


@dataclass
class Skipped:
    """A run folder left out of the report, with the reason."""

    path: Path
    reason: str


def find_run_folders(paths: Iterable[str | Path]) -> list[Path]:
    """Every run folder under ``paths`` (each a run folder or a folder of them, searched recursively), sorted.

    Hidden folders (``.hydra``) are not searched, nor are a run folder's own subfolders (its logger's files).
    Raises ``FileNotFoundError`` / ``NotADirectoryError`` naming a path that is missing or not a folder.
    """
    found: set[Path] = set()
    for path in map(Path, paths):
        if not path.exists():
            raise FileNotFoundError(f"{path} does not exist; give run folders or sweep folders")
        if not path.is_dir():
            raise NotADirectoryError(f"{path} is not a folder; give run folders or sweep folders")
        for root, dirs, files in os.walk(path):
            if any(marker in files or marker in dirs for marker in RUN_MARKERS):
                found.add(Path(root))
                dirs[:] = []
            else:
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
    return sorted(found)


def family_of(run_dir: Path) -> str:
    """The name of the sweep folder holding ``run_dir`` (the nearest ancestor with ``multirun.yaml``), or of
    ``run_dir``'s parent folder for a run outside a sweep."""
    for parent in run_dir.resolve().parents:
        if (parent / SWEEP_MARKER).exists():
            return parent.name
    return run_dir.resolve().parent.name


def flatten(config: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts to dotted keys; lists become tuples so that values can be compared and hashed."""
    flat: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = tuple(value) if isinstance(value, list) else value
    return flat


def read_metrics(path: Path) -> pd.DataFrame:
    """``metrics.csv`` checked to be whole: one row per iteration 1..N with its frames and wall clock.

    ``Trial`` writes the file atomically, so a file that fails these checks was copied or written by something
    else half-way; it raises ``RunFolderError`` naming what is wrong.
    """
    if not path.exists():
        raise RunFolderError(f"no {METRICS}")
    raw = path.read_bytes()
    if not raw.strip():
        raise RunFolderError(f"{METRICS} is empty")
    if not raw.endswith(b"\n"):
        raise RunFolderError(f"{METRICS} is truncated (its last line is incomplete)")
    try:
        frame = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        raise RunFolderError(f"{METRICS} is unreadable: {str(error).strip()}") from error
    missing = [column for column in ("iteration", "frames", "time_s") if column not in frame.columns]
    if missing:
        raise RunFolderError(f"{METRICS} lacks the column(s) {', '.join(missing)}")
    if frame.empty:
        raise RunFolderError(f"{METRICS} has a header but no rows")
    if frame[["iteration", "frames", "time_s"]].isna().any().any():
        raise RunFolderError(f"{METRICS} has rows without iteration, frames or time_s (truncated)")
    if list(frame["iteration"]) != list(range(1, len(frame) + 1)):
        raise RunFolderError(f"{METRICS} iterations are not 1..{len(frame)} in order")
    return frame


def load_run(run_dir: Path, family: str | None = None) -> Run:
    """Read one run folder, raising ``RunFolderError`` that says why it cannot be used (a failed job, a missing,
    empty, truncated or unreadable file, or a ``summary.json`` that does not match ``metrics.csv``)."""
    run_dir = Path(run_dir)
    error_file = run_dir / ERROR
    if error_file.exists():
        lines = [line for line in error_file.read_text(errors="replace").splitlines() if line.strip()]
        raise RunFolderError(f"the job failed: {lines[-1].strip() if lines else '(empty error.txt)'}")
    if not (run_dir / CONFIG).exists():
        raise RunFolderError(f"no {CONFIG} (the job stopped before training)")
    try:
        config = OmegaConf.to_container(OmegaConf.load(run_dir / CONFIG), resolve=True)
    except Exception as error:  # any YAML or interpolation error means the same: the config is unusable
        raise RunFolderError(f"{CONFIG} is unreadable: {str(error).splitlines()[0]}") from error
    if not isinstance(config, dict) or not {"env", "opponent", "algo", "seed"} <= set(config):
        raise RunFolderError(f"{CONFIG} is not a run's config (it lacks env, opponent, algo or seed)")
    metrics = read_metrics(run_dir / METRICS)
    summary_path = run_dir / SUMMARY
    if not summary_path.exists():
        raise RunFolderError(f"no {SUMMARY} (still running, or stopped before the end)")
    try:
        summary = json.loads(summary_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise RunFolderError(f"{SUMMARY} is unreadable: {error}") from error
    if not isinstance(summary, dict):
        raise RunFolderError(f"{SUMMARY} is not a JSON object")
    # Undefined metrics are written as null (strict JSON); the statistics read them as NaN.
    summary = {k: math.nan if v is None else v for k, v in summary.items()}
    last = int(metrics["iteration"].iloc[-1])
    if "iterations" in summary and int(summary["iterations"]) != last:
        raise RunFolderError(
            f"{METRICS} ends at iteration {last} but {SUMMARY} is of iteration {summary['iterations']}"
        )
    return Run(run_dir, family or family_of(run_dir), config, flatten(config), metrics, summary)


# ---- conditions ---------------------------------------------------------------------------------------------------


def _is_bookkeeping(key: str) -> bool:
    return any(key == k or key.startswith(f"{k}.") for k in BOOKKEEPING_KEYS)


@dataclass
class Condition:
    """Runs of one config that differ only in their seed (one run per seed)."""

    key: str
    flat: dict[str, Any]  # the config without bookkeeping keys
    runs: list[Run]
    families: list[str] = field(default_factory=list)
    ident: str = ""
    label: str = ""
    duplicates: list[tuple[int, Path, Path]] = field(default_factory=list)  # (seed, kept run, left-out run)

    @property
    def domain(self) -> str:
        return str(self.flat.get("env.domain", "?"))

    @property
    def algo(self) -> str:
        return str(self.flat.get("algo.name", "?"))

    @property
    def opponent(self) -> str:
        return str(self.flat.get("opponent.name", "?"))

    @property
    def seeds(self) -> list[int]:
        return [run.seed for run in self.runs]

    def agents(self) -> list[tuple[str, str]]:
        """(metric prefix, display name) of each agent, the learner's first: ego/other for a learner against a
        scripted opponent, agent0/agent1/... where the learner plays every agent."""
        summary = self.runs[0].summary
        if self.opponent != "centralized" and "ego/success_rate" in summary:
            return [("ego", f"{self.algo.upper()} (ego)"), ("other", f"{self.opponent} (other)")]
        count = 0
        while f"agent{count}/success_rate" in summary:
            count += 1
        shaped = self.flat.get("reward.shaped_agents")
        agents = []
        for index in range(count):
            suffix = "" if shaped is None else (" shaped" if index in shaped else " unshaped")
            agents.append((f"agent{index}", f"agent {index}{suffix}"))
        return agents


def _sort_key(condition: Condition) -> tuple:
    flat = condition.flat

    def rank(value: str, order: Sequence[str]) -> int:
        return order.index(value) if value in order else len(order)

    return (
        rank(condition.domain, DOMAIN_ORDER),
        condition.algo,
        rank(condition.opponent, OPPONENT_ORDER),
        float(flat.get("noise", 0.0) or 0.0),
        -float(flat.get("reward.alpha", 0.0) or 0.0),
        condition.key,
    )


def group_conditions(runs: Sequence[Run]) -> list[Condition]:
    """Group runs by their config without seed and bookkeeping keys; one run per seed (a repeated seed, e.g. the
    same condition run by two presets, keeps the newest run and notes the others). Conditions are sorted (domain,
    algorithm, opponent, noise, reward) and numbered C1, C2, ..."""
    grouped: dict[str, Condition] = {}
    for run in runs:
        flat = {k: v for k, v in run.flat.items() if not _is_bookkeeping(k)}
        key = json.dumps(sorted(flat.items()), default=str)
        condition = grouped.setdefault(key, Condition(key, flat, []))
        condition.runs.append(run)
    conditions = sorted(grouped.values(), key=_sort_key)
    for number, condition in enumerate(conditions, 1):
        by_seed: dict[int, Run] = {}
        for run in sorted(condition.runs, key=lambda r: (r.path / SUMMARY).stat().st_mtime):
            if run.seed in by_seed:
                condition.duplicates.append((run.seed, run.path, by_seed[run.seed].path))
            by_seed[run.seed] = run
        condition.runs = [by_seed[seed] for seed in sorted(by_seed)]
        condition.families = sorted({run.family for run in condition.runs})
        condition.ident = f"C{number}"
    _label(conditions)
    return conditions


def _value(key: str, value: Any, domain: str) -> str:
    """A config value as a short legend text."""
    if key == "opponent.name":
        return str(value)
    if key == "noise":
        return (
            f"{'n' if domain == 'discrete' else 'ε'}={value:g}"
            if isinstance(value, (int, float))
            else f"noise={value}"
        )
    if key == "reward.name":
        return f"{value} reward"
    if key == "reward.shaped_agents":
        return "all shaped" if value is None else f"shaped {list(value)}"
    short = key.split(".", 1)[1] if key.startswith(("env.", "algo.")) else key
    return f"{short}={list(value) if isinstance(value, tuple) else value}"


def varying_keys(conditions: Sequence[Condition], ignore: Iterable[str] = ()) -> list[str]:
    """Config keys whose value is not the same in every one of ``conditions`` (a key missing counts as a value)."""
    ignore = set(ignore)
    keys = sorted({k for c in conditions for k in c.flat} - ignore)
    return [
        k for k in keys if len({json.dumps(c.flat.get(k, "<absent>"), default=str) for c in conditions}) > 1
    ]


def describe(condition: Condition, keys: Sequence[str], limit: int | None = 4) -> str:
    """``condition`` told by its values of ``keys`` (opponent first, then noise, reward, the rest), at most
    ``limit`` of them and then how many more; keys the condition does not have are left out."""
    order = ["opponent.name", "reward.shaped_agents", "noise", "reward.name", "reward.alpha"]
    ranked = sorted(
        (k for k in keys if k in condition.flat),
        key=lambda k: (order.index(k) if k in order else len(order), k),
    )
    if "reward.name" in ranked and "reward.alpha" in ranked:
        ranked.remove("reward.alpha")  # explicit/implicit already says it
    if "opponent.name" in ranked:  # each opponent brings its own parameters; its name says which
        ranked = [k for k in ranked if k == "opponent.name" or not k.startswith("opponent.")]
    shown = ranked if limit is None else ranked[:limit]
    text = ", ".join(_value(k, condition.flat.get(k), condition.domain) for k in shown)
    return text + (f", +{len(ranked) - len(shown)} more" if len(ranked) > len(shown) else "")


def _peer_keys(condition: Condition, conditions: Sequence[Condition]) -> list[str]:
    """The keys that set ``condition`` apart from the others of its domain, algorithm and opponent (other
    domains, algorithms and opponents have other keys altogether)."""
    peers = [
        c
        for c in conditions
        if (c.domain, c.algo, c.opponent) == (condition.domain, condition.algo, condition.opponent)
    ]
    return varying_keys(peers, ignore=("env.domain", "algo.name", "opponent.name"))


def _label(conditions: Sequence[Condition]) -> None:
    """Label each condition by domain, algorithm and opponent, plus what sets it apart from its peers."""
    for condition in conditions:
        extra = _peer_keys(condition, conditions)
        head = f"{condition.domain}: {condition.algo.upper()}" + (
            " centralized" if condition.opponent == "centralized" else f" vs {condition.opponent}"
        )
        rest = describe(condition, extra)
        condition.label = f"{head}, {rest}" if rest else head


# ---- numbers ------------------------------------------------------------------------------------------------------


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
    out = []
    for agent in agents:
        values = summary_values(condition, f"{agent}/{metric}")
        mean, se, _ = mean_se(values)
        interval = interval_estimate(
            values,
            "iqm",
            confidence=settings.confidence,
            n_resamples=settings.n_resamples,
            seed=settings.seed,
        )
        out.append(Final(agent, metric, values, float(mean), float(se), interval))
    return out


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


# ---- drawing ------------------------------------------------------------------------------------------------------


def _lighter(colour: str, amount: float = 0.5) -> tuple[float, float, float]:
    rgb = np.array([int(colour[i : i + 2], 16) / 255 for i in (1, 3, 5)])
    return tuple(rgb + (1.0 - rgb) * amount)


def draw_curves(
    ax,
    conditions: Sequence[Condition],
    labels: Sequence[str],
    metric: str,
    settings: Settings,
    curves_out: list[dict[str, Any]],
    figure_name: str,
) -> bool:
    """Mean ± SE curves of ``metric`` for every agent of every condition on ``ax``: one hue per condition, the
    learner's agent dark and solid, the other agent(s) light and dashed (the paper's convention). Appends the
    plotted points to ``curves_out`` under ``figure_name``; returns whether anything was drawn."""
    drawn = False
    for index, (condition, label) in enumerate(zip(conditions, labels)):
        colour = COLOURS[index % len(COLOURS)]
        for rank, (agent, agent_name) in enumerate(condition.agents()):
            data = curve(condition, agent, metric, settings.x)
            if data.empty:
                continue
            drawn = True
            shade = colour if rank == 0 else _lighter(colour, 0.45)
            x, mean, se = data["x"].to_numpy(float), data["mean"].to_numpy(float), data["se"].to_numpy(float)
            ax.plot(
                x,
                mean,
                color=shade,
                linestyle="-" if rank == 0 else "--",
                linewidth=1.8 if rank == 0 else 1.4,
                label=f"{label}: {agent_name}",
            )
            band = np.isfinite(se)
            if band.any():
                ax.fill_between(
                    x,
                    mean - np.where(band, se, 0),
                    mean + np.where(band, se, 0),
                    where=band,
                    color=shade,
                    alpha=0.2,
                    linewidth=0,
                )
            for row in data.itertuples(index=False):
                curves_out.append(
                    {
                        "figure": figure_name,
                        "condition_id": condition.ident,
                        "condition": condition.label,
                        "agent": agent,
                        "metric": metric,
                        "x_axis": settings.x,
                        "x": row.x,
                        "mean": row.mean,
                        "se": row.se,
                        "seeds": int(row.n),
                    }
                )
    ax.set_xlabel(settings.x)
    ax.set_ylabel(CURVE_METRICS.get(metric, metric))
    ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    return drawn


def _save(figure: Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110, bbox_inches="tight")


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "runs"


# ---- the paper's figures -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PaperFigure:
    """A figure of the paper drawn from conditions that differ only in ``vary`` (keys, or prefixes ending in
    '.'), at least two values of ``primary`` apart; one panel per such group."""

    name: str
    title: str
    metric: str
    vary: tuple[str, ...]
    primary: str
    needs: str  # what to run when the figure is missing


PAPER_FIGURES = (
    PaperFigure(
        "fig5_success_by_opponent",
        "Fig. 5: success by opponent",
        "success_rate",
        ("opponent.", "reward.shaped_agents"),
        "opponent.name",
        "runs of one setting against ≥ 2 opponents (+experiment=fig5_discrete / fig5_continuous)",
    ),
    PaperFigure(
        "fig6_success_under_noise",
        "Fig. 6: success under noise",
        "success_rate",
        ("noise",),
        "noise",
        "runs of one setting at ≥ 2 noise levels (+experiment=fig6_discrete / fig6_continuous)",
    ),
    PaperFigure(
        "fig7_collisions_by_opponent",
        "Fig. 7: collisions by opponent",
        "collision_rate",
        ("opponent.", "reward.shaped_agents"),
        "opponent.name",
        "the runs of Fig. 5: one setting against ≥ 2 opponents (+experiment=fig5_discrete / fig5_continuous)",
    ),
    PaperFigure(
        "fig8_explicit_vs_implicit",
        "Fig. 8: explicit vs implicit cooperative reward",
        "success_rate",
        ("reward.name", "reward.alpha"),
        "reward.alpha",
        "runs of one setting with reward=explicit and reward=implicit (+experiment=fig8)",
    ),
)


def _matches(key: str, patterns: Sequence[str]) -> bool:
    return any(key == p or (p.endswith(".") and key.startswith(p)) for p in patterns)


def figure_panels(spec: PaperFigure, conditions: Sequence[Condition]) -> list[list[Condition]]:
    """Groups of conditions that are equal but for ``spec.vary`` and take ≥ 2 values of ``spec.primary``."""
    groups: dict[str, list[Condition]] = {}
    for condition in conditions:
        rest = {k: v for k, v in condition.flat.items() if not _matches(k, spec.vary)}
        groups.setdefault(json.dumps(sorted(rest.items()), default=str), []).append(condition)
    panels = [
        group
        for group in groups.values()
        if len({json.dumps(c.flat.get(spec.primary), default=str) for c in group}) >= 2
    ]
    return sorted(panels, key=lambda group: _sort_key(group[0]))


def panel_titles(panels: Sequence[Sequence[Condition]], spec: PaperFigure) -> list[tuple[str, str]]:
    """(title, what sets it apart) of each panel: "continuous: TRPO" and, where panels of one domain and
    algorithm differ elsewhere (iterations, say), how ("dt_s=0.2"), else ""."""
    titles = []
    for group in panels:
        first = group[0]
        title = f"{first.domain}: {first.algo.upper()}"
        if not _matches("opponent.name", spec.vary):
            title += " centralized" if first.opponent == "centralized" else f" vs {first.opponent}"
        titles.append(title)
    out = []
    for title, group in zip(titles, panels):
        namesakes = [g[0] for t, g in zip(titles, panels) if t == title]
        extra = [k for k in varying_keys(namesakes) if not _matches(k, spec.vary)]
        out.append((title, describe(group[0], extra) if len(namesakes) > 1 else ""))
    return out


# ---- trajectories (Fig. 10) ----------------------------------------------------------------------------------------


def load_experiment(run_dir: str | Path, device: str = "cpu"):
    """The validated ``Experiment`` of a run folder's ``config.yaml``, on ``device``.

    The algorithm and logger sections are merged onto their schemas first, so they come back as their typed
    config dataclasses, exactly as ``runners/main.py`` built them.
    """
    from sidewalk.algos import ALGORITHMS
    from sidewalk.config import LoggerSchema, validate

    path = Path(run_dir) / CONFIG
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: {run_dir} is not a run folder")
    cfg = OmegaConf.load(path)
    cfg.algo = OmegaConf.merge(OmegaConf.structured(ALGORITHMS[cfg.algo.name].Config), cfg.algo)
    cfg.logger = OmegaConf.merge(OmegaConf.structured(LoggerSchema), cfg.logger)
    return dataclasses.replace(validate(cfg), device=device)


def load_policy(run_dir: str | Path, experiment, env):
    """The greedy evaluation policy of the learner saved in ``run_dir/checkpoint.pt``, rebuilt for ``env`` (a view
    built from ``experiment``)."""
    import torch
    from torchrl.envs import RewardSum, TransformedEnv

    from sidewalk.algos import ALGORITHMS

    path = Path(run_dir) / CHECKPOINT
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: the run has no checkpoint to replay")
    # mmap: the replay buffer in the checkpoint can be large and is not needed here.
    state = torch.load(path, map_location=experiment.device, weights_only=False, mmap=True)
    # The learner is built on the env as training built it (a RewardSum on top), so every spec matches.
    algo = ALGORITHMS[experiment.algo.name](
        experiment.algo, TransformedEnv(env, RewardSum()), device=experiment.device
    )
    algo.load_state_dict(state["algorithm"])
    return algo.evaluation_policy()


@dataclass
class Replay:
    """Episodes of a run's final policy, replayed exactly as its final evaluation ran them."""

    run: Run
    record: Any  # sidewalk.evaluate.EpisodeRecord with trajectories of the first k worlds
    layout: Any  # GridLayout | PlaneLayout
    domain: str
    matches_summary: bool


def replay(run: Run, episodes: int) -> Replay:
    """Replay the final evaluation of ``run`` (the same worlds, seed and greedy policy as ``Trial``'s) and record
    the first ``episodes`` trajectories. ``matches_summary`` tells whether the replayed success and collision rates
    equal ``summary.json``'s, i.e. the checkpoint is the policy that was evaluated."""
    import torch

    from sidewalk.evaluate import run_episodes, summarize
    from sidewalk.experiment import EVAL_SEED_OFFSET, make_view

    experiment = load_experiment(run.path)
    seed = experiment.seed + EVAL_SEED_OFFSET
    env = make_view(experiment, experiment.eval_episodes, seed)
    policy = load_policy(run.path, experiment, env)
    with torch.no_grad():
        record = run_episodes(
            env, policy, seed=seed, record_trajectories=min(episodes, experiment.eval_episodes)
        )
    replayed = summarize(record)
    keys = [k for k in replayed if k.endswith(("success_rate", "collision_rate")) and k in run.summary]
    matches = all(math.isclose(replayed[k], float(run.summary[k]), abs_tol=1e-6) for k in keys)
    return Replay(run, record, env.core.layout, experiment.domain, matches)


def representative_run(condition: Condition) -> Run | None:
    """The run with a checkpoint whose final success (the learner's, or the team's) is the median of the seeds'."""
    candidates = [run for run in condition.runs if (run.path / CHECKPOINT).exists()]
    if not candidates:
        return None
    key = "ego/success_rate" if condition.agents()[0][0] == "ego" else "team/success_rate"
    ranked = sorted(candidates, key=lambda run: (float(run.summary.get(key, math.nan)), run.seed))
    return ranked[(len(ranked) - 1) // 2]


OUTCOMES = (
    ("reached_goal", "goal"),
    ("collided_agent", "hit agent"),
    ("collided_wall", "hit wall"),
    ("timed_out", "timeout"),
)


def _outcome(record, world: int, agent: int) -> str:
    for key, text in OUTCOMES:
        if record.info[key][world, agent]:
            return text
    return "running"


def draw_trajectories(ax, replay_: Replay, condition: Condition) -> None:
    """The sidewalk outline with each agent's path in the replayed episodes (agent colours as in ``render``)."""
    from matplotlib.patches import Rectangle

    from sidewalk.envs.render import colour

    record, layout = replay_.record, replay_.layout
    paths = record.trajectories  # (T, k, N, 2)
    names = dict(condition.agents())
    agent_names = [
        names.get("ego" if a == record.ego else "other", f"agent {a}")
        if record.ego is not None
        else names.get(f"agent{a}", f"agent {a}")
        for a in range(paths.shape[2])
    ]
    if replay_.domain == "discrete":
        # Grid paths run along cell centres; x is the column (along the sidewalk), y the row, row 0 on top.
        ax.add_patch(Rectangle((-0.5, -0.5), layout.cols, layout.rows, fill=False, color="0.25", linewidth=2))
        for row, col in layout.blocked:
            ax.add_patch(Rectangle((col - 0.5, row - 0.5), 1, 1, color="0.25"))
        xy = paths[..., ::-1].astype(float)
        ax.set_xlim(-0.8, layout.cols - 0.2)
        ax.set_ylim(layout.rows - 0.2, -0.8)
        goals = [(c, r) for r, c in layout.goals]
        # Episodes often repeat a path cell for cell; a small offset per episode keeps them apart.
        offsets = np.linspace(-0.15, 0.15, paths.shape[1]) if paths.shape[1] > 1 else np.zeros(1)
    else:
        ax.add_patch(
            Rectangle((0, 0), layout.length_m, layout.width_m, fill=False, color="0.25", linewidth=2)
        )
        for x0, y0, x1, y1 in layout.boxes:
            ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color="0.25"))
        xy = paths.astype(float)
        ax.set_xlim(-0.2, layout.length_m + 0.2)
        ax.set_ylim(-0.2, layout.width_m + 0.2)
        goals = list(layout.goals)
        offsets = np.zeros(paths.shape[1])
    ax.set_aspect("equal")
    for agent in range(paths.shape[2]):
        rgb = tuple(c / 255 for c in colour(agent))
        for episode in range(paths.shape[1]):
            track = xy[:, episode, agent] + offsets[episode]
            track = track[~np.isnan(track).any(-1)]
            if not len(track):
                continue
            ax.plot(
                track[:, 0],
                track[:, 1],
                color=rgb,
                alpha=0.8,
                linewidth=1.5,
                label=agent_names[agent] if episode == 0 else None,
            )
            ax.plot(*track[0], marker="o", color=rgb, markersize=5)
            if record.info["collided_agent"][episode, agent] or record.info["collided_wall"][episode, agent]:
                ax.plot(*track[-1], marker="X", color="k", markersize=8, zorder=4)
        gx, gy = goals[agent]
        ax.plot(gx, gy, marker="*", markersize=14, color=rgb, markeredgecolor="k", linestyle="none", zorder=5)
    episodes = paths.shape[1]
    tallies = []
    for agent in range(paths.shape[2]):
        counts: dict[str, int] = {}
        for episode in range(episodes):
            text = _outcome(record, episode, agent)
            counts[text] = counts.get(text, 0) + 1
        tallies.append(
            f"{agent_names[agent].split(' (')[0]}: " + ", ".join(f"{n}× {t}" for t, n in counts.items())
        )
    ax.set_title(
        f"{condition.ident} {condition.label} (seed {replay_.run.seed})\n{episodes} episode(s): "
        + "; ".join(tallies),
        fontsize=8,
    )
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=paths.shape[2], frameon=False)
    ax.set_axis_off()  # the outline is the frame


# ---- the report ---------------------------------------------------------------------------------------------------


@dataclass
class ReportResult:
    """What ``write_report`` wrote and what it left out."""

    out: Path
    report_md: Path
    figures: list[Path]
    skipped: list[Skipped]
    notes: list[str]
    conditions: list[Condition]


def write_report(
    paths: Sequence[str | Path],
    out: str | Path | None = None,
    settings: Settings | None = None,
    preamble: str | Path | None = None,
) -> ReportResult:
    """Read every run folder under ``paths`` and write the report (see the module docstring) into ``out``
    (default: ``report/`` inside the single path given, or inside the paths' common folder); PNG files
    already in ``out/figures`` are replaced. ``preamble``: a Markdown file placed under the title (how the runs
    were made, say), read before any work starts.

    Unusable run folders are listed in ``report.md`` with the reason and left out; a paper figure without its runs
    is skipped with a note. Raises ``FileNotFoundError`` for a missing path and ``ValueError`` when no run
    folder is found at all.
    """
    settings = settings or Settings()
    preamble_text = ""
    if preamble is not None:
        if not Path(preamble).is_file():
            raise FileNotFoundError(f"preamble {preamble} is not a file; give a Markdown file")
        preamble_text = Path(preamble).read_text().strip()
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("give at least one run folder or sweep folder")
    folders = find_run_folders(paths)
    if not folders:
        raise ValueError(
            f"no run folder (a folder with {CONFIG} and {METRICS}) under {', '.join(map(str, paths))}"
        )
    if out is None:
        base = paths[0] if len(paths) == 1 else Path(os.path.commonpath([p.resolve() for p in paths]))
        out = base / "report"
    out = Path(out)
    figures_dir = out / "figures"
    figures_dir.mkdir(parents=True, exist_ok=True)
    for stale in figures_dir.glob("*.png"):  # figures of an earlier report that this one may not redraw
        stale.unlink()
    log.info("reading %d run folder(s)", len(folders))

    runs: list[Run] = []
    skipped: list[Skipped] = []
    for folder in folders:
        try:
            runs.append(load_run(folder))
        except RunFolderError as error:
            skipped.append(Skipped(folder, str(error)))
            log.warning("skipped %s: %s", folder, error)
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
        + ", ".join(f"`{p}`" for p in paths)
        + f": {len(folders)} run folder(s), {len(runs)} used in {len(conditions)} condition(s), "
        f"{len(skipped)} skipped.",
        "",
    ]
    if preamble_text:
        md += [preamble_text, ""]

    md += _runs_section(conditions, numbers, out)
    md += _skipped_section(skipped)
    from sidewalk.claims import claims_section  # claims.py builds on this module's conditions and panels

    md += claims_section(conditions, numbers)
    md += ["## Paper figures", ""]
    for spec in PAPER_FIGURES:
        md += _paper_figure(spec, conditions, settings, figures_dir, figures, numbers, curves_rows, notes)
    md += _trajectory_figure(conditions, settings, figures_dir, figures, notes)
    md += _family_sections(conditions, settings, figures_dir, figures, numbers, curves_rows)
    md += _statistics_section(settings)

    report_md = out / "report.md"
    report_md.write_text("\n".join(md) + "\n")
    numbers.frame().to_csv(out / "report.csv", index=False)
    pd.DataFrame(
        curves_rows,
        columns=[
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
        ],
    ).to_csv(out / "curves.csv", index=False)
    log.info("wrote %s (%d figure(s))", report_md, len(figures))
    return ReportResult(out, report_md, figures, skipped, notes, conditions)


def _runs_section(conditions: Sequence[Condition], numbers: NumberLog, out: Path) -> list[str]:
    md = [
        "## Conditions",
        "",
        f"Runs are grouped by their config without the seed and bookkeeping keys ({', '.join(BOOKKEEPING_KEYS)}).",
        "",
        "| id | condition | family | seeds | iterations | frames |",
        "| --- | --- | --- | --- | ---: | ---: |",
    ]
    for condition in conditions:
        iterations = int(condition.runs[0].metrics["iteration"].iloc[-1])
        frames = int(condition.runs[0].metrics["frames"].iloc[-1])
        md.append(
            f"| {condition.ident} | {condition.label} | {', '.join(condition.families)} | "
            f"{', '.join(map(str, condition.seeds))} | {iterations} | {frames} |"
        )
        numbers.add("conditions", condition, "", "", "seeds", len(condition.runs), len(condition.runs))
        numbers.add("conditions", condition, "", "", "iterations", iterations, len(condition.runs))
        numbers.add("conditions", condition, "", "", "frames", frames, len(condition.runs))
    md.append("")
    for condition in conditions:
        if "+" in condition.label and " more" in condition.label:
            md.append(
                f"- {condition.ident} differs from the other {condition.domain} {condition.algo.upper()} "
                f"{condition.opponent} conditions in: {describe(condition, _peer_keys(condition, conditions), None)}"
            )
        for seed, kept, left_out in condition.duplicates:
            md.append(
                f"- {condition.ident}: seed {seed} was run twice (the same config, e.g. by two presets); "
                f"used `{_shown(kept, out)}`, left out `{_shown(left_out, out)}`"
            )
    return md + [""]


def _skipped_section(skipped: Sequence[Skipped]) -> list[str]:
    if not skipped:
        return ["No run folder was skipped.", ""]
    md = ["## Skipped run folders", "", "| run folder | reason |", "| --- | --- |"]
    md += [
        f"| `{item.path}` | {item.reason} |" for item in skipped
    ]  # absolute: the folder must be found to fix it
    return md + [""]


def _paper_figure(
    spec: PaperFigure,
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    numbers: NumberLog,
    curves_rows: list[dict[str, Any]],
    notes: list[str],
) -> list[str]:
    md = [f"### {spec.title}", ""]
    panels = figure_panels(spec, conditions)
    if not panels:
        notes.append(f"{spec.title} skipped: it needs {spec.needs}")
        return md + [f"_Skipped: it needs {spec.needs}._", ""]
    figure = Figure(figsize=(6.2 * len(panels), 4.6))
    axes = figure.subplots(1, len(panels), squeeze=False)[0]
    final_rows = []
    for ax, group, (title, apart) in zip(axes, panels, panel_titles(panels, spec)):
        title += f" ({apart})" if apart else ""
        within = varying_keys(group)
        labels = [describe(c, within) for c in group]
        draw_curves(ax, group, labels, spec.metric, settings, curves_rows, spec.name)
        ax.set_title(title)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
        for condition in group:
            agents = condition.agents()
            for (agent, agent_name), final in zip(
                agents, finals(condition, [a for a, _ in agents], spec.metric, settings)
            ):
                final_rows.append((condition, agent_name, final))
                numbers.add_final(spec.name, condition, final)
    figure.suptitle(spec.title + " (mean over seeds, SE shaded)")
    path = figures_dir / f"{spec.name}.png"
    _save(figure, path)
    figures.append(path)
    log.info("drew %s", path.name)
    md += [f"![{spec.title}](figures/{path.name})", "", f"Final values (`summary.json`), {spec.metric}:", ""]
    return md + final_table(final_rows, settings.confidence) + [""]


def _trajectory_figure(
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    notes: list[str],
) -> list[str]:
    title = "Fig. 10: representative trajectories"
    md = [f"### {title}", ""]
    if settings.trajectory_episodes == 0 or settings.max_trajectory_panels == 0:
        notes.append(f"{title} skipped: trajectories switched off")
        return md + ["_Skipped: switched off (--trajectories 0)._", ""]
    # The paper draws Fig. 10 from its opponent and reward comparisons; those conditions come first.
    ordered: list[Condition] = []
    for spec in (PAPER_FIGURES[0], PAPER_FIGURES[3], PAPER_FIGURES[1]):
        for group in figure_panels(spec, conditions):
            ordered += [c for c in group if c not in ordered]
    ordered += [c for c in conditions if c not in ordered]
    replays: list[tuple[Condition, Replay]] = []
    problems: list[str] = []
    for condition in ordered:
        if len(replays) == settings.max_trajectory_panels:
            break
        run = representative_run(condition)
        if run is None:
            problems.append(f"{condition.ident}: no {CHECKPOINT}")
            continue
        try:
            log.info("replaying %s (%s, seed %d)", condition.ident, condition.label, run.seed)
            replays.append((condition, replay(run, settings.trajectory_episodes)))
        except Exception as error:  # noqa: BLE001 (a checkpoint of another code version must not sink the report)
            problems.append(
                f"{condition.ident}: could not replay {run.path}: {type(error).__name__}: {error}"
            )
            log.warning("could not replay %s: %s", run.path, error)
    if not replays:
        note = f"{title} skipped: no run with a loadable {CHECKPOINT}" + (
            f" ({'; '.join(problems)})" if problems else ""
        )
        notes.append(note)
        return (
            md
            + [f"_Skipped: no run with a loadable `{CHECKPOINT}`._", ""]
            + [f"- {p}" for p in problems]
            + [""]
        )
    # The continuous sidewalk is long and thin (10 m × 1.5 m): one panel per row; grid panels go two abreast.
    md += [
        (
            "Each panel replays one run (the seed with the median final success) with its checkpoint, on the same "
            "worlds and seed as its final evaluation, and draws its first episodes (○ start, ★ goal, ✕ collision)."
        ),
        "",
    ]
    for domain in DOMAIN_ORDER:
        chosen = [(c, r) for c, r in replays if r.domain == domain]
        if not chosen:
            continue
        # The continuous sidewalk is long and thin (10 m × 1.5 m): one panel per row; grid panels go two abreast.
        columns = 1 if domain == "continuous" else min(2, len(chosen))
        rows = math.ceil(len(chosen) / columns)
        size = (11, 2.4 * rows + 0.5) if domain == "continuous" else (6.5 * columns, 3.8 * rows + 0.5)
        figure = Figure(figsize=size, layout="constrained")  # makes room for each panel's legend below it
        axes = figure.subplots(rows, columns, squeeze=False).ravel()
        for ax, (condition, replay_) in zip(axes, chosen):
            draw_trajectories(ax, replay_, condition)
        for ax in axes[len(chosen) :]:
            ax.set_visible(False)
        figure.suptitle(f"{title}, {domain}")
        path = figures_dir / f"fig10_trajectories_{domain}.png"
        _save(figure, path)
        figures.append(path)
        log.info("drew %s", path.name)
        md += [f"![{title}, {domain}](figures/{path.name})", ""]
    for condition, replay_ in replays:
        check = "match" if replay_.matches_summary else "DIFFER from"
        md.append(
            f"- {condition.ident}: seed {replay_.run.seed} (`{_shown(replay_.run.path, figures_dir.parent)}`): "
            f"replayed success and collision rates {check} its `{SUMMARY}`"
        )
    md += [f"- {p}" for p in problems]
    return md + [""]


def _shown(path: Path, out: Path) -> str:
    """``path`` relative to the report folder when that is shorter, so a moved report still reads well."""
    relative = os.path.relpath(path.resolve(), out.resolve())
    return relative if len(relative) < len(str(path)) else str(path)


def _family_sections(
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    numbers: NumberLog,
    curves_rows: list[dict[str, Any]],
) -> list[str]:
    md = [
        "## Learning curves and final values by family",
        "",
        "A family is a sweep folder (or the parent folder of runs outside a sweep).",
        "",
    ]
    families = sorted({family for condition in conditions for family in condition.families})
    for family in families:
        members = [c for c in conditions if family in c.families]
        md += [f"### {family}", ""]
        figure = Figure(figsize=(13, 4.8))
        axes = figure.subplots(1, len(CURVE_METRICS), squeeze=False)[0]
        within = varying_keys(members)
        labels = [f"{c.ident} {describe(c, within) or c.label}" for c in members]
        drawn = False
        for ax, metric in zip(axes, CURVE_METRICS):
            drawn |= draw_curves(ax, members, labels, metric, settings, curves_rows, f"curves_{slug(family)}")
            ax.set_title(CURVE_METRICS[metric])
        if drawn:
            handles, texts = axes[0].get_legend_handles_labels()
            figure.legend(
                handles,
                texts,
                fontsize=7,
                loc="upper center",
                bbox_to_anchor=(0.5, 0.02),
                ncol=min(4, len(texts)),
                frameon=False,
            )
            figure.suptitle(f"{family}: mean over seeds, SE shaded")
            path = figures_dir / f"curves_{slug(family)}.png"
            _save(figure, path)
            figures.append(path)
            log.info("drew %s", path.name)
            md += [f"![learning curves of {family}](figures/{path.name})", ""]
        else:
            md += ["_No learning curve: these runs did not evaluate during training (eval_every=0)._", ""]
        final_rows = []
        for condition in members:
            agents = condition.agents()
            for metric in CURVE_METRICS:
                for (agent, name), final in zip(
                    agents, finals(condition, [a for a, _ in agents], metric, settings)
                ):
                    final_rows.append((condition, name, final))
                    numbers.add_final(f"family:{family}", condition, final)
            for final in finals(condition, ["team"], "success_rate", settings):
                final_rows.append((condition, "team", final))
                numbers.add_final(f"family:{family}", condition, final)
        md += ["Final values (`summary.json`):", ""] + final_table(final_rows, settings.confidence) + [""]
    return md


def _statistics_section(settings: Settings) -> list[str]:
    level = f"{settings.confidence:.0%}"
    return [
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
            f"- {level} CI: percentile interval of the IQM under the stratified bootstrap (rliable's method), "
            f"{settings.n_resamples} resamples, seed {settings.seed}, computed with `scipy.stats.bootstrap`."
        ),
        (
            "- With 1 seed there is no SE and no CI (shown as – / 'no CI'); with 2 seeds the CI is marked coarse "
            "(a bootstrap of two values can take only three values). The paper used 3 seeds."
        ),
        "",
    ]
