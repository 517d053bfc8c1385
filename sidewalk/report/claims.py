"""The paper's findings (SPEC §4) held against a set of runs: a verdict per claim and the numbers behind it.

Each check reads the same conditions the report's paper figures are drawn from (``figure_panels``), so a verdict
is always about the curves shown above it in ``report.md``. The verdict is one of ``VERDICTS``, decided by the
thresholds below; they are stated in the report next to the table, so a reader can disagree with a threshold
and still use the numbers. The learner's agent is ``ego`` against a scripted opponent and ``agent0`` when it
plays both agents (in the ego views the learner is agent 0, so the two are the same walker).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import pandas as pd

from sidewalk.report.conditions import PAPER_FIGURES, Condition, figure_panels, panel_titles
from sidewalk.report.tables import NumberLog, curve, fmt, summary_values
from sidewalk.stats import mean_se

__all__ = [
    "CLAIMS",
    "LEARNED",
    "NEVER",
    "SAFE",
    "SETTLED",
    "STRAIGHT",
    "SUCCEEDS",
    "TIE",
    "VERDICTS",
    "Stat",
    "Verdict",
    "avoids_random",
    "centralized_most_robust",
    "check_claims",
    "claims_section",
    "dijkstra_yields",
    "explicit_learns_better",
    "faster",
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
TIE = 0.02  # differences within max(SE, TIE) are ties
# Learning speed is read off the training curve (every iteration's episodes), not the evaluations (every 50): the
# learner's training success, smoothed by a rolling mean of SMOOTHING iterations (5 % of a shorter run), against its
# final training success (the mean of its last FINAL_SHARE of iterations), seed by seed.
TRAINING_SUCCESS = {"ego": "train/ego_success_rate", "agent0": "train/team_success_rate"}  # centralized: both home
SMOOTHING = 10
FINAL_SHARE = 0.1
SIGNIFICANT = 2.0  # a difference in learning speed beyond this many standard errors of the difference is no tie


@dataclass
class Verdict:
    """One claim of SPEC §4 held against the runs of one figure panel."""

    verdict: str
    evidence: str
    conditions: list[Condition] = field(default_factory=list)
    numbers: list[tuple[Condition, str, str, float]] = field(
        default_factory=list
    )  # (condition, agent, metric, value)
    claim: str = ""  # the check's docstring and the domain, set by check_claims
    figure: str = ""

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict={self.verdict!r}; valid: {', '.join(VERDICTS)}")


@dataclass(frozen=True)
class Stat:
    """A final value over seeds (``summary.json``): mean and standard error."""

    mean: float
    se: float

    def __str__(self) -> str:
        return fmt(self.mean, 2) + ("" if math.isnan(self.se) else f" ± {fmt(self.se, 2)}")

    def tolerance(self, other: Stat) -> float:
        return max(TIE, *(s for s in (self.se, other.se) if not math.isnan(s)))


def learner(condition: Condition) -> str:
    return condition.agents()[0][0]


def final(condition: Condition, agent: str, metric: str) -> Stat:
    mean, se, _ = mean_se(summary_values(condition, f"{agent}/{metric}"))
    return Stat(float(mean), float(se))


def first_evaluation(condition: Condition, agent: str, metric: str) -> float:
    points = curve(condition, agent, metric, "frames")
    return float(points["mean"].iloc[0]) if len(points) else math.nan


def frames_to_learn(condition: Condition, agent: str) -> Stat:
    """Frames at which each seed's training success (``TRAINING_SUCCESS``, smoothed) first reaches ``SETTLED`` of
    its final training success, mean ± SE over seeds (a seed that ends at 0 has none and is left out)."""
    column = TRAINING_SUCCESS.get(agent, TRAINING_SUCCESS["agent0"])
    per_seed = [_run_frames_to_learn(run.metrics, column) for run in condition.runs]
    mean, se, _ = mean_se(per_seed)
    return Stat(float(mean), float(se))


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


def faster(a: Stat, b: Stat) -> bool:
    """Whether ``a`` frames to learn is fewer than ``b``'s beyond ``SIGNIFICANT`` standard errors of the difference
    (a missing SE, one seed, counts as 0)."""
    spread = math.hypot(*(0.0 if math.isnan(s) else s for s in (a.se, b.se)))
    return not (math.isnan(a.mean) or math.isnan(b.mean)) and a.mean < b.mean - SIGNIFICANT * spread


def _frames(frames: Stat) -> str:
    if math.isnan(frames.mean):
        return "– (ends at 0)"
    return f"{frames.mean:,.0f}" + ("" if math.isnan(frames.se) else f" ± {frames.se:,.0f}")


def training_success(condition: Condition, agent: str) -> Stat:
    """Each seed's mean training success over all of training (``TRAINING_SUCCESS``): how fast and how well it
    learned, mean ± SE over seeds."""
    column = TRAINING_SUCCESS.get(agent, TRAINING_SUCCESS["agent0"])
    per_seed = [float(run.metrics[column].mean()) if column in run.metrics.columns else math.nan
                for run in condition.runs]
    mean, se, _ = mean_se(per_seed)
    return Stat(float(mean), float(se))


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
        straight = ego_success.mean >= SUCCEEDS and ego_path.mean >= STRAIGHT
        yields = other_success.mean >= SUCCEEDS and other_path.mean < ego_path.mean
        verdict = (
            "reproduced" if straight and yields else "partly" if straight or yields else "not reproduced"
        )
        out.append(
            Verdict(
                verdict,
                f"ego success {ego_success}, path efficiency {ego_path}; Dijkstra success {other_success}, "
                f"path efficiency {other_path}",
                [c],
                [
                    (c, "ego", "success_rate", ego_success.mean),
                    (c, "ego", "path_efficiency", ego_path.mean),
                    (c, "other", "success_rate", other_success.mean),
                    (c, "other", "path_efficiency", other_path.mean),
                ],
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
    # A tie at nothing learned is not robustness: the centralized learner must also have learned something.
    robust = success.mean >= best_success.mean - success.tolerance(best_success) and success.mean >= LEARNED
    learn = frames_to_learn(c, "agent0")
    learn_others = {o.opponent: frames_to_learn(o, "ego") for o in others}
    learned = [f for f in learn_others.values() if not math.isnan(f.mean)]
    slower = not math.isnan(learn.mean) and bool(learned) and all(faster(f, learn) for f in learned)
    verdict = "reproduced" if robust and slower else "partly" if robust or slower else "not reproduced"
    frames = ", ".join(f"{name} {_frames(f)}" for name, f in learn_others.items())
    return [
        Verdict(
            verdict,
            f"centralized agent 0 success {success} (team {final(c, 'team', 'success_rate')}) vs best ego "
            f"{best_success} ({best.opponent}); frames to {SETTLED:.0%} of final training success (team for the "
            f"centralized learner): centralized {_frames(learn)}, {frames}",
            [c, *others],
            [
                (c, "agent0", "success_rate", success.mean),
                (c, "agent0", "frames_to_learn", learn.mean),
                *((o, "ego", "frames_to_learn", learn_others[o.opponent].mean) for o in others),
            ],
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
    steps_down = all(b.mean <= a.mean + a.tolerance(b) for a, b in itertools.pairwise(stats))
    lower = stats[-1].mean < stats[0].mean - stats[0].tolerance(stats[-1])
    verdict = "reproduced" if lower and steps_down else "partly" if lower else "not reproduced"
    symbol = "n" if ordered[0].domain == "discrete" else "ε"
    levels = ", ".join(f"{symbol}={float(c.flat.get('noise', 0.0)):g}: {s}" for c, s in zip(ordered, stats))
    return [
        Verdict(
            verdict,
            f"{agent} success {levels}",
            list(ordered),
            [(c, agent, "success_rate", s.mean) for c, s in zip(ordered, stats)],
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
    higher = e.mean > i.mean + e.tolerance(i)
    sooner = e.mean >= i.mean - e.tolerance(i) and faster(e_speed, i_speed)  # the same end point, reached sooner
    verdict = "reproduced" if higher or sooner else "not reproduced"
    return [
        Verdict(
            verdict,
            f"{agent} success explicit {e} vs implicit {i}; frames to {SETTLED:.0%} of final training success "
            f"{_frames(e_speed)} vs {_frames(i_speed)}; mean training success {e_area} vs {i_area}",
            [explicit, implicit],
            [
                (explicit, agent, "success_rate", e.mean),
                (implicit, agent, "success_rate", i.mean),
                (explicit, agent, "frames_to_learn", e_speed.mean),
                (implicit, agent, "frames_to_learn", i_speed.mean),
                (explicit, agent, "mean_training_success", e_area.mean),
                (implicit, agent, "mean_training_success", i_area.mean),
            ],
        )
    ]


# SPEC §4, claim by claim: (figure, the paper figure whose panels the check reads, the check, the domains the paper
# makes the claim for, what to run for it)
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
    md = ["## The paper's claims (SPEC §4)", ""]
    if all(v.verdict == "not run" for v in verdicts):
        return md + [
            "_None tested: these runs make none of the paper's figures (`runners/reproduce.sh` runs them all)._",
            "",
        ]
    md += [
        "| claim | figure | conditions | verdict | measured (final values: mean ± SE over seeds) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for v in verdicts:
        ids = ", ".join(c.ident for c in v.conditions) or "–"
        md.append(f"| {v.claim} | {v.figure} | {ids} | **{v.verdict}** | {v.evidence} |")
        for condition, agent, metric, value in v.numbers:
            numbers.add(
                "claims",
                condition,
                agent,
                metric,
                "mean",
                value,
                len(condition.runs),
                f"{v.claim}: {v.verdict}",
            )
    counts = {name: sum(v.verdict == name for v in verdicts) for name in VERDICTS}
    md += [
        "",
        "Tally: " + ", ".join(f"{count} {name}" for name, count in counts.items() if count) + ".",
        "",
        (
            "How verdicts are decided (`sidewalk/report/claims.py`): an agent reaches its goal when its final "
            f"success is ≥ {SUCCEEDS}, avoids collisions at ≤ {SAFE}, heads straight at path efficiency ≥ "
            f"{STRAIGHT}, never reaches its goal at success ≤ {NEVER}; 'learns' is a rise of ≥ {LEARNED} over the "
            "first evaluation; "
            f"learning speed ('needs more training', 'learns better') is read off every iteration's training "
            f"success: per seed, the frames at which its rolling mean over {SMOOTHING} iterations first reaches "
            f"{SETTLED:.0%} of its final training success (the mean of its last {FINAL_SHARE:.0%} of iterations), "
            f"the ego's own success for an ego learner and the team's for the centralized one, mean ± SE over "
            f"seeds; one learner is faster when the difference exceeds {SIGNIFICANT:g} standard errors of the "
            f"difference. Final values within max(SE, {TIE}) are ties. The centralized learner's robustness is read "
            "through agent 0, the walker the learner plays in the ego views. 'Partly' means one half of a two-part "
            "claim holds. Fig. 8's explicit reward learns better when it ends higher, or ends as high and learns "
            "faster."
        ),
        "",
    ]
    return md
