"""Geometry of a world: where the agents start, where their goals are, and what is wall.

A layout decides the number of agents, so an N-agent variant (circle, teams, door, lanes) is one new factory
here and nothing else. ``sample`` returns per-world starts and goals, so a layout may randomise them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from sidewalk._checks import check_choice, check_int, check_range


@dataclass(frozen=True)
class GridLayout:
    """A grid of ``rows`` (across the sidewalk) × ``cols`` (along it); cells are addressed (row, col)."""

    rows: int
    cols: int
    starts: tuple[tuple[int, int], ...]
    goals: tuple[tuple[int, int], ...]
    center_row: float
    blocked: tuple[tuple[int, int], ...] = ()  # interior wall cells; the border of the grid is always wall

    def __post_init__(self) -> None:
        check_int("rows", self.rows, 1)
        check_int("cols", self.cols, 1)
        if len(self.starts) != len(self.goals) or not self.starts:
            raise ValueError(f"a layout needs one goal per start; got {len(self.starts)} starts, {len(self.goals)} goals")
        for what, cells in (("starts", self.starts), ("goals", self.goals), ("blocked", self.blocked)):
            for row, col in cells:
                if not (0 <= row < self.rows and 0 <= col < self.cols):
                    raise ValueError(f"{what} cell {(row, col)} lies outside the {self.rows}×{self.cols} grid")
        if len(set(self.starts)) != len(self.starts):
            raise ValueError(f"two agents share a start cell: {self.starts}")

    # Fixed layouts give every world the same starts and goals; a layout that randomises them sets this False.
    fixed = True

    @property
    def n_agents(self) -> int:
        return len(self.starts)

    def blocked_mask(self, device: torch.device) -> torch.Tensor:
        """Bool (rows, cols): True where a cell is an interior wall."""
        mask = torch.zeros(self.rows, self.cols, dtype=torch.bool, device=device)
        for row, col in self.blocked:
            mask[row, col] = True
        return mask

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Starts and goals of ``n`` worlds, each int64 (n, N, 2). Fixed layouts ignore ``generator``."""
        device = generator.device
        starts = torch.tensor(self.starts, dtype=torch.long, device=device)
        goals = torch.tensor(self.goals, dtype=torch.long, device=device)
        return starts.expand(n, -1, -1), goals.expand(n, -1, -1)


@dataclass(frozen=True)
class PlaneLayout:
    """A rectangle ``length_m`` (x) × ``width_m`` (y) with walls on its border and optional interior boxes."""

    length_m: float
    width_m: float
    starts: tuple[tuple[float, float], ...]
    headings: tuple[float, ...]
    goals: tuple[tuple[float, float], ...]
    boxes: tuple[tuple[float, float, float, float], ...] = ()  # interior walls as (x_min, y_min, x_max, y_max)

    def __post_init__(self) -> None:
        check_range("length_m", self.length_m, 0.0, low_open=True)
        check_range("width_m", self.width_m, 0.0, low_open=True)
        if not (len(self.starts) == len(self.goals) == len(self.headings)) or not self.starts:
            raise ValueError("a layout needs one heading and one goal per start")
        for what, points in (("starts", self.starts), ("goals", self.goals)):
            for x, y in points:
                if not (0.0 <= x <= self.length_m and 0.0 <= y <= self.width_m):
                    raise ValueError(f"{what} point {(x, y)} lies outside the {self.length_m}×{self.width_m} m world")

    @property
    def n_agents(self) -> int:
        return len(self.starts)

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Start positions (n, N, 2), start headings (n, N) and goals (n, N, 2) of ``n`` worlds, float32."""
        device = generator.device
        starts = torch.tensor(self.starts, dtype=torch.float32, device=device)
        headings = torch.tensor(self.headings, dtype=torch.float32, device=device)
        goals = torch.tensor(self.goals, dtype=torch.float32, device=device)
        return starts.expand(n, -1, -1), headings.expand(n, -1), goals.expand(n, -1, -1)


def sidewalk_grid(rows: int = 7, cols: int = 15) -> GridLayout:
    """The paper's discrete sidewalk: two agents on the centre line at opposite ends, goals at the far ends."""
    check_int("width_cells", rows, 1)
    check_int("length_cells", cols, 2)
    center = rows // 2
    return GridLayout(
        rows=rows,
        cols=cols,
        starts=((center, 0), (center, cols - 1)),
        goals=((center, cols - 1), (center, 0)),
        center_row=(rows - 1) / 2,
    )


def sidewalk_plane(length_m: float = 4.0, width_m: float = 3.0, end_margin_m: float = 0.5) -> PlaneLayout:
    """The paper's continuous sidewalk: two agents on the centre line facing each other, goals at the far ends."""
    check_range("length_m", length_m, 0.0, low_open=True)
    check_range("width_m", width_m, 0.0, low_open=True)
    check_range("end_margin_m", end_margin_m, 0.0, length_m / 2, low_open=True)
    mid = width_m / 2
    near, far = end_margin_m, length_m - end_margin_m
    return PlaneLayout(
        length_m=length_m,
        width_m=width_m,
        starts=((near, mid), (far, mid)),
        headings=(0.0, math.pi),
        goals=((far, mid), (near, mid)),
    )


GRID_LAYOUTS: dict[str, Callable[..., GridLayout]] = {"sidewalk": sidewalk_grid}
PLANE_LAYOUTS: dict[str, Callable[..., PlaneLayout]] = {"sidewalk": sidewalk_plane}


def grid_layout(name: str, rows: int, cols: int) -> GridLayout:
    check_choice("layout", name, GRID_LAYOUTS)
    return GRID_LAYOUTS[name](rows, cols)


def plane_layout(name: str, length_m: float, width_m: float) -> PlaneLayout:
    check_choice("layout", name, PLANE_LAYOUTS)
    return PLANE_LAYOUTS[name](length_m, width_m)
