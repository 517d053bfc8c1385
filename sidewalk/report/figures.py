"""Figures: learning curves (mean over seeds, SE shaded), the paper's Fig. 5 to 8 (one panel per group of
conditions), Fig. 10's trajectories and each family's curves and cumulative training cost; each section draws its
figure into ``figures/``, logs its numbers and returns its ``report.md`` lines."""

from __future__ import annotations

import logging
import math
import re
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from sidewalk.envs.base import OUTCOME_WORDS, crashed
from sidewalk.report.checkpoints import Replay, replay, representative_run
from sidewalk.report.conditions import (
    DOMAIN_ORDER,
    PAPER_FIGURES,
    Condition,
    PaperFigure,
    describe,
    figure_panels,
    panel_titles,
    varying_keys,
)
from sidewalk.report.runs import POLICY_FILES, shown_path
from sidewalk.report.tables import (
    CUMULATIVE_COST,
    NOT_RECORDED,
    NumberLog,
    Settings,
    column_curve,
    curve,
    final_of,
    final_table,
    finals,
    learner_agent,
    recorded,
    records_safety,
    safety_finals,
    safety_table,
    social_finals,
    social_table,
)
from sidewalk.run_folder import SUMMARY, UnsafeFile

log = logging.getLogger(__name__)


CURVE_METRICS = {"success_rate": "success rate", "collision_rate": "collision rate"}
# Whole-team coordination metrics of summary.json (sidewalk.evaluate), beside team success: in the scenarios other than
# the sidewalk both; in the sidewalk the standoff rate (the greedy pair's failure, issue "Who yields, learned") where
# the runs record it.
SCENARIO_METRICS = ("makespan", "deadlock_rate")
SOCIAL_NOTE = (
    "How the passes felt: the social measures of the final evaluation (`sidewalk.social`, defined in the "
    "evaluation guide's \"Social measures of a pass\"), each seed's value over its episodes; mean ± SE and the "
    "IQM's interval over seeds, and how many distinct episodes each seed's value rests on."
)
SAFETY_NOTE = (
    "Safety, as Safety Gym reports it (Ray, Achiam & Amodei 2019): the learner's final return and final episode "
    "cost (the last evaluation) and its cost rate over all of training (the cost it paid per frame collected); "
    f"mean ± SE over seeds, each one's IQM and CI in the table above; {NOT_RECORDED}: not recorded by these runs."
)
COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f")


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
            _plot_mean_se(
                ax,
                data,
                colour if rank == 0 else _lighter(colour, 0.45),
                f"{label}: {agent_name}",
                dashed=rank != 0,
            )
            _record(curves_out, data, figure_name, condition, agent, metric, settings)
    ax.set_xlabel(settings.x)
    ax.set_ylabel(CURVE_METRICS.get(metric, metric))
    ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    return drawn


def draw_cost_curves(
    ax,
    conditions: Sequence[Condition],
    labels: Sequence[str],
    settings: Settings,
    curves_out: list[dict[str, Any]],
    figure_name: str,
) -> bool:
    """Mean ± SE over seeds of the cost the learner's agents paid during training, summed since its start
    (``train/cumulative_cost``), one line per condition in the hue ``draw_curves`` gives it; conditions whose runs
    predate the column are left out. Appends the plotted points to ``curves_out``; returns whether anything was
    drawn."""
    drawn = False
    for index, (condition, label) in enumerate(zip(conditions, labels)):
        data = column_curve(condition, CUMULATIVE_COST, settings.x)
        if data.empty:
            continue
        drawn = True
        agent, agent_name = learner_agent(condition)
        _plot_mean_se(ax, data, COLOURS[index % len(COLOURS)], f"{label}: {agent_name}")
        _record(curves_out, data, figure_name, condition, agent, "cumulative_cost", settings)
    ax.set_xlabel(settings.x)
    ax.set_ylabel("learner's cumulative cost (collisions)")
    # A little below zero, so that a learner that never collided (a shielded one) draws a visible line.
    ax.set_ylim(bottom=-0.03 * max(ax.get_ylim()[1], 1.0))
    ax.grid(alpha=0.3)
    return drawn


def _plot_mean_se(ax, data, colour, label: str, dashed: bool = False) -> None:
    x, mean, se = data["x"].to_numpy(float), data["mean"].to_numpy(float), data["se"].to_numpy(float)
    ax.plot(
        x,
        mean,
        color=colour,
        linestyle="--" if dashed else "-",
        linewidth=1.4 if dashed else 1.8,
        label=label,
    )
    band = np.isfinite(se)
    if band.any():
        ax.fill_between(
            x,
            mean - np.where(band, se, 0),
            mean + np.where(band, se, 0),
            where=band,
            color=colour,
            alpha=0.2,
            linewidth=0,
        )


def _record(
    curves_out: list[dict[str, Any]],
    data,
    figure_name: str,
    condition: Condition,
    agent: str,
    metric: str,
    settings: Settings,
) -> None:
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


def _save(figure: Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110, bbox_inches="tight")


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "runs"


# ---- trajectories (Fig. 10) -------------------------------------------------------------------------------------


# Fig. 10's layout by the world's length / width: (at least, panels per row, panel width in inches). A long thin
# world (10 m × 1.5 m) needs a whole row; the 15 × 7 grid fits two abreast, the squarish 4 m × 3 m sidewalk three.
TRAJECTORY_COLUMNS = ((4.0, 1, 11.0), (1.8, 2, 6.5), (0.0, 3, 4.8))
TITLE_POINTS = 8  # a panel's title size
# Characters of a title line per inch of panel: DejaVu Sans averages about 0.55 em a character; 0.65 leaves the
# space between panels free, so a title wrapped to its panel does not run into its neighbour's.
TITLE_CHARS_PER_INCH = 72 / (0.65 * TITLE_POINTS)


def world_aspect(replay_: Replay) -> float:
    """The replayed world's length over its width as drawn: columns over rows of a grid, metres of a plane."""
    layout = replay_.layout
    if replay_.domain == "discrete":
        return layout.cols / layout.rows
    return layout.length_m / layout.width_m


def trajectory_columns(aspect: float) -> tuple[int, float]:
    """Panels per row and each panel's width in inches for worlds ``aspect`` times as long as they are wide."""
    return next((columns, width_in) for least, columns, width_in in TRAJECTORY_COLUMNS if aspect >= least)


def _outcome(record, world: int, agent: int) -> str:
    return next((words for key, words in OUTCOME_WORDS.items() if record.info[key][world, agent]), "running")


def draw_trajectories(ax, replay_: Replay, condition: Condition, panel_width_in: float = 6.5) -> None:
    """The sidewalk outline with each agent's path in the replayed episodes (agent colours as in ``render``), under
    a title wrapped to the panel's width."""
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
    crashes = crashed(record.info)
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
            if crashes[episode, agent]:
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
        # No-break spaces: a wrapped title keeps "3× hit a wall" on one line.
        counted = (f"{n}× {text}".replace(" ", "\u00a0") for text, n in counts.items())
        tallies.append(f"{agent_names[agent].split(' (')[0]}: " + ", ".join(counted))
    width = int(panel_width_in * TITLE_CHARS_PER_INCH)
    lines = [f"{condition.ident} {condition.label} (seed {replay_.run.seed})",
             f"{episodes} episode(s): " + "; ".join(tallies)]
    ax.set_title("\n".join(textwrap.fill(line, width) for line in lines), fontsize=TITLE_POINTS)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=paths.shape[2], frameon=False)
    ax.set_axis_off()  # the outline is the frame


# ---- sections of report.md --------------------------------------------------------------------------------------


def paper_figure_section(
    spec: PaperFigure,
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    numbers: NumberLog,
    curves_rows: list[dict[str, Any]],
    notes: list[str],
) -> list[str]:
    """``report.md`` lines of one paper figure (``spec``): the figure, one panel per group of conditions, drawn into
    ``figures_dir`` and appended to ``figures``, then its final-value table; its numbers go to ``numbers`` and its
    plotted points to ``curves_rows``. Without the runs it needs, a line saying so, and a note in ``notes``."""
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


def trajectory_section(
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    notes: list[str],
) -> list[str]:
    """``report.md`` lines of Fig. 10: a representative run of each condition (the paper's comparisons first, at
    most ``settings.max_trajectory_panels``) replayed from its checkpoint, one figure per domain drawn into
    ``figures_dir`` and appended to ``figures``, and whether each replay gave its ``summary.json`` back. Runs that
    could not be replayed are listed; with none replayed, or trajectories off, a note goes to ``notes``."""
    title = "Fig. 10: representative trajectories"
    md = [f"### {title}", ""]
    if settings.trajectory_episodes == 0 or settings.max_trajectory_panels == 0:
        notes.append(f"{title} skipped: trajectories switched off")
        return md + ["_Skipped: switched off (--trajectories 0)._", ""]
    replays, problems = _replay_representatives(_paper_comparisons_first(conditions), settings)
    if not replays:
        note = f"{title} skipped: no run with a loadable {POLICY_FILES}" + (
            f" ({'; '.join(problems)})" if problems else ""
        )
        notes.append(note)
        return (
            md
            + [f"_Skipped: no run with a loadable {POLICY_FILES}._", ""]
            + [f"- {p}" for p in problems]
            + [""]
        )
    md += [
        (
            "Each panel replays one run (of the seeds whose policy is kept, the one with the median final success) "
            "with its checkpoint, on the same worlds and seed as its final evaluation, and draws its first episodes "
            "(○ start, ★ goal, ✕ collision)."
        ),
        "",
    ]
    for domain in DOMAIN_ORDER:
        chosen = [(c, r) for c, r in replays if r.domain == domain]
        if chosen:
            md += _trajectory_figure(f"{title}, {domain}", domain, chosen, figures_dir, figures)
    for condition, replay_ in replays:
        check = "match" if replay_.matches_summary else "DIFFER from"
        md.append(
            f"- {condition.ident}: seed {replay_.run.seed} (`{shown_path(replay_.run.path, figures_dir.parent)}`): "
            f"replayed success and collision rates {check} its `{SUMMARY}`"
        )
    md += [f"- {p}" for p in problems]
    return md + [""]


def _paper_comparisons_first(conditions: Sequence[Condition]) -> list[Condition]:
    """``conditions`` with those of the paper's opponent and reward comparisons first, from which it draws Fig. 10."""
    ordered: list[Condition] = []
    for spec in (PAPER_FIGURES[0], PAPER_FIGURES[3], PAPER_FIGURES[1]):
        for group in figure_panels(spec, conditions):
            ordered += [c for c in group if c not in ordered]
    return ordered + [c for c in conditions if c not in ordered]


def _replay_representatives(
    ordered: Sequence[Condition], settings: Settings
) -> tuple[list[tuple[Condition, Replay]], list[str]]:
    """The replays of the first ``settings.max_trajectory_panels`` conditions whose representative run replays, and
    why each run before them could not."""
    replays: list[tuple[Condition, Replay]] = []
    problems: list[str] = []
    for condition in ordered:
        if len(replays) == settings.max_trajectory_panels:
            break
        run = representative_run(condition)
        if run is None:
            problems.append(f"{condition.ident}: no {POLICY_FILES}")
            continue
        try:
            log.info("replaying %s (%s, seed %d)", condition.ident, condition.label, run.seed)
            replays.append((condition, replay(run, settings.trajectory_episodes)))
        except UnsafeFile:
            raise  # a file that would run code is refused outright, not skipped like a stale checkpoint
        except Exception as error:  # noqa: BLE001 (a checkpoint of another code version must not sink the report)
            problems.append(
                f"{condition.ident}: could not replay {run.path}: {type(error).__name__}: {error}"
            )
            log.warning("could not replay %s: %s", run.path, error)
    return replays, problems


def trajectory_figure(title: str, chosen: Sequence[tuple[Condition, Replay]]) -> Figure:
    """One domain's replays, a panel each, their titles wrapped to their panels."""
    # The longest, thinnest world drawn sets the grid, so that every world in the figure stays legible.
    aspect = max(world_aspect(replay_) for _, replay_ in chosen)
    columns, panel_width_in = trajectory_columns(aspect)
    columns = min(columns, len(chosen))
    rows = math.ceil(len(chosen) / columns)
    # Each panel: the world at its aspect ratio, plus room for a title of up to four lines and the legend below.
    size = (panel_width_in * columns, (panel_width_in / aspect + 1.1) * rows + 0.5)
    figure = Figure(figsize=size, layout="constrained")  # makes room for each panel's title and legend
    axes = figure.subplots(rows, columns, squeeze=False).ravel()
    for ax, (condition, replay_) in zip(axes, chosen):
        draw_trajectories(ax, replay_, condition, panel_width_in)
    for ax in axes[len(chosen) :]:
        ax.set_visible(False)
    figure.suptitle(title)
    return figure


def _trajectory_figure(
    title: str, domain: str, chosen: Sequence[tuple[Condition, Replay]], figures_dir: Path, figures: list[Path]
) -> list[str]:
    """The figure of one domain's replays drawn into ``figures_dir`` and appended to ``figures``."""
    figure = trajectory_figure(title, chosen)
    path = figures_dir / f"fig10_trajectories_{domain}.png"
    _save(figure, path)
    figures.append(path)
    log.info("drew %s", path.name)
    return [f"![{title}](figures/{path.name})", ""]


def family_sections(
    conditions: Sequence[Condition],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    numbers: NumberLog,
    curves_rows: list[dict[str, Any]],
) -> list[str]:
    """``report.md`` lines of each family (sweep folder): its conditions' learning curves and cumulative training
    cost, drawn into ``figures_dir`` and appended to ``figures``, their final values and, for runs with the safety
    accounting, Safety Gym's triple; numbers go to ``numbers`` and plotted points to ``curves_rows``."""
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
        within = varying_keys(members)
        if len({c.algo for c in members}) > 1:  # each learner has settings of its own; its name (in the label) says which
            within = [key for key in within if not key.startswith("algo.")]
        labels = [f"{c.ident} {describe(c, within) or c.label}" for c in members]
        md += _curves_figure(family, members, labels, settings, figures_dir, figures, curves_rows)
        md += _cost_figure(family, members, labels, settings, figures_dir, figures, curves_rows)
        md += _family_finals(family, members, settings, numbers)
    return md


def _curves_figure(
    family: str,
    members: Sequence[Condition],
    labels: Sequence[str],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    curves_rows: list[dict[str, Any]],
) -> list[str]:
    """``report.md`` lines of ``family``'s learning curves figure, drawn into ``figures_dir``; a line saying why
    there is none where no run evaluated during training."""
    figure = Figure(figsize=(13, 4.8))
    axes = figure.subplots(1, len(CURVE_METRICS), squeeze=False)[0]
    drawn = False
    for ax, metric in zip(axes, CURVE_METRICS):
        drawn |= draw_curves(ax, members, labels, metric, settings, curves_rows, f"curves_{slug(family)}")
        ax.set_title(CURVE_METRICS[metric])
    if not drawn:
        return ["_No learning curve: these runs did not evaluate during training (eval_every=0)._", ""]
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
    return [f"![learning curves of {family}](figures/{path.name})", ""]


def _family_finals(family: str, members: Sequence[Condition], settings: Settings, numbers: NumberLog) -> list[str]:
    """``report.md`` lines of ``family``'s final values and, where some runs record costs, its safety table; the
    numbers go to ``numbers``."""
    # Where some runs record costs, every condition gets a safety row: one without says so rather than vanishing.
    family_safety = any(records_safety(condition) for condition in members)
    safety_rows = []
    final_rows = []
    social_rows = []
    for condition in members:
        agents = condition.agents()
        for metric in CURVE_METRICS:
            for (agent, name), final in zip(
                agents, finals(condition, [a for a, _ in agents], metric, settings)
            ):
                final_rows.append((condition, name, final))
                numbers.add_final(f"family:{family}", condition, final)
        team = finals(condition, ["team"], "success_rate", settings)
        if condition.flat.get("env.layout", "sidewalk") != "sidewalk":
            team += [final_of(condition, "team", key, key, settings) for key in SCENARIO_METRICS]
        elif recorded(deadlock := final_of(condition, "team", "deadlock_rate", "deadlock_rate", settings)):
            team.append(deadlock)
        social = social_finals(condition, settings)
        if social:
            social_rows.append((condition, social))
        final_rows += [(condition, "team", final) for final in team]
        for final in team + social:
            numbers.add_final(f"family:{family}", condition, final)
        if family_safety:
            by_metric = safety_finals(condition, settings)
            learner_name = learner_agent(condition)[1]
            safety_rows.append((condition, learner_name, by_metric))
            for metric, final in by_metric.items():
                if recorded(final):
                    numbers.add_final(f"safety:{family}", condition, final)
                    if metric != "success_rate":  # the learner's success has its rows above
                        final_rows.append((condition, learner_name, final))
    md = ["Final values (`summary.json`):", ""] + final_table(final_rows, settings.confidence) + [""]
    if safety_rows:
        md += [SAFETY_NOTE, ""] + safety_table(safety_rows) + [""]
    if social_rows:
        md += [SOCIAL_NOTE, ""] + social_table(social_rows, settings.confidence) + [""]
    return md


def _cost_figure(
    family: str,
    members: Sequence[Condition],
    labels: Sequence[str],
    settings: Settings,
    figures_dir: Path,
    figures: list[Path],
    curves_rows: list[dict[str, Any]],
) -> list[str]:
    """``report.md`` lines of ``family``'s cumulative training cost figure, drawn into ``figures_dir``; none where
    no run logs ``train/cumulative_cost`` (runs written before the safety accounting)."""
    name = f"cost_{slug(family)}"
    figure = Figure(figsize=(7.5, 4.8))
    ax = figure.subplots()
    if not draw_cost_curves(ax, members, labels, settings, curves_rows, name):
        return []
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, frameon=False)
    ax.set_title(
        f"{family}: the learner's collisions (cost) during training\n"
        "cumulative since the start, mean over seeds, SE shaded"
    )
    path = figures_dir / f"{name}.png"
    _save(figure, path)
    figures.append(path)
    log.info("drew %s", path.name)
    return [f"![cumulative training cost of {family}](figures/{path.name})", ""]
