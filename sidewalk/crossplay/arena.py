"""The evaluation worlds of a cross-play matrix and its learned players, built once and reseeded for every cell."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase

from sidewalk.crossplay.conventions import convention
from sidewalk.crossplay.players import (
    Column,
    Player,
)
from sidewalk.envs import core_class
from sidewalk.evaluate import distinct_rows, evaluate, run_episodes
from sidewalk.experiment import EVAL_SEED_OFFSET
from sidewalk.opponents.base import ACTION_KEY, Opponent
from sidewalk.partners.policy import (
    OBSERVATION_KEY,
    PolicyOpponent,
)

METRICS = {  # CSV column -> key of sidewalk.evaluate's metrics in the row's ego view
    "success": "ego/success_rate",
    "partner_success": "other/success_rate",
    "collision_rate": "ego/collision_rate",
    "partner_collision_rate": "other/collision_rate",
    "team_success": "team/success_rate",
    "deadlock_rate": "deadlock_rate",  # episodes that timed out with the unfinished agents stuck in front of each other
    "return": "ego/return",
    "path_efficiency": "ego/path_efficiency",  # straight-line distance over the path walked, arrived episodes only
    "partner_path_efficiency": "other/path_efficiency",
    "episodes": "episodes",
    "distinct_episodes": "distinct_episodes",  # how many different episodes the cell's worlds played
}


class DistinctPlayer(Opponent):
    """A learned player (a greedy ``PolicyOpponent``) run once per distinct observation of the worlds, as
    ``sidewalk.evaluate.act_on_distinct`` runs a policy: its actions are a function of every agent's observation in
    that world alone, so worlds that look alike get the same actions. At noise 0 two deterministic players (or one
    and the Dijkstra agent) play the same episode in every world, so a cell costs one world's networks, not 256."""

    def __init__(self, player: PolicyOpponent) -> None:
        if player.sample:
            raise ValueError("a sampling player acts differently in worlds that look alike: run it on every world")
        super().__init__(player.env, controlled=player.controlled, ego=player.ego)
        self.player = player
        self.in_keys = list(player.in_keys)  # the observation, or what the env computes a partner's own one from
        self._zero_action = player.env.full_action_spec[ACTION_KEY].zero()

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        inputs = tensordict.select(*self.in_keys)
        batch = inputs.batch_size[0]
        first_of, inverse = distinct_rows(
            torch.cat([inputs.get(key).reshape(batch, -1).to(torch.float64) for key in self.in_keys], dim=-1))
        seen = TensorDict({key: inputs.get(key)[first_of] for key in self.in_keys}, batch_size=[first_of.numel()])
        seen.set(ACTION_KEY, self._zero_action[first_of])  # the player fills in its agents' columns of a joint action
        acted = self.player(seen).get(ACTION_KEY)[inverse]  # (B, N, ...): the controlled agents' columns set
        joint = tensordict.get(ACTION_KEY, None)
        joint = acted if joint is None else joint.clone()
        joint.index_copy_(1, self._controlled_index, acted.index_select(1, self._controlled_index).to(joint.dtype))
        tensordict.set(ACTION_KEY, joint)
        return tensordict


class LearnedAgent(TensorDictModuleBase):
    """A learned policy acting for the ego of an ``EgoView``: its player (controlling the ego alone) reads every
    agent's observation from the view's last core output, which a centralized or self-play learner needs, and the
    ego's share of its action is the view's action.

    It acts on all worlds at once: evaluate it with ``deterministic=False`` (``act_on_distinct`` would hand it a
    subset of worlds that the view's output does not match); it is greedy all the same.
    """

    def __init__(self, view: Any, player: Opponent) -> None:
        super().__init__()
        if list(player.controlled) != [view.ego]:
            raise ValueError(f"the player controls agents {player.controlled}; the view's ego is {view.ego}")
        self.player = player
        self._view = [view]  # a list: the view is not a submodule of its own policy
        self.in_keys = ["observation"]
        self.out_keys = ["action"]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = self._view[0]._last.get(OBSERVATION_KEY)
        joint = self.player(TensorDict({OBSERVATION_KEY: observation}, batch_size=observation.shape[:1]))
        tensordict.set("action", joint.get(ACTION_KEY).select(1, self._view[0].ego))
        return tensordict


class Arena:
    """The evaluation worlds of a matrix: one core env of ``episodes`` worlds per agent a row plays, and each
    learned player built once on it (a row for its agent, a partner for every other agent), so a matrix rebuilds
    no network per cell. Every evaluation reseeds and resets the whole core, so a cell's worlds do not depend on
    the cells before it."""

    def __init__(self, domain: str, world: Any, episodes: int, seed: int, device: str = "cpu") -> None:
        self.domain, self.world, self.episodes, self.device = domain, world, episodes, device
        self.world_seed = seed + EVAL_SEED_OFFSET
        self._cores: dict[int, Any] = {}
        self._players: dict[tuple[str, int, bool], DistinctPlayer] = {}

    def core(self, ego: int):
        if ego not in self._cores:
            self._cores[ego] = core_class(self.domain)(
                self.episodes, device=self.device, seed=self.world_seed, params=self.world
            )
        return self._cores[ego]

    def _player(self, player: Player, ego: int, as_row: bool) -> DistinctPlayer:
        key = (str(player.path.resolve()), ego, as_row)
        if key not in self._players:
            core = self.core(ego)
            controlled = (ego,) if as_row else tuple(a for a in range(core.n_agents) if a != ego)
            self._players[key] = DistinctPlayer(
                PolicyOpponent(core, controlled=controlled, ego=None if as_row else ego, path=player.path)
            )
        return self._players[key]

    def evaluate(self, row: Player, column: Column) -> dict[str, float]:
        """Metrics (``sidewalk.evaluate``'s keys, the row's agent as ego) of ``row`` with ``column`` playing every
        other agent."""
        from sidewalk.views import view_for_opponent

        ego = row.agent
        if column.player is None:  # a scripted partner: a registered opponent's name, with its settings
            partner = column.opponent or column.name
        else:
            partner = self._player(column.player, ego, as_row=False)
        view = view_for_opponent(self.core(ego), partner, ego, opponent_kwargs=column.params)
        policy = LearnedAgent(view, self._player(row, ego, as_row=True))
        return evaluate(view, policy, seed=self.world_seed, deterministic=False)

    def convention(self, row: Player) -> dict[str, Any]:
        """The convention (``convention``) of ``row``'s policy playing every agent of the two-agent sidewalk, on the
        matrix's worlds; "n/a" for other layouts."""
        from sidewalk.views import EgoView

        core = self.core(row.agent)
        if self.world.layout != "sidewalk" or core.n_agents != 2:
            return {"passing_side": "n/a", "passing_fraction": float("nan"), "yielder": "n/a", "episodes": 0}
        view = EgoView(core, self._player(row, row.agent, as_row=False), ego=row.agent)
        policy = LearnedAgent(view, self._player(row, row.agent, as_row=True))
        record = run_episodes(view, policy, seed=self.world_seed, record_trajectories=self.episodes, deterministic=False)
        return convention(record.trajectories, self.domain, core.layout)


def evaluate_cell(
    row: Player, column: Column, world: Any, episodes: int, seed: int, device: str = "cpu"
) -> dict[str, float]:
    """One cell alone (``Arena.evaluate``): ``row`` with ``column`` playing every other agent, one episode in each
    of ``episodes`` worlds seeded ``seed + EVAL_SEED_OFFSET``."""
    return Arena(row.partner.world.domain, world, episodes, seed, device).evaluate(row, column)
