"""Gymnasium face of the Sidewalk views: ``sidewalk/Discrete-v0`` and ``sidewalk/Continuous-v0``.

Its worlds by default: the scenario's own starts and goals, so at noise 0 every episode is the same one (the paper's
evaluation, ``eval=nominal``). ``runners/main.py`` trains and evaluates under ``eval=perturbed``; its worlds are
``start_jitter_rows=1, goal_jitter_rows=1`` (grid) and ``start_jitter_m=0.2, goal_jitter_m=0.2,
heading_jitter_rad=0.3927`` (continuous, the sidewalk), given as keywords here.

Importing this module (``import sidewalk`` does) registers both ids::

    env = gymnasium.make("sidewalk/Discrete-v0", opponent="dijkstra", noise=0.1)
    envs = gymnasium.make_vec("sidewalk/Continuous-v0", num_envs=4096, opponent="prm")

``opponent`` is a registered opponent name (``"random"``; ``"dijkstra"`` in the grid, ``"prm"`` in the continuous
world) for the ego view, or ``"centralized"`` for the joint-action view; ``shield=True`` puts the safety shield in
front of the learner's actions (docs/guide/safe-rl.md); every other keyword (``noise``,
``rewards``, ``observation``, ``max_steps``, ...) goes to the core env and is checked there. ``make_vec`` builds one
batched core env of ``num_envs`` worlds (``vector_entry_point``), not ``num_envs`` copies.

Spaces: the grid's image observation is a uint8 Box (1, H, W), its vector observation a float32 Box in [0, 1]; the
continuous observation is a float32 Box whose bounds follow from the world's size, the speed limit and the noise.
Actions: ``Discrete(4)`` (UP, DOWN, LEFT, RIGHT) or ``Discrete(16)`` for the centralized grid (joint index
``a0 * 4 + a1``); a float32 Box of (acceleration m/s², turn rad) per controlled agent in the continuous world, in
physical units (libraries that want [-1, 1], like Stable-Baselines3, take ``gymnasium.wrappers.RescaleAction``).
``step`` checks its action against the action space, as Gymnasium's own envs do (``checked_action``): one of
the wrong kind (a float or bool for ``Discrete``, a string, NaN or inf), of the wrong shape or outside a
``Discrete`` raises ``InvalidActionError`` (a ``gymnasium.error.InvalidAction`` and a ``ValueError``) naming
the action and the space; a finite ``Box`` action beyond the bounds is accepted and clamped to them (SPEC §1).

``info`` holds ``is_success`` (the ego reached its goal; centralized: every agent did), ``cost`` (the learner's
safety cost of the step, a float: the ego's, or the sum over the agents for the centralized view; 1 per agent that
hit a wall or another agent in the step, with the core's ``cost="near_miss"`` also per agent that ended it within
``near_miss_margin`` of another; 0 on reset), ``agents`` (every agent's outcome flags ``reached_goal``,
``collided_agent``, ``collided_wall``, ``timed_out`` (sticky for the episode), its own ``reward`` and ``cost`` of the
step, each indexed by agent) and the true ``state`` and ``goal`` of every agent. Constrained-RL code written for
Safety-Gymnasium's ``(obs, reward, cost, terminated, truncated, info)`` takes ``sidewalk.interop.safety_gymnasium``.

The vector env batches each entry along a leading ``num_envs`` axis and adds gymnasium's ``_key`` masks (so
``info["cost"]`` is a (num_envs,) float array); it autoresets in gymnasium's default next-step mode
(``metadata["autoreset_mode"]``): the step after an episode ends ignores that world's action and returns its first
observation with reward 0, cost 0 and ``terminated = truncated = False``.
"""

from __future__ import annotations

import dataclasses
import math
import reprlib
from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, TensorSpec

from sidewalk._checks import check_choice
from sidewalk.envs import CORE_ENVS
from sidewalk.envs.base import AGENT_GROUP, INFO_KEYS, RENDER_MODES, SidewalkEnvBase
from sidewalk.envs.unicycle import OBSERVATION_FIELDS, ContinuousSidewalkEnv
from sidewalk.interop.window import FrameWindow
from sidewalk.registry import OPPONENTS
from sidewalk.views import WORLD, CentralizedView, EgoView, view_for_opponent
from sidewalk.world import World

ENV_IDS = {"discrete": "sidewalk/Discrete-v0", "continuous": "sidewalk/Continuous-v0"}
CENTRALIZED = "centralized"
RENDER_FPS = 10
# One world's faces also show it in a window (sidewalk.interop.window), as Gymnasium's envs do with "human".
WINDOW_RENDER_MODES = (*RENDER_MODES, "human")
# Float32 rounding of positions and headings may land a hair past the nominal bounds.
_BOUND_SLACK = 1e-3


def build_view(
    domain: str,
    num_envs: int,
    opponent: str = "random",
    ego: int | None = None,
    end_on_ego_done: bool | None = None,
    opponent_kwargs: Mapping[str, Any] | None = None,
    device: str | torch.device = "cpu",
    shield: bool = False,
    **env_kwargs: Any,
) -> tuple[World, EgoView | CentralizedView]:
    """The World behind the gymnasium face and its TorchRL view of ``num_envs`` worlds: an ``EgoView`` against
    ``opponent``, or a ``CentralizedView`` for ``opponent="centralized"`` (which takes no ``ego``,
    ``end_on_ego_done`` or ``opponent_kwargs``). ``shield=True`` puts the safety shield in front of the learner's
    actions (``sidewalk.views``)."""
    check_choice("domain", domain, CORE_ENVS)
    check_choice("opponent", opponent, [*OPPONENTS, CENTRALIZED])
    if opponent == CENTRALIZED:
        given = {"ego": ego, "end_on_ego_done": end_on_ego_done, "opponent_kwargs": opponent_kwargs}
        extra = [name for name, value in given.items() if value is not None]
        if extra:
            raise ValueError(f"opponent='centralized' has no ego agent; drop {', '.join(extra)}")
    core = CORE_ENVS[domain](num_envs=num_envs, device=device, **env_kwargs)  # its room where the keywords give none
    world = World(domain, core.params, opponent, dict(opponent_kwargs or {}), 0 if ego is None else ego,
                  end_on_ego_done=bool(end_on_ego_done), shield=shield)
    return world, view_for_opponent(core, opponent, world.ego, shield=shield, end_on_ego_done=world.end_on_ego_done,
                                    opponent_kwargs=opponent_kwargs)


def world_kwargs(world: World) -> dict[str, Any]:
    """The ``gymnasium.make`` keywords of ``world`` (``sidewalk.world.World``): its partner and view, and every core
    env parameter; ``gymnasium.make(ENV_IDS[world.domain], **world_kwargs(world))`` plays its worlds. A world the
    face cannot show (self-play, other-play) raises naming it."""
    if world.opponent == "self" or world.other_play or world.role_frame:
        raise ValueError(f"the Gymnasium face shows one learner's view; opponent={world.opponent!r} "
                         f"other_play={world.other_play} is every agent's (sidewalk.interop.pettingzoo)")
    view = {"opponent": world.opponent, "shield": world.shield}
    if world.opponent != CENTRALIZED:
        view.update(ego=world.ego, end_on_ego_done=world.end_on_ego_done, opponent_kwargs=dict(world.opponent_params))
    return {**view, **dataclasses.asdict(world.env_params)}


def _continuous_observation_bounds(core: SidewalkEnvBase) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the continuous observation: positions stay within one step (max_speed·dt) of the world's
    rectangle (a crashed agent stops where it crossed the wall), goals inside it, headings in [-π, π) once the
    agents move (a layout's start headings may lie outside), plus ±noise on every entry."""
    p, layout = core.params, core.layout
    length, width, overshoot = layout.length_m, layout.width_m, p.max_speed_mps * p.dt_s
    start_headings = tuple(getattr(layout, "headings", ()))
    per_field = {
        "x": (-overshoot, length + overshoot),
        "y": (-overshoot, width + overshoot),
        "v": (-p.max_speed_mps, p.max_speed_mps),
        # A random layout draws its headings per world (no fixed ones): the bounds are then [-π, π].
        "theta": (min((-math.pi, *start_headings)), max((math.pi, *start_headings))),
        "goal_x": (0.0, length),
        "goal_y": (0.0, width),
        "active": (0.0, 1.0),
        "present": (0.0, 1.0),
    }
    # A field added to the observation later gets no bound rather than a wrong one.
    low = [per_field.get(name, (-math.inf, math.inf))[0] for name in OBSERVATION_FIELDS] * core.n_agents
    high = [per_field.get(name, (-math.inf, math.inf))[1] for name in OBSERVATION_FIELDS] * core.n_agents
    margin = p.noise + _BOUND_SLACK
    return (np.asarray(low, dtype=np.float32) - margin, np.asarray(high, dtype=np.float32) + margin)


def _space(spec: TensorSpec, batch_dims: int) -> spaces.Space:
    """The gymnasium space of one entry of a TorchRL spec whose leading ``batch_dims`` axes are batch axes."""
    if isinstance(spec, Categorical):
        return spaces.Discrete(spec.space.n)
    if isinstance(spec, Bounded):
        first = (0,) * batch_dims
        return spaces.Box(
            low=spec.space.low[first].cpu().numpy(),
            high=spec.space.high[first].cpu().numpy(),
            dtype=torch.empty((), dtype=spec.dtype).numpy().dtype,
        )
    raise TypeError(f"no gymnasium space for {type(spec).__name__}")


def agent_spaces(core: SidewalkEnvBase) -> tuple[spaces.Space, spaces.Space]:
    """One agent's observation and action spaces in ``core`` (every agent's look alike)."""
    if isinstance(core, ContinuousSidewalkEnv):
        low, high = _continuous_observation_bounds(core)
        observation_space: spaces.Space = spaces.Box(low=low, high=high, dtype=np.float32)
    else:
        observation_space = _space(core.observation_spec[AGENT_GROUP, "observation"], batch_dims=2)
    return observation_space, _space(core.full_action_spec[AGENT_GROUP, "action"], batch_dims=2)


def view_spaces(view: EgoView | CentralizedView) -> tuple[spaces.Space, spaces.Space]:
    """One world's observation and action spaces of ``view`` (its observation is one agent's)."""
    observation_space, agent_action_space = agent_spaces(view.core)
    if isinstance(view, EgoView):
        return observation_space, agent_action_space
    return observation_space, _space(view.full_action_spec["action"], batch_dims=1)


class InvalidActionError(gymnasium.error.InvalidAction, ValueError):
    """An action outside its action space (wrong kind, shape or value): gymnasium's ``InvalidAction``, and a
    ``ValueError`` for code that catches bad arguments."""


def _shown(action: Any) -> str:
    """A short one-line text of an action for an error message (a numpy scalar as its value: ``7``)."""
    if isinstance(action, (np.ndarray, np.generic)):
        if action.ndim == 0:
            return reprlib.repr(action.item())
        return " ".join(np.array2string(action, separator=", ", threshold=12, edgeitems=3).split())
    return reprlib.repr(action)


def checked_action(
    action: Any, space: spaces.Discrete | spaces.Box, num_worlds: int | None = None, name: str = "action"
) -> np.ndarray:
    """``action`` as an array of ``space``'s dtype once it lies in ``space`` (with ``num_worlds``: one action
    per world along a leading axis), else an ``InvalidActionError`` naming ``name``, the action (the first bad
    world's) and the space. ``Discrete`` takes integers (Python or numpy, 0-d arrays included), not bools,
    floats or strings. ``Box`` takes real numbers of its shape, not NaN or inf.

    Decision: a finite ``Box`` value beyond the bounds is accepted and clamped by the core (SPEC §1), as
    Gymnasium's Pendulum and MuJoCo envs clip theirs. Vectorised: no loop over worlds."""
    batch_shape = () if num_worlds is None else (num_worlds,)
    space_text = str(space)
    if num_worlds is not None:
        space_text += f", the action space of each of the {num_worlds} worlds"
    try:
        array = np.asarray(action)
    except (TypeError, ValueError) as error:  # a ragged nested list
        raise InvalidActionError(f"{name} {_shown(action)} is not in {space_text}: {error}") from None
    discrete = isinstance(space, spaces.Discrete)
    if array.dtype.kind not in ("iu" if discrete else "iuf"):
        expected = "integers" if discrete else "real numbers"
        raise InvalidActionError(
            f"{name} {_shown(action)} is not in {space_text}: expected {expected}, got "
            f"{type(action).__name__} (dtype {array.dtype})"
        )
    if array.shape != batch_shape + space.shape:
        per_world = " (one action per world)" if num_worlds is not None else ""
        raise InvalidActionError(
            f"{name} {_shown(action)} is not in {space_text}: its shape is {array.shape}, expected "
            f"{batch_shape + space.shape}{per_world}"
        )
    if discrete:
        low, high = int(space.start), int(space.start + space.n)
        bad = (array < low) | (array >= high)
        reason = f"expected an integer in [{low}, {high})"
    else:
        with np.errstate(over="ignore"):  # a float64 beyond float32's range becomes inf, refused below
            array = array.astype(space.dtype, copy=False)
        bad = ~np.isfinite(array)
        reason = f"NaN or infinite (as {space.dtype}); finite values beyond the bounds are clamped to them"
        bad = bad.reshape(*batch_shape, -1).any(-1)
    if not bad.any():
        return array
    if num_worlds is None:
        raise InvalidActionError(f"{name} {_shown(action)} is not in {space_text}: {reason}")
    worlds = np.flatnonzero(bad)
    more = f" ({len(worlds)} worlds' actions are bad)" if len(worlds) > 1 else ""
    raise InvalidActionError(
        f"{name}[{worlds[0]}] = {_shown(array[worlds[0]])} is not in {space_text}: {reason}{more}"
    )


def _numpy(tensor: torch.Tensor) -> np.ndarray:
    # A copy, so that a caller editing its arrays in place cannot reach the env's tensors (the continuous core
    # hands the last noisy observation back on partial resets).
    return tensor.detach().cpu().numpy().copy()


def _info(view: EgoView | CentralizedView, out: TensorDictBase) -> dict[str, Any]:
    """Every world's info arrays, each with a leading (B,) axis."""
    world = out.get(WORLD)
    flags = world.get("info")
    agents = {key: _numpy(flags.get(key).squeeze(-1)) for key in INFO_KEYS}
    agents["reward"] = _numpy(world.get("reward").squeeze(-1))
    agents["cost"] = _numpy(world.get("cost").squeeze(-1))
    if isinstance(view, EgoView):
        success = agents["reached_goal"][:, view.ego]
    else:
        success = agents["reached_goal"].all(-1)
    return {
        "is_success": success,
        "cost": _numpy(out.get("cost").squeeze(-1)),
        "agents": agents,
        "state": _numpy(world.get("state")),
        "goal": _numpy(world.get("goal")),
    }


class SidewalkGymEnv(gymnasium.Env):
    """One Sidewalk world as a ``gymnasium.Env`` (``sidewalk/Discrete-v0`` or ``sidewalk/Continuous-v0``).

    ``domain`` is ``"discrete"`` or ``"continuous"``; ``opponent`` names the scripted opponent of the ego view or
    is ``"centralized"``; ``ego``, ``end_on_ego_done`` and ``opponent_kwargs`` go to ``EgoView``; every other
    keyword goes to the core env. ``reset(seed=...)`` seeds the world's generator (core, opponent and noise).
    ``step`` refuses an action outside ``action_space`` with ``InvalidActionError`` (``checked_action``).
    The TorchRL view behind it is ``self.view``, the worlds it shows ``self.world`` (``sidewalk.world.World``).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": list(WINDOW_RENDER_MODES), "render_fps": RENDER_FPS}

    def __init__(
        self,
        domain: str = "discrete",
        opponent: str = "random",
        *,
        render_mode: str | None = None,
        ego: int | None = None,
        end_on_ego_done: bool | None = None,
        opponent_kwargs: Mapping[str, Any] | None = None,
        device: str | torch.device = "cpu",
        **env_kwargs: Any,
    ) -> None:
        if render_mode is not None:
            check_choice("render_mode", render_mode, WINDOW_RENDER_MODES)
        self.render_mode = render_mode
        self._window = FrameWindow(ENV_IDS.get(domain, "sidewalk"), RENDER_FPS) if render_mode == "human" else None
        self.world, self.view = build_view(
            domain, 1, opponent, ego, end_on_ego_done, opponent_kwargs, device=device, **env_kwargs
        )
        self.observation_space, self.action_space = view_spaces(self.view)
        self._action_shape = tuple(self.view.full_action_spec["action"].shape)
        self._action_dtype = self.view.full_action_spec["action"].dtype

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; this env takes none")
        super().reset(seed=seed)
        if seed is not None:
            self.view.set_seed(seed)
        out = self.view._reset(None)
        self._show()
        return self._observation(out), self._single_info(out)

    def step(self, action: Any):
        checked = checked_action(action, self.action_space)
        action = torch.as_tensor(checked, dtype=self._action_dtype, device=self.view.device)
        out = self.view._step(TensorDict({"action": action.reshape(self._action_shape)}, batch_size=[1]))
        self._show()
        return (
            self._observation(out),
            float(out.get("reward")[0, 0]),
            bool(out.get("terminated")[0, 0]),
            bool(out.get("truncated")[0, 0]),
            self._single_info(out),
        )

    def _observation(self, out: TensorDictBase) -> np.ndarray:
        return _numpy(out.get("observation")[0])

    def _single_info(self, out: TensorDictBase) -> dict[str, Any]:
        info = _info(self.view, out)
        return {
            "is_success": bool(info["is_success"][0]),
            "cost": float(info["cost"][0]),
            "agents": {key: value[0] for key, value in info["agents"].items()},
            "state": info["state"][0],
            "goal": info["goal"][0],
        }

    def render(self) -> np.ndarray | None:
        """The world as an RGB uint8 array with ``render_mode="rgb_array"``; with ``"human"`` it is shown in a
        window (as ``reset`` and ``step`` do) and ``None`` returned; ``None`` (with a warning) without a mode."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() was called without a render mode; pass render_mode='rgb_array' (or 'human', a window) to "
                "gymnasium.make"
            )
            return None
        if self._window is not None:
            self._show()
            return None
        return self.view.render(0)

    def _show(self) -> None:
        """``render_mode="human"``: the world in the window (not drawn at all where no window opens)."""
        if self._window is not None and self._window.opens:
            self._window.show(self.view.render(0))

    def close(self) -> None:
        """Close the window of ``render_mode="human"``; the world itself lives in tensors."""
        if self._window is not None:
            self._window.close()


class SidewalkVectorEnv(VectorEnv):
    """``num_envs`` Sidewalk worlds as one ``gymnasium.vector.VectorEnv`` backed by one batched core env.

    Arguments are those of ``SidewalkGymEnv`` plus ``num_envs``. Observations, rewards and done flags are batched
    along a leading ``num_envs`` axis; autoreset is gymnasium's default next-step mode (see the module docstring).
    ``reset(seed=s)`` seeds the one generator shared by every world; ``reset(options={"reset_mask": mask})``
    resets only the worlds in the bool mask and returns every world's observation. ``render()`` returns one frame
    per world. ``step`` refuses actions of the wrong kind or shape, or any world's outside
    ``single_action_space``, with ``InvalidActionError`` naming the first bad world (``checked_action``;
    worlds about to autoreset included).
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": list(RENDER_MODES),
        "render_fps": RENDER_FPS,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        domain: str = "discrete",
        opponent: str = "random",
        *,
        render_mode: str | None = None,
        ego: int | None = None,
        end_on_ego_done: bool | None = None,
        opponent_kwargs: Mapping[str, Any] | None = None,
        device: str | torch.device = "cpu",
        **env_kwargs: Any,
    ) -> None:
        if render_mode is not None:
            check_choice("render_mode", render_mode, RENDER_MODES)
        self.render_mode = render_mode
        self.world, self.view = build_view(
            domain, num_envs, opponent, ego, end_on_ego_done, opponent_kwargs, device=device, **env_kwargs
        )
        self.num_envs = num_envs
        self.single_observation_space, self.single_action_space = view_spaces(self.view)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._action_shape = tuple(self.view.full_action_spec["action"].shape)
        self._action_dtype = self.view.full_action_spec["action"].dtype
        self._batch = torch.Size([num_envs])
        self._autoreset = torch.zeros(num_envs, dtype=torch.bool, device=self.view.device)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None and not isinstance(seed, int):
            raise TypeError(
                f"seed={seed!r} must be an int: one generator drives every world of the batched core"
            )
        super().reset(seed=seed)
        if seed is not None:
            self.view.set_seed(seed)
        options = dict(options or {})
        reset_mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; valid: 'reset_mask'")
        if reset_mask is None:
            out = self.view._reset(None)
            self._autoreset.zero_()
        else:
            rows = torch.as_tensor(np.asarray(reset_mask), dtype=torch.bool, device=self.view.device)
            if rows.shape != self._batch:
                raise ValueError(f"reset_mask has shape {tuple(rows.shape)}; expected ({self.num_envs},)")
            out = self.view._reset(TensorDict({"_reset": rows.unsqueeze(-1)}, batch_size=self._batch))
            self._autoreset &= ~rows
        return _numpy(out.get("observation")), self._vector_info(out)

    def step(self, actions: Any):
        checked = checked_action(actions, self.single_action_space, self.num_envs, name="actions")
        action = torch.as_tensor(checked, dtype=self._action_dtype, device=self.view.device)
        out = self.view._step(
            TensorDict({"action": action.reshape(self._action_shape)}, batch_size=self._batch)
        )
        reward = out.get("reward").squeeze(-1)
        rows = self._autoreset
        if rows.any():
            # Next-step autoreset: worlds that ended last step restart now. They were stepped with the others (one
            # batched step is cheaper than a masked one); the reset overwrites that step, whose reward is dropped.
            stepped = out
            out = self.view._reset(TensorDict({"_reset": rows.unsqueeze(-1)}, batch_size=self._batch))
            reward = reward.masked_fill(rows, 0.0)
            # A reset output zeroes every world's reward and cost; the worlds that did not restart keep their step's.
            for key in ("cost", (WORLD, "reward"), (WORLD, "cost")):
                step_value = stepped.get(key)
                restarted = rows.reshape(-1, *(1,) * (step_value.dim() - 1))
                out.set(key, step_value.masked_fill(restarted, 0.0))
        terminated = out.get("terminated").squeeze(-1)
        truncated = out.get("truncated").squeeze(-1)
        self._autoreset = terminated | truncated
        return (
            _numpy(out.get("observation")),
            _numpy(reward),
            _numpy(terminated),
            _numpy(truncated),
            self._vector_info(out),
        )

    def _vector_info(self, out: TensorDictBase) -> dict[str, Any]:
        info = _info(self.view, out)

        def with_masks(entries: dict[str, Any]) -> dict[str, Any]:
            masked = {}
            for key, value in entries.items():
                masked[key] = with_masks(value) if isinstance(value, dict) else value
                masked[f"_{key}"] = np.ones(self.num_envs, dtype=np.bool_)
            return masked

        return with_masks(info)

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB uint8 frame per world with ``render_mode="rgb_array"``; ``None`` (with a warning) without."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() was called without a render mode; pass render_mode='rgb_array' to gymnasium.make_vec"
            )
            return None
        return tuple(self.view.render(index) for index in range(self.num_envs))


def register_envs(
    ids: Mapping[str, str] = ENV_IDS,
    env_class: type = SidewalkGymEnv,
    vector_class: type = SidewalkVectorEnv,
    **options: Any,
) -> None:
    """Register one id per domain of ``ids`` with gymnasium (once per process), built by ``env_class`` and, for
    ``make_vec``, ``vector_class`` (by default ``sidewalk/Discrete-v0`` and ``sidewalk/Continuous-v0``; the
    Safety-Gymnasium face registers its own); ``options`` go to ``gymnasium.register``."""
    for domain, env_id in ids.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point=f"{env_class.__module__}:{env_class.__qualname__}",
            vector_entry_point=f"{vector_class.__module__}:{vector_class.__qualname__}",
            kwargs={"domain": domain},
            **options,
        )


register_envs()
