"""Learners: one file each, each with its dataclass config, registered by name (``sidewalk.registry.LEARNERS``,
where plug-ins from other packages join them). Single-agent (an ego view or the centralized view): dqn, trpo, ppo,
and ppo_lagrangian (safe RL: PPO under a limit on the expected episode cost). Multi-agent (every agent learns,
``opponent=self``): ippo, mappo, iql, vdn, qmix."""

from __future__ import annotations

from sidewalk.algos.base import AlgoConfig, Algorithm, MultiAgentAlgorithm, MultiAgentConfig

__all__ = ["AlgoConfig", "Algorithm", "MultiAgentAlgorithm", "MultiAgentConfig"]
