"""The continuous Sidewalk: unicycle agents with bounded acceleration and turn rate (paper §3.1, SPEC §1)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torchrl.data import Bounded, Unbounded

from sidewalk._checks import check_choice, check_int, check_range
from sidewalk.envs.base import COSTS, RENDER_MODES, SidewalkEnvBase, new_output
from sidewalk.envs.geodesic import GeodesicDistance, blocked
from sidewalk.envs.layouts import PlaneLayout, RandomPlaneLayout, plane_layout, plane_room
from sidewalk.envs.layouts.jitter import JitteredPlaneLayout
from sidewalk.envs.rewards import RewardParams
from sidewalk.envs.shield import unicycle_shield

STATE_FIELDS = ("x", "y", "v", "theta")
OBSERVATION_FIELDS = ("x", "y", "v", "theta", "goal_x", "goal_y", "active", "present")
# The fields that carry observation noise: the flags say exactly who is still there.
NOISY_FIELDS = 6


@dataclass(frozen=True)
class ContinuousParams:
    """Parameters of the continuous Sidewalk.

    The paper fixes the bounds (``|acceleration| ≤ 1`` m/s², ``|turn| ≤ π/8`` per step, ``|v| ≤ 1`` m/s). The
    geometry is ours (SPEC §1): the straight walk takes about as many steps as the grid's, so the paper's one set of
    reward constants makes walking pay in both domains, and the width leaves a planner room to go around an agent on
    the centre line (``length_m=10, width_m=1.5, dt_s=0.1``, a walk so long that crashing at once paid more, did not).
    """

    layout: str = "sidewalk"  # a registered scenario (sidewalk.envs.layouts.scenario_names())
    n_agents: int = 2  # agents in the scenario (sidewalk and zipper: 2)
    min_start_goal_m: float = 1.5  # random layout: least distance from an agent's start to its goal
    # Fixed layouts: each reset moves every start (goal) by a uniform ±j m in x and y and turns every start heading
    # by a uniform ±rad (sidewalk.envs.layouts.jitter); 0: the scenario's own.
    start_jitter_m: float = 0.0
    goal_jitter_m: float = 0.0
    heading_jitter_rad: float = 0.0
    length_m: float = 4.0
    width_m: float = 3.0
    agent_radius_m: float = 0.3
    goal_radius_m: float = 0.3
    dt_s: float = 0.2
    max_speed_mps: float = 1.0
    max_accel_mps2: float = 1.0
    max_turn_rad: float = math.pi / 8
    noise: float = 0.0  # ε: uniform ±ε added to every action (before the bounds) and every observation
    max_steps: int = 300
    remove_crashed: bool = True
    check_actions: bool = True  # a non-finite action raises, naming its worlds, rather than turning them NaN
    cost: str = "collision"  # the safety cost ("agents", "cost"): "collision", or "near_miss" (collisions too)
    near_miss_margin: float = 0.3  # cost="near_miss": another agent's disc within this many metres of the agent's
    # True: each agent's observed goal is the next point of its shortest path around interior walls (the goal itself
    # where no wall stands between; sidewalk.envs.geodesic), so an agent sees where the door's gap is.
    observe_route: bool = False
    rewards: RewardParams = field(default_factory=RewardParams)

    def __post_init__(self) -> None:
        check_int("n_agents", self.n_agents, 1, 64)
        check_range("min_start_goal_m", self.min_start_goal_m, 0.0)
        check_range("start_jitter_m", self.start_jitter_m, 0.0)
        check_range("goal_jitter_m", self.goal_jitter_m, 0.0)
        check_range("heading_jitter_rad", self.heading_jitter_rad, 0.0, math.pi)
        check_range("length_m", self.length_m, 0.0, 1000.0, low_open=True)
        check_range("width_m", self.width_m, 0.0, 1000.0, low_open=True)
        check_range("agent_radius_m", self.agent_radius_m, 0.0, min(self.length_m, self.width_m) / 2, low_open=True)
        check_range("goal_radius_m", self.goal_radius_m, 0.0, low_open=True)
        check_range("dt_s", self.dt_s, 0.0, 1.0, low_open=True)
        check_range("max_speed_mps", self.max_speed_mps, 0.0, low_open=True)
        check_range("max_accel_mps2", self.max_accel_mps2, 0.0, low_open=True)
        check_range("max_turn_rad", self.max_turn_rad, 0.0, math.pi, low_open=True)
        check_range("noise", self.noise, 0.0, 10.0)
        check_int("max_steps", self.max_steps, 1)
        check_choice("cost", self.cost, COSTS)
        check_range("near_miss_margin", self.near_miss_margin, 0.0, low_open=True)
        for name in ("remove_crashed", "check_actions", "observe_route"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name}={getattr(self, name)!r} must be a bool")
        if not isinstance(self.rewards, RewardParams):
            raise TypeError(f"rewards={self.rewards!r} must be a RewardParams or a mapping of its fields")


def touches_box(boxes: torch.Tensor, x: torch.Tensor, y: torch.Tensor, distance_m: float) -> torch.Tensor:
    """Bool, the shape of ``x``: the point (x, y) lies within ``distance_m`` of an interior box (x_min, y_min, x_max,
    y_max) of ``boxes`` (n, 4), on the points' device."""
    x_min, y_min, x_max, y_max = boxes.unbind(-1)  # each (n,)
    x, y = x.unsqueeze(-1), y.unsqueeze(-1)
    near_x = torch.maximum(torch.minimum(x, x_max), x_min)
    near_y = torch.maximum(torch.minimum(y, y_max), y_min)
    return ((x - near_x).square() + (y - near_y).square() < distance_m**2).any(-1)


class ContinuousSidewalkEnv(SidewalkEnvBase):
    """The continuous Sidewalk as a batched multi-agent TorchRL env.

    Per agent: ``action`` is (acceleration m/s², turn rad) within ±(max_accel_mps2, max_turn_rad); ``state`` is
    (x, y, v, θ) with θ in [-π, π); ``goal`` is (x, y); ``observation`` lists (x, y, v, θ, goal_x, goal_y, active,
    present) of every agent in ego order (self first), the first six plus uniform ±``noise``: ``active`` is 1 while
    the agent still moves (not arrived, not crashed), ``present`` while it occupies space (moving or parked at its
    goal); a crashed agent removed from the world is all zeros, so no one sees it as an obstacle. With
    ``observe_route`` the observed goal is the next point of the agent's path around interior walls.

    One step: action noise, then the bounds; θ += turn; v = clip(v + a·dt, ±max_speed); (x, y) += v·(cos θ,
    sin θ)·dt. Collisions: a disc leaving the rectangle or touching an interior box at the end of the step, or
    its centre crossing a box during the step (so no dt passes through a wall; a disc may graze a corner); two
    discs coming closer than two radii at any time during the step (each moves in a straight line within a step,
    so the closest approach of the pair is exact and no dt lets them pass through each other). An agent is at its
    goal when its centre is within ``goal_radius_m`` of it; it then stops there.
    """

    Params = ContinuousParams
    shaping_weight_name = None  # two shaping terms, weighed in _advance: c_potential and c_progress

    room_sides = ("length_m", "width_m")
    # x, y, speed, cos and sin of the heading, goal x, y (positions over the room's sides, speed over the top
    # speed), present
    STATE_WIDTH = 8

    @staticmethod
    def _room(p: ContinuousParams, given: tuple[Any, Any], default: tuple[Any, Any]) -> tuple[float, float]:
        return plane_room(p.layout, p.n_agents, *given, default=default, agent_radius_m=p.agent_radius_m,
                          goal_radius_m=p.goal_radius_m)

    @staticmethod
    def layout_for(p: ContinuousParams) -> PlaneLayout | RandomPlaneLayout | JitteredPlaneLayout:
        """The layout that parameters ``p`` describe (raises on a bad scenario name or agent count, or on jitter
        bounds that put an agent into a wall)."""
        if isinstance(p.layout, (PlaneLayout, RandomPlaneLayout, JitteredPlaneLayout)):
            layout = p.layout
        else:
            layout = plane_layout(
                p.layout, p.length_m, p.width_m, p.n_agents, p.agent_radius_m, p.goal_radius_m, p.min_start_goal_m
            )
        if p.start_jitter_m or p.goal_jitter_m or p.heading_jitter_rad:
            return JitteredPlaneLayout(
                layout, p.agent_radius_m, p.goal_radius_m, p.start_jitter_m, p.goal_jitter_m, p.heading_jitter_rad
            )
        return layout

    def _make_layout(self) -> PlaneLayout | RandomPlaneLayout:
        return self.layout_for(self.params)

    def _init_world(self) -> None:
        p, device, n = self.params, self.device, self.n_agents
        self._action_high = torch.tensor([p.max_accel_mps2, p.max_turn_rad], device=device)
        # Coordinates live in separate (B, N) tensors and pairwise agent checks run agent-major, (N, N, B), with the
        # base's _not_self: broadcasting over a long last axis is faster than over trailing axes of size 2.
        self._ego_order = (torch.arange(n, device=device)[:, None] + torch.arange(n, device=device)) % n
        # The swept contact of agents i and j is that of j and i, bit for bit: it is computed for the pairs i < j
        # and copied to rows i·N + j and j·N + i of the (N·N, B) result, whose diagonal rows are True.
        self._pair_first, self._pair_second = torch.triu_indices(n, n, 1, device=device)
        self._pair_rows = torch.cat(
            [self._pair_first * n + self._pair_second, self._pair_second * n + self._pair_first]
        )
        self._self_pairs = torch.eye(n, dtype=torch.bool, device=device).view(n * n, 1)
        radius = p.agent_radius_m
        self._x_range = (radius, self.layout.length_m - radius)
        self._y_range = (radius, self.layout.width_m - radius)
        self._boxes = torch.tensor(self.layout.boxes, dtype=torch.float32, device=device).reshape(-1, 4)
        shape = (self.num_envs, n)
        self._x, self._y, self._speed, self._heading, self._goal_x, self._goal_y = (
            torch.zeros(shape, device=device) for _ in range(6)
        )
        self._present = torch.zeros(shape, dtype=torch.bool, device=device)
        self._c_potential, self._c_progress = float(p.rewards.c_potential), float(p.rewards.c_progress)
        # Progress is measured along the shortest path around interior walls: a straight line would pay for
        # walking into the door's wall.
        self._path_length = GeodesicDistance(self._boxes, self.layout.length_m, self.layout.width_m, radius)

    def _agent_specs(self) -> tuple[dict[str, Any], Any]:
        agents, device, n = (*self.batch_size, self.n_agents), self.device, self.n_agents
        specs = {
            "observation": Unbounded(shape=(*agents, len(OBSERVATION_FIELDS) * n), device=device),
            "state": Unbounded(shape=(*agents, len(STATE_FIELDS)), device=device),
            "goal": Unbounded(shape=(*agents, 2), device=device),
        }
        high = self._action_high.expand(*agents, 2)
        action = Bounded(-high, high, shape=(*agents, 2), device=device)
        return specs, action

    def _reset_world(self, reset: torch.Tensor) -> None:
        if self.layout.fixed:
            starts, headings, goals = self.layout.sample(self.num_envs, self._generator)
            self._x = torch.where(reset, starts[..., 0], self._x)
            self._y = torch.where(reset, starts[..., 1], self._y)
            self._goal_x = torch.where(reset, goals[..., 0], self._goal_x)
            self._goal_y = torch.where(reset, goals[..., 1], self._goal_y)
            wrapped = torch.remainder(headings + math.pi, 2 * math.pi) - math.pi  # layouts may say π; state: [-π, π)
            self._heading = torch.where(reset, wrapped, self._heading)
        else:
            # A random layout draws only the worlds being reset: with auto-reset, a few worlds a step.
            worlds = reset[:, 0].nonzero().squeeze(-1)
            starts, headings, goals = self.sample_layout(worlds)
            wrapped = torch.remainder(headings + math.pi, 2 * math.pi) - math.pi
            for name, value in (("_x", starts[..., 0]), ("_y", starts[..., 1]), ("_goal_x", goals[..., 0]),
                                ("_goal_y", goals[..., 1]), ("_heading", wrapped)):
                setattr(self, name, getattr(self, name).index_copy(0, worlds, value))
        self._speed = self._speed.masked_fill(reset, 0.0)
        self._present = self._present | reset

    def _uniform_noise(self, shape: torch.Size, rows: torch.Tensor | None = None) -> torch.Tensor:
        """Uniform ±noise of ``shape``; with ``rows`` (int64 worlds), drawn for the whole shape (of the replicas
        holding those worlds: ``rand``) but only those rows kept."""
        if rows is None:
            noise = self.rand(shape)
        else:
            drawn = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device).index_fill_(0, rows, True)
            noise = self.rand(shape, drawn).index_select(0, rows)
        return (2.0 * noise - 1.0) * self.params.noise

    def _advance(self, action: torch.Tensor, active: torch.Tensor):
        p = self.params
        if p.noise > 0.0:
            action = action + self._uniform_noise(action.shape)
        accel = action[..., 0].clamp(-p.max_accel_mps2, p.max_accel_mps2)
        turn = action[..., 1].clamp(-p.max_turn_rad, p.max_turn_rad)

        heading = self._heading + turn * active
        heading = torch.remainder(heading + math.pi, 2 * math.pi) - math.pi
        speed = (self._speed + accel * p.dt_s).clamp(-p.max_speed_mps, p.max_speed_mps) * active
        x = self._x + speed * torch.cos(heading) * p.dt_s
        y = self._y + speed * torch.sin(heading) * p.dt_s

        (x_low, x_high), (y_low, y_high) = self._x_range, self._y_range
        hit_wall = active & ((x < x_low) | (x > x_high) | (y < y_low) | (y > y_high))
        if self._boxes.numel():
            # The end of the step, and the centre's path: a long step (large dt_s or speed) must not cross a wall.
            crossed = blocked(torch.stack([self._x, self._y], -1), torch.stack([x, y], -1), self._boxes)
            hit_wall = hit_wall | (active & (self._touches_box(x, y) | crossed))
        # Like the grid, an agent that hits a wall stays where it was (removed, or an obstacle there).
        x, y = torch.where(hit_wall, self._x, x), torch.where(hit_wall, self._y, y)
        present = self._present & ~hit_wall if p.remove_crashed else self._present
        touching = self._swept_contact(x, y) & present.t().contiguous().unsqueeze(0) & self._not_self
        mover = active & ~hit_wall
        hit_agent = mover & touching.any(1).t()
        to_goal_sq = (self._goal_x - x).square() + (self._goal_y - y).square()
        reached = mover & ~hit_agent & (to_goal_sq <= p.goal_radius_m**2)
        shaping = self._c_potential * to_goal_sq
        if self._c_progress != 0.0:
            before = self._path_length(self._x, self._y, self._goal_x, self._goal_y)
            shaping = shaping + self._c_progress * (before - self._path_length(x, y, self._goal_x, self._goal_y))

        self._x, self._y, self._heading = x, y, heading
        self._speed = speed.masked_fill(reached | hit_wall | hit_agent, 0.0)
        self._present = present & ~hit_agent if p.remove_crashed else present
        return reached, hit_wall, hit_agent, shaping

    def _swept_contact(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Bool (N, N, B): agents i and j come closer than two radii at some time of the step that moves every
        agent in a straight line from its last position to (x, y) (B, N).

        In the pair's relative frame one disc moves from p0 to p0 + d; the gap is smallest at
        t = clamp(-p0·d / |d|², 0, 1), which covers agents that would pass through each other within a step.
        The relation is symmetric bit for bit (swapping i and j negates p0 and d exactly), so only the pairs i < j
        are computed; (x, y) and (dx, dy) are stacked to compute both coordinates in one operation.
        """
        n, batch = self.n_agents, self.num_envs
        points = torch.stack([self._x.t(), self._y.t(), x.t(), y.t()])  # (4, N, B): x0, y0, x1, y1
        # (4, P, B): x0, y0, x1, y1 of agent i minus those of agent j, for the pairs i < j.
        differences = points.index_select(1, self._pair_first) - points.index_select(1, self._pair_second)
        start = differences[:2]
        delta = differences[2:].sub_(start)  # (dx, dy): the relative motion in the step
        products = start * delta
        approach = products[0].add_(products[1]).neg_()
        squares = delta.square()
        closest = approach.div_(squares[0].add_(squares[1]).clamp_min_(1e-12)).clamp_(0.0, 1.0)
        gap = delta.mul_(closest).add_(start).square_()
        contact = gap[0].add_(gap[1]) < (2 * self.params.agent_radius_m) ** 2
        pairs = self._self_pairs.expand(n * n, batch).clone()
        pairs.index_copy_(0, self._pair_rows, torch.cat([contact, contact]))
        return pairs.view(n, n, batch)

    def shield_action(self, action: torch.Tensor, shielded: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The continuous shield (see the base class; the rule: ``sidewalk.envs.shield.unicycle_shield``)."""
        return unicycle_shield(self, action, shielded)

    def _centres(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self._x.t(), self._y.t()

    def _near(self, gap_sq: torch.Tensor) -> torch.Tensor:
        return gap_sq < (2 * self.params.agent_radius_m + self.params.near_miss_margin) ** 2  # discs' edges

    def _touches_box(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Bool (B, N): the agent's disc overlaps an interior box."""
        return touches_box(self._boxes, x, y, self.params.agent_radius_m)

    def _state_features(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        p = self.params
        x, y, speed, heading = state.unbind(-1)
        return torch.stack(
            [x / p.length_m, y / p.width_m, speed / p.max_speed_mps, heading.cos(), heading.sin(),
             goal[..., 0] / p.length_m, goal[..., 1] / p.width_m], dim=-1,
        )

    def _observe(self, worlds: torch.Tensor | None) -> dict[str, torch.Tensor]:
        fields = (self._x, self._y, self._speed, self._heading, self._goal_x, self._goal_y, self._active, self._present)
        if worlds is not None:
            fields = tuple(tensor.index_select(0, worlds) for tensor in fields)
        state = torch.stack(fields[:4], dim=-1)
        goal = torch.stack(fields[4:6], dim=-1)
        shown_goal = self._path_length.next_point(*fields[:2], *fields[4:6]) if self.params.observe_route else goal
        present = fields[7].unsqueeze(-1)
        flags = torch.stack(fields[6:], dim=-1).to(torch.float32)
        per_agent = torch.cat([state * present, shown_goal * present, flags], dim=-1)
        n, width = self.n_agents, len(OBSERVATION_FIELDS)
        observation = new_output((len(per_agent), n * n, width), torch.float32, self.device)
        torch.index_select(per_agent, 1, self._ego_order.view(-1), out=observation)
        if self.params.noise > 0.0:
            # A reset draws the noise of every world and keeps its own worlds' (the others keep what they were
            # shown), so the generator's stream does not depend on which worlds reset.
            noise = self._uniform_noise(torch.Size((self.num_envs, n, n * NOISY_FIELDS)), worlds)
            shown = observation[..., -1:]  # present: a removed agent stays all zeros
            observation[..., :NOISY_FIELDS].add_(noise.view(len(per_agent), n * n, NOISY_FIELDS) * shown)
        return {"observation": observation.view(len(per_agent), n, n * width), "state": state, "goal": goal}

    def render(self, env_index: int = 0, pixels_per_m: int = 60, *, mode: str = "rgb_array") -> np.ndarray:
        """The world ``env_index`` as an RGB uint8 array: agents as discs with a heading tick, goals as stars.
        ``mode``: ``"rgb_array"`` only (VMAS's keyword, which trainers such as BenchMARL pass)."""
        check_choice("mode", mode, RENDER_MODES)
        check_int("env_index", env_index, 0, self.num_envs - 1)
        from sidewalk.envs.render import draw_plane

        return draw_plane(
            length_m=self.layout.length_m,
            width_m=self.layout.width_m,
            boxes=self._boxes.cpu().numpy(),
            positions=torch.stack([self._x[env_index], self._y[env_index]], -1).cpu().numpy(),
            headings=self._heading[env_index].cpu().numpy(),
            goals=torch.stack([self._goal_x[env_index], self._goal_y[env_index]], -1).cpu().numpy(),
            present=self._present[env_index].cpu().numpy(),
            radius_m=self.params.agent_radius_m,
            pixels_per_m=pixels_per_m,
        )
