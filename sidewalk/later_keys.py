"""Config keys that came in after runs were made, with the value a run written without them had. One table, read by
the schema (a run folder's config resumes and replays as the run it was) and by the report, cross-play and the
reference (an old run and a new run of one setting are seeds of one condition)."""

from __future__ import annotations

from typing import Any

# Top-level keys: an older run without ``shield`` trained unshielded, so it is a ``shield=false`` run.
LATER_KEYS: dict[str, Any] = {"shield": False, "other_play": False}
# Env keys, per domain (env.domain): the safety cost of runs written before it was counted, the observed route.
LATER_ENV_KEYS: dict[str, dict[str, Any]] = {
    "discrete": {"env.cost": "collision", "env.near_miss_margin": 1.0},
    "continuous": {"env.cost": "collision", "env.near_miss_margin": 0.3, "env.observe_route": False},
}
# Learner keys whose default is not what a run written before them did, with the learners (algo.name) that have them.
LATER_ALGO_KEYS: dict[str, tuple[Any, tuple[str, ...]]] = {
    "advantage_learning": (0.0, ("dqn", "iql", "vdn", "qmix")),
}


def later_algo_keys(algo: str) -> dict[str, Any]:
    """The later keys of learner ``algo``, at the value a run of it written before them had."""
    return {key: value for key, (value, learners) in LATER_ALGO_KEYS.items() if algo in learners}


def with_later_keys(flat: dict[str, Any]) -> dict[str, Any]:
    """A run's flat config (``"algo.name"``-style keys) with every later key it lacks at the value it had then, so a
    run from before a key existed groups with today's runs of the same setting."""
    algo = {f"algo.{key}": value for key, value in later_algo_keys(str(flat.get("algo.name"))).items()}
    return {**LATER_KEYS, **LATER_ENV_KEYS.get(str(flat.get("env.domain")), {}), **algo, **flat}
