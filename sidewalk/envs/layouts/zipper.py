"""Scenario ``zipper`` (zipper merge, paper §7): two cars in two lanes that narrow to one."""

from __future__ import annotations

from sidewalk.envs.layouts.base import GridLayout, PlaneLayout, Scenario, check_agents


def zipper_grid(rows: int, cols: int, n_agents: int = 2, min_start_goal_cells: int = 0) -> GridLayout:
    """Zipper merge: two lanes (the two middle rows; the rows beside them are wall) narrowing to one lane at the
    merge column, two thirds along. Both cars start at the left end, side by side; the car in the upper lane heads
    for the lower lane just before the merge, the car in the lower lane for the end of the upper lane (the one
    that continues): they must swap lanes without blocking each other."""
    check_agents("zipper", n_agents, 2, 2)
    if rows < 2 or cols < 6:
        raise ValueError(f"layout 'zipper' needs width_cells ≥ 2 and length_cells ≥ 6; got {rows}×{cols}")
    upper, lower = rows // 2 - 1, rows // 2
    merge = (2 * cols) // 3
    blocked = [(r, c) for r in range(rows) if r not in (upper, lower) for c in range(cols)]
    blocked += [(lower, c) for c in range(merge, cols)]
    return GridLayout(
        rows=rows,
        cols=cols,
        starts=((upper, 0), (lower, 0)),
        goals=((lower, merge - 1), (upper, cols - 1)),
        center_row=(upper + lower) / 2,
        blocked=tuple(blocked),
    )


def zipper_plane(
    length_m: float,
    width_m: float,
    n_agents: int = 2,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 0.0,
    end_margin_m: float = 0.5,
) -> PlaneLayout:
    """Zipper merge for two unicycle cars: two lanes (each half the width) narrowing to the upper one at the merge
    point, two thirds along. Both start at the left end, side by side; the car in the upper lane heads for the lower
    lane just before the merge, the car in the lower lane for the end of the lane that continues: they must swap
    lanes without blocking each other."""
    check_agents("zipper", n_agents, 2, 2)
    if width_m < 4 * agent_radius_m:
        raise ValueError(f"layout 'zipper' needs width_m ≥ {4 * agent_radius_m} m for two lanes; got {width_m}")
    lower, upper = width_m / 4, 3 * width_m / 4
    merge = 2 * length_m / 3
    near = end_margin_m
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=((near, upper), (near, lower)),
        headings=(0.0, 0.0),
        goals=((merge - end_margin_m - agent_radius_m, lower), (length_m - end_margin_m, upper)),
        boxes=((merge, 0.0, length_m, width_m / 2),),
    )


SCENARIO = Scenario(
    "zipper",
    grid=zipper_grid,
    plane=zipper_plane,
    rank=6,
)
