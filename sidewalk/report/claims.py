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
    holm_adjusted,
    mean_se,
    paired_difference_interval,
    separates,
    separation_text,
)

__all__ = [
    "BOOTSTRAP",
    "CLAIMS",
    "LEARNED",
    "LEARN_CRITERION",
    "NEVER",
    "SAFE",
    "SPEED_MARGIN",
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
    "sooner",
    "training_success",
    "unshaped_agent_steps_aside",
]

VERDICTS = ("reproduced", "partly", "not reproduced", "not run")

SUCCEEDS = 0.8  # final success rate at or above which a learned behaviour "reaches its goal"
SAFE = 0.2  # collision rate at or below which an agent "avoids" collisions
STRAIGHT = 0.9  # path efficiency at or above which an agent "heads straight"
NEVER = 0.05  # success rate at or below which an agent "never reaches its goal"
LEARNED = 0.2  # improvement over the first evaluation that counts as learning something
# A seed has learned once its smoothed training success reaches this absolute level, "reaches its goal": a seed that
# learns nothing never gets there (it is censored, slower than any that does), however low it ends.
LEARN_CRITERION = SUCCEEDS
# A learner learns sooner only when its median frames to learn are at least this share below the other's: a test on
# ten seeds can separate a 1.5-iteration difference that no reader would call faster.
SPEED_MARGIN = 0.2
# A difference of final values whose interval excludes 0 is still a tie when it is smaller than this: with seeds
# that agree (a deterministic evaluation), any difference at all would separate.
TIE = 0.02
# Learning speed is read off the training curve (every iteration's episodes), not the evaluations (every 50): the
# learner's training success, smoothed by a rolling mean of SMOOTHING iterations (5 % of a shorter run), seed by seed.
TRAINING_SUCCESS = {"ego": "train/ego_success_rate", "agent0": "train/team_success_rate"}  # centralized: both home
SMOOTHING = 10
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
    bootstrap at ``BOOTSTRAP``'s confidence, resamples and seed, and the p-value of an exact permutation test with
    the seed as the unit: independent (each condition's seeds resampled on their own, the Mann-Whitney test:
    ``difference_interval``) or, for two measures of the same runs, ``paired`` (the per-seed differences: the
    sign-flip test, ``paired_difference_interval``). Within ``check_claims`` the p-value is Holm-adjusted over every
    comparison of the claims table (``FAMILY``)."""
    bootstrap = {"confidence": BOOTSTRAP.confidence, "n_resamples": BOOTSTRAP.n_resamples, "seed": BOOTSTRAP.seed}
    if paired:
        interval = paired_difference_interval(a_stat.values, b_stat.values, **bootstrap)
    else:
        interval = difference_interval(a_stat.values, b_stat.values, "mean", **bootstrap)
    return Difference(a, b, agent, metric, FAMILY.adjusted(interval))


class Family:
    """The claims table's comparisons as one family for Holm's adjustment (``stats.holm``): ``check_claims`` runs the
    checks once to collect every comparison's p-value, then again (the same comparisons in the same order) with the
    i-th replaced by its adjusted one, so verdicts are decided at a family-wise error rate of 1 − confidence."""

    def __init__(self) -> None:
        self.collected: list[Interval] = []
        self.adjusted_ones: list[Interval] | None = None  # None: still collecting
        self.next = 0

    def adjusted(self, interval: Interval) -> Interval:
        if self.adjusted_ones is None:
            self.collected.append(interval)
            return interval
        adjusted, self.next = self.adjusted_ones[self.next], self.next + 1
        return adjusted

    def close(self) -> None:
        self.adjusted_ones = holm_adjusted(self.collected)


FAMILY = Family()  # replaced by check_claims for each table; outside it, comparisons are single tests


def above_zero(difference: Interval, margin: float = 0.0) -> bool:
    """Whether ``difference`` is positive: its test separates it (``stats.separates``) and its point is above 0 and
    at least ``margin``. No test or one seed is never positive."""
    return separates(difference, 0.0) and difference.point > 0.0 and difference.point >= margin


def below_zero(difference: Interval, margin: float = 0.0) -> bool:
    """Whether ``difference`` is negative: its test separates it and its point is below 0 and at most ``-margin``."""
    return separates(difference, 0.0) and difference.point < 0.0 and difference.point <= -margin


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
    """Frames at which each seed's training success (``TRAINING_SUCCESS``, smoothed) first reaches
    ``LEARN_CRITERION``: ``inf`` for a seed that never does (censored at its run's length), NaN for one without
    training success."""
    column = TRAINING_SUCCESS.get(agent, TRAINING_SUCCESS["agent0"])
    return Stat.of([_run_frames_to_learn(run.metrics, column) for run in condition.runs])


def _run_frames_to_learn(metrics: pd.DataFrame, column: str) -> float:
    if column not in metrics.columns or metrics[column].isna().all():
        return math.nan
    success = metrics[column]
    window = max(1, min(SMOOTHING, len(success) // 20))
    reached = metrics["frames"][success.rolling(window, min_periods=1).mean() >= LEARN_CRITERION]
    return float(reached.iloc[0]) if len(reached) else math.inf


def run_frames(condition: Condition) -> float:
    """The frames of the condition's shortest run: where a seed that has not learned by then is censored."""
    return float(min(run.metrics["frames"].max() for run in condition.runs))


def compare_speed(a: Condition, a_frames: Stat, b: Condition, b_frames: Stat, agent: str) -> Difference:
    """``compare`` of frames to learn, each seed censored (``inf``) where it learns later than the shorter of the two
    conditions' runs lasts, so a longer run does not make its late learners look faster than the other's
    censored ones. Its test is the Mann-Whitney test, censored seeds ranking last."""
    limit = min(run_frames(a), run_frames(b))
    censored = [Stat.of(np.where(np.asarray(f.values) > limit, math.inf, f.values)) for f in (a_frames, b_frames)]
    return compare(a, censored[0], b, censored[1], agent, "frames_to_learn")


def median_frames(frames: Stat) -> float:
    """The median over the seeds that have frames to learn (a censored one counts as slowest): NaN without seeds,
    ``inf`` when half or more never learned."""
    values = np.asarray(frames.values)
    values = values[~np.isnan(values)]
    return float(np.median(values)) if values.size else math.nan


def sooner(speed: Interval, a_frames: Stat, b_frames: Stat) -> bool:
    """Whether a condition of ``a_frames`` learns sooner than one of ``b_frames``: the test of their comparison
    ``speed`` (``compare_speed``, either way round: the test is two-sided) separates them and ``a``'s median frames to
    learn are at least ``SPEED_MARGIN`` below ``b``'s."""
    a_median, b_median = median_frames(a_frames), median_frames(b_frames)
    return (separates(speed, 0.0, BOOTSTRAP.confidence) and a_median < math.inf
            and a_median <= (1.0 - SPEED_MARGIN) * b_median)


def _reached(frames: Stat) -> str:
    """"7 of 10 seeds reach 0.8": the seeds with frames to learn, and how many of them learned."""
    values = np.asarray(frames.values)
    counted = values[~np.isnan(values)]
    return f"{int(np.isfinite(counted).sum())} of {counted.size} seeds reach {LEARN_CRITERION:g}"


def _frames(frames: Stat) -> str:
    """"median 47,104 (10 of 10 seeds reach 0.8)"; "never (0 of 10 seeds reach 0.8)"."""
    median = median_frames(frames)
    if math.isnan(median) or not np.isfinite(frames.values).any():
        return f"never ({_reached(frames)})"
    return ("median later than its runs last" if median == math.inf else f"median {median:,.0f}") + f" ({_reached(frames)})"


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
    # Most robust: as good as the best of the others (within TIE, and not separated below it). A tie at nothing
    # learned is not robustness: the centralized learner must also have learned something.
    robust = (success.mean >= best_success.mean - TIE and not below_zero(versus_best.interval, TIE)
              and success.mean >= LEARNED)
    learn = frames_to_learn(c, "agent0")
    learn_others = [frames_to_learn(o, "ego") for o in others]
    later = [compare_speed(c, learn, o, f, "agent0 − ego") for o, f in zip(others, learn_others)]
    # "Needs more training": the centralized learner learns (on most seeds), later than every other condition that
    # learns does, by the test and the margin.
    learned = [(d, f) for d, f in zip(later, learn_others) if median_frames(f) < math.inf]
    slower = median_frames(learn) < math.inf and bool(learned) and all(
        sooner(d.interval, f, learn) for d, f in learned
    )
    verdict = "reproduced" if robust and slower else "partly" if robust or slower else "not reproduced"
    frames = "; ".join(
        f"vs {o.opponent} ({o.ident}) {_frames(f)}, {d.text(_count)}" for o, f, d in zip(others, learn_others, later)
    )
    return [
        Verdict(
            verdict,
            f"centralized agent 0 success {success} (team {final(c, 'team', 'success_rate')}) vs best ego "
            f"{best_success} ({best.opponent}), {versus_best.text(margin=TIE)}; frames until training success "
            f"reaches {LEARN_CRITERION:g} (the team's for the centralized learner): centralized {_frames(learn)} "
            f"{frames}",
            [c, *others],
            [
                (c, "agent0", "success_rate", success.mean),
                (c, "agent0", "frames_to_learn", median_frames(learn)),
                *((o, "ego", "frames_to_learn", median_frames(f)) for o, f in zip(others, learn_others)),
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
    speed = compare_speed(explicit, e_speed, implicit, i_speed, agent)
    higher = above_zero(ends.interval, TIE)
    # The same end point, reached sooner. Two tests for one verdict: both are in the table's Holm family, which bounds
    # the chance that either falsely separates.
    faster = not below_zero(ends.interval, TIE) and sooner(speed.interval, e_speed, i_speed)
    verdict = "reproduced" if higher or faster else "not reproduced"
    return [
        Verdict(
            verdict,
            f"{agent} success explicit {e} vs implicit {i}, {ends.text(margin=TIE)}; frames until training success "
            f"reaches {LEARN_CRITERION:g}: {_frames(e_speed)} vs {_frames(i_speed)}, {speed.text(_count)}; mean "
            f"training success {e_area} vs {i_area}",
            [explicit, implicit],
            [
                (explicit, agent, "success_rate", e.mean),
                (implicit, agent, "success_rate", i.mean),
                (explicit, agent, "frames_to_learn", median_frames(e_speed)),
                (implicit, agent, "frames_to_learn", median_frames(i_speed)),
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
    global FAMILY
    FAMILY = Family()
    _check_every_claim(conditions)  # the first pass only collects the family's p-values
    FAMILY.close()
    try:
        return _check_every_claim(conditions)
    finally:
        FAMILY = Family()


def _check_every_claim(conditions: Sequence[Condition]) -> list[Verdict]:
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
        if metric == "frames_to_learn":  # a median, and how many seeds it rests on
            numbers.add("claims", condition, agent, metric, "median", value, len(condition.runs),
                        f"{_reached(frames_to_learn(condition, agent))}; {v.claim}: {v.verdict}")
            continue
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
    alpha = f"{1 - BOOTSTRAP.confidence:.2g}"
    return (
        "How verdicts are decided (`sidewalk/report/claims.py`): an agent reaches its goal when its final "
        f"success is ≥ {SUCCEEDS}, avoids collisions at ≤ {SAFE}, heads straight at path efficiency ≥ "
        f"{STRAIGHT}, never reaches its goal at success ≤ {NEVER}; 'learns' is a rise of ≥ {LEARNED} over the "
        "first evaluation. "
        "Learning speed ('needs more training', 'learns better') is read off every iteration's training success: "
        f"per seed, the frames at which its rolling mean over {SMOOTHING} iterations first reaches {LEARN_CRITERION:g} "
        "(the ego's own success for an ego learner, the team's for the centralized one); a seed that never does is "
        "censored (counted slower than any that does, at the shorter run's length of the two compared), each speed "
        f"says how many seeds reach it, and one learner is sooner only when its median is at least "
        f"{SPEED_MARGIN:.0%} below the other's and the test below separates them. "
        "Two measures are compared by the difference of their means over seeds, shown with its "
        f"{level} percentile bootstrap interval (`scipy.stats.bootstrap`, {BOOTSTRAP.n_resamples:,} resamples, seed "
        f"{BOOTSTRAP.seed}), and decided by an exact permutation test with the seed as the unit: the Mann-Whitney "
        "test of two conditions' seeds, or the sign-flip test of the per-seed differences where two agents of the "
        f"same runs are compared. Every test of this table is one family: its p-values are Holm-adjusted, and a "
        f"comparison separates when its adjusted p is ≤ {alpha}, so the chance that any verdict here rests on a false "
        "separation is at most that. Few seeds cannot separate anything (3 against 3: the smallest p is 0.1), and "
        "the table says so. Final values are tied unless the test separates them and the difference is at least "
        f"{TIE}: with seeds that agree (a deterministic evaluation) any difference at all would separate. The "
        "centralized learner's robustness is read through agent 0, the walker the learner plays in the ego views; "
        "it is compared with the best of the other conditions, chosen on the same runs. 'Partly' means one half "
        "of a two-part claim holds. Fig. 8's explicit reward learns better when it ends higher, or ends as high "
        "and learns sooner."
    )
