"""The report's "who yields" table: one row per condition whose runs recorded the pass (``sidewalk.social``'s
who-yields-first shares), scenario and learner against how the pass was settled.

Columns: the team's success (every agent home) and deadlock rate (the pair stuck in front of each other to the time
limit), each as the IQM over seeds with its 95 % bootstrap interval; who yields first (steps off its line first) as
the mean share of a seed's final episodes, per agent, both at once, or no one; and the salsa count (mirrored dodges:
steps in which one sidestepped toward the side the other had just stepped to), with the seeds and the distinct
episodes a seed's final evaluation played.
Rates are per seed first, so the seed is the unit throughout.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from sidewalk.report.conditions import Condition
from sidewalk.report.tables import (
    NumberLog,
    Settings,
    distinct_range,
    final_of,
    fmt,
    iqm_text,
    mean_se_text,
)

YIELD_SHARES = {  # summary key -> column text; a condition shows the pair it recorded (ego/partner or agent0/agent1)
    "social/ego_yields_first": "learner (ego) first",
    "social/partner_yields_first": "partner first",
    "social/agent0_yields_first": "agent 0 first",
    "social/agent1_yields_first": "agent 1 first",
    "social/both_yield_first": "both at once",
    "social/no_yield": "no one",
}
SALSA = "social/salsa_count"


def recorded_the_pass(condition: Condition) -> bool:
    """Whether the condition's runs recorded who yields first (two-agent worlds, ``sidewalk.social``)."""
    return any(key in run.summary for run in condition.runs for key in YIELD_SHARES)


def who_yields_section(conditions: Sequence[Condition], settings: Settings, numbers: NumberLog) -> list[str]:
    """``report.md`` lines of the who-yields table (the module docstring); nothing where no condition recorded the
    pass. Its IQMs and shares go to ``numbers`` under ``who_yields``."""
    rows = [condition for condition in conditions if recorded_the_pass(condition)]
    if not rows:
        return []
    level = f"{settings.confidence:.0%}"
    md = [
        "## Who yields",
        "",
        (
            "How each condition's pass was settled in its final evaluations: team success and deadlock rate as the "
            f"IQM over seeds [{level} bootstrap interval over seeds]; who stepped aside first as the mean share of a "
            "seed's episodes (`sidewalk.social`: the first to stray a row, or 0.2 m, from its straight line while the "
            "two are still to pass; ego/partner against a scripted partner, agent 0/agent 1 where the learner plays "
            "both; the shares sum to 1 with 'no one'); the salsa count, the steps an episode in which one sidestepped "
            "toward the side the other had just stepped to (mean ± SE over seeds)."
        ),
        "",
        (f"| id | condition | seeds | distinct episodes a seed | team success [{level} CI] | deadlock rate [{level} CI] "
         "| who yields first (mean share) | salsa count |"),
        "| --- | --- | ---: | ---: | --- | --- | --- | --- |",
    ]
    for condition in rows:
        team = final_of(condition, "team", "success_rate", "team/success_rate", settings)
        deadlock = final_of(condition, "team", "deadlock_rate", "deadlock_rate", settings)
        salsa = final_of(condition, "team", SALSA, SALSA, settings)
        shares = []
        for key, text in YIELD_SHARES.items():
            final = final_of(condition, "team", key, key, settings)
            if math.isnan(final.mean):  # the other view's names (ego/partner against agent0/agent1)
                continue
            shares.append(f"{text} {fmt(final.mean)}")
            numbers.add_final("who_yields", condition, final)
        for final in (team, deadlock, salsa):
            numbers.add_final("who_yields", condition, final)
        seeds = sum(not math.isnan(value) for value in team.values)
        distinct = distinct_range(run.summary.get("distinct_episodes") for run in condition.runs)
        salsa_text = "–" if math.isnan(salsa.mean) else mean_se_text(salsa)
        md.append(
            f"| {condition.ident} | {condition.label} | {seeds} | {distinct} | {iqm_text(team)} | "
            f"{iqm_text(deadlock)} | {'; '.join(shares) or '–'} | {salsa_text} |"
        )
    return md + [""]
