"""A world with someone in it, as one value: the scenario and every env parameter, the partner, and how a learner sees
it. Training, evaluation, a saved policy, a learned partner and the Gymnasium face all describe their worlds with it::

    world = World("discrete", DiscreteParams(noise=0.1), opponent="dijkstra")
    env = world.make(num_envs=64, seed=0)        # the TorchRL env a learner plays: core env + view
    World.from_dict(world.to_dict()) == world    # how policy.pt and cross-play keep it

A ``World`` is frozen: ``replace(...)`` gives another. ``differences`` says what separates two worlds (a partner may
have trained in a world that differs only in ``MAY_DIFFER``). The env parameters carry the evaluation protocol's
jitter bounds, so a world is all that decides which episodes are drawn (the seed aside).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torchrl.envs import EnvBase

from sidewalk.envs import CORE_ENVS, core_class
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.envs.rewards import RewardParams
from sidewalk.later_keys import LATER_ENV_KEYS
from sidewalk.views import view_for_opponent

# Choices of ``opponent`` where the learner plays every agent (through one joint action, or as every agent).
LEARNER_PLAYS_ALL = ("centralized", "self")
# Env parameters a learned partner may have been trained under differently: they change the game's payoffs, noise or
# where its episodes start (an evaluation protocol's jitter), not what an observation means or what an action does.
MAY_DIFFER = ("noise", "rewards", "max_steps", "remove_crashed", "check_actions", "start_jitter_rows",
              "goal_jitter_rows", "start_jitter_cells", "goal_jitter_cells", "start_jitter_m", "goal_jitter_m",
              "heading_jitter_rad")


@dataclass(frozen=True)
class World:
    """The worlds a learner plays: ``domain`` (``discrete``/``continuous``) and its ``env_params`` (scenario,
    noise, rewards, jitter bounds, ...), the ``opponent`` as an experiment names it (a registered opponent or
    partner, built with ``opponent_params``; ``centralized`` or ``self`` where the learner plays every agent), the
    learner's agent ``ego`` and whether its episode ends with it (``end_on_ego_done``), the safety ``shield`` and
    self-play's ``other_play`` and ``role_frame`` (``sidewalk.views.SelfPlayView``)."""

    domain: str
    env_params: Any  # DiscreteParams | ContinuousParams
    opponent: str = "random"
    opponent_params: Mapping[str, Any] = field(default_factory=dict)
    ego: int = 0
    end_on_ego_done: bool = False
    shield: bool = False
    other_play: bool = False
    role_frame: bool = False

    def __post_init__(self) -> None:
        params_class = core_class(self.domain).Params
        if not isinstance(self.env_params, params_class):
            raise TypeError(f"env_params={self.env_params!r} must be a {params_class.__name__} ({self.domain} world)")

    @property
    def core_class(self) -> type[SidewalkEnvBase]:
        """The core env class of this world's domain (``sidewalk.envs.CORE_ENVS``)."""
        return core_class(self.domain)

    @property
    def learner_plays_every_agent(self) -> bool:
        return self.opponent in LEARNER_PLAYS_ALL

    @property
    def n_agents(self) -> int:
        return self.core_class.layout_for(self.env_params).n_agents

    def replace(self, **changes: Any) -> World:
        """This world with ``changes``: fields of the world, or of its env parameters (``noise=0.1``)."""
        own = {name: value for name, value in changes.items() if name in _FIELDS}
        env = {name: value for name, value in changes.items() if name not in _FIELDS}
        if env:
            own["env_params"] = dataclasses.replace(own.get("env_params", self.env_params), **env)
        return dataclasses.replace(self, **own)

    def core(self, num_envs: int, seed: int = 0, device: str | torch.device = "cpu") -> SidewalkEnvBase:
        """The core env of ``num_envs`` of these worlds, every agent's (no view)."""
        return self.core_class(num_envs, device=device, seed=seed, params=self.env_params)

    def make(self, num_envs: int, seed: int = 0, device: str | torch.device = "cpu") -> EnvBase:
        """The env a learner plays: ``num_envs`` of these worlds seen through its view
        (``sidewalk.views.view_for_opponent``: ego against the opponent, centralized, or self-play)."""
        return view_for_opponent(
            self.core(num_envs, seed, device), self.opponent, self.ego, shield=self.shield,
            end_on_ego_done=self.end_on_ego_done, opponent_kwargs=self.opponent_params, other_play=self.other_play,
            role_frame=self.role_frame,
        )

    def stand_in(self) -> World:
        """The same view of the same worlds with nothing that costs to build: a random opponent in place of its
        own where the learner plays one agent (a roadmap, a saved policy), unshielded, no mirror. It has the
        observation and action specs a learner trained in this world saw (a saved policy's replay builds on it)."""
        if self.learner_plays_every_agent:
            return dataclasses.replace(self, shield=False, other_play=False)
        return dataclasses.replace(self, opponent="random", opponent_params={}, end_on_ego_done=False, shield=False)

    def to_dict(self) -> dict[str, Any]:
        """The world as plain data (JSON- and ``torch.load(weights_only=True)``-safe); ``from_dict`` reads it back."""
        return {**dataclasses.asdict(self), "env_params": dataclasses.asdict(self.env_params),
                "opponent_params": dict(self.opponent_params)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> World:
        """The world ``to_dict`` wrote. Env parameters written before a later key existed take the value such a world
        had (``sidewalk.later_keys``); a key no world has is an error naming it."""
        data = dict(data)
        domain = data.pop("domain")
        data["env_params"] = env_params_from_dict(domain, data["env_params"])
        unknown = sorted(set(data) - set(_FIELDS))
        if unknown:
            raise ValueError(f"a world has no {', '.join(unknown)}; its fields: {', '.join(_FIELDS)}")
        return cls(domain=domain, **data)

    def differences(self, other: World, ignoring: Sequence[str] = ()) -> list[str]:
        """The names of what differs from ``other``: ``domain``, world fields (``opponent``, ``ego``, ...) and env
        parameters as ``env.<name>``; the env parameters named in ``ignoring`` are not compared."""
        if self.domain != other.domain:
            return ["domain"]
        differ = [f"env.{f.name}" for f in dataclasses.fields(self.env_params)
                  if f.name not in ignoring and getattr(self.env_params, f.name) != getattr(other.env_params, f.name)]
        return differ + [name for name in _FIELDS
                         if name not in ("domain", "env_params") and getattr(self, name) != getattr(other, name)]

    def value(self, name: str) -> Any:
        """The value ``differences`` names ``name`` (``env.noise``, ``opponent``)."""
        if name.startswith("env."):
            return getattr(self.env_params, name.removeprefix("env."))
        return getattr(self, name)


_FIELDS = tuple(f.name for f in dataclasses.fields(World))


def env_params_from_dict(domain: str, data: Mapping[str, Any]) -> Any:
    """The env parameters of a ``domain`` world written as a dict (``dataclasses.asdict``), its later keys at the value
    a world written without them had."""
    if domain not in CORE_ENVS:
        raise ValueError(f"domain={domain!r} is not one of {', '.join(CORE_ENVS)}")
    later = {key.removeprefix("env."): value for key, value in LATER_ENV_KEYS[domain].items()}
    params = {**later, **data}
    params["rewards"] = RewardParams(**params["rewards"]) if isinstance(params["rewards"], Mapping) else params["rewards"]
    return core_class(domain).Params(**params)


__all__ = ["LEARNER_PLAYS_ALL", "MAY_DIFFER", "World", "env_params_from_dict"]
