"""Every agent is the learner: TorchRL's multi-agent keys, each agent with its own life cycle."""

from __future__ import annotations

import warnings

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite

from sidewalk._torchrl import new_tensordict_unchecked
from sidewalk.envs.base import AGENT_GROUP, SidewalkEnvBase, crashed
from sidewalk.symmetry import (
    check_mirror_symmetric,
    mirror_action,
    mirror_observation,
    role_turns,
    turn_action,
    turn_observation,
)
from sidewalk.views.base import WORLD, _SidewalkView


class SelfPlayView(_SidewalkView):
    """Every agent is the learner (``opponent=self``): the core's multi-agent keys, for all B worlds.

    Keys (batch shape (B,), agents group (B, N)), in TorchRL's multi-agent conventions as its VMAS wrapper gives
    them: ``("agents", "observation")`` (each agent's ego-centric observation, the group's only input entry),
    ``("agents", "action")``, ``("agents", "reward")`` (each agent's own reward, cooperative term included), each
    agent's own life cycle ``("agents", "done"|"terminated"|"truncated")``, and under ``("agents", "info")`` what is
    not an input: the outcome flags ``INFO_KEYS`` (sticky, bool (B, N, 1)), ``cost`` (the agent's safety cost of the
    step) and ``mask`` (below); the root ``done``/``terminated``/``truncated`` (B, 1) and ``state`` (B, N·k: the true
    world, ``SidewalkEnvBase.global_state``, for a centralised critic or a mixer); plus the ``"world"`` group (see the
    module docstring).

    ``legacy_keys=True`` (deprecated, removed in sidewalk 0.3) also writes the earlier places of the cost and the mask,
    ``("agents", "cost")`` and ``("agents", "mask")``, and warns (``DeprecationWarning``).

    Each agent has its own life cycle, in TorchRL's multi-agent conventions (``docs/multiagent.md``):

    - a crash terminates the agent at its crash step: its return ends there (it is paid nothing afterwards);
    - an arrival keeps the agent's value open until the world ends, because eq. 2's cooperative reward for a partner
      who arrives later is still to come; the agent is terminated with the world (every agent arrived or crashed);
    - ``truncated``: the time limit, for every agent not terminated before it;
    - ``("agents", "info", "mask")`` (``~done``, as TorchRL's PettingZoo wrapper's ``mask``): the agent's value is
      still open at this state, so the step taken from it carries learning signal; learners leave the other steps out
      of every loss and statistic.

    The root ``done``/``terminated``/``truncated`` are the world's: every agent done, or the time limit. An agent's
    own outcome flags are in ``("world", "info")``; whether it still moves is in its observation (``active``).

    ``other_play=True`` (Other-Play, Hu et al. 2020): at every reset of a world each agent but agent 0 plays, with
    probability 1/2 drawn from the env's generator, through the mirror across the centre line
    (``sidewalk.symmetry``): it sees its observation mirrored and its action is mirrored back before the world steps.
    Its data stays in its own frame, so the learner needs no change, and the policy cannot rely on a convention that
    the mirror breaks. Refused for layouts the mirror does not map onto themselves.

    ``role_frame=True``: every agent sees the game from agent 0's role. In a layout a half turn maps onto itself and
    agent 0's start and goal onto agent j's (``sidewalk.symmetry.role_map``: the two-agent sidewalk), agent j
    sees its observation turned by half a turn and its action is turned back (``sidewalk.symmetry``), as a learned
    partner playing another role does. One shared policy then takes one action in two situations that mirror each
    other, and that action moves the two apart (each steps to its own side), where in the world's frame the same
    action of both keeps them face to face: the greedy pair's standoff. Refused where some agent's role has no map.
    """

    def __init__(
        self, env: SidewalkEnvBase, shield: bool = False, other_play: bool = False, legacy_keys: bool = False,
        role_frame: bool = False,
    ) -> None:
        super().__init__(env, shield=shield)
        if not isinstance(legacy_keys, bool):
            raise TypeError(f"legacy_keys={legacy_keys!r} must be a bool")
        if legacy_keys:
            warnings.warn(
                "SelfPlayView(legacy_keys=True) also writes ('agents', 'cost') and ('agents', 'mask'), deprecated and "
                "removed in sidewalk 0.3: read ('agents', 'info', 'cost') and ('agents', 'info', 'mask')",
                DeprecationWarning,
                stacklevel=3,  # the caller's line, past TorchRL's EnvBase metaclass __call__
            )
        self.legacy_keys = legacy_keys
        if not isinstance(other_play, bool):
            raise TypeError(f"other_play={other_play!r} must be a bool")
        if other_play:
            check_mirror_symmetric(env.layout)
        self.other_play = other_play
        if not isinstance(role_frame, bool):
            raise TypeError(f"role_frame={role_frame!r} must be a bool")
        self.role_frame = role_frame
        # (N,) bool: the agent plays through the half turn (role_frame); agent 0 never does.
        turns = role_turns(self.domain, env.params) if role_frame else [False] * env.n_agents
        self._turned = torch.tensor(turns, device=self.device)
        # (B, N) bool: the agent plays this episode through the mirror; agent 0 never does.
        self._mirrored = torch.zeros(self._agents_shape, dtype=torch.bool, device=self.device)
        self._view_action_key = (AGENT_GROUP, "action")
        self._make_spec()

    @property
    def group_map(self) -> dict[str, list[str]]:
        """TorchRL's multi-agent group map: every agent in the ``"agents"`` group (the core's)."""
        return self.core.group_map

    def _make_spec(self) -> None:
        core_agents = self.core.observation_spec[AGENT_GROUP]
        agents_shape = self._agents_shape
        done = self.core.full_done_spec
        agent_done = {key: done[AGENT_GROUP, key].clone() for key in ("done", "terminated", "truncated")}
        info = core_agents["info"].clone()
        info.update({"cost": core_agents["cost"].clone(), "mask": core_agents["present"].clone()})
        group = {"observation": core_agents["observation"].clone(), "info": info}
        if self.legacy_keys:
            group.update(cost=info["cost"].clone(), mask=info["mask"].clone())
        self.observation_spec = Composite(
            {AGENT_GROUP: Composite(group, shape=agents_shape, device=self.device),
             "state": self.core.global_state_spec(), WORLD: self._world_spec()},
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
            # Drawn for every world (of each replica with a world reset) and kept for the reset ones: the stream does
            # not depend on which worlds reset.
            draw = self.core.rand(self._agents_shape, rows) < 0.5
            draw[:, 0] = False
            self._mirrored = torch.where(rows.unsqueeze(-1), draw, self._mirrored)

    def _where_turned(self, value: torch.Tensor, turned_value: torch.Tensor) -> torch.Tensor:
        """Per agent (B, N, ...): ``turned_value`` where the agent plays through the half turn, else ``value``."""
        return torch.where(self._turned.view(1, -1, *([1] * (value.dim() - 2))), turned_value, value)

    def _where_mirrored(self, value: torch.Tensor, mirrored_value: torch.Tensor) -> torch.Tensor:
        """Per agent (B, N, ...): ``mirrored_value`` where the agent plays through the mirror, else ``value``."""
        mirrored = self._mirrored.view(*self._mirrored.shape, *([1] * (value.dim() - 2)))
        return torch.where(mirrored, mirrored_value, value)

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        if self.other_play:
            action = self._where_mirrored(action, mirror_action(action, self.domain))
        if self.role_frame:
            action = self._where_turned(action, turn_action(action, self.domain))
        return action

    def _observation(self, agents: TensorDictBase) -> torch.Tensor:
        observation = agents.get("observation")
        if self.role_frame:  # the half turn and the mirror commute: the order is the action's, reversed
            observation = self._where_turned(observation, turn_observation(observation, self.core.layout))
        if self.other_play:
            observation = self._where_mirrored(observation, mirror_observation(observation, self.core.layout))
        return observation

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        agents = core_out.get(AGENT_GROUP)
        reward = self._world_reward(agents, reset)
        info = agents.get("info")
        crash = crashed(info)
        flags = {key: core_out.get(key) for key in ("done", "terminated", "truncated")}
        terminated = crash | flags["terminated"].unsqueeze(1).expand(*self._agents_shape, 1)
        truncated = flags["truncated"].unsqueeze(1) & ~crash
        done = terminated | truncated
        cost, mask = agents.get("cost"), ~done
        group = {
            "observation": self._observation(agents),
            "info": new_tensordict_unchecked(
                {**dict(info.items()), "cost": cost, "mask": mask}, batch_size=self._agents_shape
            ),
            "done": done, "terminated": terminated, "truncated": truncated,
        }
        if self.legacy_keys:
            group.update(cost=cost, mask=mask)
        if not reset:
            group["reward"] = reward
        return new_tensordict_unchecked(
            {
                AGENT_GROUP: new_tensordict_unchecked(group, batch_size=self._agents_shape),
                "state": self.core.global_state(agents),
                WORLD: self._world(agents, reward),
                **flags,
            },
            batch_size=self.batch_size,
        )
