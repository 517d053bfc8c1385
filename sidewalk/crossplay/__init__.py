"""Cross-play: every learned policy (a row) playing with every partner (a column) on the same seeded worlds.

``crossplay(rows, partners, ...)`` evaluates each pairing and returns the long table (one row per pairing) that
``runners/crossplay.py`` writes as ``crossplay.csv`` and ``sidewalk.report.crossplay`` draws; the coordination
literature's zero-shot test (Other-Play): does a policy still succeed with a partner it never trained with?

The pairing:

- a row is a run folder (its ``policy.pt``, or the ``checkpoint.pt`` of a run from before ``policy.pt``); it plays the agent it trained as: its ego for a single-agent
  learner, agent 0 for a centralized or self-play learner (both were trained as every agent);
- a column is a scripted opponent of the domain (``random``, ``dijkstra``/``prm``) or a learned partner (a run
  folder, ``sidewalk.partners.policy.PolicyOpponent``); it plays every other agent. By default the columns are
  the domain's scripted opponents and every row, so the matrix holds each run with itself (self-pairs), with the
  other seeds of its condition (cross-seed pairs) and with the other conditions. ``heldout`` adds the domain's
  held-out partner population (``sidewalk.partners.population``), whose team success per condition is the ad-hoc
  score (``sidewalk.report.crossplay.adhoc_table``): partners no learner met in training;
- both sides act greedily (the evaluation policy: greedy Q, the distribution's mode), as in the runs' own
  evaluations;
- every cell plays one episode in each of ``episodes`` worlds of the core env seeded ``seed + EVAL_SEED_OFFSET``
  (the stream a run of seed ``seed`` is evaluated on, so a run paired with its own training opponent, at the same
  seed, episodes and noise, reproduces its ``summary.json``); the world is the first row's training world (its
  domain, scenario, rewards and time limit) at the noise given, by default the rows' training noise when they all
  agree; with ``nominal``, from the scenario's own starts and goals (the paper's evaluation, ``eval=nominal``) even for
  rows trained under ``eval=perturbed``.

Checks before any evaluation: every row and learned partner has a ``policy.pt`` and shares the first row's domain,
scenario and observation (``check_partner``; noise, rewards, time limit may differ), every partner name is a
scripted opponent of that domain. A learned partner that cannot play the other agent's role (a single-agent
learner in a layout without the half-turn symmetry that maps its role onto the other's) leaves that cell empty
with the reason in the ``skipped`` column rather than stopping the matrix.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from sidewalk.crossplay.arena import METRICS, Arena
from sidewalk.crossplay.conventions import CONVENTION_COLUMNS
from sidewalk.crossplay.pairings import (
    cell_problem,
    check_players,
    check_scripted_settings,
    evaluation_world,
    met_in_training,
    n_agents,
)
from sidewalk.crossplay.players import (
    HELDOUT,
    Column,
    CrossplayError,
    Player,
    find_runs,
    label_players,
    load_player,
    resolve_partners,
)
from sidewalk.experiment import EVAL_SEED_OFFSET

COLUMNS = (
    "row_run",
    "row_label",
    "row_seed",
    "row_agent",
    "partner",
    "partner_label",
    "partner_kind",
    "partner_seed",
    "self_pair",
    "same_condition",
    "success",
    "partner_success",
    "collision_rate",
    "partner_collision_rate",
    "team_success",
    "deadlock_rate",
    "return",
    "path_efficiency",
    "partner_path_efficiency",
    "episodes",
    "distinct_episodes",
    "skipped",
    "heldout",
    "met_in_training",
)


def crossplay(
    rows: Sequence[Player],
    columns: Sequence[Column],
    world: Any,
    episodes: int = 256,
    seed: int = 0,
    device: str = "cpu",
    progress: Callable[[int], Any] | None = None,
) -> pd.DataFrame:
    """The long table of the matrix (``COLUMNS``, one row per (row, column), rows in order, then columns):

    ``row_run``/``partner`` the run folders as given (a scripted partner by name), ``*_label`` their conditions'
    labels, ``*_seed`` their seeds, ``row_agent`` the agent the row played, ``partner_kind`` scripted/learned,
    ``self_pair`` (a run with itself), ``same_condition`` (two seeds of one condition, or a self-pair);
    ``success``/``collision_rate``/``return``/``path_efficiency`` of the row's agent,
    ``partner_success``/``partner_collision_rate``/``partner_path_efficiency`` over the partner's agents,
    ``team_success`` (every agent arrived), ``episodes``; ``skipped`` the reason a cell was not played (its metrics
    empty). ``progress(1)`` is called after each cell.

    Call ``check_players`` first (``run_crossplay`` does).
    """
    records = []
    arena = Arena(rows[0].partner.world.domain, world, episodes, seed, device) if rows else None
    for row in rows:
        for column in columns:
            partner = column.player
            record = {
                "row_run": str(row.path),
                "row_label": row.label,
                "row_seed": row.seed,
                "row_agent": row.agent,
                "partner": column.name,
                "partner_label": column.label,
                "partner_kind": column.kind,
                "partner_seed": None if partner is None else partner.seed,
                "self_pair": partner is not None and partner.path.resolve() == row.path.resolve(),
                "same_condition": partner is not None and partner.condition == row.condition,
                "skipped": cell_problem(row, column, world),
                "heldout": column.heldout,
                "met_in_training": met_in_training(row, column),
            }
            if not record["skipped"]:
                metrics = arena.evaluate(row, column)
                record.update({name: metrics[key] for name, key in METRICS.items()})
            records.append(record)
            if progress is not None:
                progress(1)
    frame = pd.DataFrame(records, columns=list(COLUMNS))
    for column in ("episodes", "distinct_episodes"):
        frame[column] = frame[column].astype("Int64")
    for column in ("row_seed", "partner_seed"):
        frame[column] = frame[column].astype("Int64")
    return frame


@dataclass
class Matrix:
    """A cross-play matrix evaluated: its table, how it was made (``crossplay.json``) and the convention each row's
    policy follows with itself (``CONVENTION_COLUMNS``, ``conventions.csv``)."""

    frame: pd.DataFrame
    meta: dict[str, Any]
    conventions: pd.DataFrame | None = None


def run_crossplay(
    run_paths: Sequence[str | Path],
    partners: str | Sequence[str] | None = None,
    episodes: int = 256,
    seed: int = 0,
    noise: float | None = None,
    device: str = "cpu",
    show_progress: bool = True,
    nominal: bool = False,
) -> Matrix:
    """Resolve the rows (``find_runs``) and partners (``resolve_partners``), check every pairing can be played
    (``check_players``) and evaluate the matrix (``crossplay``), with a tqdm bar over the cells."""
    from tqdm import tqdm

    if episodes < 1:
        raise CrossplayError(f"episodes={episodes} must be at least 1")
    rows = [load_player(path) for path in find_runs(run_paths)]
    if not rows:
        raise CrossplayError("give at least one run folder (a row)")
    domain = rows[0].partner.world.domain
    columns = resolve_partners(partners, rows, domain)
    world = evaluation_world(rows, noise, nominal)
    if any(column.heldout for column in columns) and (world.layout != "sidewalk" or n_agents(domain, world) != 2):
        raise CrossplayError(
            f"--partners {HELDOUT} holds the two-agent sidewalk's partners; the rows play env.layout={world.layout!r} "
            f"with {n_agents(domain, world)} agents"
        )
    learned = list(rows) + [c.player for c in columns if c.player is not None and all(c.player is not r for r in rows)]
    label_players(learned)
    check_players(learned, world, rows[0])
    check_scripted_settings(columns, domain, world)
    with tqdm(total=len(rows) * len(columns), desc="cross-play", unit="cell", disable=not show_progress) as bar:
        frame = crossplay(rows, columns, world, episodes, seed, device, progress=bar.update)
    arena = Arena(domain, world, episodes, seed, device)
    conventions = pd.DataFrame(
        [{"row_run": str(row.path), "row_label": row.label, "row_seed": row.seed, **arena.convention(row)} for row in rows],
        columns=list(CONVENTION_COLUMNS),
    )
    meta = {
        "domain": domain,
        "layout": world.layout,
        "noise": world.noise,
        # The starts, goals and headings each world draws (eval=perturbed's bounds where the rows trained under it).
        "jitter": {f.name: getattr(world, f.name) for f in dataclasses.fields(world) if "jitter" in f.name},
        "episodes": episodes,
        "seed": seed,
        "world_seed": seed + EVAL_SEED_OFFSET,
        "world_of": str(rows[0].path),
        "rows": [str(row.path) for row in rows],
        "partners": [column.name for column in columns],
    }
    return Matrix(frame, meta, conventions)


def write_matrix(matrix: Matrix, out: str | Path, command: str, wall_clock_s: float) -> Path:
    """``matrix``'s CSVs and ``crossplay.json`` (with ``command``, the time, the code and package versions) written
    into ``out``, each file atomically, then its report; returns the report's path."""
    from sidewalk.report.crossplay import (
        CONVENTIONS_CSV,
        CROSSPLAY_CSV,
        CROSSPLAY_JSON,
        write_crossplay_report,
    )
    from sidewalk.run_folder import atomic_write, git_revision, package_versions

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "command": command,
        "created": datetime.datetime.now().isoformat(timespec="seconds"),
        **matrix.meta,
        "wall_clock_s": round(wall_clock_s, 1),
        "git_revision": git_revision(),
        "versions": package_versions(),
    }
    atomic_write(out / CROSSPLAY_CSV, lambda tmp: matrix.frame.to_csv(tmp, index=False))
    atomic_write(out / CONVENTIONS_CSV, lambda tmp: matrix.conventions.to_csv(tmp, index=False))
    atomic_write(out / CROSSPLAY_JSON, lambda tmp: tmp.write_text(json.dumps(meta, indent=2) + "\n"))
    return write_crossplay_report(out)
