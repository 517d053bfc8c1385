"""Scenario ``teams`` (paper Fig. 9): two groups side by side facing each other, goals behind the other group."""

from __future__ import annotations

import math

from sidewalk.envs.layouts.base import (
    TEAM_SPACING_M,
    GridLayout,
    PlaneLayout,
    Scenario,
    check_agents,
    round_up,
    side_by_side,
    spread,
)


def teams_grid_capacity(rows: int, cols: int, min_start_goal_cells: int = 0) -> int:
    """Agents a ``rows`` × ``cols`` teams room holds: one per row at each end."""
    return 2 * rows


def teams_grid_room(n_agents: int) -> tuple[int, int]:
    """(rows, cols) of the teams room for ``n_agents`` when the user gives none: the preset's 12 columns, and
    one row more than a team needs (3 × 12 for 2 v 2)."""
    return n_agents // 2 + 1, 12


def teams_plane_capacity(
    length_m: float, width_m: float, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> int:
    """Agents a ``length_m`` × ``width_m`` teams world holds: two groups side by side across its ends."""
    return 2 * side_by_side(width_m, agent_radius_m)


def teams_plane_room(
    n_agents: int, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> tuple[float, float]:
    """(length_m, width_m) of the teams world for ``n_agents`` when the user gives none: the preset's 6 m
    long, wide enough for one more agent beside each group."""
    return 6.0, round_up(2 * agent_radius_m + TEAM_SPACING_M * (n_agents // 2), 0.1)


def teams_grid(rows: int, cols: int, n_agents: int = 4, min_start_goal_cells: int = 0) -> GridLayout:
    """Two groups of ``n_agents / 2`` in adjacent rows at the two ends, facing each other; each agent's goal is at
    the far end of its row, behind the other group (Fig. 9). With fewer free rows than agents there is no room for
    everyone to step aside at once."""
    capacity = teams_grid_capacity(rows, cols)
    check_agents("teams", n_agents, 2, capacity, even=True, room=f"{rows}×{cols}-cell")
    per_team = n_agents // 2
    first = (rows - per_team) // 2
    team_rows = range(first, first + per_team)
    starts = tuple((r, 0) for r in team_rows) + tuple((r, cols - 1) for r in team_rows)
    goals = tuple((r, cols - 1) for r in team_rows) + tuple((r, 0) for r in team_rows)
    return GridLayout(rows=rows, cols=cols, starts=starts, goals=goals, center_row=(rows - 1) / 2)


def teams_plane(
    length_m: float,
    width_m: float,
    n_agents: int = 4,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 0.0,
    end_margin_m: float = 0.5,
) -> PlaneLayout:
    """Two groups of ``n_agents / 2`` side by side (``SIDE_BY_SIDE_M`` apart) at the two ends, facing each other;
    each agent's goal is at the far end of its line, behind the other group (Fig. 9)."""
    per_team = n_agents // 2
    capacity = teams_plane_capacity(length_m, width_m, agent_radius_m)
    check_agents("teams", n_agents, 2, capacity, even=True, room=f"{length_m}×{width_m} m")
    half_span = (per_team - 1) * TEAM_SPACING_M / 2
    ys = spread(per_team, width_m / 2 - half_span, width_m / 2 + half_span)
    near, far = end_margin_m, length_m - end_margin_m
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=tuple((near, y) for y in ys) + tuple((far, y) for y in ys),
        headings=(0.0,) * per_team + (math.pi,) * per_team,
        goals=tuple((far, y) for y in ys) + tuple((near, y) for y in ys),
    )


SCENARIO = Scenario(
    "teams",
    grid=teams_grid,
    plane=teams_plane,
    grid_capacity=teams_grid_capacity,
    grid_room=teams_grid_room,
    plane_capacity=teams_plane_capacity,
    plane_room=teams_plane_room,
    any_n_agents=True,
    rank=4,
)
