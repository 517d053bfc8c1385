"""What both Sidewalk domains share: the TorchRL specs, the agents' life cycle, rewards, timeout, resets, seeding.

A subclass supplies the dynamics through four hooks, VMAS-style:

- ``_init_world()``: allocate the world's state tensors for ``self.batch_size`` worlds, among them ``_present``
  (B, N) bool, which the base publishes as ``("agents", "present")``;
- ``_reset_world(reset)``: put the worlds selected by the bool mask ``reset`` (B, N) -- all of a world's agents
  alike -- back at their start;
- ``_advance(action, active)``: move the agents one step and report, per agent (B, N), who reached its goal,
  who hit a wall, who hit another agent, and the shaping term of the step;
- ``_centres()`` and ``_near(gap_sq)``: the agents' centres and whether two are within ``near_miss_margin``, from
  which the base finds the near misses of a step (``cost="near_miss"``);
- ``_observe(worlds)``: the per-agent entries ``observation``, ``state`` and ``goal`` of every world (``worlds`` None)
  or of the rows ``worlds`` (int64 (k,)) only: on a partial reset the base computes the worlds just reset and gives
  every other world back exactly what the last output gave it. Random draws (observation noise) stay those of
  every world, whichever worlds reset, so that a seed fixes them.

Replicas (``seed`` a sequence of R seeds): the env holds R independent copies of one experiment, replica ``r`` owning
the worlds ``[r·B, (r+1)·B)`` (B = ``num_envs // R``) and its own generator, seeded with its seed. Every per-world
random draw goes through ``rand``/``randint``/``sample_layout``, which draw each replica's block from its own
generator exactly as a lone env of that seed and B worlds would, so replica ``r``'s worlds step bit for bit like that
lone env; with one replica they are today's single draws. A reset draws only for the replicas with a world reset (a
lone env is reset only when one of its worlds is), and every world it skips keeps the last output, cost included.

Masks are materialised at (B, N) before use: mixing (B, N) with (B, 1) operands takes a broadcasting path that is
several times slower than same-shape operands at thousands of worlds.

Every world lives in tensors of shape (B, N, ...) and one step is a fixed sequence of tensor operations for all
worlds at once: there is no Python loop over worlds or agents.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, TensorSpec, Unbounded
from torchrl.envs import EnvBase

from sidewalk._checks import check_int, replace_checked
from sidewalk._torchrl import new_tensordict_unchecked
from sidewalk.envs.actions import ActionCheck
from sidewalk.envs.rewards import RewardParams, compose_reward

AGENT_GROUP = "agents"
# What ``render`` can return: an RGB array (no window: the worlds are drawn off-screen).
RENDER_MODES = ("rgb_array",)
# Each agent's sticky outcome flags and their words, in the order an outcome is told (the first flag set).
OUTCOME_WORDS = {"reached_goal": "reached the goal", "collided_agent": "hit another agent", "collided_wall": "hit a wall",
                 "timed_out": "timed out"}
INFO_KEYS = tuple(OUTCOME_WORDS)
# What the per-step safety cost ("agents", "cost") counts (env.cost): collisions only, or near misses too.
COSTS = ("collision", "near_miss")
HUGE_PAGE_BYTES = 4 << 20  # NumPy advises huge pages for arrays from 4 MiB on


def crashed(info: Any) -> Any:
    """Per agent, whether it hit another agent or a wall, from its outcome flags (a dict or TensorDict of them)."""
    return info["collided_agent"] | info["collided_wall"]


def new_output(
    shape: tuple[int, ...], dtype: torch.dtype, device: torch.device, stride: tuple[int, ...] | None = None
) -> torch.Tensor:
    """An uninitialised tensor for a large output of a step, contiguous or with the (positive) ``stride`` given.
    On the CPU, from 4 MiB on, its memory is NumPy's: NumPy asks Linux for transparent huge pages (madvise), so the
    first write into a fresh batch of images takes far fewer page faults than with 4 KiB pages (torch's allocator
    asks for huge pages only under THP_MEM_ALLOC_ENABLE=1)."""
    if stride is None or math.prod(shape) == 0:
        stride = torch.empty(shape, device="meta").stride()
    extent = 1 + sum((size - 1) * step for size, step in zip(shape, stride)) if math.prod(shape) else 0
    if torch.device(device).type != "cpu" or extent * dtype.itemsize < HUGE_PAGE_BYTES:
        return torch.empty_strided(shape, stride, dtype=dtype, device=device)
    memory = torch.from_numpy(np.empty(extent, dtype=torch.empty((), dtype=dtype).numpy().dtype))
    return memory.as_strided(shape, stride)


def _replica_seeds(seed: Any, num_envs: int) -> list[int] | None:
    """The replicas' seeds that ``seed`` gives (None: an int or None, one replica), checked against ``num_envs``."""
    if seed is None or not isinstance(seed, Sequence) or isinstance(seed, str):
        return None
    seeds = list(seed)
    if not seeds:
        raise ValueError("seed=[]: give one seed per replica (at least one)")
    for value in seeds:
        check_int("seed", value)
    if num_envs % len(seeds):
        raise ValueError(
            f"num_envs={num_envs} is not divisible by the {len(seeds)} replicas of seed={seeds}: num_envs counts the "
            "worlds of every replica together"
        )
    return seeds


def swap_in_reset(
    tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase, reset_keys: list
) -> TensorDictBase:
    """Merge a reset output that covers every world into the running tensordict.

    Our envs' ``_reset`` returns every world (the reset ones fresh, the others exactly as the last step left them)
    with every done key (False where reset), so TorchRL's masked merge -- a ``where`` over every entry, images
    included -- and its done completion and checks reduce to swapping in the new entries. Keys others put beside
    ours (a policy's recurrent state, ...) stay, at the root and inside our groups.
    """
    if tensordict is None:
        return tensordict_reset
    for key in reset_keys:
        tensordict.pop(key, None)
    for key, fresh in tensordict_reset.items():
        previous = tensordict.get(key, None)
        if isinstance(previous, TensorDictBase) and isinstance(fresh, TensorDictBase):
            # .keys(): a tensordict iterates over its first batch dimension, not its keys.
            for inner in previous.keys():  # noqa: SIM118
                if inner not in fresh.keys():  # noqa: SIM118
                    fresh.set(inner, previous.get(inner))
        tensordict.set(key, fresh)
    return tensordict


def _spec_text(leaf: TensorSpec) -> str:
    """A spec leaf in a few words: its kind and values, dtype and shape."""
    if isinstance(leaf, Categorical):
        kind = f"Categorical(n={leaf.space.n})"
    elif isinstance(leaf, Bounded):
        low, high = leaf.space.low, leaf.space.high
        if bool((low == low.reshape(-1)[0]).all() and (high == high.reshape(-1)[0]).all()):
            kind = f"Bounded({low.reshape(-1)[0].item():.4g}, {high.reshape(-1)[0].item():.4g})"
        else:  # bounds that vary along the last axis only (a continuous action's)
            rows = [", ".join(f"{x:.4g}" for x in bound.reshape(-1, bound.shape[-1])[0].tolist()) for bound in (low, high)]
            kind = f"Bounded(low=[{rows[0]}], high=[{rows[1]}])"
    else:
        kind = "Unbounded" if isinstance(leaf, Unbounded) else type(leaf).__name__
    return f"{kind} {str(leaf.dtype).removeprefix('torch.')} {tuple(leaf.shape)}"


def spec_lines(env: EnvBase) -> list[str]:
    """``env``'s specs as TorchRL's ``full_*_spec`` hold them, one leaf a line: key, kind and values, dtype, shape."""
    lines = []
    for name in ("observation", "action", "reward", "done"):
        lines.append(f"{name}_spec:")
        for key, leaf in getattr(env, f"full_{name}_spec").items(include_nested=True, leaves_only=True):
            lines.append(f"  {key!r}: {_spec_text(leaf)}")
    return lines


class SidewalkEnvBase(EnvBase):
    """A batch of ``num_envs`` Sidewalk worlds as one multi-agent TorchRL environment.

    Keys follow TorchRL's multi-agent layout: the group ``"agents"`` (batch shape (B, N)) holds
    ``observation``, ``state`` (the true state, before observation noise), ``goal``, ``present`` (the agent
    occupies space in the world: moving, or parked at its goal; not crashed and removed), ``action``, ``reward``,
    ``cost`` (the safety cost of the step, float (B, N, 1): 1 when the agent collided with a wall or another agent
    in the step, with ``cost="near_miss"`` also when it ended the step within ``near_miss_margin`` of another agent,
    else 0; only agents not yet done pay it; 0 on reset),
    per-agent ``done``/``terminated``/``truncated`` and ``info`` (sticky per-episode outcome flags
    ``reached_goal``, ``collided_agent``, ``collided_wall``, ``timed_out``); the root holds the global
    ``done``/``terminated``/``truncated`` (shape (B, 1)).

    An agent is *terminated* once it reaches its goal or collides, and then no longer moves; a world is
    terminated when all its agents are, and truncated when ``max_steps`` steps pass first. Parameters come
    as keyword overrides of the domain's ``Params`` dataclass; an unknown name or a bad value raises before
    anything is built.

    ``seed`` is an int (or None: a fresh random seed), or a sequence of R ints: the env then holds R replicas, replica
    ``r`` owning the ``worlds_per_replica`` worlds ``[r·B, (r+1)·B)`` of the ``num_envs`` (a multiple of R) and drawing
    from ``generators[r]``, seeded with ``seed[r]``: its worlds step bit for bit as a lone env of that seed and B
    worlds (see the module docstring). ``seed=[s]`` is ``seed=s``.
    """

    Params: ClassVar[type]
    ACTION_LABELS: ClassVar[tuple[str, ...]] = ()  # the names of a discrete action's values, for error messages
    # The name in RewardParams of the weight of the domain's shaping term; None: the domain weighs its terms itself.
    shaping_weight_name: ClassVar[str | None]
    # Observation kinds the env can compute for a partner whatever its own ``params.observation``: a learned partner
    # trained on one of them plays in this env (sidewalk.partners.policy), reading it from ``observe_as`` applied to
    # the output's ``PARTNER_OBSERVATION_KEYS``.
    PARTNER_OBSERVATIONS: ClassVar[tuple[str, ...]] = ()
    PARTNER_OBSERVATION_KEYS: ClassVar[tuple[tuple[str, str], ...]] = ()

    def __init__(
        self,
        num_envs: int = 1,
        *,
        device: str | torch.device = "cpu",
        seed: int | Sequence[int] | None = None,
        params: Any = None,
        **overrides: Any,
    ) -> None:
        check_int("num_envs", num_envs, 1)
        seeds = _replica_seeds(seed, num_envs)
        if params is None:
            overrides = self.with_room(overrides)
        if isinstance(overrides.get("rewards"), Mapping):
            overrides["rewards"] = replace_checked(RewardParams(), overrides["rewards"], "rewards")
        self.params = replace_checked(params if params is not None else self.Params(), overrides, type(self).__name__)
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.num_envs = num_envs
        self.layout = self._make_layout()
        self.n_agents = self.layout.n_agents
        self.replicas = 1 if seeds is None else len(seeds)
        self.worlds_per_replica = num_envs // self.replicas
        self.generators = [torch.Generator(device=self.device) for _ in range(self.replicas)]
        self._generator = self.generators[0]
        self._set_seed(seed if seeds is None else seeds)

        rewards: RewardParams = self.params.rewards
        self._shaping_mask = rewards.shaping_mask(self.n_agents, self.device)
        self._shaping_weight = 1.0 if self.shaping_weight_name is None else float(getattr(rewards, self.shaping_weight_name))

        shape = (num_envs, self.n_agents)
        self._active = torch.zeros(shape, dtype=torch.bool, device=self.device)
        self._status = {key: torch.zeros(shape, dtype=torch.bool, device=self.device) for key in INFO_KEYS}
        self._steps = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        # The observation, state and goal entries of the last output; a partial reset recomputes only its worlds.
        self._last_observed: dict[str, torch.Tensor] | None = None
        self._last_cost: torch.Tensor | None = None  # the last output's cost, which worlds a reset skips keep
        # (N, N, 1): pairs of two different agents, for pairwise checks run agent-major, (N, N, B): broadcasting over
        # a long last axis is faster than over a trailing axis of 2 agents.
        self._not_self = ~torch.eye(self.n_agents, dtype=torch.bool, device=self.device).unsqueeze(-1)
        self._init_world()
        self._make_spec()

    # ---- hooks for the domains -------------------------------------------------------------------------------

    def _make_layout(self) -> Any:
        raise NotImplementedError

    def _init_world(self) -> None:
        raise NotImplementedError

    def _reset_world(self, reset: torch.Tensor) -> None:
        raise NotImplementedError

    def _advance(
        self, action: torch.Tensor, active: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def _observe(self, worlds: torch.Tensor | None) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def _centres(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The agents' centres as two float (N, B) planes, agent-major (grid: row, col; continuous: x, y)."""
        raise NotImplementedError

    def _near(self, gap_sq: torch.Tensor) -> torch.Tensor:
        """Bool, elementwise: centres ``gap_sq`` (squared distance) apart are within the near-miss margin."""
        raise NotImplementedError

    def _near_miss(self) -> torch.Tensor:
        """Bool (B, N): the agent is in the world and another agent in the world is near it (``_near``)."""
        first, second = self._centres()
        gap_sq = (first.unsqueeze(1) - first.unsqueeze(0)).square() + (second.unsqueeze(1) - second.unsqueeze(0)).square()
        near = self._near(gap_sq) & self._present.t().unsqueeze(0) & self._not_self
        return near.any(1).t() & self._present

    def shield_action(self, action: torch.Tensor, shielded: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The safety shield (``shield=true``): the joint action ``action`` (B, N[, 2]) about to be stepped, with
        every agent's action that a one-step look-ahead on the known dynamics finds unsafe replaced by the nearest
        safe one, for the agents marked in ``shielded`` (bool (N,)); and bool (B, N): where it replaced one. Only
        agents still moving are shielded. The domains define safe: no wall hit, and no contact with any other
        agent wherever that agent can be after the step (its worst case)."""
        raise NotImplementedError

    def _agent_specs(self) -> tuple[dict[str, Any], Any]:
        """The per-agent observation specs (``observation``, ``state``, ``goal``) and the action spec."""
        raise NotImplementedError

    # ---- specs ------------------------------------------------------------------------------------------------

    def _make_spec(self) -> None:
        batch, agents = self.batch_size, (*self.batch_size, self.n_agents)
        observation_specs, action_spec = self._agent_specs()

        def flag(shape: tuple[int, ...]) -> Categorical:
            return Categorical(2, shape=(*shape, 1), dtype=torch.bool, device=self.device)

        info = Composite({key: flag(agents) for key in INFO_KEYS}, shape=agents, device=self.device)
        cost = Unbounded(shape=(*agents, 1), device=self.device)
        agent_specs = {**observation_specs, "present": flag(agents), "cost": cost, "info": info}
        self.observation_spec = Composite(
            {AGENT_GROUP: Composite(agent_specs, shape=agents, device=self.device)},
            shape=batch,
            device=self.device,
        )
        self.action_spec = Composite(
            {AGENT_GROUP: Composite(action=action_spec, shape=agents, device=self.device)},
            shape=batch,
            device=self.device,
        )
        # The grid's actions are indices, always checked; a continuous one's finiteness is the check_actions switch.
        self._check_action = ActionCheck(action_spec, (AGENT_GROUP, "action"), type(self).__name__,
                                         labels=self.ACTION_LABELS,
                                         check_finite=getattr(self.params, "check_actions", True))
        self.reward_spec = Composite(
            {
                AGENT_GROUP: Composite(
                    reward=Unbounded(shape=(*agents, 1), device=self.device), shape=agents, device=self.device
                )
            },
            shape=batch,
            device=self.device,
        )
        done_leaves = ("done", "terminated", "truncated")
        self.done_spec = Composite(
            {
                AGENT_GROUP: Composite({k: flag(agents) for k in done_leaves}, shape=agents, device=self.device),
                **{k: flag(batch) for k in done_leaves},
            },
            shape=batch,
            device=self.device,
        )

    # ---- TorchRL interface --------------------------------------------------------------------------------------

    def _set_seed(self, seed: int | Sequence[int] | None) -> None:
        """Seed the generator (one replica: an int, or None for a fresh random seed), or each replica's with its own
        seed (R replicas: a sequence of R ints; through TorchRL, ``env.set_seed(seeds, static_seed=True)``)."""
        if isinstance(seed, Sequence) and not isinstance(seed, str):
            if len(seed) != self.replicas:
                raise ValueError(f"{len(seed)} seeds {list(seed)} for an env of {self.replicas} replicas")
            for generator, replica_seed in zip(self.generators, seed):
                generator.manual_seed(int(replica_seed))
        elif self.replicas > 1:
            raise ValueError(
                f"seed={seed!r}: an env of {self.replicas} replicas takes a sequence of {self.replicas} seeds, one per "
                "replica (env.set_seed([...], static_seed=True))"
            )
        elif seed is None:
            self._generator.seed()
        else:
            self._generator.manual_seed(int(seed))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        rows = self._rows_to_reset(tensordict)
        reset = rows.unsqueeze(-1).expand(self.num_envs, self.n_agents).contiguous()
        self._reset_world(reset)
        self._active = self._active | reset
        keep = ~reset
        for key, status in self._status.items():
            self._status[key] = status & keep
        self._steps = self._steps.masked_fill(rows, 0)
        return self._output(None, rows)

    def _step_proc_data(self, next_tensordict_out: TensorDictBase) -> TensorDictBase:
        # _step emits every done key and the reward in its spec's shape, so TorchRL's completion and reshaping
        # pass (as costly as the grid's dynamics) has nothing to do; its type checks stay opt-in.
        if self.run_type_checks:
            return super()._step_proc_data(next_tensordict_out)
        return next_tensordict_out

    def _reset_proc_data(self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase):
        return swap_in_reset(tensordict, tensordict_reset, self.reset_keys)

    def _rows_to_reset(self, tensordict: TensorDictBase | None) -> torch.Tensor:
        """Bool (B,): the worlds a reset call asks for. A per-agent ``_reset`` resets the agents' whole world."""
        if tensordict is not None:
            mask = tensordict.get("_reset", None)
            if mask is None:
                mask = tensordict.get((AGENT_GROUP, "_reset"), None)
            if mask is not None:
                return mask.reshape(self.num_envs, -1).any(-1)
        return torch.ones(self.num_envs, dtype=torch.bool, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get((AGENT_GROUP, "action"), None)
        self._check_action(action, tensordict)
        active = self._active
        reached_now, hit_wall_now, hit_agent_now, shaping_term = self._advance(action, active)
        collided_now = hit_wall_now | hit_agent_now
        status = self._status
        status["reached_goal"] = status["reached_goal"] | reached_now
        status["collided_wall"] = status["collided_wall"] | hit_wall_now
        status["collided_agent"] = status["collided_agent"] | hit_agent_now
        reward = compose_reward(
            self.params.rewards,
            self._shaping_mask,
            active,
            reached_now,
            collided_now,
            crashed(status),
            shaping_term,
            self._shaping_weight,
        )
        cost = collided_now
        if self.params.cost == "near_miss":
            cost = cost | (active & self._near_miss())
        self._active = active = active & ~(reached_now | collided_now)
        self._steps = self._steps + 1
        return self._output(reward, None, cost)

    def _observations(self, rows: torch.Tensor | None) -> dict[str, torch.Tensor]:
        """``_observe``'s entries of every world; on a reset (``rows``: bool (B,), the worlds reset) only the reset
        worlds are observed anew, the others keep the last output's (with auto-reset a few worlds reset a step, and
        observing all of them again cost as much as the step). Out of place: the caller holds the last output."""
        last = self._last_observed
        if rows is None or last is None:
            entries = self._observe(None)
        else:
            worlds = rows.nonzero().squeeze(-1)
            if worlds.numel() == self.num_envs:
                entries = self._observe(None)
            else:
                entries = {}
                for key, value in self._observe(worlds).items():
                    # Laid out as the last output (the grid's images skip a spare pixel): the copy runs row by row
                    # and every image batch of the env has one size, which the allocator reuses.
                    held = last[key]
                    stride = held.stride() if all(step > 0 for step in held.stride()) else None
                    entries[key] = new_output(held.shape, held.dtype, self.device, stride).copy_(held)
                    entries[key].index_copy_(0, worlds, value)
        self._last_observed = entries
        return dict(entries)

    def _output(
        self, reward: torch.Tensor | None, rows: torch.Tensor | None, cost: torch.Tensor | None = None
    ) -> TensorDictBase:
        """The env's output for every world, from the current state; ``rows`` (B,) marks the worlds a reset reset;
        ``cost`` (B, N) bool: who paid the safety cost in the step (None on reset: nobody in the worlds reset, the
        others keep the last step's)."""
        agents_shape = torch.Size((*self.batch_size, self.n_agents))
        terminated = ~self._active
        all_terminated = terminated.all(-1)
        timeout = self._steps >= self.params.max_steps
        truncated = self._active & timeout.unsqueeze(-1).expand(agents_shape).contiguous()
        if reward is not None:
            self._status["timed_out"] = self._status["timed_out"] | truncated
        world_truncated = timeout & ~all_terminated
        entries = self._observations(rows)
        entries["present"] = self._present.unsqueeze(-1)
        if cost is not None:
            entries["cost"] = cost.to(torch.float32).unsqueeze(-1)
        elif rows is None or self._last_cost is None:
            entries["cost"] = torch.zeros((*agents_shape, 1), device=self.device)
        else:
            # Worlds a partial reset skips keep the last step's output, cost included, as a lone env's would.
            entries["cost"] = self._last_cost.masked_fill(rows.view(-1, 1, 1), 0.0)
        self._last_cost = entries["cost"]
        entries["info"] = new_tensordict_unchecked(
            {key: value.unsqueeze(-1) for key, value in self._status.items()}, batch_size=agents_shape
        )
        entries["terminated"] = terminated.unsqueeze(-1)
        entries["truncated"] = truncated.unsqueeze(-1)
        entries["done"] = (terminated | truncated).unsqueeze(-1)
        if reward is not None:
            entries["reward"] = reward.unsqueeze(-1)
        all_terminated = all_terminated.unsqueeze(-1)
        world_truncated = world_truncated.unsqueeze(-1)
        # new_tensordict_unchecked skips validation that costs more than the step itself at small batch sizes; the
        # shapes are right by construction and check_env_specs covers them in the tests.
        return new_tensordict_unchecked(
            {
                AGENT_GROUP: new_tensordict_unchecked(entries, batch_size=agents_shape),
                "terminated": all_terminated,
                "truncated": world_truncated,
                "done": all_terminated | world_truncated,
            },
            batch_size=self.batch_size,
        )

    # ---- conveniences -------------------------------------------------------------------------------------------

    def extra_repr(self) -> str:
        # nn.Module's repr (EnvBase has none of its own) shows only this: the worlds, then every spec.
        layout = self.params.layout if isinstance(self.params.layout, str) else type(self.params.layout).__name__
        head = (f"num_envs={self.num_envs}, n_agents={self.n_agents}, layout={layout!r}, replicas={self.replicas}, "
                f"device={self.device}")
        return "\n".join([head, *spec_lines(self)])

    STATE_WIDTH: ClassVar[int]  # numbers per agent in ``global_state``
    room_sides: tuple[str, str]  # the names of the room's two sides in ``Params``, in ``_room``'s order

    @classmethod
    def with_room(cls, overrides: Mapping[str, Any]) -> dict[str, Any]:
        """``overrides`` of ``Params`` with the room's sides that were left out set for the named layout and its
        agents: the default room wherever it holds them (every result there stays as it was), else the scenario's
        own room (``_room``). A side the user gives stays, too small or not (the layout then refuses it)."""
        if all(side in overrides for side in cls.room_sides):
            return dict(overrides)
        # Checked as the env checks them, so that a bad value raises the same error (rewards: checked there).
        p = replace_checked(cls.Params(), {k: v for k, v in overrides.items() if k != "rewards"}, cls.__name__)
        if not isinstance(p.layout, str):
            return dict(overrides)
        default = cls.Params()
        sides = cls._room(p, tuple(overrides.get(side) for side in cls.room_sides),
                          tuple(getattr(default, side) for side in cls.room_sides))
        return {**overrides, **dict(zip(cls.room_sides, sides, strict=True))}

    @staticmethod
    def _room(p: Any, given: tuple[Any, Any], default: tuple[Any, Any]) -> tuple[Any, Any]:
        """The room's two sides for params ``p``: ``given`` where not None, else the layout's choice."""
        raise NotImplementedError

    @property
    def max_steps(self) -> int:
        """The time limit: a world not terminated after this many steps is truncated."""
        return self.params.max_steps

    def global_state(self, agents: TensorDictBase) -> torch.Tensor:
        """The true world as one vector per world, (..., N·``STATE_WIDTH``) float32, from an agents group's
        ``state``, ``goal`` and ``present`` (..., N, ·): every agent's fields scaled to about [0, 1] and its presence
        flag, in agent order. No agent observes it whole: it is the input of a centralised critic or a mixer (the
        self-play view's root ``"state"``, where TorchRL's PettingZoo wrapper puts a global state)."""
        features = self._state_features(agents.get("state"), agents.get("goal"))
        return torch.cat([features, agents.get("present").to(torch.float32)], dim=-1).flatten(-2)

    def global_state_spec(self) -> Unbounded:
        """The spec of ``global_state`` for the env's worlds, (B, N·``STATE_WIDTH``)."""
        return Unbounded(shape=(*self.batch_size, self.n_agents * self.STATE_WIDTH), device=self.device)

    def _state_features(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """``global_state``'s fields of each agent but its presence flag, (..., N, ``STATE_WIDTH`` - 1)."""
        raise NotImplementedError

    @property
    def agent_names(self) -> list[str]:
        """The agents' names in agent order, ``agent_0``, ``agent_1``, ... (the PettingZoo API's too)."""
        return [f"agent_{index}" for index in range(self.n_agents)]

    @property
    def group_map(self) -> dict[str, list[str]]:
        """TorchRL's multi-agent group map, as its VMAS and PettingZoo wrappers give it: every agent in the
        ``"agents"`` group."""
        return {AGENT_GROUP: self.agent_names}

    @property
    def generator(self) -> torch.Generator:
        """The first replica's generator: with one replica, the env's, from which opponents and views may draw so that
        one seed fixes everything. With several replicas every per-world draw must go through ``rand``/``randint``
        (or an opponent built per replica, whose env proxy holds its replica's generator)."""
        return self._generator

    # ---- per-world random draws, replica by replica ---------------------------------------------------------

    def rand(self, shape: Sequence[int], rows: torch.Tensor | None = None) -> torch.Tensor:
        """Uniform [0, 1) float32 of ``shape``, whose first dimension is the worlds (``num_envs``). One replica:
        ``torch.rand(shape, generator=env.generator)``. R replicas: each draws its (B, ...) block from its own
        generator; with ``rows`` (bool (num_envs,): the worlds that use the draw, as on a partial reset) only the
        replicas holding one of those rows draw (a lone env is reset only when one of its worlds is), the other
        blocks are zeros."""
        return self._draw(torch.rand, (), torch.float32, shape, rows)

    def randint(self, high: int, shape: Sequence[int], rows: torch.Tensor | None = None) -> torch.Tensor:
        """Uniform int64 in [0, ``high``) of ``shape``, drawn replica by replica as ``rand`` draws."""
        return self._draw(torch.randint, (high,), torch.int64, shape, rows)

    def _draw(
        self, draw: Any, args: tuple, dtype: torch.dtype, shape: Sequence[int], rows: torch.Tensor | None
    ) -> torch.Tensor:
        shape = torch.Size(shape)
        if self.replicas == 1:
            return draw(*args, shape, generator=self._generator, device=self.device)
        if shape[0] != self.num_envs:
            raise ValueError(f"a per-world draw of shape {tuple(shape)} on an env of {self.num_envs} worlds")
        block = (self.worlds_per_replica, *shape[1:])
        drawing = self.replicas_of(rows)
        return torch.cat([
            draw(*args, block, generator=generator, device=self.device) if drawing[r]
            else torch.zeros(block, dtype=dtype, device=self.device)
            for r, generator in enumerate(self.generators)
        ])

    def replica_blocks(self) -> list[slice]:
        """Each replica's worlds, in replica order: slices of the world dimension."""
        size = self.worlds_per_replica
        return [slice(replica * size, (replica + 1) * size) for replica in range(self.replicas)]

    def replicas_of(self, rows: torch.Tensor | None) -> list[bool]:
        """Per replica, whether it holds one of the worlds ``rows`` (bool (num_envs,); None: every world)."""
        if rows is None:
            return [True] * self.replicas
        return rows.view(self.replicas, self.worlds_per_replica).any(1).tolist()

    def sample_layout(self, worlds: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """A random layout's draws (``layout.sample``) for the worlds ``worlds`` (int64 (k,), ascending): one call
        for one replica; else one per replica holding some of them, on its generator, concatenated in world order."""
        if self.replicas == 1:
            return self.layout.sample(worlds.numel(), self._generator)
        counts = torch.bincount(worlds // self.worlds_per_replica, minlength=self.replicas).tolist()
        parts = [self.layout.sample(count, generator) for count, generator in zip(counts, self.generators) if count]
        if not parts:
            return self.layout.sample(0, self._generator)
        return tuple(torch.cat(pieces) for pieces in zip(*parts))

    def params_dict(self) -> dict[str, Any]:
        """The env's parameters as a plain (nested) dict, for logging and config files."""
        return dataclasses.asdict(self.params)
