"""How a learner sees the Sidewalk game: against a scripted opponent, as one joint controller, or as all agents.

Three views of one batched core env (``DiscreteSidewalkEnv`` or ``ContinuousSidewalkEnv`` with B worlds):

- ``EgoView(env, opponent, ego)``: one learning agent; the others are played by a scripted opponent. Keys are
  flat single-agent ones, so stock single-agent TorchRL losses (``DQNLoss``, ``ClipPPOLoss``) work unchanged.
- ``CentralizedView(env)``: the learner plays every agent through one joint action and receives the team reward.
- ``SelfPlayView(env)``: every agent is the learner (``opponent=self``): TorchRL's multi-agent keys
  ``("agents", ...)``, each agent with its own life cycle and a mask of the steps that carry learning signal (see
  the class), for the multi-agent learners (IPPO, MAPPO, IQL, VDN, QMIX);
- the all-agents view is the multi-agent core env itself (``make_view("all", env)`` returns it).

Every view takes ``shield=True``: before the core steps, the safety shield (the core's ``shield_action``, a one-step
look-ahead on the known dynamics) replaces the learner's actions that would collide -- the ego's in an ego view,
every agent's in the others -- with the nearest safe ones. The shield is part of the environment the learner sees:
the learner's own action stays in its data, and its evaluation runs shielded too.

The wrappers are thin ``EnvBase`` subclasses over the core's tensors: one step is a fixed sequence of tensor
operations for all B worlds, and the specs are built once. They carry the same ``"world"`` group for evaluation
and plots (every agent, in agent order, batch shape (B, N)):

- ``("world", "state")`` / ``("world", "goal")``: the true state and goal of every agent (no observation noise);
- ``("world", "present")``: the agent occupies space (moving, or parked at its goal; not crashed and removed);
- ``("world", "reward")``: every agent's own reward of the step, (B, N, 1), zero on reset;
- ``("world", "cost")``: every agent's safety cost of the step (the core's ``("agents", "cost")``), (B, N, 1);
- ``("world", "shield")`` (only with ``shield=True``): bool (B, N, 1), the shield replaced that agent's action in the
  step (``SidewalkEnvBase.shield_action``);
- ``("world", "info", k)`` for ``k`` in ``INFO_KEYS`` (``reached_goal``, ``collided_agent``, ``collided_wall``,
  ``timed_out``): the sticky per-episode outcome flags, (B, N, 1) bool.

The ego view adds ``("info", k)``, the ego agent's own flags, (B, 1) bool, so ``ego/success_rate`` reads
``("info", "reached_goal")`` and ``other/...`` reads ``("world", "info", k)`` at the other agents' indices.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from sidewalk._checks import check_choice, check_int
from sidewalk.envs.base import AGENT_GROUP, INFO_KEYS, SidewalkEnvBase, swap_in_reset
from sidewalk.opponents.base import Opponent, env_domain
from sidewalk.symmetry import check_mirror_symmetric, mirror_action, mirror_observation

VIEW_KINDS = ("ego", "centralized", "self", "all")
WORLD = "world"
# Opponent name -> (module, class). Modules are imported on first use, so a planner that is not installed (or not
# written yet) costs nothing until it is asked for.
OPPONENTS: dict[str, tuple[str, str]] = {
    "random": ("sidewalk.opponents.random", "RandomOpponent"),
    "dijkstra": ("sidewalk.opponents.dijkstra", "DijkstraOpponent"),
    "prm": ("sidewalk.opponents.prm", "PRMOpponent"),
}
# Beyond this many joint actions (5 grid agents) a Categorical head is impractical; the all-agents view scales.
MAX_JOINT_ACTIONS = 4**5


def opponent_class(name: str) -> type[Opponent]:
    """The ``Opponent`` subclass registered under ``name``; raises naming the valid names or the missing module."""
    check_choice("opponent", name, OPPONENTS)
    module_name, class_name = OPPONENTS[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        if error.name != module_name:
            raise
        raise ValueError(
            f"opponent {name!r} is not available: its module {module_name} is not present"
        ) from error
    return getattr(module, class_name)


def available_opponents(domain: str | None = None) -> list[str]:
    """Names of the registered opponents whose module imports, optionally only those playing ``domain``."""
    names = []
    for name in OPPONENTS:
        try:
            cls = opponent_class(name)
        except ValueError:
            continue
        if domain is None or domain in cls.domains:
            names.append(name)
    return names


def make_opponent(
    name: str, env: SidewalkEnvBase, controlled: tuple[int, ...] = (1,), ego: int | None = 0, **kwargs: Any
) -> Opponent:
    """Build the opponent registered as ``name`` for ``env``, playing the ``controlled`` agents against ``ego``;
    ``"policy"`` is a learned partner (``sidewalk.opponents.policy.PolicyOpponent``, ``path=RUN_DIR``).

    Raises ``ValueError`` for an unknown name (listing the valid ones), a planner module that is missing, or an
    opponent that does not play the env's domain (listing those that do).
    """
    if name == "policy":  # a learned partner, from the run folder kwargs["path"] (not a scripted opponent)
        from sidewalk.opponents.policy import PolicyOpponent

        return PolicyOpponent(env, controlled=controlled, ego=ego, **kwargs)
    cls = opponent_class(name)
    domain = env_domain(env)
    if domain not in cls.domains:
        raise ValueError(
            f"opponent {name!r} plays the {' and '.join(cls.domains)} domain, not {domain!r}; "
            f"opponents for the {domain} domain: {', '.join(map(repr, available_opponents(domain)))}"
        )
    return cls(env, controlled=controlled, ego=ego, **kwargs)


def _reset_rows(tensordict: TensorDictBase | None, batch_size: int, device: torch.device) -> torch.Tensor:
    """Bool (B,): the worlds a reset call asks for (``"_reset"`` of shape (B, 1)); all of them when absent."""
    if tensordict is not None:
        mask = tensordict.get("_reset", None)
        if mask is not None:
            return mask.reshape(batch_size, -1).any(-1)
    return torch.ones(batch_size, dtype=torch.bool, device=device)


class _SidewalkView(EnvBase):
    """What both wrappers share: the core env, seeding, the ``"world"`` group and the fast reset path.

    The core's ``_step``/``_reset`` are called directly (as ``TransformedEnv`` does with its base env), so a step
    costs one core step plus a few tensor selections. The core's last output is kept as ``self._last``: the core
    is stateful (its worlds live in its tensors), and an opponent reads the agents' state and done flags from it.
    """

    def __init__(self, env: SidewalkEnvBase, shield: bool = False) -> None:
        if not isinstance(env, SidewalkEnvBase):
            raise TypeError(
                f"env={env!r} must be a Sidewalk core env (DiscreteSidewalkEnv or ContinuousSidewalkEnv)"
            )
        if not isinstance(shield, bool):
            raise TypeError(f"shield={shield!r} must be a bool")
        super().__init__(device=env.device, batch_size=env.batch_size)
        self.shield = shield
        # The agents the shield guards: the learner's (every agent here; the ego view narrows it to the ego).
        self._shielded = torch.ones(env.n_agents, dtype=torch.bool, device=env.device)
        self._intervened: torch.Tensor | None = None
        self.core = env
        self.n_agents = env.n_agents
        self.num_envs = env.num_envs
        self.domain = env_domain(env)
        self._agents_shape = torch.Size((*env.batch_size, env.n_agents))
        self._last: TensorDictBase | None = None
        self._view_action_key: str | tuple[str, str] = "action"

    # ---- specs shared by the views -------------------------------------------------------------------------

    def _world_spec(self) -> Composite:
        core_agents = self.core.observation_spec[AGENT_GROUP]
        # The shield's flags are bool (B, N, 1), as the presence flags are.
        extra = {"shield": core_agents["present"].clone()} if self.shield else {}
        return Composite(
            **extra,
            state=core_agents["state"].clone(),
            goal=core_agents["goal"].clone(),
            present=core_agents["present"].clone(),
            reward=self.core.full_reward_spec[AGENT_GROUP, "reward"].clone(),
            cost=core_agents["cost"].clone(),
            info=core_agents["info"].clone(),
            shape=self._agents_shape,
            device=self.device,
        )

    def _global_done_spec(self) -> Composite:
        core_done = self.core.full_done_spec
        return Composite(
            {key: core_done[key].clone() for key in ("done", "terminated", "truncated")},
            shape=self.batch_size,
            device=self.device,
        )

    # ---- TorchRL interface ---------------------------------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        self.core._set_seed(seed)

    @property
    def generator(self) -> torch.Generator:
        """The core env's generator: the core, the opponent and the view all draw from it."""
        return self.core.generator

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        rows = _reset_rows(tensordict, self.num_envs, self.device)
        # The core reads the same root "_reset" mask and returns every world: reset ones fresh, the others as the
        # last step left them (observation noise included), so this view's output is complete too.
        core_out = self.core._reset(tensordict)
        self._on_reset(rows)
        self._intervened = None
        self._last = core_out
        return self._output(core_out, reset=True)

    def _reset_proc_data(self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase):
        # Like the core, _reset returns every world, so the reset output is swapped in rather than merged.
        return swap_in_reset(tensordict, tensordict_reset, self.reset_keys)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        last = self._last
        if last is None:
            raise RuntimeError(f"{type(self).__name__}.step() was called before reset()")
        last.set((AGENT_GROUP, "action"), self._joint_action(tensordict.get(self._view_action_key)))
        self._before_core_step(last)
        if self.shield:
            safe, self._intervened = self.core.shield_action(last.get((AGENT_GROUP, "action")), self._shielded)
            last.set((AGENT_GROUP, "action"), safe)
        core_out = self.core._step(last)
        self._last = core_out
        return self._output(core_out, reset=False)

    # ---- hooks for the views -------------------------------------------------------------------------------

    def _on_reset(self, rows: torch.Tensor) -> None:
        """Called with the bool (B,) mask of the worlds just reset."""

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        """The core's ("agents", "action") (B, N[, 2]) from the view's ``action``."""
        raise NotImplementedError

    def _before_core_step(self, core_in: TensorDictBase) -> None:
        """Last chance to fill in the core's input (the ego view's opponent writes its agents' actions)."""

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        raise NotImplementedError

    def _world(self, agents: TensorDictBase, reward: torch.Tensor) -> TensorDictBase:
        extra = {}
        if self.shield:
            intervened = self._intervened
            extra["shield"] = (
                intervened.unsqueeze(-1) if intervened is not None
                else torch.zeros((*self._agents_shape, 1), dtype=torch.bool, device=self.device)
            )
        return TensorDict._new_unsafe(
            {
                **extra,
                "state": agents.get("state"),
                "goal": agents.get("goal"),
                "present": agents.get("present"),
                "reward": reward,
                "cost": agents.get("cost"),
                "info": agents.get("info"),
            },
            batch_size=self._agents_shape,
        )

    def render(self, env_index: int = 0, **kwargs: Any):
        """The core's RGB rendering of world ``env_index`` (see the core env's ``render``)."""
        return self.core.render(env_index, **kwargs)


class EgoView(_SidewalkView):
    """One learning agent (``ego``) against a scripted opponent that plays every other agent, for all B worlds.

    Keys (batch shape (B,)): ``observation`` (the ego's observation, as the core gives it), ``action`` (the ego's
    action: Categorical(4) in the grid, Bounded (acceleration, turn) in the continuous world), ``reward`` (B, 1)
    (the ego's reward, cooperative term included), ``cost`` (B, 1) (the ego's safety cost of the step, 0 on reset),
    ``done``/``terminated``/``truncated`` (B, 1), the ego's outcome
    flags ``("info", k)`` (B, 1) and the ``"world"`` group of every agent (see the module docstring).

    By default the ego's episode is the world's: it ends when every agent is done or at the timeout, so rewards
    that reach the ego after it is done (the explicit cooperative reward for the other agent's arrival) still
    reach the learner. With ``end_on_ego_done=True`` the episode ends, and the world is reset, as soon as the ego
    is done; ``terminated``/``truncated`` are then the ego's own.

    ``opponent`` is a registered name (``"random"``, ``"dijkstra"`` for the grid, ``"prm"`` for the continuous
    world; see ``OPPONENTS``), built with ``opponent_kwargs``, or an ``Opponent`` already built on this ``env``
    that controls every agent but ``ego``. The opponent's ``reset(rows)`` is called whenever worlds reset.
    """

    def __init__(
        self,
        env: SidewalkEnvBase,
        opponent: str | Opponent = "random",
        ego: int = 0,
        end_on_ego_done: bool = False,
        opponent_kwargs: Mapping[str, Any] | None = None,
        shield: bool = False,
    ) -> None:
        super().__init__(env, shield=shield)
        check_int("ego", ego, 0, env.n_agents - 1)
        if not isinstance(end_on_ego_done, bool):
            raise TypeError(f"end_on_ego_done={end_on_ego_done!r} must be a bool")
        self.ego = ego
        self._shielded = torch.arange(env.n_agents, device=env.device) == ego
        self.others = tuple(agent for agent in range(env.n_agents) if agent != ego)
        self.end_on_ego_done = end_on_ego_done
        self.opponent = self._resolve_opponent(opponent, dict(opponent_kwargs or {}))
        self._make_spec()

    def _resolve_opponent(self, opponent: str | Opponent, kwargs: dict[str, Any]) -> Opponent:
        if isinstance(opponent, str):
            if opponent == "centralized":
                raise ValueError(
                    "opponent='centralized' means the learner plays every agent: use CentralizedView(env) or "
                    "make_view('centralized', env)"
                )
            return make_opponent(opponent, self.core, controlled=self.others, ego=self.ego, **kwargs)
        if kwargs:
            raise TypeError(f"opponent_kwargs={kwargs!r} apply only to an opponent given by name")
        if not isinstance(opponent, Opponent):
            raise TypeError(
                f"opponent={opponent!r} must be an Opponent or one of the names {', '.join(map(repr, OPPONENTS))}"
            )
        if opponent.env is not self.core:
            raise ValueError("the opponent was built on another env; build it on the env this view wraps")
        if sorted(opponent.controlled) != list(self.others):
            raise ValueError(
                f"the opponent controls agents {opponent.controlled}; "
                f"with ego={self.ego} it must control {list(self.others)}"
            )
        return opponent

    def _make_spec(self) -> None:
        core_agents = self.core.observation_spec[AGENT_GROUP]
        ego = self.ego
        self.observation_spec = Composite(
            observation=core_agents["observation"].unbind(1)[ego].clone(),
            cost=core_agents["cost"].unbind(1)[ego].clone(),
            info=core_agents["info"].unbind(1)[ego].clone(),
            world=self._world_spec(),
            shape=self.batch_size,
            device=self.device,
        )
        self.action_spec = self.core.full_action_spec[AGENT_GROUP, "action"].unbind(1)[ego].clone()
        self.reward_spec = Unbounded(shape=(*self.batch_size, 1), device=self.device)
        self.done_spec = self._global_done_spec()

    def _on_reset(self, rows: torch.Tensor) -> None:
        self.opponent.reset(rows)

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        # The other agents' columns are placeholders: the opponent overwrites them before the core steps.
        joint = action.new_zeros((*self._agents_shape, *action.shape[1:]))
        joint.select(1, self.ego).copy_(action)
        return joint

    def _before_core_step(self, core_in: TensorDictBase) -> None:
        self.opponent(core_in)

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        agents = core_out.get(AGENT_GROUP)
        ego = self.ego
        info = agents.get("info")
        reward = (
            agents.get("reward") if not reset else torch.zeros((*self._agents_shape, 1), device=self.device)
        )
        if self.end_on_ego_done:
            done_source, index = agents, (slice(None), ego)
        else:
            done_source, index = core_out, (slice(None),)
        # _new_unsafe skips validation that costs more than the view's own work at small batch sizes (the core does
        # the same); shapes are right by construction and check_env_specs covers them in the tests.
        out = TensorDict._new_unsafe(
            {
                "observation": agents.get("observation").select(1, ego),
                "cost": agents.get("cost").select(1, ego),
                "info": TensorDict._new_unsafe(
                    {key: info.get(key).select(1, ego) for key in INFO_KEYS}, batch_size=self.batch_size
                ),
                WORLD: self._world(agents, reward),
                "done": done_source.get("done")[index],
                "terminated": done_source.get("terminated")[index],
                "truncated": done_source.get("truncated")[index],
            },
            batch_size=self.batch_size,
        )
        if not reset:
            out.set("reward", reward.select(1, ego))
        return out


class CentralizedView(_SidewalkView):
    """The learner plays every agent through one joint action and receives the team reward, for all B worlds.

    - ``action``: in the grid, Categorical(4**N) over the product of the agents' action sets; the joint index is
      ``sum(a_i * 4**(N-1-i))``, i.e. ``a0 * 4 + a1`` for two agents (``a_i`` in UP, DOWN, LEFT, RIGHT order:
      index 6 = (DOWN, LEFT)); ``decode_action``/``encode_action`` convert. In the continuous world, the agents'
      (acceleration, turn) pairs concatenated, (B, 2N) Bounded: ``[a0_accel, a0_turn, a1_accel, a1_turn]``.
    - ``observation``: agent 0's observation (it shows every agent and goal).
    - ``reward`` (B, 1): the sum of the agents' rewards (each one's own reward, cooperative term included);
      ``("world", "reward")`` keeps them apart. ``cost`` (B, 1): the sum of the agents' safety costs, likewise.
    - ``done``/``terminated``/``truncated`` (B, 1): the world's.
    """

    def __init__(self, env: SidewalkEnvBase, shield: bool = False) -> None:
        super().__init__(env, shield=shield)
        core_action = self.core.full_action_spec[AGENT_GROUP, "action"]
        if self.domain == "discrete":
            n_moves = core_action.space.n
            n_joint = n_moves**self.n_agents
            if n_joint > MAX_JOINT_ACTIONS:
                raise ValueError(
                    f"{self.n_agents} agents make {n_joint} joint actions (more than {MAX_JOINT_ACTIONS}); "
                    "use the all-agents view (make_view('all', env)) for this many agents"
                )
            place = n_moves ** torch.arange(self.n_agents - 1, -1, -1, device=self.device)
            self._joint_place = place
            # Row j of the table is the per-agent action tuple of joint action j.
            self._decode_table = (torch.arange(n_joint, device=self.device)[:, None] // place) % n_moves
        self._make_spec()

    def _make_spec(self) -> None:
        core_agents = self.core.observation_spec[AGENT_GROUP]
        batch = self.batch_size
        self.observation_spec = Composite(
            observation=core_agents["observation"].unbind(1)[0].clone(),
            cost=core_agents["cost"].unbind(1)[0].clone(),
            world=self._world_spec(),
            shape=batch,
            device=self.device,
        )
        core_action = self.core.full_action_spec[AGENT_GROUP, "action"]
        if self.domain == "discrete":
            self.action_spec = Categorical(
                self._decode_table.shape[0], shape=batch, dtype=torch.long, device=self.device
            )
        else:
            low = core_action.space.low.reshape(*batch, -1)
            high = core_action.space.high.reshape(*batch, -1)
            self.action_spec = Bounded(
                low, high, shape=low.shape, dtype=core_action.dtype, device=self.device
            )
        self.reward_spec = Unbounded(shape=(*batch, 1), device=self.device)
        self.done_spec = self._global_done_spec()

    def decode_action(self, joint: torch.Tensor) -> torch.Tensor:
        """Per-agent actions (..., N) of grid joint indices (...); the inverse of ``encode_action``."""
        if self.domain != "discrete":
            raise ValueError(
                "decode_action applies to the discrete domain; continuous joint actions are concatenated"
            )
        return self._decode_table[joint]

    def encode_action(self, per_agent: torch.Tensor) -> torch.Tensor:
        """Grid joint indices (...) of per-agent actions (..., N): ``sum(a_i * 4**(N-1-i))``."""
        if self.domain != "discrete":
            raise ValueError(
                "encode_action applies to the discrete domain; continuous joint actions are concatenated"
            )
        return (per_agent * self._joint_place).sum(-1)

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        if self.domain == "discrete":
            return self._decode_table.index_select(0, action.reshape(-1)).view(self._agents_shape)
        return action.reshape(*self._agents_shape, -1)

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        agents = core_out.get(AGENT_GROUP)
        reward = (
            agents.get("reward") if not reset else torch.zeros((*self._agents_shape, 1), device=self.device)
        )
        out = TensorDict._new_unsafe(
            {
                "observation": agents.get("observation").select(1, 0),
                "cost": agents.get("cost").sum(1),
                WORLD: self._world(agents, reward),
                "done": core_out.get("done"),
                "terminated": core_out.get("terminated"),
                "truncated": core_out.get("truncated"),
            },
            batch_size=self.batch_size,
        )
        if not reset:
            out.set("reward", reward.sum(1))
        return out


class SelfPlayView(_SidewalkView):
    """Every agent is the learner (``opponent=self``): the core's multi-agent keys, for all B worlds.

    Keys (batch shape (B,), agents group (B, N)): ``("agents", "observation")`` (each agent's ego-centric
    observation), ``("agents", "action")``, ``("agents", "reward")`` (each agent's own reward, cooperative term
    included), ``("agents", "cost")`` (each agent's safety cost of the step), each agent's own life cycle
    ``("agents", "done"|"terminated"|"truncated")`` and ``("agents", "mask")``, the root ``done``/``terminated``/
    ``truncated`` (B, 1), plus the ``"world"`` group (see the module docstring).

    Each agent has its own life cycle, in TorchRL's multi-agent conventions (``docs/multiagent.md``):

    - a crash terminates the agent at its crash step: its return ends there (it is paid nothing afterwards);
    - an arrival keeps the agent's value open until the world ends, because eq. 2's cooperative reward for a partner
      who arrives later is still to come; the agent is terminated with the world (every agent arrived or crashed);
    - ``truncated``: the time limit, for every agent not terminated before it;
    - ``mask`` (``~done``, as TorchRL's PettingZoo wrapper's): the agent's value is still open at this state, so the
      step taken from it carries learning signal; learners leave the other steps out of every loss and statistic.

    The root ``done``/``terminated``/``truncated`` are the world's: every agent done, or the time limit. An agent's
    own outcome flags are in ``("world", "info")``; whether it still moves is in its observation (``active``).

    ``other_play=True`` (Other-Play, Hu et al. 2020): at every reset of a world each agent but agent 0 plays, with
    probability 1/2 drawn from the env's generator, through the mirror across the centre line
    (``sidewalk.symmetry``): it sees its observation mirrored and its action is mirrored back before the world steps.
    Its data stays in its own frame, so the learner needs no change, and the policy cannot rely on a convention that
    the mirror breaks. Refused for layouts the mirror does not map onto themselves.
    """

    def __init__(self, env: SidewalkEnvBase, shield: bool = False, other_play: bool = False) -> None:
        super().__init__(env, shield=shield)
        if not isinstance(other_play, bool):
            raise TypeError(f"other_play={other_play!r} must be a bool")
        if other_play:
            check_mirror_symmetric(env.layout)
        self.other_play = other_play
        # (B, N) bool: the agent plays this episode through the mirror; agent 0 never does.
        self._mirrored = torch.zeros(self._agents_shape, dtype=torch.bool, device=self.device)
        self._view_action_key = (AGENT_GROUP, "action")
        self._make_spec()

    def _make_spec(self) -> None:
        core_agents = self.core.observation_spec[AGENT_GROUP]
        agents_shape = self._agents_shape
        done = self.core.full_done_spec
        agent_done = {key: done[AGENT_GROUP, key].clone() for key in ("done", "terminated", "truncated")}
        self.observation_spec = Composite(
            {AGENT_GROUP: Composite(observation=core_agents["observation"].clone(),
                                    cost=core_agents["cost"].clone(), mask=core_agents["present"].clone(),
                                    shape=agents_shape, device=self.device),
             WORLD: self._world_spec()},
            shape=self.batch_size,
            device=self.device,
        )
        self.action_spec = Composite(
            {AGENT_GROUP: Composite(action=self.core.full_action_spec[AGENT_GROUP, "action"].clone(),
                                    shape=agents_shape, device=self.device)},
            shape=self.batch_size,
            device=self.device,
        )
        self.reward_spec = Composite(
            {AGENT_GROUP: Composite(reward=self.core.full_reward_spec[AGENT_GROUP, "reward"].clone(),
                                    shape=agents_shape, device=self.device)},
            shape=self.batch_size,
            device=self.device,
        )
        self.done_spec = Composite(
            {**{key: done[key].clone() for key in ("done", "terminated", "truncated")},
             AGENT_GROUP: Composite(agent_done, shape=agents_shape, device=self.device)},
            shape=self.batch_size,
            device=self.device,
        )

    def _on_reset(self, rows: torch.Tensor) -> None:
        if self.other_play:
            # Drawn for every world and kept for the reset ones: the stream does not depend on which worlds reset.
            draw = torch.rand(self._agents_shape, generator=self.generator, device=self.device) < 0.5
            draw[:, 0] = False
            self._mirrored = torch.where(rows.unsqueeze(-1), draw, self._mirrored)

    def _where_mirrored(self, value: torch.Tensor, mirrored_value: torch.Tensor) -> torch.Tensor:
        """Per agent (B, N, ...): ``mirrored_value`` where the agent plays through the mirror, else ``value``."""
        mirrored = self._mirrored.view(*self._mirrored.shape, *([1] * (value.dim() - 2)))
        return torch.where(mirrored, mirrored_value, value)

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        if not self.other_play:
            return action
        return self._where_mirrored(action, mirror_action(action, self.domain))

    def _observation(self, agents: TensorDictBase) -> torch.Tensor:
        observation = agents.get("observation")
        if not self.other_play:
            return observation
        return self._where_mirrored(observation, mirror_observation(observation, self.core.layout))

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        agents = core_out.get(AGENT_GROUP)
        reward = (
            agents.get("reward") if not reset else torch.zeros((*self._agents_shape, 1), device=self.device)
        )
        info = agents.get("info")
        crashed = info.get("collided_agent") | info.get("collided_wall")
        flags = {key: core_out.get(key) for key in ("done", "terminated", "truncated")}
        terminated = crashed | flags["terminated"].unsqueeze(1).expand(*self._agents_shape, 1)
        truncated = flags["truncated"].unsqueeze(1) & ~crashed
        done = terminated | truncated
        group = {
            "observation": self._observation(agents), "cost": agents.get("cost"),
            "done": done, "terminated": terminated, "truncated": truncated, "mask": ~done,
        }
        if not reset:
            group["reward"] = reward
        return TensorDict._new_unsafe(
            {
                AGENT_GROUP: TensorDict._new_unsafe(group, batch_size=self._agents_shape),
                WORLD: self._world(agents, reward),
                **flags,
            },
            batch_size=self.batch_size,
        )


class ScriptedTeam(TensorDictModuleBase):
    """One scripted opponent playing every agent as one team, seen as an ego view and a policy of it.

    ``ScriptedTeam(env, name)`` builds the opponent registered as ``name`` controlling every agent (the ego first),
    ``team.view`` is an ``EgoView`` of ``env`` and ``team`` itself is the policy of its ego: evaluation treats the
    team like a learner with its partners (``sidewalk.evaluate``). Each step plans all agents at once -- the
    policy plans, the view's opponent replays the plan for the others -- so a planner that coordinates the agents
    it controls (Dijkstra's moves in agent order) coordinates the whole team. The scenarios' scripted baselines
    (``runners/baselines.py``) use it.
    """

    def __init__(self, env: SidewalkEnvBase, name: str, ego: int = 0, **kwargs: Any) -> None:
        super().__init__()
        check_int("ego", ego, 0, env.n_agents - 1)
        others = tuple(agent for agent in range(env.n_agents) if agent != ego)
        self.planner = make_opponent(name, env, controlled=(ego, *others), ego=None, **kwargs)
        self.in_keys = [(WORLD, "state"), (WORLD, "goal"), (WORLD, "present"), (WORLD, "info")]
        self.out_keys = ["action"]
        self._planned: torch.Tensor | None = None
        self.view = EgoView(env, _PlannedOthers(self, env, others, ego), ego=ego)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        world = tensordict.get(WORLD)
        info = world.get("info")
        done = info.get("reached_goal") | info.get("collided_agent") | info.get("collided_wall") | info.get("timed_out")
        self._planned = self.planner.act(world.get("state"), world.get("goal"), done, world.get("present"))
        tensordict.set("action", self._planned.select(1, 0))
        return tensordict


class _PlannedOthers(Opponent):
    """The other agents' share of the ``ScriptedTeam``'s last plan."""

    def __init__(self, team: ScriptedTeam, env: SidewalkEnvBase, others: tuple[int, ...], ego: int) -> None:
        super().__init__(env, controlled=others, ego=ego)
        self._team = [team]  # a list: not a registered submodule (the team holds this opponent already)

    def act(self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        planned = self._team[0]._planned
        if planned is None:
            raise RuntimeError("ScriptedTeam: the view stepped before its policy planned")
        return planned[:, 1:]


def make_view(
    kind: str,
    env: SidewalkEnvBase,
    opponent: str | Opponent | None = None,
    ego: int | None = None,
    shield: bool = False,
    **kwargs: Any,
) -> EnvBase:
    """The view ``kind`` of ``env``: ``"ego"`` (``EgoView``; ``opponent`` defaults to ``"random"``, ``kwargs`` go
    to ``EgoView``), ``"centralized"`` (``CentralizedView``), ``"self"`` (``SelfPlayView``) or ``"all"`` (the
    multi-agent core env itself).

    ``opponent`` and ``ego`` (default 0) apply only to ``"ego"``; giving either to another view is an error, as is
    an opponent that does not play the env's domain. ``shield=True`` shields the learner's actions (every view but
    ``"all"``, the bare core, which has no learner to shield).
    """
    check_choice("kind", kind, VIEW_KINDS)
    if not isinstance(env, SidewalkEnvBase):
        raise TypeError(
            f"env={env!r} must be a Sidewalk core env (DiscreteSidewalkEnv or ContinuousSidewalkEnv)"
        )
    if kind == "ego":
        return EgoView(
            env, opponent="random" if opponent is None else opponent, ego=0 if ego is None else ego, shield=shield,
            **kwargs,
        )
    if opponent is not None and not (kind == "centralized" and opponent == "centralized"):
        raise ValueError(
            f"the {kind!r} view has no opponent (the learner plays every agent); got opponent={opponent!r}"
        )
    if ego is not None:
        raise ValueError(
            f"the {kind!r} view has no ego agent (the learner plays every agent); got ego={ego!r}"
        )
    if kwargs:
        raise TypeError(f"unexpected argument(s) {', '.join(map(repr, kwargs))} for the {kind!r} view")
    if kind == "centralized":
        return CentralizedView(env, shield=shield)
    if kind == "self":
        return SelfPlayView(env, shield=shield)
    if shield:
        raise ValueError(
            "shield=True: the 'all' view is the bare core env; call env.shield_action, or use kind='self'"
        )
    return env
