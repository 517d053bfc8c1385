"""Learners: one file each, each with its dataclass config, registered by name (``sidewalk.registry.LEARNERS``,
where plug-ins from other packages join them). Single-agent (an ego view or the centralized view): dqn, trpo, ppo,
and ppo_lagrangian (safe RL: PPO under a limit on the expected episode cost). Multi-agent (every agent learns,
``opponent=self``): ippo, mappo, iql, vdn, qmix."""

from __future__ import annotations

from collections.abc import Mapping

from sidewalk.algos.base import AlgoConfig, Algorithm, MultiAgentAlgorithm, MultiAgentConfig
from sidewalk.registry import LEARNERS

# Only for sidewalk/group.py, sidewalk/bench/* and Trial's rewrite, which read it here until their owners move them
# to sidewalk.registry.LEARNERS; then this line goes.
ALGORITHMS: Mapping[str, type[Algorithm]] = LEARNERS

__all__ = ["ALGORITHMS", "AlgoConfig", "Algorithm", "MultiAgentAlgorithm", "MultiAgentConfig"]
