"""Learners: one file each, each with its dataclass config. Single-agent (an ego view or the centralized view):
dqn, trpo, ppo, and ppo_lagrangian (safe RL: PPO under a limit on the expected episode cost). Multi-agent (every
agent learns, ``opponent=self``): ippo, mappo, iql, vdn, qmix."""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from sidewalk.algos.base import AlgoConfig, Algorithm, MultiAgentAlgorithm, MultiAgentConfig

# name -> "module:Class"; a learner's module is imported when it is first asked for.
_REGISTRY = {
    "dqn": "sidewalk.algos.dqn:DQN",
    "trpo": "sidewalk.algos.trpo:TRPO",
    "ppo": "sidewalk.algos.ppo:PPO",
    "ppo_lagrangian": "sidewalk.algos.ppo_lagrangian:PPOLagrangian",
    "ippo": "sidewalk.algos.ippo:IPPO",
    "mappo": "sidewalk.algos.mappo:MAPPO",
    "iql": "sidewalk.algos.iql:IQL",
    "vdn": "sidewalk.algos.vdn:VDN",
    "qmix": "sidewalk.algos.qmix:QMIX",
}


class _Algorithms(Mapping):
    """Read-only name → ``Algorithm`` class mapping that imports each learner on first use."""

    def __getitem__(self, name: str) -> type[Algorithm]:
        if name not in _REGISTRY:
            raise KeyError(f"algo={name!r} is not valid; valid: {', '.join(map(repr, _REGISTRY))}")
        module, cls = _REGISTRY[name].split(":")
        return getattr(importlib.import_module(module), cls)

    def __iter__(self) -> Iterator[str]:
        return iter(_REGISTRY)

    def __len__(self) -> int:
        return len(_REGISTRY)


ALGORITHMS: Mapping[str, type[Algorithm]] = _Algorithms()

__all__ = ["ALGORITHMS", "AlgoConfig", "Algorithm", "MultiAgentAlgorithm", "MultiAgentConfig"]
