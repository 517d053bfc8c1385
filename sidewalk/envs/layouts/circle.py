"""Scenario ``circle``: N agents evenly spaced on a circle (grid: the border of a room), goals opposite."""

from __future__ import annotations

import math

from sidewalk.envs.layouts.base import CLEARANCE_M, GridLayout, PlaneLayout, check_agents


def circle_grid(rows: int, cols: int, n_agents: int = 4, min_start_goal_cells: int = 0) -> GridLayout:
    """Agents evenly spaced along the border of the room, each goal the cell point-opposite through the centre,
    so every path crosses the middle; with an even number, each agent's goal is another agent's start."""
    border = (
        [(0, c) for c in range(cols)]
        + [(r, cols - 1) for r in range(1, rows)]
        + [(rows - 1, c) for c in range(cols - 2, -1, -1)]
        + [(r, 0) for r in range(rows - 2, 0, -1)]
    )
    check_agents("circle", n_agents, 2, len(border) // 2)
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
    # Neighbours on the circle are 2·R·sin(π/N) apart and must start clear of each other.
    fit = 2
    while 2 * radius * math.sin(math.pi / (fit + 1)) >= 2 * agent_radius_m + CLEARANCE_M:
        fit += 1
    check_agents("circle", n_agents, 2, fit)
    cx, cy = length_m / 2, width_m / 2
    angles = [2 * math.pi * i / n_agents for i in range(n_agents)]
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=tuple((cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in angles),
        headings=tuple(math.remainder(a + math.pi, 2 * math.pi) for a in angles),
        goals=tuple((cx - radius * math.cos(a), cy - radius * math.sin(a)) for a in angles),
    )
