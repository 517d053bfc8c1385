"""A scripted opponent playing every agent as one team: the scenarios' scripted baselines."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from sidewalk._checks import check_int
from sidewalk.envs.base import INFO_KEYS, SidewalkEnvBase
from sidewalk.opponents.base import Opponent, make_opponent
from sidewalk.views import WORLD, EgoView


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
        done = torch.stack([info.get(key) for key in INFO_KEYS]).any(0)  # any outcome ends an agent's walk
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
