"""The paper's sidewalk (§3): two agents on the centre line walking toward each other's start."""

from __future__ import annotations

import math

from sidewalk._checks import check_int, check_range
from sidewalk.envs.layouts.base import GridLayout, PlaneLayout, Scenario, check_agents


def sidewalk_grid(rows: int = 7, cols: int = 15, n_agents: int = 2, min_start_goal_cells: int = 0) -> GridLayout:
    """The paper's discrete sidewalk: two agents on the centre line at opposite ends, goals at the far ends."""
    check_int("width_cells", rows, 1)
    check_int("length_cells", cols, 2)
    check_agents("sidewalk", n_agents, 2, 2)
    center = rows // 2
    return GridLayout(
        rows=rows,
        cols=cols,
        starts=((center, 0), (center, cols - 1)),
        goals=((center, cols - 1), (center, 0)),
        center_row=(rows - 1) / 2,
    )


def sidewalk_plane(
    length_m: float = 4.0,
    width_m: float = 3.0,
    n_agents: int = 2,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 0.0,
    end_margin_m: float = 0.5,
) -> PlaneLayout:
    """The paper's continuous sidewalk: two agents on the centre line facing each other, goals at the far ends."""
    check_range("length_m", length_m, 0.0, low_open=True)
    check_range("width_m", width_m, 0.0, low_open=True)
    check_range("end_margin_m", end_margin_m, 0.0, length_m / 2, low_open=True)
    check_agents("sidewalk", n_agents, 2, 2)
    mid = width_m / 2
    near, far = end_margin_m, length_m - end_margin_m
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=((near, mid), (far, mid)),
        headings=(0.0, math.pi),
        goals=((far, mid), (near, mid)),
    )


SCENARIO = Scenario(
    "sidewalk",
    grid=sidewalk_grid,
    plane=sidewalk_plane,
    rank=1,
)
