"""Learners: one file each (dqn, trpo, ppo), each with its dataclass config."""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from sidewalk.algos.base import AlgoConfig, Algorithm

# name -> "module:Class"; a learner's module is imported when it is first asked for.
_REGISTRY = {
    "dqn": "sidewalk.algos.dqn:DQN",
    "trpo": "sidewalk.algos.trpo:TRPO",
    "ppo": "sidewalk.algos.ppo:PPO",
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

__all__ = ["ALGORITHMS", "AlgoConfig", "Algorithm"]
