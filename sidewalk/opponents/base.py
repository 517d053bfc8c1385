"""The common shape of every opponent: a TensorDict module that plays some agents of a Sidewalk env, and the
registry of opponents by name (``sidewalk.registry.OPPONENTS``), which every subclass with a ``name`` joins.

On a replicated env (several seeds in one core, ``env.replicas`` > 1) ``make_opponent`` gives each replica's worlds the
play a lone env of that seed would get, as each opponent class declares (``per_replica``, ``batch_invariant``): one
opponent for every world, or a ``ReplicaOpponent`` that hands each replica's block of worlds to its own opponent."""

from __future__ import annotations

import inspect
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from sidewalk._checks import check_int
from sidewalk.envs.base import AGENT_GROUP, SidewalkEnvBase
from sidewalk.opponents.replicas import ReplicaEnv
from sidewalk.registry import OPPONENTS

STATE_KEY = (AGENT_GROUP, "state")
GOAL_KEY = (AGENT_GROUP, "goal")
DONE_KEY = (AGENT_GROUP, "done")
ACTION_KEY = (AGENT_GROUP, "action")
PRESENT_KEY = (AGENT_GROUP, "present")


class Opponent(TensorDictModuleBase):
    """Writes the actions of the ``controlled`` agents into ``("agents", "action")``, for all worlds at once.

    An opponent reads only what the env exposes: the true state and goals of every agent, who is done, the
    layout and the env's parameters, and it draws randomness from ``env.generator`` (or per world through
    ``env.rand``/``env.randint``) so that one seed fixes a run.
    ``ego`` names the agent it plays against (the learner), or ``None``. Entries of agents it does not control
    are left as they are, so an opponent can fill in around a learner's action.

    Subclasses implement ``act(state, goal, done, present=None)`` returning the controlled agents' actions, shape
    (B, C) for the grid or (B, C, 2) for the continuous world (``present`` (B, N, 1): who occupies space, as the
    env publishes it; ``None`` where a caller has only state, goal and done), and may override ``reset(rows)`` to drop
    per-world memory (a planner's warm start) of the worlds in the bool mask ``rows`` (B,).
    """

    name: ClassVar[str | None] = None  # the config choice (``opponent=NAME``); a class with a name registers itself
    domains: ClassVar[tuple[str, ...]] = ("discrete", "continuous")  # the domains it plays
    scripted: ClassVar[bool] = True  # False: a learned partner, which needs a run folder to play
    # False: chosen by name only, left out of the default lists (``available_opponents(scripted_only=True)``:
    # cross-play's "scripted" columns, the benchmarks), which hold the paper's opponents.
    listed: ClassVar[bool] = True
    # On a replicated env: True builds one instance per replica, on a ReplicaEnv (that replica's worlds and generator),
    # for opponents that draw from env.generator or build something from the env's seed; False: one instance for all
    # replicas (it draws nothing, or draws through env.rand/env.randint, which split the worlds by replica).
    per_replica: ClassVar[bool] = True
    # True: one call plays every replica's worlds exactly as each replica's lone env would (per-world arithmetic);
    # False (a network, whose kernels round differently at other batch sizes): each replica's block gets its own call.
    batch_invariant: ClassVar[bool] = False
    # Attributes a checkpoint leaves out (``sidewalk.snapshot``): scratch tensors rewritten before they are read.
    scratch: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__ and cls.name is not None:
            OPPONENTS.register(cls.name, cls)

    def __init__(self, env: SidewalkEnvBase, controlled: Sequence[int] = (1,), ego: int | None = 0) -> None:
        super().__init__()
        domain = env_domain(env)
        if domain not in self.domains:
            raise ValueError(
                f"opponent {type(self).__name__} plays the {' and '.join(self.domains)} domain(s), not {domain!r}"
            )
        self.controlled = [int(a) for a in controlled]
        for agent in self.controlled:
            check_int("controlled agent", agent, 0, env.n_agents - 1)
        if ego is not None:
            check_int("ego", ego, 0, env.n_agents - 1)
            if ego in self.controlled:
                raise ValueError(f"ego={ego} cannot also be a controlled agent {self.controlled}")
        self.env = env
        self.ego = ego
        self.in_keys = [STATE_KEY, GOAL_KEY, DONE_KEY]
        self.out_keys = [ACTION_KEY]
        self._controlled_index = torch.tensor(self.controlled, dtype=torch.long, device=env.device)
        # Opponents written before the env published "present" implement act(state, goal, done): they still work.
        self._act_takes_present = "present" in inspect.signature(self.act).parameters

    def __repr__(self) -> str:
        # The env by its class only: its own repr lists every spec.
        return (f"{type(self).__name__}(controlled={self.controlled}, ego={self.ego}, env={type(self.env).__name__}, "
                f"in_keys={self.in_keys}, out_keys={self.out_keys})")

    @classmethod
    def replicated(cls, **kwargs: Any) -> bool:
        """Whether an opponent built with ``kwargs`` needs an instance per replica: ``per_replica``, unless a class
        lets its arguments decide (the PRM's roadmap comes from the env's seed only without a ``roadmap_seed``)."""
        return cls.per_replica

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        raise NotImplementedError

    def present(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Bool (B, N): who occupies space -- the env's ``("agents", "present")`` (B, N, 1) when given, else what
        ``inferred_present`` makes of state, goal and done (callers that hold only those)."""
        if present is not None:
            return present.squeeze(-1)
        return self.inferred_present(state, goal, done)

    def inferred_present(self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Bool (B, N): presence as the opponent infers it without the env's flag; by default, not done."""
        return ~done.squeeze(-1)

    def reset(self, rows: torch.Tensor | None = None) -> None:
        """Forget per-world memory of the worlds in ``rows`` (all worlds if ``None``)."""

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        inputs = [tensordict.get(STATE_KEY), tensordict.get(GOAL_KEY), tensordict.get(DONE_KEY)]
        if self._act_takes_present:
            inputs.append(tensordict.get(PRESENT_KEY, None))
        action = self.act(*inputs)
        joint = tensordict.get(ACTION_KEY, None)
        if joint is None:
            joint = self.env.full_action_spec[ACTION_KEY].zero()
        else:
            joint = joint.clone()
        joint.index_copy_(1, self._controlled_index, action.to(joint.dtype))
        tensordict.set(ACTION_KEY, joint)
        return tensordict


class ReplicaOpponent(Opponent):
    """Plays a replicated env (``env.replicas`` R > 1) with one opponent per replica: ``opponents[r]`` gets replica
    ``r``'s block of B worlds (``act``, ``forward``, ``reset``), and the blocks' actions are concatenated in world
    order. ``opponents`` are built on each replica's ``ReplicaEnv``, or are one instance on the whole env listed R
    times (a network played block by block, so that each call has a lone env's batch). ``make_opponent`` builds it."""

    def __init__(
        self, env: SidewalkEnvBase, opponents: Sequence[Opponent], controlled: Sequence[int] = (1,), ego: int | None = 0
    ) -> None:
        super().__init__(env, controlled, ego)
        if len(opponents) != env.replicas:
            raise ValueError(f"{len(opponents)} opponents for an env of {env.replicas} replicas")
        self.opponents = torch.nn.ModuleList(opponents)
        self.in_keys = list(opponents[0].in_keys)
        self._blocks = env.replica_blocks()

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        actions = []
        for opponent, block in zip(self.opponents, self._blocks):
            inputs = [state[block], goal[block], done[block]]
            if opponent._act_takes_present:
                inputs.append(None if present is None else present[block])
            actions.append(opponent.act(*inputs))
        return torch.cat(actions)

    def reset(self, rows: torch.Tensor | None = None) -> None:
        for opponent, block in zip(self.opponents, self._blocks):
            opponent.reset(None if rows is None else rows[block])

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        # Each opponent's own forward on its block (a learned partner reads observations, not act's inputs), every
        # block given the joint action to fill in.
        if tensordict.get(ACTION_KEY, None) is None:
            tensordict.set(ACTION_KEY, self.env.full_action_spec[ACTION_KEY].zero())
        joints = [opponent(tensordict[block]).get(ACTION_KEY) for opponent, block in zip(self.opponents, self._blocks)]
        tensordict.set(ACTION_KEY, torch.cat(joints))
        return tensordict


def env_domain(env: SidewalkEnvBase | ReplicaEnv) -> str:
    """``"discrete"`` or ``"continuous"`` (a replica's proxy: its core's)."""
    from sidewalk.envs.grid import DiscreteSidewalkEnv

    if isinstance(env, ReplicaEnv):
        env = env.core
    return "discrete" if isinstance(env, DiscreteSidewalkEnv) else "continuous"


# What every opponent's constructor takes before its own settings.
OPPONENT_PLACES = ("self", "env", "controlled", "ego")


def opponent_config(name: str, given: Mapping[str, Any]) -> dict[str, Any]:
    """The opponent ``name``'s settings as it plays with ``given``: its constructor's defaults overridden by
    ``given`` (every setting named, so that a changed default shows); ``given`` itself for a name no opponent has
    (``centralized``). Two partners are the same where their names and these settings are."""
    if name not in OPPONENTS:
        return dict(given)
    parameters = inspect.signature(OPPONENTS[name].__init__).parameters.values()
    defaults = {p.name: p.default for p in parameters
                if p.name not in OPPONENT_PLACES and p.default is not inspect.Parameter.empty}
    return {**defaults, **given}


def opponent_class(name: str) -> type[Opponent]:
    """The ``Opponent`` subclass registered as ``name``; raises ``ValueError`` naming the valid names."""
    return OPPONENTS[name]


def available_opponents(domain: str | None = None, scripted_only: bool = False) -> list[str]:
    """Names of the registered opponents, optionally only those playing ``domain``, or only the scripted ones
    that the default lists hold (``listed``)."""
    return OPPONENTS.names(
        lambda cls: (domain is None or domain in cls.domains) and (not scripted_only or (cls.scripted and cls.listed))
    )


def make_opponent(
    name: str, env: SidewalkEnvBase, /, controlled: Sequence[int] = (1,), ego: int | None = 0, **kwargs: Any
) -> Opponent:
    """Build the opponent registered as ``name`` for ``env``, playing the ``controlled`` agents against ``ego``
    (``"policy"``: a learned partner, ``path=RUN_DIR``; ``name`` and ``env`` are positional only, so that an opponent
    may take a setting called ``name``: ``make_opponent("zoo", env, name="keep_left")``). Raises ``ValueError`` for an
    unknown name (listing the valid ones) or an opponent that does not play the env's domain (listing those that do).

    On a replicated env (``env.replicas`` > 1) every replica's worlds are played as a lone env of its seed would
    play them: by one opponent for all worlds when the class needs no instance per replica and is batch-invariant
    (scripted planners: planned once for all), else by a ``ReplicaOpponent``."""
    cls = opponent_class(name)
    domain = env_domain(env)
    if domain not in cls.domains:
        raise ValueError(
            f"opponent {name!r} plays the {' and '.join(cls.domains)} domain, not {domain!r}; "
            f"opponents for the {domain} domain: {', '.join(map(repr, available_opponents(domain)))}"
        )
    replicas = getattr(env, "replicas", 1)
    per_replica = cls.replicated(**kwargs)
    if replicas == 1 or (not per_replica and cls.batch_invariant):
        return cls(env, controlled=controlled, ego=ego, **kwargs)
    if per_replica:
        opponents = [cls(ReplicaEnv(env, r), controlled=controlled, ego=ego, **kwargs) for r in range(replicas)]
    else:
        opponents = [cls(env, controlled=controlled, ego=ego, **kwargs)] * replicas
    return ReplicaOpponent(env, opponents, controlled=controlled, ego=ego)
