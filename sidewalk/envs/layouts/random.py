"""Scenario ``random``: N agents with starts and goals drawn per world and per episode in an open area."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.envs.layouts.base import (
    CLEARANCE_M,
    LARGER_ROOM_HINT,
    Scenario,
    blocked_mask_of,
    clear_of,
    round_up,
)


def _far_cells(rows: int, cols: int, min_start_goal_cells: int) -> int:
    """Cells at least ``min_start_goal_cells`` (Manhattan) from the centre of a ``rows`` × ``cols`` room: the
    centre has the fewest cells far enough away, and each agent needs a goal among them."""
    cells = rows * cols
    center_row, center_col = rows // 2, cols // 2
    row, col = torch.arange(cells) // cols, torch.arange(cells) % cols
    return int(((row - center_row).abs() + (col - center_col).abs() >= min_start_goal_cells).sum())


def _density(n_agents: int, length_m: float, width_m: float, wall_gap_m: float, gap_m: float) -> float:
    """Area of ``n_agents`` discs of diameter ``gap_m`` over the free area of a random plane layout."""
    return n_agents * math.pi * (gap_m / 2) ** 2 / ((length_m - 2 * wall_gap_m) * (width_m - 2 * wall_gap_m))


def _gaps_m(agent_radius_m: float, goal_radius_m: float) -> tuple[float, float, float]:
    """(start_gap_m, goal_gap_m, wall_gap_m): what a random plane layout keeps between starts, between goals
    and from the walls, for discs and goals of these radii."""
    start_gap_m = 2 * agent_radius_m + CLEARANCE_M
    goal_gap_m = 2 * (agent_radius_m + goal_radius_m) + CLEARANCE_M
    return start_gap_m, goal_gap_m, agent_radius_m + CLEARANCE_M


@dataclass(frozen=True)
class RandomGridLayout:
    """``n_agents`` agents in an open ``rows`` × ``cols`` room, starts and goals drawn per world and per episode.

    Starts are distinct cells; goals are distinct cells at least ``min_start_goal_cells`` (Manhattan) from their
    agent's start. An agent's goal may be another agent's start: it must wait for that agent to leave.
    """

    rows: int
    cols: int
    n_agents: int
    min_start_goal_cells: int
    center_row: float
    blocked: tuple[tuple[int, int], ...] = ()
    starts: tuple = ()  # drawn per world: the report draws no fixed start or goal
    goals: tuple = ()

    fixed = False

    def __post_init__(self) -> None:
        check_int("rows", self.rows, 1)
        check_int("cols", self.cols, 1)
        check_int("n_agents", self.n_agents, 1)
        room = f"the {self.rows}×{self.cols}-cell random layout"
        if self.n_agents > self.rows * self.cols // 2:
            raise ValueError(
                f"n_agents={self.n_agents} crowd {room} (at most {self.rows * self.cols // 2}: half its "
                f"cells); {LARGER_ROOM_HINT}"
            )
        far = _far_cells(self.rows, self.cols, self.min_start_goal_cells)
        if far < self.n_agents:
            raise ValueError(
                f"min_start_goal_cells={self.min_start_goal_cells} leaves {far} goal cells for an agent starting at "
                f"the centre of {room}; {self.n_agents} agents need {self.n_agents}: "
                "lower min_start_goal_cells or n_agents, or enlarge the room"
            )

    def blocked_mask(self, device: torch.device) -> torch.Tensor:
        return blocked_mask_of(self.rows, self.cols, self.blocked, device)

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Starts and goals of ``n`` worlds, int64 (n, N, 2), drawn from ``generator``."""
        device, cells, n_agents = generator.device, self.rows * self.cols, self.n_agents
        blocked_cells = tuple(tuple(cell) for cell in self.blocked)
        blocked, cell_of, near = _grid_tables(self.rows, self.cols, self.min_start_goal_cells, blocked_cells, device)
        # The start scores and then each agent's goal scores, (n, cells) each. A few worlds' come in one draw: the
        # generator's stream is the same as drawing them one after another (a CPU generator fills a tensor in
        # order), and one call costs less than N + 1; many worlds' (a full reset) one at a time, as they are used.
        if (n_agents + 1) * n * cells <= MAX_ONE_DRAW:
            scores = iter(torch.rand(n_agents + 1, n, cells, generator=generator, device=device).unbind(0))
        else:
            scores = (torch.rand(n, cells, generator=generator, device=device) for _ in range(n_agents + 1))
        # The top N of i.i.d. scores are a uniform random subset of cells in a uniform random order.
        start_score = next(scores)
        start_score = start_score if blocked is None else start_score.masked_fill(blocked, -1.0)
        start_cell = start_score.topk(n_agents, dim=1).indices  # (n, N)
        taken = torch.zeros(n, cells, dtype=torch.bool, device=device) if blocked is None else blocked.repeat(n, 1)
        # Agent-major outputs, so that max writes each agent's row in place.
        best = torch.empty(n_agents, n, device=device)
        goal_cell = torch.empty(n_agents, n, dtype=torch.long, device=device)
        for agent in range(n_agents):  # agents one after another: each goal avoids those drawn before it
            # Goal candidates: at least min_start_goal_cells from the agent's start, on no wall or earlier goal.
            invalid = near(start_cell[:, agent]).logical_or_(taken)
            torch.max(next(scores).masked_fill(invalid, -1.0), -1, out=(best[agent], goal_cell[agent]))
            taken.scatter_(1, goal_cell[agent, :, None], True)
        if not bool((best >= 0.0).all()):
            agent = int((best < 0.0).any(1).nonzero()[0])
            raise RuntimeError(f"no free goal cell for agent {agent} in some world of the random layout")
        goal_cell = goal_cell.t()
        return cell_of[start_cell], cell_of[goal_cell]


MAX_NEAR_TABLE_CELLS = 2048  # rooms up to this many cells keep a cells × cells table of which cells lie too near
MAX_ONE_DRAW = 1 << 22  # scores drawn in one call at most (16 MB)


@functools.lru_cache(maxsize=16)
def _grid_tables(
    rows: int, cols: int, min_start_goal_cells: int, blocked_cells: tuple[tuple[int, int], ...], device: torch.device
):
    """What ``RandomGridLayout.sample`` reuses on every call: the blocked cells (bool (cells,), None when there are
    none), each cell's (row, col) (int64 (cells, 2)), and ``near(start)``, bool (k, cells): the cells closer than
    ``min_start_goal_cells`` (Manhattan) to each of the cells ``start`` (k,), a new tensor each call."""
    cells = rows * cols
    blocked = blocked_mask_of(rows, cols, blocked_cells, device).view(-1)
    flat = torch.arange(cells, device=device)
    cell_row, cell_col = flat // cols, flat % cols
    cell_of = torch.stack([cell_row, cell_col], dim=-1)

    def distance_below(start: torch.Tensor) -> torch.Tensor:
        start_row, start_col = cell_row[start].unsqueeze(1), cell_col[start].unsqueeze(1)
        return (cell_row - start_row).abs() + (cell_col - start_col).abs() < min_start_goal_cells

    if cells <= MAX_NEAR_TABLE_CELLS:
        table = distance_below(flat)
        near = functools.partial(torch.index_select, table, 0)
    else:
        near = distance_below
    return (blocked if bool(blocked.any()) else None), cell_of, near


@dataclass(frozen=True)
class RandomPlaneLayout:
    """``n_agents`` agents in an open ``length_m`` × ``width_m`` rectangle, drawn per world and per episode.

    Start discs keep ``start_gap_m`` between centres (no agent starts touching another); goals keep ``goal_gap_m``
    between them (two agents parked within their goal radii never touch) and lie at least ``min_start_goal_m``
    from their agent's start; every point keeps ``wall_gap_m`` from the walls. Each agent starts at rest, facing
    its goal.
    """

    length_m: float
    width_m: float
    n_agents: int
    min_start_goal_m: float
    start_gap_m: float
    goal_gap_m: float
    wall_gap_m: float
    boxes: tuple[tuple[float, float, float, float], ...] = ()
    starts: tuple = ()
    headings: tuple = ()
    goals: tuple = ()

    fixed = False
    CANDIDATES = 8  # points tried at once per agent and world ...
    PLACE_ROUNDS = 32  # ... in up to this many rounds; then the world is drawn again
    MAX_REDRAWS = 1000
    MAX_DENSITY = 0.4  # area of the gap discs over the free area (random sequential addition jams near 0.55)

    def __post_init__(self) -> None:
        check_int("n_agents", self.n_agents, 1)
        inner_x, inner_y = self.length_m - 2 * self.wall_gap_m, self.width_m - 2 * self.wall_gap_m
        if inner_x <= 0 or inner_y <= 0:
            raise ValueError(f"the {self.length_m}×{self.width_m} m world has no room for an agent")
        gap = max(self.start_gap_m, self.goal_gap_m)
        density = _density(self.n_agents, self.length_m, self.width_m, self.wall_gap_m, gap)
        if density > self.MAX_DENSITY:
            side = math.sqrt(self.n_agents * math.pi * (gap / 2) ** 2 / self.MAX_DENSITY) + 2 * self.wall_gap_m
            raise ValueError(
                f"n_agents={self.n_agents} crowd the {self.length_m}×{self.width_m} m random layout ({density:.2f} of "
                f"its area, at most {self.MAX_DENSITY}); use at least about {side:.1f}×{side:.1f} m, or give "
                "no size: the layout then picks one that holds its agents"
            )
        reach = 0.5 * math.hypot(inner_x, inner_y)
        check_range("min_start_goal_m", self.min_start_goal_m, 0.0, round(0.8 * reach, 3))

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Start positions (n, N, 2), start headings (n, N) and goals (n, N, 2), float32, drawn from ``generator``.

        A world whose candidates ran out (rare below the density limit, commoner in small worlds where the walls
        crowd the start-goal distance) is drawn again, whole, until every world is valid."""
        starts, goals, valid = self._draw(n, generator)
        for _ in range(self.MAX_REDRAWS):
            if bool(valid.all()):
                break
            again = (~valid).nonzero().squeeze(-1)
            new_starts, new_goals, new_valid = self._draw(again.numel(), generator)
            starts[again], goals[again], valid[again] = new_starts, new_goals, new_valid
        else:
            raise RuntimeError(
                f"the random layout found no valid placement for {int((~valid).sum())} worlds in {self.MAX_REDRAWS} "
                f"draws; give the {self.n_agents} agents more room than {self.length_m}×{self.width_m} m or lower "
                f"min_start_goal_m={self.min_start_goal_m}"
            )
        to_goal = goals - starts
        return starts, torch.atan2(to_goal[..., 1], to_goal[..., 0]), goals

    def _draw(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One placement of ``n`` worlds: starts, goals and whether each world's placement is valid (n,)."""
        device = generator.device
        low, span = _plane_bounds(self.length_m, self.width_m, self.wall_gap_m, device)
        starts = torch.empty(n, self.n_agents, 2, device=device)
        goals = torch.empty(n, self.n_agents, 2, device=device)
        ok = torch.ones(n, dtype=torch.bool, device=device)
        for agent in range(self.n_agents):  # agents one after another: each point keeps clear of those before it
            for out, placed, gap_m, own_start in (
                (starts, starts[:, :agent], self.start_gap_m, None),
                (goals, goals[:, :agent], self.goal_gap_m, starts[:, agent]),
            ):
                missing = self._place(out[:, agent], generator, low, span, placed, gap_m, own_start)
                if missing is not None:
                    ok[missing] = False
        return starts, goals, ok

    def _place(
        self,
        out: torch.Tensor,
        generator: torch.Generator,
        low: torch.Tensor,
        span: torch.Tensor,
        placed: torch.Tensor,
        gap_m: float,
        own_start: torch.Tensor | None = None,
    ) -> torch.Tensor | None:
        """Write into ``out`` (n, 2) the first of a few uniform candidates in ``low + span · [0, 1)²`` at least
        ``gap_m`` from every ``placed`` point (n, P, 2) -- and, for a goal, ``min_start_goal_m`` from ``own_start``
        (n, 2) --, trying again for the worlds that got none; returns the worlds (int64) that got no point in
        ``PLACE_ROUNDS`` rounds, or None. Usually every world finds one in the first round: that round skips the
        bookkeeping of the worlds still pending."""
        device, n = generator.device, out.shape[0]
        pending: torch.Tensor | None = None  # None: every world
        for _ in range(self.PLACE_ROUNDS):
            count = n if pending is None else pending.numel()
            candidates = low + span * torch.rand(count, self.CANDIDATES, 2, generator=generator, device=device)
            valid = None
            if placed.shape[1]:
                valid = clear_of(candidates, placed if pending is None else placed[pending], gap_m)
            if own_start is not None:
                start = own_start if pending is None else own_start[pending]
                far = (candidates - start.unsqueeze(1)).square().sum(-1) >= self.min_start_goal_m**2
                valid = far if valid is None else valid & far
            if valid is None:  # the first agent's start: no point to keep clear of, every world takes its first
                out.copy_(candidates[:, 0])
                return None
            first = valid.to(torch.uint8).argmax(-1)
            found = valid.any(-1)
            if bool(found.all()):
                chosen = candidates.gather(1, first.view(-1, 1, 1).expand(-1, 1, 2)).squeeze(1)
                if pending is None:
                    out.copy_(chosen)
                else:
                    out[pending] = chosen
                return None
            got = found.nonzero().squeeze(-1)
            rows = got if pending is None else pending[got]
            out[rows] = candidates[got, first[got]]
            missing = (~found).nonzero().squeeze(-1)
            pending = missing if pending is None else pending[missing]
        return pending


@functools.lru_cache(maxsize=16)
def _plane_bounds(length_m: float, width_m: float, wall_gap_m: float, device: torch.device):
    """(low, span), float32 (2,) each: the box of the points a random plane layout places, ``low + span · [0, 1)²``."""
    low = torch.tensor([wall_gap_m, wall_gap_m], device=device)
    span = torch.tensor([length_m, width_m], device=device) - 2 * low
    return low, span


def random_grid_capacity(rows: int, cols: int, min_start_goal_cells: int = 4) -> int:
    """Agents a ``rows`` × ``cols`` random room holds: half its cells, and a far enough goal for each."""
    return min(rows * cols // 2, _far_cells(rows, cols, min_start_goal_cells))


def random_grid_room(n_agents: int) -> tuple[int, int]:
    """(rows, cols) of the random room for ``n_agents`` when the user gives none: the preset's 7 × 15 up to 4
    agents, then the area grows like N (``round(7·sqrt(N/4))`` rows, twice as many columns plus one)."""
    rows = round(7 * math.sqrt(max(n_agents, 4) / 4))
    return rows, 2 * rows + 1


def random_plane_capacity(
    length_m: float, width_m: float, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> int:
    """Agents a ``length_m`` × ``width_m`` random world holds: the most whose gap discs cover at most
    ``RandomPlaneLayout.MAX_DENSITY`` of its free area."""
    start_gap_m, goal_gap_m, wall_gap_m = _gaps_m(agent_radius_m, goal_radius_m)
    if length_m <= 2 * wall_gap_m or width_m <= 2 * wall_gap_m:
        return 0
    gap_m = max(start_gap_m, goal_gap_m)
    count = int(RandomPlaneLayout.MAX_DENSITY / _density(1, length_m, width_m, wall_gap_m, gap_m))
    # The layout's own test, so that the count agrees with it to the last bit.
    while _density(count + 1, length_m, width_m, wall_gap_m, gap_m) <= RandomPlaneLayout.MAX_DENSITY:
        count += 1
    while count > 0 and _density(count, length_m, width_m, wall_gap_m, gap_m) > RandomPlaneLayout.MAX_DENSITY:
        count -= 1
    return count


def random_plane_room(
    n_agents: int, agent_radius_m: float = 0.3, goal_radius_m: float = 0.3
) -> tuple[float, float]:
    """(length_m, width_m) of the random world for ``n_agents`` when the user gives none: a square at half the
    density limit, rounded up to 0.5 m (6 m for 4 agents, the preset's)."""
    start_gap_m, goal_gap_m, wall_gap_m = _gaps_m(agent_radius_m, goal_radius_m)
    gap_m = max(start_gap_m, goal_gap_m)
    area = n_agents * math.pi * (gap_m / 2) ** 2 / (RandomPlaneLayout.MAX_DENSITY / 2)
    side = round_up(math.sqrt(area) + 2 * wall_gap_m, 0.5)
    return side, side


def random_grid(rows: int, cols: int, n_agents: int = 2, min_start_goal_cells: int = 4) -> RandomGridLayout:
    """``n_agents`` random starts and goals in an open room, redrawn per world and per episode."""
    check_int("min_start_goal_cells", min_start_goal_cells, 1, rows + cols - 2)
    return RandomGridLayout(rows, cols, n_agents, min_start_goal_cells, center_row=(rows - 1) / 2)


def random_plane(
    length_m: float,
    width_m: float,
    n_agents: int = 2,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 1.5,
) -> RandomPlaneLayout:
    """``n_agents`` random starts and goals in an open rectangle, redrawn per world and per episode."""
    start_gap_m, goal_gap_m, wall_gap_m = _gaps_m(agent_radius_m, goal_radius_m)
    return RandomPlaneLayout(
        length_m=length_m,
        width_m=width_m,
        n_agents=n_agents,
        min_start_goal_m=min_start_goal_m,
        start_gap_m=start_gap_m,
        goal_gap_m=goal_gap_m,
        wall_gap_m=wall_gap_m,
    )


SCENARIO = Scenario(
    "random",
    grid=random_grid,
    plane=random_plane,
    grid_capacity=random_grid_capacity,
    grid_room=random_grid_room,
    plane_capacity=random_plane_capacity,
    plane_room=random_plane_room,
    any_n_agents=True,
    rank=2,
    draws_starts=True,
)
