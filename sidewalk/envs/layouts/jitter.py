"""Fixed layouts with their starts, goals and headings perturbed per world and per episode, within stated bounds.

A scenario's fixed layout gives every world one start and goal per agent, so at noise 0 every world plays the same
episode and an evaluation's rate is one episode's 0 or 1. ``JitteredGridLayout`` and ``JitteredPlaneLayout`` draw, on
every reset, each agent's start and goal around the scenario's (its *nominal* layout, ``nominal``):

- grid: each start and goal moved across the sidewalk by a whole number of rows, uniform in
  [-``start_jitter_rows``, ``start_jitter_rows``] (goals: ``goal_jitter_rows``); or, in a scenario whose walls hold
  no row move (the circle's corners, the zipper's lanes, the teams' edge rows), to a free cell within
  ``start_jitter_cells`` (``goal_jitter_cells``) rows and columns of its own, uniform over those cells (one kind of
  move per start or goal: rows or cells);
- continuous: each start and goal moved by a uniform offset in the square ±``start_jitter_m`` (``goal_jitter_m``) in x
  and y, each start heading turned by a uniform angle in ±``heading_jitter_rad``.

The bounds are checked when the layout is built: every start cell (disc) and goal the bounds allow lies inside the
room and off its walls, or the layout raises naming the largest bound that does. Draws in which two agents would
share a start (grid: a cell; continuous: discs closer than the nominal layout keeps them), two goals would coincide,
or an agent would start on its own goal are drawn again, up to ``CANDIDATES`` times at once; a world with no valid
draw among them keeps its nominal starts (in the scenarios shipped, under bounds the checks allow, none was seen).
The draws come from the env's generator (per replica), so one seed repeats them exactly.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.envs.layouts.base import GridLayout, PlaneLayout

CANDIDATES = 8  # draws tried at once per world; the first valid one is kept


def _first_valid(valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(the index of each world's first valid candidate (n,), whether it has one (n,)) from ``valid`` (K, n)."""
    found = valid.any(0)
    first = valid.to(torch.int8).argmax(0)  # argmax returns the first maximum
    return first, found


def _pick(candidates: torch.Tensor, first: torch.Tensor, found: torch.Tensor, nominal: torch.Tensor) -> torch.Tensor:
    """Per world, the ``first`` candidate of ``candidates`` (K, n, ...) where ``found``, else ``nominal`` (n, ...)."""
    index = first.view(1, -1, *([1] * (candidates.dim() - 2))).expand(1, *candidates.shape[1:])
    chosen = candidates.gather(0, index).squeeze(0)
    keep = found.view(-1, *([1] * (chosen.dim() - 1)))
    return torch.where(keep, chosen, nominal)


def _box_gap(x: float, y: float, half: float, box: tuple[float, float, float, float]) -> float:
    """The least distance from any point of the square ``(x, y) ± half`` to the rectangle ``box``."""
    x0, y0, x1, y1 = box
    dx = max(x0 - (x + half), (x - half) - x1, 0.0)
    dy = max(y0 - (y + half), (y - half) - y1, 0.0)
    return math.hypot(dx, dy)


def largest_grid_jitter(layout: GridLayout, name: str) -> int:
    """The largest bound of jitter ``name`` (``start_jitter_rows`` or ``goal_jitter_rows``) that keeps every start
    (goal) of ``layout``, moved by any -k..k rows, inside the grid and off its walls."""
    cells = layout.starts if name.startswith("start") else layout.goals
    blocked = set(layout.blocked)
    k = 0
    while k + 1 < layout.rows and all(
        0 <= row + sign * (k + 1) < layout.rows and (row + sign * (k + 1), col) not in blocked
        for row, col in cells for sign in (-1, 1)
    ):
        k += 1
    return k


def largest_plane_jitter(layout: PlaneLayout, name: str, agent_radius_m: float) -> float:
    """The largest bound of jitter ``name`` (``start_jitter_m`` or ``goal_jitter_m``) that keeps an agent's disc
    centred anywhere within ± it (x and y) of every start (goal) of ``layout`` inside the room and off every box;
    ``heading_jitter_rad``: π."""
    if name == "heading_jitter_rad":
        return math.pi
    points = layout.starts if name.startswith("start") else layout.goals
    r = agent_radius_m
    largest = math.inf
    for x, y in points:
        largest = min(largest, x - r, layout.length_m - r - x, y - r, layout.width_m - r - y)
        for box in layout.boxes:
            if _box_gap(x, y, 0.0, box) < r:
                return 0.0
            low, high = 0.0, max(layout.length_m, layout.width_m)
            for _ in range(40):  # the gap shrinks monotonically with the bound: bisect for where it reaches r
                middle = (low + high) / 2
                low, high = (middle, high) if _box_gap(x, y, middle, box) >= r else (low, middle)
            largest = min(largest, low)
    return max(largest, 0.0)


def free_cells_within(layout: GridLayout, cells: tuple[tuple[int, int], ...], k: int) -> list[list[tuple[int, int]]]:
    """For each of ``cells``, the free cells of ``layout`` (in the grid, off its walls) at most ``k`` rows and ``k``
    columns from it, itself included, in row-major order."""
    blocked = set(layout.blocked)
    return [
        [(r, c) for r in range(row - k, row + k + 1) for c in range(col - k, col + k + 1)
         if 0 <= r < layout.rows and 0 <= c < layout.cols and (r, c) not in blocked]
        for row, col in cells
    ]


def _draw_cells(choices: list[list[tuple[int, int]]], shape: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:
    """Cells (*shape, N, 2) int64, each agent's drawn uniformly from its ``choices`` (one list per agent)."""
    device = generator.device
    counts = torch.tensor([len(c) for c in choices], device=device)
    table = torch.zeros(len(choices), int(counts.max()), 2, dtype=torch.int64, device=device)
    for agent, cells in enumerate(choices):
        table[agent, : len(cells)] = torch.tensor(cells, dtype=torch.int64, device=device)
    pick = (torch.rand((*shape, len(choices)), generator=generator, device=device) * counts).long()
    pick = torch.minimum(pick, counts - 1)  # rand < 1, but float rounding may reach the count
    return table[torch.arange(len(choices), device=device), pick]


@dataclass(frozen=True)
class JitteredGridLayout:
    """``nominal`` (a fixed ``GridLayout``) with every start and goal moved across the sidewalk by up to
    ``start_jitter_rows`` / ``goal_jitter_rows`` rows, or to a free cell within ``start_jitter_cells`` /
    ``goal_jitter_cells`` rows and columns, drawn per world and per episode (see the module docstring)."""

    nominal: GridLayout
    start_jitter_rows: int = 0
    goal_jitter_rows: int = 0
    start_jitter_cells: int = 0
    goal_jitter_cells: int = 0

    fixed = False

    def __post_init__(self) -> None:
        fixed = isinstance(self.nominal, GridLayout)  # a layout that draws its own starts is no value to perturb
        if not fixed:
            raise ValueError(
                f"start/goal jitter perturbs a fixed grid layout (sidewalk, circle, teams, door, zipper); "
                f"got {type(self.nominal).__name__}, whose starts and goals are drawn already"
            )
        for name in ("start_jitter_rows", "goal_jitter_rows"):
            bound = getattr(self, name)
            check_int(name, bound, 0)
            largest = largest_grid_jitter(self.nominal, name)
            if bound > largest:
                raise ValueError(
                    f"{name}={bound} puts an agent outside the {self.rows}×{self.cols} grid or inside a wall; "
                    f"valid: 0..{largest}"
                )
        for what in ("start", "goal"):
            cells, rows = getattr(self, f"{what}_jitter_cells"), getattr(self, f"{what}_jitter_rows")
            check_int(f"{what}_jitter_cells", cells, 0, max(self.rows, self.cols) - 1)
            if cells and rows:
                raise ValueError(
                    f"{what}_jitter_rows={rows} and {what}_jitter_cells={cells}: a {what} moves by rows or to a cell "
                    f"around it, not both; set one of them to 0"
                )

    # The nominal layout's geometry: what the env, the planners and the renderers read.
    rows = property(lambda self: self.nominal.rows)
    cols = property(lambda self: self.nominal.cols)
    starts = property(lambda self: self.nominal.starts)
    goals = property(lambda self: self.nominal.goals)
    center_row = property(lambda self: self.nominal.center_row)
    blocked = property(lambda self: self.nominal.blocked)
    n_agents = property(lambda self: self.nominal.n_agents)

    def blocked_mask(self, device: torch.device) -> torch.Tensor:
        return self.nominal.blocked_mask(device)

    @functools.cached_property
    def _cell_choices(self) -> tuple[list[list[tuple[int, int]]], list[list[tuple[int, int]]]]:
        """The free cells each start and each goal may move to under the cell bounds, found once, not every reset."""
        return (free_cells_within(self.nominal, self.nominal.starts, self.start_jitter_cells),
                free_cells_within(self.nominal, self.nominal.goals, self.goal_jitter_cells))

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Starts and goals of ``n`` worlds, int64 (n, N, 2), drawn from ``generator``."""
        nominal_starts, nominal_goals = self.nominal.sample(n, generator)
        n_agents = self.n_agents
        shape = (CANDIDATES, n, n_agents)
        start_rows = torch.randint(-self.start_jitter_rows, self.start_jitter_rows + 1, shape, generator=generator,
                                   device=generator.device)
        goal_rows = torch.randint(-self.goal_jitter_rows, self.goal_jitter_rows + 1, shape, generator=generator,
                                  device=generator.device)
        starts = nominal_starts.unsqueeze(0).repeat(CANDIDATES, 1, 1, 1)
        goals = nominal_goals.unsqueeze(0).repeat(CANDIDATES, 1, 1, 1)
        starts[..., 0] += start_rows
        goals[..., 0] += goal_rows
        # Cell moves draw nothing at 0, so the row-jittered worlds of a seed stay the worlds they were.
        start_choices, goal_choices = self._cell_choices
        if self.start_jitter_cells:
            starts = _draw_cells(start_choices, (CANDIDATES, n), generator)
        if self.goal_jitter_cells:
            goals = _draw_cells(goal_choices, (CANDIDATES, n), generator)
        start_cell = starts[..., 0] * self.cols + starts[..., 1]
        goal_cell = goals[..., 0] * self.cols + goals[..., 1]
        pair = ~torch.eye(n_agents, dtype=torch.bool, device=generator.device)
        shared_start = ((start_cell.unsqueeze(-1) == start_cell.unsqueeze(-2)) & pair).flatten(-2).any(-1)
        shared_goal = ((goal_cell.unsqueeze(-1) == goal_cell.unsqueeze(-2)) & pair).flatten(-2).any(-1)
        on_own_goal = (start_cell == goal_cell).any(-1)
        first, found = _first_valid(~(shared_start | shared_goal | on_own_goal))
        return _pick(starts, first, found, nominal_starts), _pick(goals, first, found, nominal_goals)


@dataclass(frozen=True)
class JitteredPlaneLayout:
    """``nominal`` (a fixed ``PlaneLayout``) with every start and goal moved by up to ``start_jitter_m`` /
    ``goal_jitter_m`` in x and y, and every start heading turned by up to ``heading_jitter_rad``, drawn per world and
    per episode (see the module docstring). ``agent_radius_m`` and ``goal_radius_m`` are the env's, for the checks."""

    nominal: PlaneLayout
    agent_radius_m: float
    goal_radius_m: float
    start_jitter_m: float = 0.0
    goal_jitter_m: float = 0.0
    heading_jitter_rad: float = 0.0

    fixed = False

    def __post_init__(self) -> None:
        fixed = isinstance(self.nominal, PlaneLayout)
        if not fixed:
            raise ValueError(
                f"start/goal jitter perturbs a fixed plane layout (sidewalk, circle, teams, door, zipper); "
                f"got {type(self.nominal).__name__}, whose starts and goals are drawn already"
            )
        check_range("heading_jitter_rad", self.heading_jitter_rad, 0.0, math.pi)
        for name in ("start_jitter_m", "goal_jitter_m"):
            bound = getattr(self, name)
            check_range(name, bound, 0.0)
            largest = largest_plane_jitter(self.nominal, name, self.agent_radius_m)
            if bound > largest + 1e-9:
                raise ValueError(
                    f"{name}={bound} puts an agent's disc into a wall of the {self.length_m}×{self.width_m} m world "
                    f"(agent radius {self.agent_radius_m} m); valid: 0..{math.floor(largest * 100) / 100}"
                )

    # The nominal layout's geometry: what the env, the planners and the renderers read.
    length_m = property(lambda self: self.nominal.length_m)
    width_m = property(lambda self: self.nominal.width_m)
    starts = property(lambda self: self.nominal.starts)
    headings = property(lambda self: self.nominal.headings)
    goals = property(lambda self: self.nominal.goals)
    boxes = property(lambda self: self.nominal.boxes)
    n_agents = property(lambda self: self.nominal.n_agents)

    def _min_gap(self, points: tuple[tuple[float, float], ...], floor: float) -> float:
        """The least distance the draws keep between two of ``points``: ``floor``, or less where the nominal layout
        itself places two closer."""
        gaps = [math.dist(a, b) for i, a in enumerate(points) for b in points[i + 1:]]
        return min([floor, *gaps])

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Start positions (n, N, 2), start headings (n, N) and goals (n, N, 2) of ``n`` worlds, float32."""
        nominal_starts, nominal_headings, nominal_goals = self.nominal.sample(n, generator)
        device, n_agents = generator.device, self.n_agents
        draws = torch.rand(3, CANDIDATES, n, n_agents, 2, generator=generator, device=device) * 2 - 1
        starts = nominal_starts + self.start_jitter_m * draws[0]
        goals = nominal_goals + self.goal_jitter_m * draws[1]
        headings = nominal_headings + self.heading_jitter_rad * draws[2, ..., 0]
        pair = ~torch.eye(n_agents, dtype=torch.bool, device=device)
        start_gap = self._min_gap(self.nominal.starts, 2 * self.agent_radius_m + 0.1)
        goal_gap = self._min_gap(self.nominal.goals, 2 * (self.agent_radius_m + self.goal_radius_m))
        crowded_starts = ((torch.cdist(starts, starts) < start_gap - 1e-6) & pair).flatten(-2).any(-1)
        crowded_goals = ((torch.cdist(goals, goals) < goal_gap - 1e-6) & pair).flatten(-2).any(-1)
        on_own_goal = ((starts - goals).norm(dim=-1) <= self.goal_radius_m).any(-1)
        first, found = _first_valid(~(crowded_starts | crowded_goals | on_own_goal))
        return (
            _pick(starts, first, found, nominal_starts),
            _pick(headings, first, found, nominal_headings),
            _pick(goals, first, found, nominal_goals),
        )
