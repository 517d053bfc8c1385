"""Config keys that came in after runs were made, with the value a run written without them had. One table, read by
the schema (a run folder's config resumes and replays as the run it was) and by the report, cross-play and the
reference (an old run and a new run of one setting are seeds of one condition)."""

from __future__ import annotations

from typing import Any

# Top-level keys: an older run without ``shield`` trained unshielded, so it is a ``shield=false`` run.
LATER_KEYS: dict[str, Any] = {"shield": False, "other_play": False, "role_frame": False}
# Env keys, per domain (env.domain): the safety cost of runs written before it was counted, the observed route, the
# starts' and goals' jitter.
LATER_ENV_KEYS: dict[str, dict[str, Any]] = {
    "discrete": {"env.cost": "collision", "env.near_miss_margin": 1.0, "env.start_jitter_rows": 0,
                 "env.goal_jitter_rows": 0, "env.start_jitter_cells": 0, "env.goal_jitter_cells": 0},
    "continuous": {"env.cost": "collision", "env.near_miss_margin": 0.3, "env.observe_route": False,
                   "env.start_jitter_m": 0.0, "env.goal_jitter_m": 0.0, "env.heading_jitter_rad": 0.0},
}
# Learner keys whose default is not what a run written before them did, with the learners (algo.name) that have them.
LATER_ALGO_KEYS: dict[str, tuple[Any, tuple[str, ...]]] = {
    "advantage_learning": (0.0, ("dqn", "iql", "vdn", "qmix")),
}

# Opponent settings (opponent.params) whose default is not what a run written before them played against.
LATER_OPPONENT_KEYS: dict[str, dict[str, Any]] = {"dijkstra": {"tie_break": "progress"}}
# The evaluation protocol (eval group) of a run written before protocols existed: the scenario's own worlds.
NOMINAL_EVAL: dict[str, Any] = {
    "name": "nominal", "start_jitter_rows": 0, "goal_jitter_rows": 0, "start_jitter_cells": 0, "goal_jitter_cells": 0,
    "start_jitter_m": 0.0, "goal_jitter_m": 0.0, "heading_jitter_rad": 0.0, "train_alike": True, "epsilon": 0.0,
}


def later_opponent_keys(opponent: str) -> dict[str, Any]:
    """The later settings of opponent ``opponent``, at the value a run against it written before them had."""
    return dict(LATER_OPPONENT_KEYS.get(opponent, {}))


def later_algo_keys(algo: str) -> dict[str, Any]:
    """The later keys of learner ``algo``, at the value a run of it written before them had."""
    return {key: value for key, (value, learners) in LATER_ALGO_KEYS.items() if algo in learners}


def with_later_keys(flat: dict[str, Any]) -> dict[str, Any]:
    """A run's flat config (``"algo.name"``-style keys) with every later key it lacks at the value it had then, so a
    run from before a key existed groups with today's runs of the same setting."""
    algo = {f"algo.{key}": value for key, value in later_algo_keys(str(flat.get("algo.name"))).items()}
    opponent = {f"opponent.params.{key}": value
                for key, value in later_opponent_keys(str(flat.get("opponent.name"))).items()}
    domain = str(flat.get("env.domain"))
    protocol = {f"eval.{key}": value for key, value in NOMINAL_EVAL.items()}
    return {**LATER_KEYS, **protocol, **LATER_ENV_KEYS.get(domain, {}), **algo, **opponent, **flat}
