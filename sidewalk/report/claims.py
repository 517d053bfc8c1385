"""The paper's findings (its §6.2) held against a set of runs: a verdict per claim and the numbers behind it.

Each check reads the same conditions the report's paper figures are drawn from (``figure_panels``), so a verdict
is always about the curves shown above it in ``report.md``. The verdict is one of ``VERDICTS``, decided by the
thresholds below and, where it compares two measures, by the 95 % bootstrap interval of their difference over the
seeds (``sidewalk.stats.difference_interval``); they are stated in the report next to the table, so a reader can
disagree with a threshold and still use the numbers. The learner's agent is ``ego`` against a scripted opponent and
``agent0`` when it plays both agents (in the ego views the learner is agent 0, so the two are the same walker).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from sidewalk.report.conditions import PAPER_FIGURES, Condition, figure_panels, panel_titles
from sidewalk.report.tables import NumberLog, Settings, curve, fmt, summary_values
from sidewalk.stats import (
    Interval,
    difference_interval,
    interval_estimate,
    mean_se,
    separates,
    separation_text,
)

__all__ = [
    "BOOTSTRAP",
    "CLAIMS",
    "LEARNED",
    "NEVER",
    "SAFE",
    "SETTLED",
    "STRAIGHT",
    "SUCCEEDS",
    "TIE",
    "VERDICTS",
    "Difference",
    "Stat",
    "Verdict",
    "above_zero",
    "avoids_random",
    "below_zero",
    "centralized_most_robust",
    "check_claims",
    "claims_section",
    "compare",
    "dijkstra_yields",
    "explicit_learns_better",
    "final",
    "first_evaluation",
    "frames_to_learn",
    "learner",
    "noise_lowers_success",
    "training_success",
    "unshaped_agent_steps_aside",
]

VERDICTS = ("reproduced", "partly", "not reproduced", "not run")

SUCCEEDS = 0.8  # final success rate at or above which a learned behaviour "reaches its goal"
SAFE = 0.2  # collision rate at or below which an agent "avoids" collisions
STRAIGHT = 0.9  # path efficiency at or above which an agent "heads straight"
NEVER = 0.05  # success rate at or below which an agent "never reaches its goal"
LEARNED = 0.2  # improvement over the first evaluation that counts as learning something
SETTLED = 0.9  # a curve has "learned" once it reaches this fraction of its final value
# A difference of final values whose interval excludes 0 is still a tie when it is smaller than this: with seeds
# that agree (a deterministic evaluation), any difference at all would separate.
TIE = 0.02
# Learning speed is read off the training curve (every iteration's episodes), not the evaluations (every 50): the
# learner's training success, smoothed by a rolling mean of SMOOTHING iterations (5 % of a shorter run), against its
# final training success (the mean of its last FINAL_SHARE of iterations), seed by seed.
TRAINING_SUCCESS = {"ego": "train/ego_success_rate", "agent0": "train/team_success_rate"}  # centralized: both home
SMOOTHING = 10
FINAL_SHARE = 0.1
# The claims are not given the report's Settings: they use its default confidence, resamples and seed.
BOOTSTRAP = Settings()


@dataclass(frozen=True)
class Stat:
    """A measure of a condition over its seeds: each seed's value (NaN where a seed has none), shown as mean ± SE."""

    values: tuple[float, ...]

    @classmethod
    def of(cls, values: Sequence[float] | np.ndarray) -> Stat:
        """The measure of these per-seed ``values``."""
        return cls(tuple(float(value) for value in values))

    @property
    def mean(self) -> float:
        return float(mean_se(self.values)[0])

    @property
    def se(self) -> float:
        return float(mean_se(self.values)[1])

    def __str__(self) -> str:
        return fmt(self.mean, 2) + ("" if math.isnan(self.se) else f" ± {fmt(self.se, 2)}")


@dataclass(frozen=True)
class Difference:
    """A comparison a verdict states: ``agent``'s ``metric`` in condition ``a`` minus that in ``b`` (the same
    condition for two agents: ``agent`` names both), the mean over seeds with its bootstrap interval."""

    a: Condition
    b: Condition
    agent: str
    metric: str
    interval: Interval

    def text(self, show: Callable[[float], str] = lambda rate: fmt(rate, 2), margin: float = 0.0) -> str:
        """"difference 0.20 [0.15, 0.25], separates at 95%", values shown by ``show``, "(coarse)" after the interval
        of two seeds; a separated difference smaller than ``margin`` is said to be a tie."""
        d = self.interval
        ci = "" if math.isnan(d.low) else f" [{show(d.low)}, {show(d.high)}]"
        ci += " (coarse)" if d.note.startswith("2 runs") else ""
        point = "–" if math.isnan(d.point) else show(d.point)
        tie = f" but within ±{margin:g}: a tie" if separates(d, 0.0) and abs(d.point) < margin else ""
        return f"difference {point}{ci}, {separation_text(d, 0.0, BOOTSTRAP.confidence)}{tie}"


def compare(
    a: Condition, a_stat: Stat, b: Condition, b_stat: Stat, agent: str, metric: str, *, paired: bool = False
) -> Difference:
    """``a_stat`` minus ``b_stat``: the difference of their means over seeds with the percentile interval of a
    bootstrap at ``BOOTSTRAP``'s confidence, resamples and seed; independent (each condition's seeds resampled on
    their own, ``difference_interval``) or, for two measures of the same runs, ``paired`` (the per-seed differences
    resampled)."""
    bootstrap = {"confidence": BOOTSTRAP.confidence, "n_resamples": BOOTSTRAP.n_resamples, "seed": BOOTSTRAP.seed}
    if paired:
        interval = interval_estimate(np.subtract(a_stat.values, b_stat.values), "mean", **bootstrap)
    else:
        interval = difference_interval(a_stat.values, b_stat.values, "mean", **bootstrap)
    return Difference(a, b, agent, metric, interval)


def above_zero(difference: Interval, margin: float = 0.0) -> bool:
    """Whether ``difference`` is positive: its interval lies above 0 (``stats.separates``) and its point is at least
    ``margin``. No interval (one seed) is never positive."""
    return separates(difference, 0.0) and difference.low > 0.0 and difference.point >= margin


def below_zero(difference: Interval, margin: float = 0.0) -> bool:
    """Whether ``difference`` is negative: its interval lies below 0 and its point is at most ``-margin``."""
    return separates(difference, 0.0) and difference.high < 0.0 and difference.point <= -margin


@dataclass
class Verdict:
    """One claim of the paper's §6.2 held against the runs of one figure panel."""

    verdict: str
    evidence: str
    conditions: list[Condition] = field(default_factory=list)
    numbers: list[tuple[Condition, str, str, float]] = field(
        default_factory=list
    )  # (condition, agent, metric, value)
    differences: list[Difference] = field(default_factory=list)
    claim: str = ""  # the check's docstring and the domain, set by check_claims
    figure: str = ""

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict={self.verdict!r}; valid: {', '.join(VERDICTS)}")


def learner(condition: Condition) -> str:
    return condition.agents()[0][0]


def final(condition: Condition, agent: str, metric: str) -> Stat:
    """``summary.json``'s ``<agent>/<metric>`` of each seed."""
    return Stat.of(summary_values(condition, f"{agent}/{metric}"))


def first_evaluation(condition: Condition, agent: str, metric: str) -> float:
    points = curve(condition, agent, metric, "frames")
    return float(points["mean"].iloc[0]) if len(points) else math.nan


def frames_to_learn(condition: Condition, agent: str) -> Stat:
    """Frames at which each seed's training success (``TRAINING_SUCCESS``, smoothed) first reaches ``SETTLED`` of
    its final training success (NaN for a seed that ends at 0: it has none)."""
    column = TRAINING_SUCCESS.get(agent, TRAINING_SUCCESS["agent0"])
    return Stat.of([_run_frames_to_learn(run.metrics, column) for run in condition.runs])


def _run_frames_to_learn(metrics: pd.DataFrame, column: str) -> float:
    if column not in metrics.columns or metrics[column].isna().all():
        return math.nan
    success = metrics[column]
    window = max(1, min(SMOOTHING, len(success) // 20))
    smoothed = success.rolling(window, min_periods=1).mean()
    settled = success.iloc[-max(1, round(len(success) * FINAL_SHARE)):].mean()
    if not settled > 0:
        return math.nan
    reached = metrics["frames"][smoothed >= SETTLED * settled]
    return float(reached.iloc[0]) if len(reached) else math.nan


def _frames(frames: Stat) -> str:
    if math.isnan(frames.mean):
        return "– (ends at 0)"
    return f"{frames.mean:,.0f}" + ("" if math.isnan(frames.se) else f" ± {frames.se:,.0f}")


def _count(frames: float) -> str:
    return f"{frames:,.0f}"


def training_success(condition: Condition, agent: str) -> Stat:
    """Each seed's mean training success over all of training (``TRAINING_SUCCESS``): how fast and how well it
    learned."""
    column = TRAINING_SUCCESS.get(agent, TRAINING_SUCCESS["agent0"])
    return Stat.of(
        [float(run.metrics[column].mean()) if column in run.metrics.columns else math.nan for run in condition.runs]
    )


# ---- the claims ----------------------------------------------------------------------------------------------------


def avoids_random(panel: Sequence[Condition]) -> list[Verdict]:
    """DQN learns to avoid the random agent and reach its goal"""
    out = []
    for c in panel:
        if c.domain != "discrete" or c.opponent != "random":
            continue
        success, collision = final(c, "ego", "success_rate"), final(c, "ego", "collision_rate")
        start = first_evaluation(c, "ego", "success_rate")
        if success.mean >= SUCCEEDS and collision.mean <= SAFE:
            verdict = "reproduced"
        elif success.mean - start >= LEARNED:
            verdict = "partly"
        else:
            verdict = "not reproduced"
        out.append(
            Verdict(
                verdict,
                f"ego success {success} (first evaluation {fmt(start, 2)}), ego collisions {collision}",
                [c],
                [(c, "ego", "success_rate", success.mean), (c, "ego", "collision_rate", collision.mean)],
            )
        )
    return out


def dijkstra_yields(panel: Sequence[Condition]) -> list[Verdict]:
    """against Dijkstra the DQN agent heads straight and the Dijkstra agent yields"""
    out = []
    for c in panel:
        if c.domain != "discrete" or c.opponent != "dijkstra":
            continue
        ego_success, other_success = final(c, "ego", "success_rate"), final(c, "other", "success_rate")
        ego_path, other_path = final(c, "ego", "path_efficiency"), final(c, "other", "path_efficiency")
        # The two agents of the same runs: the per-seed differences are resampled.
        detour = compare(c, other_path, c, ego_path, "other − ego", "path_efficiency", paired=True)
        straight = ego_success.mean >= SUCCEEDS and ego_path.mean >= STRAIGHT
        yields = other_success.mean >= SUCCEEDS and below_zero(detour.interval, TIE)
        verdict = (
            "reproduced" if straight and yields else "partly" if straight or yields else "not reproduced"
        )
        out.append(
            Verdict(
                verdict,
                f"ego success {ego_success}, path efficiency {ego_path}; Dijkstra success {other_success}, "
                f"path efficiency {other_path} (Dijkstra − ego: {detour.text(margin=TIE)})",
                [c],
                [
                    (c, "ego", "success_rate", ego_success.mean),
                    (c, "ego", "path_efficiency", ego_path.mean),
                    (c, "other", "success_rate", other_success.mean),
                    (c, "other", "path_efficiency", other_path.mean),
                ],
                [detour],
            )
        )
    return out


def centralized_most_robust(panel: Sequence[Condition]) -> list[Verdict]:
    """centralized learns the most robust policy but needs more training"""
    central = [c for c in panel if c.opponent == "centralized"]
    others = [c for c in panel if c.opponent != "centralized"]
    if not central or not others:
        return []
    c = central[0]
    success = final(c, "agent0", "success_rate")
    best = max(others, key=lambda o: final(o, "ego", "success_rate").mean)
    best_success = final(best, "ego", "success_rate")
    versus_best = compare(c, success, best, best_success, "agent0 − ego", "success_rate")
    # A tie at nothing learned is not robustness: the centralized learner must also have learned something.
    robust = not below_zero(versus_best.interval, TIE) and success.mean >= LEARNED
    learn = frames_to_learn(c, "agent0")
    learn_others = [frames_to_learn(o, "ego") for o in others]
    later = [compare(c, learn, o, f, "agent0 − ego", "frames_to_learn") for o, f in zip(others, learn_others)]
    learned = [d for d, f in zip(later, learn_others) if not math.isnan(f.mean)]
    slower = not math.isnan(learn.mean) and bool(learned) and all(above_zero(d.interval) for d in learned)
    verdict = "reproduced" if robust and slower else "partly" if robust or slower else "not reproduced"
    frames = "; ".join(
        f"vs {o.opponent} ({o.ident}) {_frames(f)}, {d.text(_count)}" for o, f, d in zip(others, learn_others, later)
    )
    return [
        Verdict(
            verdict,
            f"centralized agent 0 success {success} (team {final(c, 'team', 'success_rate')}) vs best ego "
            f"{best_success} ({best.opponent}), {versus_best.text(margin=TIE)}; frames to {SETTLED:.0%} of final "
            f"training success (team for the centralized learner): centralized {_frames(learn)} {frames}",
            [c, *others],
            [
                (c, "agent0", "success_rate", success.mean),
                (c, "agent0", "frames_to_learn", learn.mean),
                *((o, "ego", "frames_to_learn", f.mean) for o, f in zip(others, learn_others)),
            ],
            [versus_best, *later],
        )
    ]


def unshaped_agent_steps_aside(panel: Sequence[Condition]) -> list[Verdict]:
    """centralized with shaping on one agent: the unshaped agent gets out of the way and never reaches its goal"""
    out = []
    for c in panel:
        if c.domain != "continuous" or c.opponent != "centralized":
            continue
        if list(c.flat.get("reward.shaped_agents") or []) != [0]:
            continue
        shaped, unshaped = final(c, "agent0", "success_rate"), final(c, "agent1", "success_rate")
        unshaped_collision = final(c, "agent1", "collision_rate")
        # "Out of the way" is judged by its effect: the shaped agent gets through. An unshaped agent that crashes
        # (and so leaves the world) while the shaped one gets through is half of it.
        never, through = unshaped.mean <= NEVER, shaped.mean >= SUCCEEDS
        safely = unshaped_collision.mean <= SAFE
        verdict = (
            "reproduced"
            if never and through and safely
            else "partly"
            if never and through
            else "not reproduced"
        )
        out.append(
            Verdict(
                verdict,
                f"shaped agent 0 success {shaped}; unshaped agent 1 success {unshaped}, "
                f"collisions {unshaped_collision}",
                [c],
                [
                    (c, "agent0", "success_rate", shaped.mean),
                    (c, "agent1", "success_rate", unshaped.mean),
                    (c, "agent1", "collision_rate", unshaped_collision.mean),
                ],
            )
        )
    return out


def noise_lowers_success(panel: Sequence[Condition]) -> list[Verdict]:
    """more noise, lower success"""
    ordered = sorted(panel, key=lambda c: float(c.flat.get("noise", 0.0)))
    agent = learner(ordered[0])
    stats = [final(c, agent, "success_rate") for c in ordered]
    overall = compare(ordered[-1], stats[-1], ordered[0], stats[0], agent, "success_rate")
    # With two levels the one step between neighbours is the overall difference: stated once.
    steps = [
        compare(b, b_stat, a, a_stat, agent, "success_rate")
        for (a, a_stat), (b, b_stat) in itertools.pairwise(zip(ordered, stats))
    ] if len(ordered) > 2 else []
    steps_down = not any(above_zero(step.interval, TIE) for step in steps)
    lower = below_zero(overall.interval, TIE)
    verdict = "reproduced" if lower and steps_down else "partly" if lower else "not reproduced"
    symbol = "n" if ordered[0].domain == "discrete" else "ε"

    def level(c: Condition) -> str:
        return f"{symbol}={float(c.flat.get('noise', 0.0)):g}"

    levels = ", ".join(f"{level(c)}: {s}" for c, s in zip(ordered, stats))
    step_texts = "; ".join(f"{level(d.a)} − {level(d.b)}: {d.text(margin=TIE)}" for d in steps)
    return [
        Verdict(
            verdict,
            f"{agent} success {levels}; {level(ordered[-1])} − {level(ordered[0])}: {overall.text(margin=TIE)}"
            + (f"; between neighbouring levels: {step_texts}" if steps else ""),
            list(ordered),
            [(c, agent, "success_rate", s.mean) for c, s in zip(ordered, stats)],
            [overall, *steps],
        )
    ]


def explicit_learns_better(panel: Sequence[Condition]) -> list[Verdict]:
    """explicit cooperative reward learns better than implicit"""
    by_alpha = sorted(panel, key=lambda c: -float(c.flat.get("reward.alpha", 0.0)))
    explicit, implicit = by_alpha[0], by_alpha[-1]
    agent = learner(explicit)
    e, i = final(explicit, agent, "success_rate"), final(implicit, agent, "success_rate")
    e_speed, i_speed = frames_to_learn(explicit, agent), frames_to_learn(implicit, agent)
    e_area, i_area = training_success(explicit, agent), training_success(implicit, agent)
    ends = compare(explicit, e, implicit, i, agent, "success_rate")
    speed = compare(explicit, e_speed, implicit, i_speed, agent, "frames_to_learn")
    higher = above_zero(ends.interval, TIE)
    sooner = not below_zero(ends.interval, TIE) and below_zero(speed.interval)  # the same end point, reached sooner
    verdict = "reproduced" if higher or sooner else "not reproduced"
    return [
        Verdict(
            verdict,
            f"{agent} success explicit {e} vs implicit {i}, {ends.text(margin=TIE)}; frames to {SETTLED:.0%} of "
            f"final training success {_frames(e_speed)} vs {_frames(i_speed)}, {speed.text(_count)}; mean training "
            f"success {e_area} vs {i_area}",
            [explicit, implicit],
            [
                (explicit, agent, "success_rate", e.mean),
                (implicit, agent, "success_rate", i.mean),
                (explicit, agent, "frames_to_learn", e_speed.mean),
                (implicit, agent, "frames_to_learn", i_speed.mean),
                (explicit, agent, "mean_training_success", e_area.mean),
                (implicit, agent, "mean_training_success", i_area.mean),
            ],
            [ends, speed],
        )
    ]


# The paper's §6.2, claim by claim: (figure, the paper figure whose panels the check reads, the check, the domains
# the paper makes the claim for, what to run for it)
CLAIMS = (
    ("Fig. 5/7", PAPER_FIGURES[0], avoids_random, ("discrete",), "fig5_discrete"),
    ("Fig. 5/7", PAPER_FIGURES[0], dijkstra_yields, ("discrete",), "fig5_discrete"),
    ("Fig. 5/7", PAPER_FIGURES[0], centralized_most_robust, ("discrete", "continuous"), "fig5_{domain}"),
    ("Fig. 5/7, 10b", PAPER_FIGURES[0], unshaped_agent_steps_aside, ("continuous",), "fig5_continuous"),
    ("Fig. 6", PAPER_FIGURES[1], noise_lowers_success, ("discrete", "continuous"), "fig6_{domain}"),
    ("Fig. 8", PAPER_FIGURES[3], explicit_learns_better, ("continuous",), "fig8"),
)


def check_claims(conditions: Sequence[Condition]) -> list[Verdict]:
    """A verdict for every claim of ``CLAIMS`` in every figure panel that can test it, and 'not run' for a claim
    and domain that no panel tests."""
    verdicts: list[Verdict] = []
    for figure, spec, check, domains, preset in CLAIMS:
        claim = check.__doc__.strip()
        found = []
        panels = figure_panels(spec, conditions)
        for panel, (_, apart) in zip(panels, panel_titles(panels, spec)):
            for verdict in check(panel):
                where = verdict.conditions[0].domain + (f", {apart}" if apart else "")
                verdict.claim, verdict.figure = f"{claim} ({where})", figure
                found.append(verdict)
        tested = {v.conditions[0].domain for v in found}
        for domain in domains:
            if domain not in tested:
                command = f"python runners/main.py -m +experiment={preset.format(domain=domain)}"
                found.append(
                    Verdict(
                        "not run", f"no runs for it: `{command}`", claim=f"{claim} ({domain})", figure=figure
                    )
                )
        verdicts += found
    return verdicts


def claims_section(conditions: Sequence[Condition], numbers: NumberLog) -> list[str]:
    """``report.md`` lines: the verdict table and how verdicts are decided; every number goes to ``numbers``."""
    verdicts = check_claims(conditions)
    md = ["## The paper's claims (its §6.2)", ""]
    if all(v.verdict == "not run" for v in verdicts):
        return md + [
            "_None tested: these runs make none of the paper's figures (`runners/reproduce.sh` runs them all)._",
            "",
        ]
    level = f"{BOOTSTRAP.confidence:.0%}"
    md += [
        f"| claim | figure | conditions | verdict | measured (mean ± SE over seeds; differences [{level} CI]) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for v in verdicts:
        ids = ", ".join(c.ident for c in v.conditions) or "–"
        md.append(f"| {v.claim} | {v.figure} | {ids} | **{v.verdict}** | {v.evidence} |")
        _log_verdict(numbers, v)
    counts = {name: sum(v.verdict == name for v in verdicts) for name in VERDICTS}
    return md + [
        "",
        "Tally: " + ", ".join(f"{count} {name}" for name, count in counts.items() if count) + ".",
        "",
        _how_verdicts_are_decided(),
        "",
    ]


def _log_verdict(numbers: NumberLog, v: Verdict) -> None:
    """``v``'s means and differences (with their intervals and whether they separate) into ``numbers``."""
    for condition, agent, metric, value in v.numbers:
        numbers.add("claims", condition, agent, metric, "mean", value, len(condition.runs), f"{v.claim}: {v.verdict}")
    for d in v.differences:
        alone = d.a is d.b  # two agents of the same runs
        numbers.add_interval_row(
            "claims",
            d.a.ident if alone else f"{d.a.ident} − {d.b.ident}",
            d.a.label if alone else f"{d.a.label} − {d.b.label}",
            d.agent,
            d.metric,
            "difference",
            d.interval,
            len(d.a.runs) if alone else len(d.a.runs) + len(d.b.runs),
            f"{separation_text(d.interval, 0.0, BOOTSTRAP.confidence)}; {v.claim}: {v.verdict}",
        )


def _how_verdicts_are_decided() -> str:
    level = f"{BOOTSTRAP.confidence:.0%}"
    return (
        "How verdicts are decided (`sidewalk/report/claims.py`): an agent reaches its goal when its final "
        f"success is ≥ {SUCCEEDS}, avoids collisions at ≤ {SAFE}, heads straight at path efficiency ≥ "
        f"{STRAIGHT}, never reaches its goal at success ≤ {NEVER}; 'learns' is a rise of ≥ {LEARNED} over the "
        "first evaluation; "
        f"learning speed ('needs more training', 'learns better') is read off every iteration's training "
        f"success: per seed, the frames at which its rolling mean over {SMOOTHING} iterations first reaches "
        f"{SETTLED:.0%} of its final training success (the mean of its last {FINAL_SHARE:.0%} of iterations), "
        "the ego's own success for an ego learner and the team's for the centralized one (a seed that ends at 0 "
        "has none). Two measures are compared by the difference of their means over seeds and its "
        f"{level} percentile bootstrap interval (`scipy.stats.bootstrap`, {BOOTSTRAP.n_resamples:,} resamples, seed "
        f"{BOOTSTRAP.seed}: the report's defaults): each condition's seeds resampled on their own, or the per-seed "
        "differences where two agents of the same runs are compared; the interval separates them when it excludes "
        "0, and one seed has no interval, so separates nothing. One learner is faster when the interval of its "
        "frames to learn minus the other's lies below 0. Final values are tied unless the interval of their "
        f"difference excludes 0 and the difference is at least {TIE}: with seeds that agree (a deterministic "
        "evaluation) any difference at all would separate. The centralized learner's robustness is read "
        "through agent 0, the walker the learner plays in the ego views. 'Partly' means one half of a two-part "
        "claim holds. Fig. 8's explicit reward learns better when it ends higher, or ends as high and learns "
        "faster."
    )
