"""One learning agent against an opponent that plays every other agent."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded

from sidewalk._checks import check_int
from sidewalk._torchrl import new_tensordict_unchecked
from sidewalk.envs.base import AGENT_GROUP, INFO_KEYS, SidewalkEnvBase
from sidewalk.opponents.base import Opponent, make_opponent
from sidewalk.registry import OPPONENTS
from sidewalk.views.base import WORLD, _SidewalkView


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
        reward = self._world_reward(agents, reset)
        if self.end_on_ego_done:
            done_source, index = agents, (slice(None), ego)
        else:
            done_source, index = core_out, (slice(None),)
        # new_tensordict_unchecked skips validation that costs more than the view's own work at small batch sizes (the core does
        # the same); shapes are right by construction and check_env_specs covers them in the tests.
        out = new_tensordict_unchecked(
            {
                "observation": agents.get("observation").select(1, ego),
                "cost": agents.get("cost").select(1, ego),
                "info": new_tensordict_unchecked(
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
