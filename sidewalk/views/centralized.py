"""The learner plays every agent through one joint action and receives the team reward."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from sidewalk._torchrl import new_tensordict_unchecked
from sidewalk.envs.base import AGENT_GROUP, SidewalkEnvBase
from sidewalk.views.base import MAX_JOINT_ACTIONS, WORLD, _SidewalkView


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

    @property
    def _action_labels(self) -> tuple[str, ...]:
        return ()  # a joint index (``encode_action``), not one agent's move

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        if self.domain == "discrete":
            return self._decode_table.index_select(0, action.reshape(-1)).view(self._agents_shape)
        return action.reshape(*self._agents_shape, -1)

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        agents = core_out.get(AGENT_GROUP)
        reward = self._world_reward(agents, reset)
        out = new_tensordict_unchecked(
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
