"""Scenario ``circle``: N agents evenly spaced on a circle (grid: the border of a room), goals opposite."""

from __future__ import annotations

import math

from sidewalk.envs.layouts.base import CLEARANCE_M, GridLayout, PlaneLayout, Scenario, check_agents, round_up


def _border(rows: int, cols: int) -> list[tuple[int, int]]:
    """The border cells of a ``rows`` × ``cols`` room, clockwise from the top-left corner."""
    return (
        [(0, c) for c in range(cols)]
        + [(r, cols - 1) for r in range(1, rows)]
        + [(rows - 1, c) for c in range(cols - 2, -1, -1)]
        + [(r, 0) for r in range(rows - 2, 0, -1)]
    )


def circle_grid_capacity(rows: int, cols: int, min_start_goal_cells: int = 0) -> int:
    """Agents a ``rows`` × ``cols`` circle room holds: one on every other border cell."""
    return len(_border(rows, cols)) // 2


def circle_grid_room(n_agents: int) -> tuple[int, int]:
    """(rows, cols) of the circle room for ``n_agents`` when the user gives none: the preset's 9 × 9 square,
    grown so that neighbours start about two cells apart."""
    side = max(9, n_agents + 1)
    return side, side


def circle_plane_capacity(
    length_m: float, width_m: float, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> int:
    """Agents a ``length_m`` × ``width_m`` circle world holds on its largest circle, neighbours starting
    clear of each other."""
    radius = min(length_m, width_m) / 2 - agent_radius_m - CLEARANCE_M
    # Neighbours on the circle are 2·R·sin(π/N) apart and must start clear of each other (two: 2·R apart).
    if 2 * radius < 2 * agent_radius_m + CLEARANCE_M:
        return 1  # not even two fit: the layout refuses every count it takes
    fit = 2
    while 2 * radius * math.sin(math.pi / (fit + 1)) >= 2 * agent_radius_m + CLEARANCE_M:
        fit += 1
    return fit


def circle_plane_room(
    n_agents: int, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> tuple[float, float]:
    """(length_m, width_m) of the circle world for ``n_agents`` when the user gives none: the preset's 5 m
    square, grown so that neighbours start twice as far apart as they must."""
    circle_radius = 2 * (2 * agent_radius_m + CLEARANCE_M) / (2 * math.sin(math.pi / max(n_agents, 2)))
    side = max(5.0, round_up(2 * (circle_radius + agent_radius_m + CLEARANCE_M), 0.5))
    return side, side


def circle_grid(rows: int, cols: int, n_agents: int = 4, min_start_goal_cells: int = 0) -> GridLayout:
    """Agents evenly spaced along the border of the room, each goal the cell point-opposite through the centre,
    so every path crosses the middle; with an even number, each agent's goal is another agent's start."""
    check_agents("circle", n_agents, 2, circle_grid_capacity(rows, cols), room=f"{rows}×{cols}-cell")
    border = _border(rows, cols)
    starts = tuple(border[round(i * len(border) / n_agents) % len(border)] for i in range(n_agents))
    goals = tuple((rows - 1 - r, cols - 1 - c) for r, c in starts)
    return GridLayout(rows=rows, cols=cols, starts=starts, goals=goals, center_row=(rows - 1) / 2)


def circle_plane(
    length_m: float,
    width_m: float,
    n_agents: int = 4,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 0.0,
) -> PlaneLayout:
    """Agents evenly spaced on the largest circle that fits, facing the centre; goals diametrically opposite."""
    radius = min(length_m, width_m) / 2 - agent_radius_m - CLEARANCE_M
    capacity = circle_plane_capacity(length_m, width_m, agent_radius_m)
    check_agents("circle", n_agents, 2, capacity, room=f"{length_m}×{width_m} m")
    cx, cy = length_m / 2, width_m / 2
    angles = [2 * math.pi * i / n_agents for i in range(n_agents)]
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=tuple((cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in angles),
        headings=tuple(math.remainder(a + math.pi, 2 * math.pi) for a in angles),
        goals=tuple((cx - radius * math.cos(a), cy - radius * math.sin(a)) for a in angles),
    )


SCENARIO = Scenario(
    "circle",
    grid=circle_grid,
    plane=circle_plane,
    grid_capacity=circle_grid_capacity,
    grid_room=circle_grid_room,
    plane_capacity=circle_plane_capacity,
    plane_room=circle_plane_room,
    any_n_agents=True,
    rank=3,
)
