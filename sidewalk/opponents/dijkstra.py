"""The Dijkstra opponent of the discrete Sidewalk (paper §4.2): the shortest path to its goal on a
costmap that makes cells near the other agents expensive, replanned every step, first move taken.

Every world is planned in one batched computation: the distance-to-goal field of each (controlled agent, world)
is relaxed by directional min-plus scans over the whole grid, as tensor operations with the worlds on the last
axis. There is no per-world loop and no graph to build.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch

from sidewalk._checks import check_choice, check_int, check_range
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.envs.grid import MOVES
from sidewalk.opponents.base import Opponent

# Cells within AVOID_RADIUS_CELLS (Chebyshev) of another agent cost AVOID_COST on top of the step cost of 1:
# crossing the 5-cell-wide zone then outweighs the 6-step detour around it.
AVOID_RADIUS_CELLS = 2
AVOID_COST = 10.0
MAX_AVOID_COST = 1000.0  # keeps default-grid path costs far below float32's exact-integer limit (2**24)
# Action scores of the neighbour cells, in tiers: any free cell beats one holding an agent, which beats leaving
# the grid or entering a wall (an infinite score). Free cells cut off from the goal score UNREACHABLE_SCORE.
UNREACHABLE_SCORE = 1e20
# Tie-breaks between moves of equal path cost (costs are whole numbers, so these sums stay below 1).
TIE_ALONG = 1e-3  # per cell of distance to the goal along the sidewalk (columns, at most 255)
TIE_ACROSS = 1e-6  # per cell across it (rows)
# tie_break="random": equally cheap moves are drawn uniformly, by a score in [0, TIE_RANDOM) each (below one step).
TIE_RANDOM = 1e-2
TIE_BREAKS = ("random", "progress")
OCCUPIED_SCORE = 1e30


class GridPlan(NamedTuple):
    """What one planning call computed, world-first.

    ``costmap`` (B, C, rows, cols): the cost of entering each cell, per controlled agent (inf: blocked);
    ``field`` (B, C, rows, cols): each cell's cost of the cheapest path to that agent's goal on its costmap
    (inf: the goal cannot be reached); ``action`` (B, C): the move each controlled agent takes.
    """

    costmap: torch.Tensor
    field: torch.Tensor
    action: torch.Tensor


class DijkstraOpponent(Opponent):
    """Walks the cheapest path to its goal on a costmap, replanned every step (grid domain only).

    Costmap, per controlled agent: entering a cell costs 1, plus ``avoid_cost`` when the cell lies within
    ``avoid_radius_cells`` (Chebyshev distance: a square) of another present agent -- with two agents, the ego.
    A cell holding a present agent costs ``occupied_cost``, more than any path over free cells, so a plan crosses
    one only when nothing else reaches the goal; the agent's own goal keeps its ordinary cost, so an agent
    standing on it makes the planner wait beside it rather than wander. Blocked cells are impassable. An agent
    is present unless it is done away from its goal and the env removes crashed agents.

    The move taken is the first step of the cheapest path: the neighbour with the least entry cost plus
    distance to goal. It never leaves the grid or enters a blocked cell while another move exists, and never
    steps into an agent's cell while a free cell is next to it. Moves of done agents are computed like any other and
    ignored by the env.

    Ties between equally cheap moves (``tie_break``):

    - ``"random"`` (version 2, the default since 2026-11-28): drawn uniformly, every step, from the env's
      generator. People caught in a "sidewalk salsa" -- both stepping the same way, back and forth -- break it by
      hesitating; a planner that breaks ties the same way every time never does: a greedy learner stepping toward it
      and back held the v1 agent in a two-cycle to the time limit (docs/guide/evaluation.md). Drawing the tie also
      makes the partner's own randomness a source of distinct evaluation episodes from fixed starts.
    - ``"progress"`` (version 1, the agent of the reference runs made before): the move that leaves the agent closest
      to its goal along the sidewalk, then across it -- a fixed order (UP first) had let an ego stepping up and down
      flip the costmap each step and hold the planner in a livelock.

    Every call plans from scratch and keeps no per-world memory, so ``reset(rows)`` has nothing to do.
    ``last_rounds`` holds the number of scan rounds of the last call.
    """

    name = "dijkstra"
    domains = ("discrete",)
    per_replica = False  # draws only through env.rand, no per-world memory: one planner for every replica's worlds
    batch_invariant = True  # whole-number path costs, exact whatever the batch

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled: Sequence[int] = (1,),
        ego: int | None = 0,
        *,
        avoid_radius_cells: int = AVOID_RADIUS_CELLS,
        avoid_cost: float = AVOID_COST,
        tie_break: str = "random",
    ) -> None:
        super().__init__(env, controlled, ego)
        layout = env.layout
        check_int("avoid_radius_cells", avoid_radius_cells, 0, max(layout.rows, layout.cols))
        check_range("avoid_cost", avoid_cost, 0.0, MAX_AVOID_COST)
        check_choice("tie_break", tie_break, TIE_BREAKS)
        self.avoid_radius_cells = avoid_radius_cells
        self.avoid_cost = float(avoid_cost)
        self.tie_break = tie_break
        rows, cols, device = layout.rows, layout.cols, env.device
        self._rows, self._cols = rows, cols
        # More than the dearest path over free cells, which enters at most rows·cols cells.
        self.occupied_cost = rows * cols * (1.0 + self.avoid_cost) + 1.0
        self._remove_crashed = bool(env.params.remove_crashed)
        # Scan steps double (1, 2, 4, ...) until they span the grid; each round lowers some distance or ends
        # the solve, and a shortest path has fewer than rows·cols straight segments.
        self._col_shifts = [1 << k for k in range(max(cols - 1, 1).bit_length()) if 1 << k < cols]
        self._row_shifts = [1 << k for k in range(max(rows - 1, 1).bit_length()) if 1 << k < rows]
        self._max_rounds = rows * cols + 1
        self.last_rounds = 0

        # Planning tensors put the worlds last, (rows, cols, C, B): shifted slices then move long contiguous runs.
        blocked = layout.blocked_mask(device)
        self._entry_cost = torch.where(blocked, float("inf"), 1.0).to(torch.float32)[:, :, None, None]
        self._row_index = torch.arange(rows, device=device)[:, None, None]
        self._col_index = torch.arange(cols, device=device)[:, None, None]
        # Neighbour look-ups use a grid padded by one cell, so a move off the grid lands on a padding cell.
        self._padded_cols = cols + 2
        legal = torch.zeros(rows + 2, cols + 2, dtype=torch.bool, device=device)
        legal[1:-1, 1:-1] = ~blocked
        self._legal_padded = legal.reshape(-1)
        self._move_offsets = torch.tensor([dr * (cols + 2) + dc for dr, dc in MOVES], device=device)
        n_agents, n_controlled = env.n_agents, len(self.controlled)
        self._others = torch.ones(n_controlled, n_agents, dtype=torch.bool, device=device)
        self._others[torch.arange(n_controlled), self._controlled_index] = False
        # One controlled agent among two avoids just the other one: a slice instead of a reduction.
        self._only_other = 1 - self.controlled[0] if n_agents == 2 and n_controlled == 1 else None

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        return self._plan(state, goal, done, present)[2].t()

    def plan(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> GridPlan:
        """Plan every world from the env's ``state`` (B, N, 2), ``goal`` (B, N, 2) and ``done`` (B, N, 1)."""
        costmap, field, action = self._plan(state, goal, done, present)
        return GridPlan(costmap.permute(3, 2, 0, 1), field.permute(3, 2, 0, 1), action.t())

    def _plan(
        self,
        state: torch.Tensor,
        goal: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Costmap and field, each (rows, cols, C, B), and the action (C, B)."""
        rows, cols, padded_cols = self._rows, self._cols, self._padded_cols
        n_worlds, n_controlled = state.shape[0], len(self.controlled)
        device, controlled = state.device, self._controlled_index
        # Worlds last and contiguous, (N, B): results of broadcasts then come out contiguous too.
        row, col = state[..., 0].t().contiguous(), state[..., 1].t().contiguous()
        present = self.present(state, goal, done, present).t().contiguous()

        # Avoidance zones of the present agents, (rows, cols, N, B); each controlled agent avoids the others'.
        near_row = (self._row_index - row).abs() <= self.avoid_radius_cells
        near_col = ((self._col_index - col).abs() <= self.avoid_radius_cells) & present
        if self._only_other is not None:
            other = self._only_other
            avoided = (near_row[:, other].unsqueeze(1) & near_col[:, other]).unsqueeze(2)
        else:
            zone = near_row.unsqueeze(1) & near_col.unsqueeze(0)
            avoided = (zone.unsqueeze(2) & self._others[:, :, None]).any(3)
        cost = self._entry_cost + self.avoid_cost * avoided

        goal_cell = (goal[:, controlled, 0] * cols + goal[:, controlled, 1]).t().contiguous()  # (C, B)
        pin = torch.full((rows * cols, n_controlled, n_worlds), float("inf"), device=device)
        pin.scatter_(0, goal_cell.unsqueeze(0), 0.0)
        pin = pin.view(rows, cols, n_controlled, n_worlds)

        # Occupied cells, as padded flat cells with one spare slot past the end for absent agents.
        padded_cells = (rows + 2) * padded_cols
        agent_cell = (row + 1) * padded_cols + col + 1
        occupied = torch.zeros(padded_cells + 1, n_worlds, dtype=torch.bool, device=device)
        occupied.scatter_(0, torch.where(present, agent_cell, padded_cells), True)
        occupied_inside = occupied[:-1].view(rows + 2, padded_cols, 1, n_worlds)[1:-1, 1:-1]
        cost = torch.where(occupied_inside & (pin != 0.0), self.occupied_cost, cost)

        field = self._solve(cost, pin)

        # Score the four neighbours of each controlled agent: entry cost plus distance, in the tiers above.
        scores = torch.full((rows + 2, padded_cols, n_controlled, n_worlds), float("inf"), device=device)
        torch.add(cost, field, out=scores[1:-1, 1:-1])
        lanes = n_controlled * n_worlds
        lane = torch.arange(lanes, device=device).view(n_controlled, n_worlds, 1)
        neighbour = agent_cell[controlled].unsqueeze(-1) + self._move_offsets  # (C, B, 4)
        score = scores.view(-1)[neighbour * lanes + lane]
        score = torch.where(self._legal_padded[neighbour], score.clamp(max=UNREACHABLE_SCORE), float("inf"))
        world = torch.arange(n_worlds, device=device).view(n_worlds, 1)
        score = score.masked_fill(occupied.view(-1)[neighbour * n_worlds + world], OCCUPIED_SCORE)
        total = score.double() + self._tie_break(neighbour, goal).double()
        if n_controlled > 1:
            return cost, field, self._claim_in_turn(total, neighbour, agent_cell[controlled], done[:, controlled])
        return cost, field, total.argmin(-1)

    def _tie_break(self, neighbour: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Scores below one step added to the moves' (C, B, 4) scores, which decide between equally cheap moves."""
        if self.tie_break == "random":
            n_worlds = neighbour.shape[1]
            return TIE_RANDOM * self.env.rand((n_worlds, *neighbour.shape[::2])).transpose(0, 1)
        # Progress along the sidewalk, then across it, added to the scores in float64 (the caller's sum): float32
        # has no room for TIE_ACROSS beside path costs of a few units.
        controlled = self._controlled_index
        neighbour_row = neighbour // self._padded_cols - 1
        neighbour_col = neighbour % self._padded_cols - 1
        goal_row, goal_col = goal[:, controlled, 0].t().unsqueeze(-1), goal[:, controlled, 1].t().unsqueeze(-1)
        return TIE_ALONG * (neighbour_col - goal_col).abs() + TIE_ACROSS * (neighbour_row - goal_row).abs()

    @staticmethod
    def _claim_in_turn(
        total: torch.Tensor, neighbour: torch.Tensor, here: torch.Tensor, done: torch.Tensor
    ) -> torch.Tensor:
        """Moves (C, B) of several controlled agents that never run into each other: in agent order, each takes
        its best move among those that neither enter a cell an earlier agent moves into nor swap cells with one.

        One planner controls them all, so it can give way among them; planned apart, two agents heading for one
        gap step into it together (the door's three stooges). A move that conflicts is kept only when nothing else
        is left (it then costs OCCUPIED_SCORE more). ``total`` (C, B, 4) scores, ``neighbour`` (C, B, 4) target cells,
        ``here`` (C, B) current cells, ``done`` (B, C, 1): done agents claim nothing."""
        moving = ~done.squeeze(-1).t()  # (C, B)
        action = torch.empty(total.shape[:2], dtype=torch.long, device=total.device)
        claimed_to, claimed_from = [], []
        for agent in range(total.shape[0]):
            score = total[agent]
            if claimed_to:
                to, came_from = torch.stack(claimed_to), torch.stack(claimed_from)  # (k, B)
                target = neighbour[agent]  # (B, 4)
                enters = (target.unsqueeze(0) == to.unsqueeze(-1)).any(0)
                swaps = ((target.unsqueeze(0) == came_from.unsqueeze(-1)) & (to == here[agent]).unsqueeze(-1)).any(0)
                score = score + OCCUPIED_SCORE * (enters | swaps)
            action[agent] = score.argmin(-1)
            chosen = neighbour[agent].gather(-1, action[agent].unsqueeze(-1)).squeeze(-1)
            # A done agent claims a cell no move can reach (-1): it does not move.
            claimed_to.append(torch.where(moving[agent], chosen, -1))
            claimed_from.append(torch.where(moving[agent], here[agent], -1))
        return action

    def _solve(self, cost: torch.Tensor, pin: torch.Tensor) -> torch.Tensor:
        """The distance-to-goal field (rows, cols, C, B) on ``cost``, starting from ``pin`` (0 at the goal, inf
        elsewhere).

        A round runs four directional scans, for paths heading right, left, down and up. A scan takes every
        straight run at once: steps of 1, 2, 4, 8 cells let each cell see every cell up to 15 cells along its
        row. Rounds repeat until one changes nothing, so a path of k straight segments settles in about k + 1
        rounds. Values only decrease from ``pin`` and each is the cost of some path, so the fixed point reached
        is the exact field.
        """
        field = pin.clone()
        along_cols = self._segment_costs(cost, 1, self._col_shifts)
        along_rows = self._segment_costs(cost, 0, self._row_shifts)
        for rounds in range(1, self._max_rounds + 1):
            before = field.clone()
            for shift, segment in zip(self._col_shifts, along_cols):
                # Heading right, cell v enters v+1 .. v+shift and goes on from v+shift; heading left likewise.
                torch.minimum(field[:, :-shift], segment[:, 1:] + field[:, shift:], out=field[:, :-shift])
                torch.minimum(field[:, shift:], segment[:, :-1] + field[:, :-shift], out=field[:, shift:])
            for shift, segment in zip(self._row_shifts, along_rows):
                torch.minimum(field[:-shift], segment[1:] + field[shift:], out=field[:-shift])
                torch.minimum(field[shift:], segment[:-1] + field[:-shift], out=field[shift:])
            if torch.equal(field, before):
                self.last_rounds = rounds
                return field
        raise RuntimeError(f"the distance field did not settle in {self._max_rounds} rounds")

    @staticmethod
    def _segment_costs(cost: torch.Tensor, dim: int, shifts: Sequence[int]) -> list[torch.Tensor]:
        """For each shift s (1, 2, 4, ...), the cost of entering s consecutive cells along ``dim``, indexed by
        the first of them: n - s + 1 entries along ``dim``."""
        segments = [cost]
        for shift in shifts[:-1]:
            last = segments[-1]
            length = last.shape[dim] - shift
            segments.append(last.narrow(dim, 0, length) + last.narrow(dim, shift, length))
        return segments

    def inferred_present(self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Bool (B, N): not done, done at its goal, or kept after a crash."""
        if not self._remove_crashed:
            return torch.ones(state.shape[:2], dtype=torch.bool, device=state.device)
        return ~done.squeeze(-1) | (state == goal).all(-1)
