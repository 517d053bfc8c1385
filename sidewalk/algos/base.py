"""What every learner shares: a config dataclass, a policy to collect with, one to evaluate with, an update step.

A learner is one file plus one YAML: it subclasses ``Algorithm``, declares its ``Config`` dataclass (the defaults
are the paper's or the reference implementation's, stated where they come from) and implements ``_build``,
``collection_policy``, ``evaluation_policy`` and ``update``. The experiment loop owns the env, the collector,
the replay buffer (for learners with ``uses_replay_buffer``), the logger and the checkpoints.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sidewalk._checks import check_int, check_range
from sidewalk.envs.base import AGENT_GROUP
from sidewalk.registry import LEARNERS


@dataclass
class AlgoConfig:
    """Settings every learner has. ``frames_per_batch`` is one collector batch, i.e. one training iteration, collected
    from ``default_num_envs`` worlds stepped together unless the experiment's ``num_envs`` says otherwise (as
    BenchMARL gives on- and off-policy learners their own number of environments). ``default_iterations`` and
    ``default_eval_every`` are the length of a run and its evaluation period when the experiment does not set them:
    a learner whose iteration holds more frames needs fewer of them."""

    name: str = "?"
    frames_per_batch: int = 256
    default_num_envs: int = 32
    default_iterations: int = 500
    default_eval_every: int = 50
    gamma: float = 0.99
    lr: float = 3e-4
    max_grad_norm: float = 10.0

    def __post_init__(self) -> None:
        check_int("algo.frames_per_batch", self.frames_per_batch, 1)
        check_int("algo.default_num_envs", self.default_num_envs, 1)
        check_int("algo.default_iterations", self.default_iterations, 1)
        check_int("algo.default_eval_every", self.default_eval_every, 0)
        check_range("algo.gamma", self.gamma, 0.0, 1.0)
        check_range("algo.lr", self.lr, 0.0, 1.0, low_open=True)
        check_range("algo.max_grad_norm", self.max_grad_norm, 0.0, low_open=True)


class FixedExplorationPolicy(TensorDictModuleBase):
    """Runs ``actor`` under ``exploration_type`` whatever the caller's context: a collection policy that always
    samples, an evaluation policy that always takes the distribution's deterministic value."""

    def __init__(self, actor: TensorDictModuleBase, exploration_type: ExplorationType) -> None:
        super().__init__()
        self.actor = actor
        self.exploration_type = exploration_type
        self.in_keys = list(actor.in_keys)
        self.out_keys = list(actor.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        with set_exploration_type(self.exploration_type):
            return self.actor(tensordict)


class StochasticActorPolicies:
    """The two policies of a learner whose ``actor`` is a distribution (PPO, TRPO and theirs): sampling it to
    collect, its deterministic value to evaluate. Mixed in before ``Algorithm``; ``_build`` calls
    ``_build_policies`` once ``self.actor`` exists."""

    def _build_policies(self) -> None:
        self._collection = FixedExplorationPolicy(self.actor, ExplorationType.RANDOM)
        self._evaluation = FixedExplorationPolicy(self.actor, ExplorationType.DETERMINISTIC)

    def collection_policy(self) -> TensorDictModuleBase:
        return self._collection

    def evaluation_policy(self) -> TensorDictModuleBase:
        return self._evaluation


class Algorithm(abc.ABC):
    """A learner for a single-agent TorchRL env (a view of the Sidewalk with flat keys).

    ``env`` provides the specs, used unbatched: ``observation`` (an image or a vector), ``action``
    (Categorical or Bounded), ``reward``, ``done``/``terminated``. The modules live on ``device``.
    """

    name: ClassVar[str | None] = None  # the config choice (``algo=NAME``); a class with a name registers itself
    domains: ClassVar[tuple[str, ...]] = ()  # the domains it learns in
    Config: ClassVar[type[AlgoConfig]] = AlgoConfig
    uses_replay_buffer: ClassVar[bool] = False
    multi_agent: ClassVar[bool] = False  # trains every agent on the self-play view (opponent=self)
    replicable: ClassVar[bool] = False  # trains R replicas as one (``replicas=R``); else they run one after another

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__ and cls.name is not None:
            if cls.Config().name != cls.name:
                raise TypeError(f"{cls.__qualname__}.name={cls.name!r} but its Config's name is {cls.Config().name!r}")
            LEARNERS.register(cls.name, cls)

    def __init__(
        self, config: AlgoConfig, env: EnvBase, device: torch.device | str = "cpu", replicas: int | None = None
    ) -> None:
        """``replicas=R``: R independent copies of the learner in one (``sidewalk.algos.replicas``), its networks and
        batches with a leading replica axis; None: one learner, no such axis."""
        self.config = config
        self.device = torch.device(device)
        self.replicas = self._check_replicas(replicas)
        # Unbatched specs: per-sample shapes, as TorchRL's actors and losses expect them.
        self.observation_spec = env.full_observation_spec_unbatched["observation"]
        self.action_spec = env.full_action_spec_unbatched["action"]
        self.discrete_actions = not torch.is_floating_point(self.action_spec.zero())
        self.frames_seen = 0
        self._build(env)

    @property
    def lead(self) -> tuple[int, ...]:
        """The leading replica axis of its batches and parameters: ``()`` alone, ``(R,)`` with R replicas."""
        return (self.replicas,) if self.replicas else ()

    def frames_in(self, batch: TensorDictBase) -> int:
        """The frames of one replica's share of ``batch`` (all of it for a lone learner)."""
        return batch.numel() // (self.replicas or 1)

    def _check_replicas(self, replicas: int | None) -> int | None:
        if replicas is not None and not self.replicable:
            raise ValueError(f"algo={self.name} has no replica axis; its replicas train one after another")
        return replicas

    @abc.abstractmethod
    def _build(self, env: EnvBase) -> None:
        """Create networks, losses and optimisers."""

    @abc.abstractmethod
    def collection_policy(self) -> TensorDictModuleBase:
        """The policy the collector runs: exploring (ε-greedy, sampling)."""

    @abc.abstractmethod
    def evaluation_policy(self) -> TensorDictModuleBase:
        """The policy evaluation runs: greedy / the distribution's mode."""

    @abc.abstractmethod
    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        """Learn from one collector batch (and the replay buffer, if used); return scalar logs."""

    def modules(self) -> dict[str, torch.nn.Module]:
        """Everything with state to checkpoint (networks, target networks, exploration schedules)."""
        return {}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {}

    def state_dict(self) -> dict[str, Any]:
        """The networks (``policy_state_dict``) and the optimisers' state: what a checkpoint keeps."""
        return {
            **self.policy_state_dict(),
            "optimizers": {name: opt.state_dict() for name, opt in self.optimizers().items()},
        }

    def policy_state_dict(self) -> dict[str, Any]:
        """The networks only (no optimiser state): what ``policy.pt`` keeps for evaluation and rendering."""
        return {"modules": {name: module.state_dict() for name, module in self.modules().items()},
                "frames_seen": self.frames_seen}

    def load_policy_state_dict(self, state: dict[str, Any]) -> None:
        for name, module in self.modules().items():
            module.load_state_dict(state["modules"][name])
        self.frames_seen = state["frames_seen"]

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.load_policy_state_dict(state)
        for name, opt in self.optimizers().items():
            opt.load_state_dict(state["optimizers"][name])


@dataclass
class MultiAgentConfig(AlgoConfig):
    """Settings every multi-agent learner adds: ``share_params`` -- one set of network weights for every agent (each
    agent's observation is ego-centric, so one network can play any of them), or one set per agent."""

    share_params: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.share_params, bool):
            raise TypeError(f"algo.share_params={self.share_params!r} must be a bool")


class MultiAgentAlgorithm(Algorithm):
    """A learner of every agent at once, on the self-play view (``sidewalk.views.SelfPlayView``, ``opponent=self``).

    Keys are TorchRL's multi-agent ones: ``("agents", "observation")`` ``(N, *obs)``, ``("agents", "info", "mask")``
    (the agent's value is still open: the step carries learning signal) and ``("agents", "action")`` in,
    ``("agents", "reward")`` and ``("agents", "done"|"terminated")`` (each agent's own end) out. The unbatched specs
    below keep the agent dimension first: ``observation_spec.shape == (N, *obs)``, ``action_spec.shape == (N,)``
    (grid) or ``(N, 2)`` (continuous). ``n_agents`` is N.
    """

    multi_agent: ClassVar[bool] = True
    OBSERVATION_KEY: ClassVar[tuple[str, str]] = (AGENT_GROUP, "observation")
    ACTION_KEY: ClassVar[tuple[str, str]] = (AGENT_GROUP, "action")
    REWARD_KEY: ClassVar[tuple[str, str]] = (AGENT_GROUP, "reward")
    DONE_KEY: ClassVar[tuple[str, str]] = (AGENT_GROUP, "done")
    TERMINATED_KEY: ClassVar[tuple[str, str]] = (AGENT_GROUP, "terminated")
    MASK_KEY: ClassVar[tuple[str, str, str]] = (AGENT_GROUP, "info", "mask")

    def __init__(
        self, config: AlgoConfig, env: EnvBase, device: torch.device | str = "cpu", replicas: int | None = None
    ) -> None:
        if self.ACTION_KEY not in env.full_action_spec.keys(True, True):
            raise ValueError(
                f"{type(self).__name__} trains every agent: it needs the self-play view (opponent=self), whose "
                f"action is {self.ACTION_KEY}; this env's actions are {list(env.full_action_spec.keys(True, True))}"
            )
        self.config = config
        self.device = torch.device(device)
        self.replicas = self._check_replicas(replicas)
        self.observation_spec = env.full_observation_spec_unbatched[self.OBSERVATION_KEY]
        self.action_spec = env.full_action_spec_unbatched[self.ACTION_KEY]
        self.n_agents = int(self.observation_spec.shape[0])
        self.discrete_actions = not torch.is_floating_point(self.action_spec.zero())
        self.frames_seen = 0
        self._build(env)
