"""Safety-Gymnasium face of the Sidewalk views: ``sidewalk/SafetyDiscrete-v0`` and ``sidewalk/SafetyContinuous-v0``.

Constrained-RL code written for Safety-Gymnasium (OmniSafe, FSRL, ...) runs unchanged but for its import::

    from sidewalk.interop import safety_gymnasium

    env = safety_gymnasium.make("sidewalk/SafetyDiscrete-v0", opponent="dijkstra", cost="near_miss")
    obs, info = env.reset(seed=0)
    obs, reward, cost, terminated, truncated, info = env.step(env.action_space.sample())
    envs = safety_gymnasium.make_vec("sidewalk/SafetyContinuous-v0", num_envs=4096, opponent="prm")

``make`` mirrors ``safety_gymnasium.make`` and ``make_vec`` mirrors ``safety_gymnasium.vector.make``. Importing this
module registers both ids with gymnasium too, so ``gymnasium.make``/``gymnasium.make_vec`` build them (without
``max_episode_steps``, whose ``TimeLimit`` unpacks five values). Safety-Gymnasium itself is not needed: it pins an
older gymnasium and MuJoCo.

The envs are the gymnasium face's (``sidewalk.interop.gymnasium``: same keywords, spaces, seeding, rendering and
info) with the learner's cost moved from ``info["cost"]`` to the step's third element, where Safety-Gymnasium's envs
report it; ``info["agents"]["cost"]`` keeps every agent's. Actions are checked as there: one outside the
action space raises ``InvalidActionError`` naming it and the space. The cost is a float (the ego's; with
``opponent="centralized"`` the agents' sum); in the vector env a (num_envs,) float32 array.

The vector env is one batched core of ``num_envs`` worlds, like the gymnasium face's, but autoresets in the same step,
as ``safety_gymnasium.vector`` does (``metadata["autoreset_mode"]``): a world whose episode ends returns its final
reward, cost and done flags with the first observation and info of its next episode, and the final ones in
``info["final_observation"]`` and ``info["final_info"]`` (object arrays holding ``None`` for the worlds that go on,
masked by ``info["_final_observation"]`` and ``info["_final_info"]``).
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode

from sidewalk._checks import check_choice
from sidewalk.interop import gymnasium as gym_face
from sidewalk.interop.gymnasium import SidewalkGymEnv, SidewalkVectorEnv

SAFETY_ENV_IDS = {"discrete": "sidewalk/SafetyDiscrete-v0", "continuous": "sidewalk/SafetyContinuous-v0"}
# Keywords of safety_gymnasium.make / gymnasium.make that add wrappers unpacking gymnasium's five-element step.
_WRAPPER_KEYWORDS = {
    "max_episode_steps": "the core's max_steps=... sets the episode length",
    "autoreset": "make_vec(id, num_envs=1) autoresets in the same step, as Safety-Gymnasium's autoreset does",
    "disable_env_checker": "gymnasium's passive checker rejects the six-element step",
}


def _without_cost(info: dict[str, Any]) -> dict[str, Any]:
    # Safety-Gymnasium's envs keep the cost out of info, and its SafetyGymnasium2Gymnasium warns when it is there.
    return {key: value for key, value in info.items() if key not in ("cost", "_cost")}


class SafetySidewalkEnv(SidewalkGymEnv):
    """One Sidewalk world whose ``step`` returns ``(obs, reward, cost, terminated, truncated, info)``.

    Arguments, spaces, ``reset`` and ``render`` are ``SidewalkGymEnv``'s; ``cost`` is the learner's float safety cost
    of the step (see the module docstring).
    """

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = super().reset(seed=seed, options=options)
        return obs, _without_cost(info)

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, reward, info["cost"], terminated, truncated, _without_cost(info)


class SafetySidewalkVectorEnv(SidewalkVectorEnv):
    """``num_envs`` Sidewalk worlds on one batched core whose ``step`` returns ``(obs, reward, cost, terminated,
    truncated, info)`` with (num_envs,) arrays, autoresetting in the same step (see the module docstring).

    Arguments, spaces, ``reset`` (``reset_mask`` included) and ``render`` are ``SidewalkVectorEnv``'s.
    """

    metadata: ClassVar[dict[str, Any]] = {
        **SidewalkVectorEnv.metadata,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = super().reset(seed=seed, options=options)
        return obs, _without_cost(info)

    def step(self, actions: Any):
        obs, reward, terminated, truncated, info = super().step(actions)
        cost = info["cost"]
        info = _without_cost(info)
        ended = terminated | truncated
        if ended.any():
            final_observation = np.full(self.num_envs, None, dtype=object)
            final_info = np.full(self.num_envs, None, dtype=object)
            for world in np.flatnonzero(ended):
                final_observation[world] = obs[world].copy()
                final_info[world] = _world_info(info, world)
            # The parent then finds no world waiting for its next-step autoreset.
            next_obs, next_info = self.reset(options={"reset_mask": ended})
            obs[ended] = next_obs[ended]
            _copy_rows(info, next_info, ended)
            info.update(
                final_observation=final_observation,
                _final_observation=ended.copy(),
                final_info=final_info,
                _final_info=ended.copy(),
            )
        return obs, reward, cost, terminated, truncated, info


def _world_info(info: dict[str, Any], world: int) -> dict[str, Any]:
    """World ``world``'s entries of a batched info, without the masks: the single env's info of that world."""
    entries = {}
    for key, value in info.items():
        if key.startswith("_"):
            continue
        if isinstance(value, dict):
            entries[key] = _world_info(value, world)
        else:
            entries[key] = value[world].item() if value.ndim == 1 else value[world].copy()
    return entries


def _copy_rows(info: dict[str, Any], source: dict[str, Any], rows: np.ndarray) -> None:
    """Overwrite the ``rows`` of every batched entry of ``info`` in place with ``source``'s (same keys)."""
    for key, value in info.items():
        if isinstance(value, dict):
            _copy_rows(value, source[key], rows)
        elif not key.startswith("_"):
            value[rows] = source[key][rows]


def make(id: str, **kwargs: Any) -> gymnasium.Env:
    """A ``SafetySidewalkEnv`` (wrapped as ``gymnasium.make`` wraps) for ``id`` in ``SAFETY_ENV_IDS``; ``kwargs``
    are ``SidewalkGymEnv``'s (``opponent``, ``render_mode``, ``ego``, the core's parameters, ...)."""
    check_choice("id", id, SAFETY_ENV_IDS.values())
    for name, hint in _WRAPPER_KEYWORDS.items():
        if name in kwargs:
            raise TypeError(f"{name} is not taken here: {hint}")
    return gymnasium.make(id, **kwargs)


def make_vec(id: str, num_envs: int = 1, **kwargs: Any) -> SafetySidewalkVectorEnv:
    """A ``SafetySidewalkVectorEnv`` of ``num_envs`` worlds on one batched core for ``id`` in ``SAFETY_ENV_IDS``;
    ``kwargs`` are ``SidewalkVectorEnv``'s."""
    check_choice("id", id, SAFETY_ENV_IDS.values())
    return gymnasium.make_vec(id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)


def register_envs() -> None:
    """Register ``sidewalk/SafetyDiscrete-v0`` and ``sidewalk/SafetyContinuous-v0`` with gymnasium (once per
    process)."""
    # gymnasium's passive checker expects a five-element step.
    gym_face.register_envs(SAFETY_ENV_IDS, SafetySidewalkEnv, SafetySidewalkVectorEnv, disable_env_checker=True)


register_envs()
