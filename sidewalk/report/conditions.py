"""Conditions: runs of one config but for the seed, grouped, sorted and labelled by what sets them apart; and the
paper's figures as groups of conditions (the panels), which the figures draw and the claims read."""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sidewalk.later_keys import with_later_keys
from sidewalk.report.runs import Run
from sidewalk.run_folder import SUMMARY

# Keys that change neither what a run learns nor what it measures, so they never split runs into conditions
# (a resumed run's config says resume=true; a run logged to TensorBoard is the same experiment as one logged to CSV).
# A learner's defaults of the run's length, evaluations and worlds are not what the run did: `iterations`,
# `eval_every` and `num_envs` are (a run made before DQN's default went from 300 to 400 iterations, at iterations=200,
# is today's run at iterations=200).
BOOKKEEPING_KEYS = ("seed", "resume", "device", "torch_threads", "checkpoint_every", "logger", "plots",
                    "algo.default_iterations", "algo.default_eval_every", "algo.default_num_envs")
OPPONENT_ORDER = ("random", "dijkstra", "prm", "centralized")
DOMAIN_ORDER = ("discrete", "continuous")
def _is_bookkeeping(key: str) -> bool:
    return any(key == k or key.startswith(f"{k}.") for k in BOOKKEEPING_KEYS)


def condition_config(flat: dict[str, Any]) -> dict[str, Any]:
    """A run's flat config as its condition: without bookkeeping keys, with ``with_later_keys``'s defaults (runs whose
    condition configs are equal are seeds of one condition)."""
    return with_later_keys({k: v for k, v in flat.items() if not _is_bookkeeping(k)})


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
        bool(flat.get("shield", False)),
        condition.key,
    )


def group_conditions(runs: Sequence[Run]) -> list[Condition]:
    """Group runs by their config without seed and bookkeeping keys (a later key that a run's config lacks taking
    its value there, ``sidewalk.later_keys``); one run per seed (a repeated seed, e.g. the same condition run by two presets,
    keeps the newest run and notes the others). Conditions are sorted (domain, algorithm, opponent, noise, reward,
    shield) and numbered C1, C2, ..."""
    grouped: dict[str, Condition] = {}
    for run in runs:
        flat = condition_config(run.flat)
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
    if key == "shield":
        return "shielded" if value else "unshielded"
    if key == "other_play":
        return "Other-Play" if value else "self-play"
    if key == "role_frame":
        return "role frame" if value else "world frame"
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
    """``condition`` told by its values of ``keys`` (opponent first, then shield, noise, reward, the rest), at most
    ``limit`` of them and then how many more; keys the condition does not have are left out."""
    order = ["opponent.name", "other_play", "role_frame", "shield", "reward.shaped_agents", "noise", "reward.name", "reward.alpha"]
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


def peer_keys(condition: Condition, conditions: Sequence[Condition]) -> list[str]:
    """The keys that set ``condition`` apart from the others of its domain, algorithm and opponent (other
    domains, algorithms and opponents have other keys altogether)."""
    peers = [
        c
        for c in conditions
        if (c.domain, c.algo, c.opponent) == (condition.domain, condition.algo, condition.opponent)
    ]
    return varying_keys(peers, ignore=("env.domain", "algo.name", "opponent.name"))


def label(condition: Condition, conditions: Sequence[Condition]) -> str:
    """``condition``'s domain, algorithm and opponent, plus what sets it apart from its peers among ``conditions``."""
    head = f"{condition.domain}: {condition.algo.upper()}" + (
        " centralized" if condition.opponent == "centralized" else f" vs {condition.opponent}"
    )
    rest = describe(condition, peer_keys(condition, conditions))
    return f"{head}, {rest}" if rest else head


def _label(conditions: Sequence[Condition]) -> None:
    for condition in conditions:
        condition.label = label(condition, conditions)


# ---- the paper's figures ----------------------------------------------------------------------------------------


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
    profile: bool = False  # it compares learners: the report draws a performance profile of their final metric


PAPER_FIGURES = (
    PaperFigure(
        "fig5_success_by_opponent",
        "Fig. 5: success by opponent",
        "success_rate",
        ("opponent.", "reward.shaped_agents"),
        "opponent.name",
        "runs of one setting against ≥ 2 opponents (+experiment=fig5_discrete / fig5_continuous)",
        profile=True,
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


@dataclass
class ComparedSetting:
    """The conditions at one rank of every panel of a figure (one per panel, in the panels' order), compared as one
    setting across the panels: Fig. 5's learner against the planner is dijkstra in the grid and prm in the plane."""

    label: str  # the values it pools, as the panels' legends tell them: "dijkstra / prm"
    conditions: list[Condition]

    @property
    def ident(self) -> str:
        return "+".join(condition.ident for condition in self.conditions)


def _ranked(spec: PaperFigure, panel: Sequence[Condition]) -> dict[tuple[int, int], Condition]:
    """``panel``'s conditions by (rank of their ``spec.primary`` value in the panel's order, rank among the
    conditions sharing that value): a second condition at one value (another reward shaping, say) gets its own
    rank rather than shifting every value after it."""
    values: list[str] = []
    ranked: dict[tuple[int, int], Condition] = {}
    for condition in panel:
        value = json.dumps(condition.flat.get(spec.primary), default=str)
        if value not in values:
            values.append(value)
        rank = values.index(value)
        ranked[(rank, sum(1 for r, _ in ranked if r == rank))] = condition
    return ranked


def _ends_only(by_rank: dict[tuple[int, int], Condition]) -> dict[tuple[int, int], Condition]:
    """``_ranked``'s conditions with the first value at rank 0, the last at rank 1 and the middle ones at ranks past
    any other panel's (so they match nothing and are left out)."""
    last = max(rank for rank, _ in by_rank)
    return {
        ((0 if rank == 0 else 1 if rank == last else 1_000 + rank), sub): condition
        for (rank, sub), condition in by_rank.items()
    }


def _setting_text(spec: PaperFigure, panel: Sequence[Condition], condition: Condition) -> str:
    """``condition``'s setting in ``panel``: its values of the keys that follow ``spec.primary`` across the panel
    ("prm", "explicit reward"), or its whole legend text where another condition of the panel shares its value
    ("prm, shaped [0]")."""

    def value(c: Condition, key: str) -> str:
        return json.dumps(c.flat.get(key, "<absent>"), default=str)

    varying = varying_keys(panel)
    if sum(value(c, spec.primary) == value(condition, spec.primary) for c in panel) > 1:
        return describe(condition, varying)
    # A key follows the primary one where conditions of equal primary value have equal values of it.
    following = [
        key
        for key in varying
        if len({(value(c, spec.primary), value(c, key)) for c in panel})
        == len({value(c, spec.primary) for c in panel})
    ]
    return describe(condition, following)


def compared_settings(
    spec: PaperFigure, panels: Sequence[Sequence[Condition]]
) -> tuple[list[ComparedSetting], list[Condition]]:
    """The settings ``spec``'s panels compare, matched across panels by rank (panels sort their conditions alike:
    random, planner, centralized; lowest noise first; explicit before implicit), each labelled by the values it
    pools; and the conditions left out because some panel has nothing at their rank.

    Where panels compare different numbers of values (three noise levels in one, two in another), a middle rank
    means different things in each: only the first and the last value of every panel are matched (lowest with
    lowest, highest with highest), and the middle ones are left out."""
    ranked = [_ranked(spec, panel) for panel in panels]
    counts = {1 + max(rank for rank, _ in by_rank) for by_rank in ranked if by_rank}
    if len(counts) > 1:
        ranked = [_ends_only(by_rank) for by_rank in ranked]
    shared = sorted(set.intersection(*(set(r) for r in ranked))) if ranked else []
    settings = []
    for rank in shared:
        members = [by_rank[rank] for by_rank in ranked]
        labels: list[str] = []
        for panel, condition in zip(panels, members):
            label = _setting_text(spec, panel, condition)
            if label not in labels:
                labels.append(label)
        settings.append(ComparedSetting(" / ".join(labels), members))
    left_out = [c for by_rank in ranked for rank, c in sorted(by_rank.items()) if rank not in shared]
    return settings, left_out
