"""PettingZoo face of the Sidewalk cores: ``parallel_env(domain="discrete" | "continuous", **env_kwargs)``.

Its worlds by default: the scenario's own starts and goals, so at noise 0 every episode is the same one (the paper's
evaluation, ``eval=nominal``). ``runners/main.py`` trains and evaluates under ``eval=perturbed``; its worlds are
``start_jitter_rows=1, goal_jitter_rows=1`` (grid) and ``start_jitter_m=0.2, goal_jitter_m=0.2,
heading_jitter_rad=0.3927`` (continuous, the sidewalk), given as keywords here.

Every agent acts each step (``ParallelEnv``). Agents are named ``agent_0``, ``agent_1``, ... in the core's order;
each one's observation and action are the core's per-agent ones (ego-centric image or vector; (acceleration, turn)).
Following PettingZoo, an agent leaves ``env.agents`` once it is terminated (reached its goal or crashed) or
truncated (timeout), so the cooperative reward a finished agent would still collect when another one arrives later
(``alpha * c_goal``) is not delivered here; the TorchRL multi-agent env keeps every agent until the world ends.

``step`` checks each live agent's action against its action space, as Gymnasium's envs do: one of the wrong
kind or shape, or outside a ``Discrete``, raises ``sidewalk.interop.gymnasium.InvalidActionError`` naming the
agent, its action and its space (a finished agent's action is ignored, unchecked); a finite continuous action
beyond the bounds is clamped to them.

``infos[agent]`` holds that agent's outcome flags (``reached_goal``, ``collided_agent``, ``collided_wall``,
``timed_out``; sticky for the episode) and its safety ``cost`` of the step (a float: 1 on the step it hits a wall or
another agent, with the core's ``cost="near_miss"`` also on steps it ends within ``near_miss_margin`` of another
agent; 0 otherwise and on reset). ``state()`` is the true state of every agent, flattened (float32), for
centralized critics.
PettingZoo is an optional dependency: ``pip install 'sidewalk-problem[pettingzoo]'``.
"""

from __future__ import annotations

from typing import Any, ClassVar

try:
    from pettingzoo import ParallelEnv
except ImportError as error:  # pragma: no cover - exercised only where pettingzoo is missing
    raise ImportError(
        "sidewalk.interop.pettingzoo needs PettingZoo; install it with pip install 'sidewalk-problem[pettingzoo]'"
    ) from error

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict, TensorDictBase

from sidewalk._checks import check_choice
from sidewalk.envs import CORE_ENVS
from sidewalk.envs.base import AGENT_GROUP, INFO_KEYS
from sidewalk.interop.gymnasium import RENDER_FPS, WINDOW_RENDER_MODES, agent_spaces, checked_action
from sidewalk.interop.window import FrameWindow


class SidewalkParallelEnv(ParallelEnv):
    """One Sidewalk world as a PettingZoo ``ParallelEnv``; see the module docstring for the conventions.

    ``domain`` picks the core env; every other keyword (``noise``, ``rewards``, ``observation``, ``max_steps``,
    ...) goes to it. ``reset(seed=...)`` seeds the world's generator. The core TorchRL env is ``self.core``.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "sidewalk_v0",
        "render_modes": list(WINDOW_RENDER_MODES),
        "render_fps": RENDER_FPS,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        domain: str = "discrete",
        render_mode: str | None = None,
        device: str | torch.device = "cpu",
        **env_kwargs: Any,
    ) -> None:
        check_choice("domain", domain, CORE_ENVS)
        if render_mode is not None:
            check_choice("render_mode", render_mode, WINDOW_RENDER_MODES)
        self.render_mode = render_mode
        self._window = FrameWindow(f"sidewalk_v0 ({domain})", RENDER_FPS) if render_mode == "human" else None
        self.domain = domain
        self.core = CORE_ENVS[domain](num_envs=1, device=device, **env_kwargs)
        self.possible_agents = self.core.agent_names
        self.agents: list[str] = []
        self._index = {name: index for index, name in enumerate(self.possible_agents)}
        # Separate space objects per agent, so that seeding one agent's space leaves the others' alone.
        self._spaces = {agent: agent_spaces(self.core) for agent in self.possible_agents}
        state_dim = self.core.observation_spec[AGENT_GROUP, "state"].shape[-1] * self.core.n_agents
        self.state_space = spaces.Box(low=-np.inf, high=np.inf, shape=(state_dim,), dtype=np.float32)
        action_spec = self.core.full_action_spec[AGENT_GROUP, "action"]
        self._action_shape = tuple(action_spec.shape)
        self._action_dtype = action_spec.dtype
        self._last: TensorDictBase | None = None

    def observation_space(self, agent: str) -> spaces.Space:
        """The observation space of ``agent``: the same object on every call, as PettingZoo requires."""
        return self._spaces[agent][0]

    def action_space(self, agent: str) -> spaces.Space:
        """The action space of ``agent``: the same object on every call, as PettingZoo requires."""
        return self._spaces[agent][1]

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        # ``options`` is accepted for the PettingZoo signature; this env has none.
        if seed is not None:
            self.core.set_seed(seed)
        self._last = out = self.core._reset(None)
        self.agents = list(self.possible_agents)
        self._show()
        agents = out.get(AGENT_GROUP)
        return self._per_agent_observations(agents, self.agents), self._per_agent_infos(agents, self.agents)

    def step(self, actions: dict[str, Any]):
        if self._last is None:
            raise RuntimeError("step() was called before reset()")
        live = list(self.agents)
        missing = [agent for agent in live if agent not in actions]
        unknown = [agent for agent in actions if agent not in self._index]
        if missing or unknown:
            raise ValueError(
                f"actions name agents {sorted(actions)}; they must cover the live agents {live} "
                f"(finished ones may be given and are ignored) and name only {self.possible_agents}"
            )
        # Finished agents no longer move, so their entry in the joint action is a placeholder.
        joint = torch.zeros(self._action_shape, dtype=self._action_dtype, device=self.core.device)
        for agent in live:
            action = checked_action(actions[agent], self.action_space(agent), name=f"{agent}'s action")
            joint[0, self._index[agent]] = torch.as_tensor(action, dtype=self._action_dtype)
        core_in = TensorDict(
            {AGENT_GROUP: TensorDict({"action": joint}, batch_size=self._action_shape[:2])}, [1]
        )
        self._last = out = self.core._step(core_in)
        self._show()
        agents = out.get(AGENT_GROUP)
        reward = agents.get("reward")[0, :, 0].tolist()
        terminated = agents.get("terminated")[0, :, 0].tolist()
        truncated = agents.get("truncated")[0, :, 0].tolist()
        rewards = {agent: float(reward[self._index[agent]]) for agent in live}
        terminations = {agent: bool(terminated[self._index[agent]]) for agent in live}
        truncations = {agent: bool(truncated[self._index[agent]]) for agent in live}
        observations = self._per_agent_observations(agents, live)
        infos = self._per_agent_infos(agents, live)
        self.agents = [agent for agent in live if not (terminations[agent] or truncations[agent])]
        return observations, rewards, terminations, truncations, infos

    def _per_agent_observations(self, agents: TensorDictBase, names: list[str]) -> dict[str, np.ndarray]:
        observation = agents.get("observation")[0].detach().cpu().numpy()
        return {agent: observation[self._index[agent]].copy() for agent in names}

    def _per_agent_infos(
        self, agents: TensorDictBase, names: list[str]
    ) -> dict[str, dict[str, bool | float]]:
        flags = {key: agents.get(("info", key))[0, :, 0].tolist() for key in INFO_KEYS}
        cost = agents.get("cost")[0, :, 0].tolist()
        return {
            agent: {
                **{key: bool(flags[key][self._index[agent]]) for key in INFO_KEYS},
                "cost": float(cost[self._index[agent]]),
            }
            for agent in names
        }

    def state(self) -> np.ndarray:
        """The true state of every agent, flattened in agent order, float32 (``state_space``)."""
        if self._last is None:
            raise RuntimeError("state() was called before reset()")
        return self._last.get((AGENT_GROUP, "state"))[0].reshape(-1).to(torch.float32).cpu().numpy().copy()

    def render(self) -> np.ndarray | None:
        """The world as an RGB uint8 array with ``render_mode="rgb_array"``; with ``"human"`` it is shown in a
        window (as ``reset`` and ``step`` do) and ``None`` returned; ``None`` (with a warning) without a mode."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() was called without a render mode; pass render_mode='rgb_array' (or 'human', a window)"
            )
            return None
        if self._window is not None:
            self._show()
            return None
        return self.core.render(0)

    def _show(self) -> None:
        """``render_mode="human"``: the world in the window (not drawn at all where no window opens)."""
        if self._window is not None and self._window.opens:
            self._window.show(self.core.render(0))

    def close(self) -> None:
        """Close the window of ``render_mode="human"``; the world itself lives in tensors."""
        if self._window is not None:
            self._window.close()


def parallel_env(
    domain: str = "discrete", render_mode: str | None = None, **env_kwargs: Any
) -> SidewalkParallelEnv:
    """A PettingZoo ``ParallelEnv`` of one Sidewalk world of ``domain``; ``env_kwargs`` go to the core env."""
    return SidewalkParallelEnv(domain=domain, render_mode=render_mode, **env_kwargs)
