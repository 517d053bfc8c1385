"""Scripted partners with a convention of their own, in both domains: the ad-hoc teamwork test's partners
(``opponent=convention opponent.params.style=keep_left``).

Each walks a lane parallel to the sidewalk's centre line toward its goal, merging onto its goal's line near the end,
and ignores where the other agents are except as its style says:

- ``keep_left`` / ``keep_right``: its lane lies ``lane_fraction`` of the free half-width to its own left / right, so
  it passes an oncoming agent on that side (as the cross-play's ``convention`` reads a passing side);
- ``never_yields``: walks its line (the centre line, shifted left by ``lane_fraction``, 0 by default) whatever comes;
- ``always_yields``: walks its line, but while another present agent is ahead of it, coming, within
  ``yield_fraction`` of the sidewalk's length, it steps aside to its right, against the wall, and waits there;
- ``hesitates``: walks its line, and each step, with probability ``hesitate_prob`` (drawn from the env's generator:
  one seed, one run), stops for ``hesitate_steps`` steps.

Waiting: in the continuous world the agent brakes to a stop (the PRM's controller with a target speed of 0); the grid
has no action that stays, so it steps back and forth along the sidewalk (back first, forward where back would leave
the grid). Every world is computed at once as tensor operations; the hesitation and the back-and-forth keep a
per-world count that ``reset(rows)`` clears.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from sidewalk._checks import check_choice, check_int, check_range
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.envs.grid import ACTIONS
from sidewalk.opponents.base import Opponent, env_domain
from sidewalk.opponents.prm import steer_toward

STYLES = ("keep_left", "keep_right", "always_yields", "never_yields", "hesitates")
LANE_FRACTION = (
    0.6  # keep_left/keep_right: the lane's offset, of the free half-width (0.72 m; 2 of 3 grid cells)
)
YIELD_FRACTION = 0.5  # always_yields: steps aside once an oncoming agent is within half the sidewalk's length
HESITATE_PROB = 0.1  # hesitates: the chance per step of a pause ...
HESITATE_STEPS = 5  # ... of this many steps
LOOKAHEAD_M = 0.8  # continuous: the waypoint lies this far ahead on the lane ...
MERGE_M = 1.0  # ... until the goal is this close along the sidewalk; then the goal is the waypoint
ASIDE_AHEAD_M = 0.3  # a yielding agent heads for the wall this far ahead, not square to its path
ASIDE_TOLERANCE_M = 0.1  # ... and stops once within this of its spot
WALL_GAP_M = 0.05  # lanes and the yielding spot keep this much room from the wall
UP, DOWN, LEFT, RIGHT = (ACTIONS.index(name) for name in ("UP", "DOWN", "LEFT", "RIGHT"))


class ConventionOpponent(Opponent):
    """A scripted partner that follows one convention (``style``, see the module docstring), in either domain.

    ``lane_fraction`` (0 to 1, default 0.6 for keep_left/keep_right, 0 for the others): how far its lane lies from
    the centre line, as a fraction of the room between the centre line and the wall (grid: rounded to whole cells);
    ``yield_fraction``: how near, as a fraction of the sidewalk's length, an oncoming agent makes ``always_yields``
    step aside; ``hesitate_prob``, ``hesitate_steps``: ``hesitates``'s pauses. Parameters of other styles are
    checked and unused.
    """

    name = "convention"
    listed = False  # not one of the paper's opponents: chosen by name only
    # Each replica's own instance: its pauses draw from that replica's generator and its counts are its worlds'.
    per_replica = True
    lookahead_m = LOOKAHEAD_M  # continuous: how far ahead on its lane it steers (nearer: a sharper step aside)

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled: Sequence[int] = (1,),
        ego: int | None = 0,
        *,
        style: str = "keep_left",
        lane_fraction: float | None = None,
        yield_fraction: float = YIELD_FRACTION,
        hesitate_prob: float = HESITATE_PROB,
        hesitate_steps: int = HESITATE_STEPS,
    ) -> None:
        super().__init__(env, controlled, ego)
        check_choice("style", style, STYLES)
        if lane_fraction is None:
            lane_fraction = LANE_FRACTION if style in ("keep_left", "keep_right") else 0.0
        check_range("lane_fraction", lane_fraction, 0.0, 1.0)
        check_range("yield_fraction", yield_fraction, 0.0, 1.0, low_open=True)
        check_range("hesitate_prob", hesitate_prob, 0.0, 1.0)
        check_int("hesitate_steps", hesitate_steps, 1)
        self.style = style
        self.lane_fraction = float(lane_fraction)
        self.yield_fraction = float(yield_fraction)
        self.hesitate_prob = float(hesitate_prob)
        self.hesitate_steps = hesitate_steps
        self._grid = env_domain(env) == "discrete"
        # +1: the lane lies to the agent's left of the centre line; keep_right mirrors it.
        self._side = -1.0 if style == "keep_right" else 1.0
        self._pause_left: torch.Tensor | None = None  # (B, C) steps of the current pause still to wait
        self._ticks: torch.Tensor | None = (
            None  # (B,) steps since the world's reset: the grid's back-and-forth
        )
        if self._grid:
            layout = env.layout
            half = (layout.rows - 1) / 2
            self._lane_cells = round(self.lane_fraction * half)
            self._aside_cells = int(half)
            self._yield_cells = self.yield_fraction * layout.cols
        else:
            layout, params = env.layout, env.params
            free_half_m = layout.width_m / 2 - params.agent_radius_m - WALL_GAP_M
            self._lane_m = self.lane_fraction * free_half_m
            self._aside_m = free_half_m
            self._yield_m = self.yield_fraction * layout.length_m
            self._x_limits = (params.agent_radius_m, layout.length_m - params.agent_radius_m)
            self._y_limits = (params.agent_radius_m, layout.width_m - params.agent_radius_m)

    def reset(self, rows: torch.Tensor | None = None) -> None:
        if self._pause_left is None:
            return
        if rows is None:
            self._pause_left.zero_()
            self._ticks.zero_()
        else:
            self._pause_left.masked_fill_(rows.unsqueeze(-1), 0)
            self._ticks.masked_fill_(rows, 0)

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        n_worlds, n_controlled = state.shape[0], len(self.controlled)
        if self._pause_left is None or self._pause_left.shape[0] != n_worlds:
            self._pause_left = torch.zeros(n_worlds, n_controlled, dtype=torch.long, device=state.device)
            self._ticks = torch.zeros(n_worlds, dtype=torch.long, device=state.device)
        waiting = self._waiting(state, goal, done, present)
        self._ticks += 1
        if self._grid:
            return self._grid_moves(state, goal, done, present, waiting)
        return self._unicycle_controls(state, goal, done, present, waiting)

    def _lane_side(self) -> int | torch.Tensor:
        """+1: the lane lies to the agent's left of the centre line, -1 to its right (a partner that picks its side
        per world returns a (B, C) tensor, 0 where it keeps to the centre line)."""
        return int(self._side)

    # ---- when to wait -----------------------------------------------------------------------------------------

    def _waiting(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None
    ) -> torch.Tensor:
        """Bool (B, C): the controlled agents pausing this step (hesitates; always_yields waits by ``_yielding``)."""
        if self.style != "hesitates":
            return torch.zeros(self._pause_left.shape, dtype=torch.bool, device=state.device)
        starts = (self.env.rand(tuple(self._pause_left.shape)) < self.hesitate_prob) & (self._pause_left == 0)
        self._pause_left = torch.where(starts, self.hesitate_steps, self._pause_left)
        waiting = self._pause_left > 0
        self._pause_left = (self._pause_left - 1).clamp(min=0)
        return waiting & ~done[:, self._controlled_index].squeeze(-1)

    def _yielding(
        self,
        along: torch.Tensor,
        heading: torch.Tensor,
        state: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None,
        reach: float,
    ) -> torch.Tensor:
        """Bool (B, C): for always_yields, the controlled agents with another present agent ahead (along their way,
        ``heading`` ±1) within ``reach``; False for other styles. ``along`` (B, N): every agent's coordinate along
        the sidewalk."""
        if self.style != "always_yields":
            return torch.zeros(heading.shape, dtype=torch.bool, device=heading.device)
        return self._oncoming(along, heading, state, done, present, reach)[1].any(-1)

    def _oncoming(
        self,
        along: torch.Tensor,
        heading: torch.Tensor,
        state: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None,
        reach: float,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(ahead, coming), each (B, C, N): how far every agent is ahead of each controlled one along its way
        (``heading`` ±1, ``along`` (B, N) every agent's coordinate along the sidewalk), and whether it is another
        present agent ahead within ``reach``."""
        here = self.present(state, None, done, present)  # (B, N)
        ahead = heading.unsqueeze(-1) * (along.unsqueeze(1) - along[:, self._controlled_index].unsqueeze(-1))
        others = torch.ones(len(self.controlled), state.shape[1], dtype=torch.bool, device=state.device)
        others[torch.arange(len(self.controlled)), self._controlled_index] = False
        return ahead, (ahead > 0) & (ahead <= reach) & here.unsqueeze(1) & others

    # ---- the continuous world ---------------------------------------------------------------------------------

    def _unicycle_controls(
        self,
        state: torch.Tensor,
        goal: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None,
        waiting: torch.Tensor,
    ) -> torch.Tensor:
        layout, index = self.env.layout, self._controlled_index
        own, own_goal = state[:, index], goal[:, index]  # (B, C, 4), (B, C, 2)
        x, y = own[..., 0], own[..., 1]
        heading = torch.where(own_goal[..., 0] >= x, 1.0, -1.0)  # +1: walking toward +x, whose left is +y
        centre = layout.width_m / 2
        lane_y = centre + heading * self._lane_side() * self._lane_m
        merging = (own_goal[..., 0] - x).abs() <= MERGE_M
        way_x = torch.where(merging, own_goal[..., 0], x + heading * self.lookahead_m)
        way_y = torch.where(merging, own_goal[..., 1], lane_y)
        yielding = self._yielding(state[..., 0], heading, state, done, present, self._yield_m)
        aside_y = centre - heading * self._aside_m  # against the wall on its right
        way_x = torch.where(yielding, x + heading * ASIDE_AHEAD_M, way_x)
        way_y = torch.where(yielding, aside_y, way_y)
        stopped = waiting | (yielding & ((y - aside_y).abs() <= ASIDE_TOLERANCE_M))
        waypoint = torch.stack([way_x, way_y]).transpose(1, 2)  # (2, C, B)
        # The controller divides by -sin(heading): at a heading of exactly 0 that is -0, a wall at -inf that stops the
        # agent (the PRM never walks exactly along the axis; these lanes do). A nudge of 1e-6 rad changes nothing else.
        own = own.clone()
        own[..., 3] = torch.where(torch.sin(own[..., 3]) == 0, own[..., 3] + 1e-6, own[..., 3])
        accel, turn = steer_toward(
            own.permute(2, 1, 0),
            own_goal.permute(2, 1, 0),
            waypoint,
            self.env.params,
            self._x_limits,
            self._y_limits,
            speed_scale=(~stopped).t().float(),
        )
        action = torch.stack([accel, turn], dim=-1).transpose(0, 1)  # (B, C, 2)
        return action.masked_fill(done[:, index], 0.0)

    # ---- the grid ---------------------------------------------------------------------------------------------

    def _grid_moves(
        self,
        state: torch.Tensor,
        goal: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None,
        waiting: torch.Tensor,
    ) -> torch.Tensor:
        layout, index = self.env.layout, self._controlled_index
        row, col = state[:, index, 0], state[:, index, 1]  # (B, C)
        goal_row, goal_col = goal[:, index, 0], goal[:, index, 1]
        heading = torch.where(goal_col >= col, 1, -1)  # +1: walking toward +col, whose left is a smaller row
        centre = round(layout.center_row)
        lane_row = centre - heading * self._lane_side() * self._lane_cells
        # Back onto the goal's row once the steps left along the sidewalk are no more than those across.
        target_row = torch.where((goal_col - col).abs() <= (lane_row - goal_row).abs(), goal_row, lane_row)
        yielding = self._yielding(
            state[..., 1].float(), heading.float(), state, done, present, self._yield_cells
        )
        aside_row = centre + heading * self._aside_cells  # against the wall on its right
        target_row = torch.where(yielding, aside_row, target_row)
        across = torch.where(target_row < row, UP, DOWN)
        forward = torch.where(heading > 0, RIGHT, LEFT)
        move = torch.where(target_row != row, across, forward)
        # Waiting without a stay action: back and forth along the sidewalk, back first unless back leaves the grid.
        back = torch.where(heading > 0, LEFT, RIGHT)
        back_inside = (col - heading >= 0) & (col - heading < layout.cols)
        step_back = (self._ticks.unsqueeze(-1) % 2 == 1) & back_inside
        dither = torch.where(step_back, back, forward)
        stopped = waiting | (yielding & (row == aside_row))
        return torch.where(stopped, dither, move)
