"""What every scenario is made of: its declaration (``Scenario``), the fixed layouts of both domains
(``GridLayout``, ``PlaneLayout``), and the helpers the scenario files share (agent counts, spacing, clearances)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.registry import LAYOUTS


@dataclass(frozen=True)
class Scenario:
    """A scenario (``env.layout=NAME``), declared once in its own module; declaring it registers it.

    ``grid(rows, cols, n_agents, min_start_goal_cells)`` and ``plane(length_m, width_m, n_agents, agent_radius_m,
    goal_radius_m, min_start_goal_m)`` build its layout in each domain it has (``None``: not in that domain). A
    scenario for any number of agents also says how many agents a room holds (``grid_capacity(rows, cols,
    min_start_goal_cells)``, ``plane_capacity(length_m, width_m, agent_radius_m, goal_radius_m)``) and its own room
    for N agents (``grid_room(n_agents)``, ``plane_room(n_agents, agent_radius_m, goal_radius_m)``), from which an
    env given no size picks its room. ``rank`` orders tables and galleries (the built-ins: the paper's order).
    ``draws_starts``: its layout draws every world's starts and goals (``random``), so an evaluation protocol's
    start/goal jitter leaves it as it is.
    """

    name: str
    grid: Callable[..., Any] | None = None
    plane: Callable[..., Any] | None = None
    grid_capacity: Callable[..., int] | None = None
    grid_room: Callable[[int], tuple[int, int]] | None = None
    plane_capacity: Callable[..., int] | None = None
    plane_room: Callable[..., tuple[float, float]] | None = None
    any_n_agents: bool = False
    rank: int = 100
    draws_starts: bool = False  # its layout draws starts and goals per world already: no start/goal jitter applies

    def __post_init__(self) -> None:
        if self.grid is None and self.plane is None:
            raise TypeError(f"scenario {self.name!r} builds no layout: give grid=..., plane=... or both")
        LAYOUTS.register(self.name, self)

    @property
    def domains(self) -> tuple[str, ...]:
        return tuple(domain for domain, build in (("discrete", self.grid), ("continuous", self.plane)) if build)


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
        return blocked_mask_of(self.rows, self.cols, self.blocked, device)

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

    fixed = True  # every world gets the same starts and goals

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

# Free space kept between discs (and between a disc and a wall) when the scenarios place agents, in metres.
CLEARANCE_M = 0.1
# Centre-to-centre spacing of agents side by side (teams, door): two radii plus a gap of 0.2 m.
TEAM_SPACING_M = 0.8
DOOR_WALL_M = 0.2  # thickness of the door's wall
DOOR_SPACING_M = 1.2  # centre-to-centre spacing of the door's agents at the start
# What a refusal of too many agents for the room suggests.
LARGER_ROOM_HINT = "give a larger room, or none: the layout then picks one that holds its agents"


def blocked_mask_of(rows: int, cols: int, blocked: tuple[tuple[int, int], ...], device: torch.device) -> torch.Tensor:
    """Bool (rows, cols): True at the ``blocked`` cells."""
    mask = torch.zeros(rows, cols, dtype=torch.bool, device=device)
    for row, col in blocked:
        mask[row, col] = True
    return mask


def clear_of(candidates: torch.Tensor, placed: torch.Tensor, gap: float) -> torch.Tensor:
    """Bool (n, K): candidate points (n, K, 2) at least ``gap`` from every placed point (n, P, 2). Written out
    rather than ``torch.cdist``, whose batched path is ~50× slower on 2-D points."""
    dx = candidates[..., 0, None] - placed[:, None, :, 0]
    dy = candidates[..., 1, None] - placed[:, None, :, 1]
    return (dx.square() + dy.square() >= gap * gap).all(-1)


def check_agents(
    layout: str,
    n_agents: int,
    low: int,
    high: int | None = None,
    *,
    even: bool = False,
    room: str | None = None,
) -> None:
    """Raise naming the counts the scenario ``layout`` takes unless ``n_agents`` is one of them; ``room``
    (e.g. ``"4.0×3.0 m"``) names the room that sets ``high``, so that a room too small for its agents is
    named."""
    check_int("n_agents", n_agents, 1)
    too_many = high is not None and n_agents > high
    if n_agents < low or too_many or (even and n_agents % 2):
        span = f"{low}..{'any' if high is None else high}"
        need = f"exactly {low}" if high == low else f"an even number in {span}" if even else span
        where = f" in the {room} room" if room else ""
        hint = f"; {LARGER_ROOM_HINT}" if room and too_many else ""
        raise ValueError(
            f"layout {layout!r} takes {need} agents{where}; got n_agents={n_agents}{hint} "
            f"(layouts for any number: {', '.join(LAYOUTS.names(lambda scenario: scenario.any_n_agents))})"
        )


def side_by_side(width_m: float, agent_radius_m: float) -> int:
    """How many agents fit side by side, ``TEAM_SPACING_M`` apart, across a ``width_m``-wide world."""
    return int((width_m - 2 * agent_radius_m) // TEAM_SPACING_M) + 1


def round_up(value: float, step: float) -> float:
    """``value`` rounded up to a multiple of ``step`` (a room's side: round numbers, never smaller)."""
    # The rounding to 9 places keeps 2.4000000000000004 at 2.4 rather than one step more.
    return round(math.ceil(round(value / step, 9)) * step, 9)


def spread(count: int, low: float, high: float) -> list[float]:
    """``count`` evenly spaced values centred in [low, high] (one value: the centre)."""
    if count == 1:
        return [(low + high) / 2]
    step = (high - low) / (count - 1)
    return [low + i * step for i in range(count)]
