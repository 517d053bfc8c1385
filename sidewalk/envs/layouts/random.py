"""Scenario ``random``: N agents with starts and goals drawn per world and per episode in an open area."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.envs.layouts.base import CLEARANCE_M, blocked_mask_of, clear_of


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
        cells = self.rows * self.cols
        check_int("n_agents", self.n_agents, 1, cells // 2)
        # The centre cell has the fewest cells far enough away; each agent needs a goal among them.
        center_row, center_col = self.rows // 2, self.cols // 2
        row, col = torch.arange(cells) // self.cols, torch.arange(cells) % self.cols
        far = int(((row - center_row).abs() + (col - center_col).abs() >= self.min_start_goal_cells).sum())
        if far < self.n_agents:
            raise ValueError(
                f"min_start_goal_cells={self.min_start_goal_cells} leaves {far} goal cells for an agent starting at "
                f"the centre of the {self.rows}×{self.cols} room; {self.n_agents} agents need {self.n_agents}: "
                "lower min_start_goal_cells or n_agents, or enlarge the room"
            )

    def blocked_mask(self, device: torch.device) -> torch.Tensor:
        return blocked_mask_of(self.rows, self.cols, self.blocked, device)

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Starts and goals of ``n`` worlds, int64 (n, N, 2), drawn from ``generator``."""
        device, cells, cols = generator.device, self.rows * self.cols, self.cols
        free = ~self.blocked_mask(device).view(-1)
        # The top N of i.i.d. scores are a uniform random subset of cells in a uniform random order.
        score = torch.rand(n, cells, generator=generator, device=device).masked_fill(~free, -1.0)
        start_cell = score.topk(self.n_agents, dim=1).indices  # (n, N)
        cell_row = torch.arange(cells, device=device) // cols
        cell_col = torch.arange(cells, device=device) % cols
        taken = (~free).expand(n, -1).clone()
        goal_cell = torch.empty_like(start_cell)
        for agent in range(self.n_agents):  # agents one after another: each goal avoids those drawn before it
            start_row, start_col = (start_cell[:, agent : agent + 1] // cols, start_cell[:, agent : agent + 1] % cols)
            distance = (cell_row - start_row).abs() + (cell_col - start_col).abs()
            valid = (distance >= self.min_start_goal_cells) & ~taken
            score = torch.rand(n, cells, generator=generator, device=device).masked_fill(~valid, -1.0)
            pick = score.argmax(-1)
            if not bool(valid.gather(1, pick[:, None]).all()):
                raise RuntimeError(f"no free goal cell for agent {agent} in some world of the random layout")
            goal_cell[:, agent] = pick
            taken.scatter_(1, pick[:, None], True)
        as_cells = lambda flat: torch.stack([flat // cols, flat % cols], dim=-1)
        return as_cells(start_cell), as_cells(goal_cell)


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
        density = self.n_agents * math.pi * (gap / 2) ** 2 / (inner_x * inner_y)
        if density > self.MAX_DENSITY:
            side = math.sqrt(self.n_agents * math.pi * (gap / 2) ** 2 / self.MAX_DENSITY) + 2 * self.wall_gap_m
            raise ValueError(
                f"n_agents={self.n_agents} crowd the {self.length_m}×{self.width_m} m random layout ({density:.2f} of "
                f"its area, at most {self.MAX_DENSITY}); use at least about {side:.1f}×{side:.1f} m"
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
        starts = torch.empty(n, self.n_agents, 2, device=device)
        goals = torch.empty(n, self.n_agents, 2, device=device)
        ok = torch.ones(n, dtype=torch.bool, device=device)
        for agent in range(self.n_agents):  # agents one after another: each point keeps clear of those before it
            ok &= self._place(starts[:, agent], generator, starts[:, :agent], self.start_gap_m)
            ok &= self._place(goals[:, agent], generator, goals[:, :agent], self.goal_gap_m, starts[:, agent])
        return starts, goals, ok

    def _place(
        self,
        out: torch.Tensor,
        generator: torch.Generator,
        placed: torch.Tensor,
        gap_m: float,
        own_start: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Write into ``out`` (n, 2) the first of a few uniform candidates at least ``gap_m`` from every ``placed``
        point (n, P, 2) -- and, for a goal, ``min_start_goal_m`` from ``own_start`` (n, 2) --, trying again for the
        worlds that got none; returns bool (n,): a point was found."""
        device, n = generator.device, out.shape[0]
        low = torch.tensor([self.wall_gap_m, self.wall_gap_m], device=device)
        span = torch.tensor([self.length_m, self.width_m], device=device) - 2 * low
        pending = torch.arange(n, device=device)
        for _ in range(self.PLACE_ROUNDS):
            candidates = low + span * torch.rand(pending.numel(), self.CANDIDATES, 2, generator=generator, device=device)
            valid = clear_of(candidates, placed[pending], gap_m)
            if own_start is not None:
                to_start = candidates - own_start[pending].unsqueeze(1)
                valid &= to_start.square().sum(-1) >= self.min_start_goal_m**2
            found = valid.any(-1)
            first = valid.to(torch.uint8).argmax(-1)
            out[pending[found]] = candidates[found, first[found]]
            pending = pending[~found]
            if pending.numel() == 0:
                break
        placed = torch.ones(n, dtype=torch.bool, device=device)
        placed[pending] = False
        return placed


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
    return RandomPlaneLayout(
        length_m=length_m,
        width_m=width_m,
        n_agents=n_agents,
        min_start_goal_m=min_start_goal_m,
        start_gap_m=2 * agent_radius_m + CLEARANCE_M,
        goal_gap_m=2 * (agent_radius_m + goal_radius_m) + CLEARANCE_M,
        wall_gap_m=agent_radius_m + CLEARANCE_M,
    )
