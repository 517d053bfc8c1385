"""One replica of a replicated core env, as an opponent built for that replica sees it.

A core env built with several seeds (``seed=[s0, s1, ...]``, ``sidewalk.envs.base``) holds R replicas of one
experiment, replica ``r`` owning a contiguous block of B worlds and its own generator. An opponent whose play depends on
the env's seed (it draws from ``env.generator``, or builds something from the seed, as the PRM's roadmap) is built once
per replica on a ``ReplicaEnv``: to it the proxy is a lone env of B worlds seeded with that replica's seed, so it plays
exactly as it would there. ``sidewalk.opponents.base.ReplicaOpponent`` holds those opponents and splits the worlds.
"""

from __future__ import annotations

from typing import Any

import torch
from torchrl.data import Composite

from sidewalk._checks import check_int
from sidewalk.envs.base import SidewalkEnvBase


class ReplicaEnv:
    """Replica ``replica`` of the replicated core env ``core``: ``num_envs`` and ``batch_size`` are its B worlds,
    ``generator`` (and ``rand``/``randint``) its own generator, ``full_action_spec`` the core's for B worlds,
    ``worlds`` its slice of the core's worlds. Other public attributes are the core's: the layout, params, n_agents and
    device that opponents read are the same for every world (the core's other specs stay sized for all worlds)."""

    def __init__(self, core: SidewalkEnvBase, replica: int) -> None:
        check_int("replica", replica, 0, core.replicas - 1)
        self.core = core
        self.replica = replica
        self.replicas = 1
        self.num_envs = self.worlds_per_replica = core.worlds_per_replica
        self.batch_size = torch.Size([self.num_envs])
        self.worlds = slice(replica * self.num_envs, (replica + 1) * self.num_envs)
        self.generator = core.generators[replica]
        self.generators = [self.generator]
        self._full_action_spec: Composite | None = None

    def __getattr__(self, name: str) -> Any:
        # Only public attributes: the core's private state is every world's, never one replica's.
        if name.startswith("_") or name == "core":
            raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")
        return getattr(self.core, name)

    @property
    def full_action_spec(self) -> Composite:
        """The core's joint action spec for this replica's B worlds."""
        if self._full_action_spec is None:
            self._full_action_spec = self.core.full_action_spec[: self.num_envs]
        return self._full_action_spec

    def replica_blocks(self) -> list[slice]:
        """One replica: all of its worlds (``SidewalkEnvBase.replica_blocks`` of a lone env)."""
        return [slice(0, self.num_envs)]

    def rand(self, shape: Any, rows: torch.Tensor | None = None) -> torch.Tensor:
        """``torch.rand(shape)`` from this replica's generator (``SidewalkEnvBase.rand`` of a lone env)."""
        return torch.rand(shape, generator=self.generator, device=self.core.device)

    def randint(self, high: int, shape: Any, rows: torch.Tensor | None = None) -> torch.Tensor:
        """``torch.randint(high, shape)`` from this replica's generator."""
        return torch.randint(high, shape, generator=self.generator, device=self.core.device)

    def __repr__(self) -> str:
        return f"ReplicaEnv(replica {self.replica} of {self.core.replicas} of a {type(self.core).__name__}, {self.num_envs} worlds)"
