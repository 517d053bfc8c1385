"""Scenario ``door`` ("three stooges", paper §7): a wall across the world with a gap one agent wide."""

from __future__ import annotations

import math

from sidewalk.envs.layouts.base import (
    CLEARANCE_M,
    DOOR_SPACING_M,
    DOOR_WALL_M,
    TEAM_SPACING_M,
    GridLayout,
    PlaneLayout,
    Scenario,
    check_agents,
    round_up,
    spread,
)


def door_grid_capacity(rows: int, cols: int, min_start_goal_cells: int = 0) -> int:
    """Agents a ``rows`` × ``cols`` door room holds: one per row of the first column."""
    return rows


def door_grid_room(n_agents: int) -> tuple[int, int]:
    """(rows, cols) of the door room for ``n_agents`` when the user gives none: the preset's 7 × 15, with rows
    for every agent to start two rows apart."""
    return max(7, 2 * n_agents - 1), 15


def door_plane_capacity(
    length_m: float, width_m: float, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> int:
    """Agents a ``length_m`` × ``width_m`` door world holds: side by side across its first end, each a radius of
    free space from the side walls and starting clear of its neighbours."""
    if width_m < 2 * agent_radius_m:
        return 0
    return 1 + math.floor(max(width_m - 4 * agent_radius_m, 0.0) / (2 * agent_radius_m + CLEARANCE_M) + 1e-9)


def door_plane_room(
    n_agents: int, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> tuple[float, float]:
    """(length_m, width_m) of the door world for ``n_agents`` when the user gives none: the preset's 6 m long,
    wide enough for one more agent abreast (3 m for three)."""
    apart = 4 * agent_radius_m + (n_agents - 1) * (2 * agent_radius_m + CLEARANCE_M)  # what door_plane_capacity needs
    return 6.0, round_up(max(2 * agent_radius_m + TEAM_SPACING_M * n_agents, apart), 0.1)


def door_grid(rows: int, cols: int, n_agents: int = 2, min_start_goal_cells: int = 0) -> GridLayout:
    """"Three stooges": a wall across the middle column with a one-cell gap on the centre row; the agents start in
    the first column, two rows apart around the gap's row (agent 0 nearest it), their goals in the same rows of the
    last column: all must pass the gap one at a time."""
    check_agents("door", n_agents, 1, door_grid_capacity(rows, cols), room=f"{rows}×{cols}-cell")
    if cols < 5:
        raise ValueError(f"layout 'door' needs length_cells ≥ 5 (a wall between two sides); got {cols}")
    wall, gap = cols // 2, rows // 2
    # Two rows apart where they fit (nobody starts beside another), centred on the gap's row.
    spacing = 2 if 2 * (n_agents - 1) < rows else 1
    first = gap - (spacing * (n_agents - 1) + 1) // 2
    first = min(max(first, 0), rows - 1 - spacing * (n_agents - 1))
    # The agent nearest the gap's row comes first: agent 0 (the learner of an ego view) walks straight at the gap.
    agent_rows = sorted((first + spacing * i for i in range(n_agents)), key=lambda r: (abs(r - gap), r))
    return GridLayout(
        rows=rows,
        cols=cols,
        starts=tuple((r, 0) for r in agent_rows),
        goals=tuple((r, cols - 1) for r in agent_rows),
        center_row=(rows - 1) / 2,
        blocked=tuple((r, wall) for r in range(rows) if r != gap),
    )


def door_plane(
    length_m: float,
    width_m: float,
    n_agents: int = 2,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 0.0,
    end_margin_m: float = 0.5,
) -> PlaneLayout:
    """"Three stooges": a wall across the middle (``DOOR_WALL_M`` thick) with a gap of 1.5 agent diameters in the
    centre -- one agent passes, two side by side touch; the agents start ``DOOR_SPACING_M`` apart (less where the
    width is short, keeping a radius from the side walls) around the centre line at the first end (agent 0 nearest it), their goals in the same lines at
    the other end."""
    gap = 1.5 * 2 * agent_radius_m
    capacity = door_plane_capacity(length_m, width_m, agent_radius_m)
    check_agents("door", n_agents, 1, capacity, room=f"{length_m}×{width_m} m")
    x0, x1 = length_m / 2 - DOOR_WALL_M / 2, length_m / 2 + DOOR_WALL_M / 2
    y0, y1 = width_m / 2 - gap / 2, width_m / 2 + gap / 2
    # Each disc keeps a radius of free space from the side walls, room for a planner to turn.
    half_span = min(DOOR_SPACING_M * (n_agents - 1) / 2, width_m / 2 - 2 * agent_radius_m)
    ys = spread(n_agents, width_m / 2 - half_span, width_m / 2 + half_span)
    ys = sorted(ys, key=lambda y: (round(abs(y - width_m / 2), 6), y))  # agent 0 nearest the gap's line
    near, far = end_margin_m, length_m - end_margin_m
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=tuple((near, y) for y in ys),
        headings=(0.0,) * n_agents,
        goals=tuple((far, y) for y in ys),
        boxes=((x0, 0.0, x1, y0), (x0, y1, x1, width_m)),
    )


SCENARIO = Scenario(
    "door",
    grid=door_grid,
    plane=door_plane,
    grid_capacity=door_grid_capacity,
    grid_room=door_grid_room,
    plane_capacity=door_plane_capacity,
    plane_room=door_plane_room,
    any_n_agents=True,
    rank=5,
)
