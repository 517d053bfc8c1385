"""The learners of a trial's seeds behind one face (``sidewalk.experiment.Trial``): one learner for one seed; for R
seeds one learner with a replica axis where its class has one (``Algorithm.replicable``, ``sidewalk.algos.replicas``),
else R lone learners updated one after another, each on its own random stream (``sidewalk.streams``)."""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.envs import EnvBase

from sidewalk.algos.base import Algorithm
from sidewalk.algos.replicas import replica_state
from sidewalk.stops import divergence
from sidewalk.streams import ReplicaStreams


class ReplicaPolicy(TensorDictModuleBase):
    """A collection policy over every replica's worlds (replica-major blocks of one env's batch): a replicated
    learner's policy on the batch laid out (R, worlds), or each lone learner's on its block, on its own stream."""

    def __init__(self, policies: list[TensorDictModuleBase], replicas: int, streams: ReplicaStreams | None) -> None:
        super().__init__()
        self.policies = nn.ModuleList(policies)
        self.replicas, self.streams = replicas, streams
        self.in_keys, self.out_keys = list(policies[0].in_keys), list(policies[0].out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.streams is None:
            return self.policies[0](tensordict.reshape(self.replicas, -1)).reshape(-1)
        outputs = []
        for replica, (policy, block) in enumerate(zip(self.policies, tensordict.split(len(tensordict) // self.replicas))):
            with self.streams.use(replica):
                outputs.append(policy(block.clone()))
        return torch.cat(outputs, 0)


class ReplicaSet:
    """The learners of a run's seeds, behind one face for the trial (``sidewalk.experiment``): one learner for one
    seed; for R seeds one learner with a replica axis where its class has one (``Algorithm.replicable``), else R
    lone learners updated one after another, each drawing from its own stream (``sidewalk.streams``)."""

    def __init__(
        self, cls: type[Algorithm], config: Any, env: EnvBase, device: Any, seeds: Sequence[int]
    ) -> None:
        self.count = len(seeds)
        self.streams: ReplicaStreams | None = None
        if self.count == 1:
            self.algos = [cls(config, env, device=device)]
        elif cls.replicable:
            self.algos = [cls(config, env, device=device, replicas=self.count)]
            with torch.random.fork_rng(devices=[]):  # plays one replica at a time: evaluation, policy.pt
                self.lone = cls(config, env, device=device)
        else:
            self.streams = ReplicaStreams(seeds)
            self.algos = []
            for replica in range(self.count):
                with self.streams.use(replica):
                    self.algos.append(cls(config, env, device=device))
        self.uses_replay_buffer = cls.uses_replay_buffer

    @property
    def replicated(self) -> bool:
        """One learner with a replica axis for several seeds."""
        return self.count > 1 and self.streams is None

    def collection_policy(self) -> TensorDictModuleBase:
        if self.count == 1:
            return self.algos[0].collection_policy()
        return ReplicaPolicy([algo.collection_policy() for algo in self.algos], self.count, self.streams)

    def use(self, replica: int) -> contextlib.AbstractContextManager:
        """Replica ``replica``'s random stream where the replicas keep their own; else nothing to switch."""
        return self.streams.use(replica) if self.streams is not None else contextlib.nullcontext()

    def update(self, batch: TensorDictBase, replay_buffers: list[Any]) -> list[dict[str, float]]:
        """Every replica's update on its block of the collected batch (replica-major worlds); each one's logs."""
        if self.count == 1:
            return [self.algos[0].update(batch, replay_buffers[0])]
        if self.replicated:
            logs = self.algos[0].update(batch.reshape(self.count, -1, *batch.shape[1:]), replay_buffers[0])
            return [{key: float(value[r]) if isinstance(value, torch.Tensor) else value for key, value in logs.items()}
                    for r in range(self.count)]
        blocks = batch.split(len(batch) // self.count)
        out = []
        for replica, (algo, block, buffer) in enumerate(zip(self.algos, blocks, replay_buffers)):
            with self.use(replica):
                out.append(algo.update(block, buffer))
        return out

    def learner(self, replica: int) -> Algorithm:
        """A lone learner holding replica ``replica``'s networks now: to evaluate it or write its ``policy.pt``."""
        if not self.replicated:
            return self.algos[replica]
        self.lone.load_policy_state_dict(self.policy_state(replica))
        return self.lone

    def policy_state(self, replica: int) -> dict[str, Any]:
        """Replica ``replica``'s ``Algorithm.policy_state_dict``, in a lone learner's layout."""
        if not self.replicated:
            return self.algos[replica].policy_state_dict()
        return replica_state(self.algos[0].policy_state_dict(), self.lone.policy_state_dict(), replica)

    def divergence(self, replica: int, logs: dict[str, float]) -> str | None:
        """What turned non-finite in replica ``replica``'s update (``sidewalk.stops.divergence``), or None."""
        if self.replicated:
            return divergence(self.algos[0], logs, replica)
        return divergence(self.algos[replica], logs)

    def state_dict(self) -> Any:
        state = [algo.state_dict() for algo in self.algos]
        return state[0] if len(state) == 1 else {"learners": state, "streams": self.streams.state_dict()}

    def load_state_dict(self, state: Any) -> None:
        if len(self.algos) == 1:
            self.algos[0].load_state_dict(state)
            return
        for algo, held in zip(self.algos, state["learners"]):
            algo.load_state_dict(held)
        self.streams.load_state_dict(state["streams"])
