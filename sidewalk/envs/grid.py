"""The discrete Sidewalk: agents on a grid with the actions UP, DOWN, LEFT, RIGHT (paper §3.1, SPEC §1)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torchrl.data import Bounded, Categorical
from torchrl.data.tensor_specs import BoundedDiscrete

from sidewalk._checks import check_choice, check_int, check_range
from sidewalk._torchrl import set_uniform_box
from sidewalk.envs.base import AGENT_GROUP, COSTS, RENDER_MODES, SidewalkEnvBase, new_output
from sidewalk.envs.layouts import GridLayout, RandomGridLayout, grid_layout, grid_room
from sidewalk.envs.layouts.jitter import JitteredGridLayout
from sidewalk.envs.rewards import RewardParams
from sidewalk.envs.shield import grid_shield

# (d_row, d_col) of UP, DOWN, LEFT, RIGHT; rows run across the sidewalk, columns along it.
ACTIONS = ("UP", "DOWN", "LEFT", "RIGHT")
MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))
OBSERVATIONS = ("image", "vector")
# What observation="vector" lists of every agent, cells scaled to [0, 1]: present (it occupies a cell: moving or
# parked at its goal) and active (it still moves: not arrived, not crashed).
VECTOR_FIELDS = ("row", "col", "goal_row", "goal_col", "present", "active")

# Grey levels of the image observation. Roles are ego-centric: in agent i's image, agent i is SELF, agent
# i+1 (mod N) the first OTHER, and so on, so each agent and each goal has its own fixed value in every image.
SELF, OWN_GOAL, WALL = 255, 128, 32


def role_values(n_agents: int) -> tuple[list[int], list[int]]:
    """Grey levels of the agents and of the goals, indexed by ego-centric role (0 = self)."""
    others = np.linspace(224, 160, max(n_agents - 1, 1)).round().astype(int).tolist()[: n_agents - 1]
    other_goals = np.linspace(96, 48, max(n_agents - 1, 1)).round().astype(int).tolist()[: n_agents - 1]
    agents, goals = [SELF, *others], [OWN_GOAL, *other_goals]
    if len(set(agents + goals + [WALL])) != 2 * n_agents + 1:
        raise ValueError(f"{n_agents} agents are too many for distinct grey levels; use observation='vector'")
    return agents, goals


class _KeepSubclass(type(BoundedDiscrete)):
    """TorchRL's Bounded metaclass turns every instance into a BoundedDiscrete or BoundedContinuous; keep ours."""

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        return type.__call__(cls, *args, **kwargs)


class UniformBounded(BoundedDiscrete, metaclass=_KeepSubclass):
    """TorchRL's ``Bounded`` integer spec (a ``BoundedDiscrete``), for bounds that are the same in every world and
    agent, as the image's 0..255.

    When a ``Composite`` takes a ``Bounded`` it keeps one batch item's bounds if all items' agree, and checks that
    with ``torch.allclose`` over the full-size bounds, seconds for the images of thousands of worlds. Here the check
    is exact (for integers the same answer as ``allclose``'s) and far cheaper; otherwise, and on any later
    registration, TorchRL's own runs. Clones, indexing and reshapes keep this class (they call ``self.__class__``).
    """

    def _register_batch_size(self, batch_size: torch.Size | tuple) -> None:
        box, batch_size = self.space, torch.Size(batch_size)
        dims = len(batch_size)
        if box.batch_size is None and dims and box.low.shape[:dims] == batch_size:
            low, high = box.low.flatten(0, dims - 1), box.high.flatten(0, dims - 1)
            if all(bool((bounds.amin(0) == bounds.amax(0)).all()) for bounds in (low, high)):
                set_uniform_box(box, low[0].clone(), high[0].clone(), batch_size)
                return
        super()._register_batch_size(batch_size)


@dataclass(frozen=True)
class DiscreteParams:
    """Parameters of the discrete Sidewalk, with SPEC defaults (7 × 15 grid, 2 px per cell, 300-step timeout)."""

    layout: str = "sidewalk"  # a registered scenario (sidewalk.envs.layouts.scenario_names())
    n_agents: int = 2  # agents in the scenario (sidewalk and zipper: 2)
    min_start_goal_cells: int = 4  # random layout: least Manhattan distance from an agent's start to its goal
    # Fixed layouts: each reset moves every start (goal) across the sidewalk by a uniform -k..k rows
    # (sidewalk.envs.layouts.jitter); 0: the scenario's own cells.
    start_jitter_rows: int = 0
    goal_jitter_rows: int = 0
    # ... or to a uniform free cell within k rows and columns of its own (where the walls hold no row move).
    start_jitter_cells: int = 0
    goal_jitter_cells: int = 0
    width_cells: int = 7
    length_cells: int = 15
    noise: float = 0.0  # probability that an agent's action is replaced by a uniformly random one
    observation: str = "image"  # "image": grey image (1, H·k, W·k) uint8; "vector": positions as floats
    pixels_per_cell: int = 2
    max_steps: int = 300
    remove_crashed: bool = True  # a crashed agent leaves the world; False keeps it as an obstacle
    cost: str = "collision"  # the safety cost ("agents", "cost"): "collision", or "near_miss" (collisions too)
    near_miss_margin: float = 1.0  # cost="near_miss": another agent within this many cells (Euclidean, centres)
    rewards: RewardParams = field(default_factory=RewardParams)

    def __post_init__(self) -> None:
        check_int("n_agents", self.n_agents, 1, 64)
        check_int("min_start_goal_cells", self.min_start_goal_cells, 1)
        check_int("start_jitter_rows", self.start_jitter_rows, 0)
        check_int("goal_jitter_rows", self.goal_jitter_rows, 0)
        check_int("start_jitter_cells", self.start_jitter_cells, 0)
        check_int("goal_jitter_cells", self.goal_jitter_cells, 0)
        check_int("width_cells", self.width_cells, 1, 255)
        check_int("length_cells", self.length_cells, 2, 255)
        check_range("noise", self.noise, 0.0, 1.0)
        check_choice("observation", self.observation, OBSERVATIONS)
        check_int("pixels_per_cell", self.pixels_per_cell, 1, 32)
        check_int("max_steps", self.max_steps, 1)
        check_choice("cost", self.cost, COSTS)
        check_range("near_miss_margin", self.near_miss_margin, 0.0, low_open=True)
        if not isinstance(self.remove_crashed, bool):
            raise TypeError(f"remove_crashed={self.remove_crashed!r} must be a bool")
        if not isinstance(self.rewards, RewardParams):
            raise TypeError(f"rewards={self.rewards!r} must be a RewardParams or a mapping of its fields")


class DiscreteSidewalkEnv(SidewalkEnvBase):
    """The grid Sidewalk as a batched multi-agent TorchRL env.

    Per agent: ``action`` is Categorical(4) (UP, DOWN, LEFT, RIGHT); ``observation`` is the ego-centric grey
    image (uint8, (1, rows·k, cols·k)) or, with ``observation="vector"``, the positions of every agent and goal
    in ego order, normalised to [0, 1], plus a presence and an active flag per agent (``VECTOR_FIELDS``, 6·N floats;
    a crashed agent removed from the world is all zeros); ``state`` and ``goal`` are (row, col) int64.

    With probability ``noise`` an agent's action is replaced by a uniformly random one. Collisions: moving off
    the grid or into an interior wall; two agents ending in one cell; two agents swapping cells. An agent at its
    goal stays there as an obstacle; a crashed agent is removed unless ``remove_crashed=False``.

    Example:
        >>> env = DiscreteSidewalkEnv(num_envs=64, seed=0, noise=0.1)
        >>> rollout = env.rollout(50, break_when_any_done=False)
    """

    Params = DiscreteParams
    ACTION_LABELS = ACTIONS
    shaping_weight_name = None  # two shaping terms, weighed in _advance: c_center and c_progress
    PARTNER_OBSERVATIONS = ("vector",)  # a vector is cheap to compute from the state in any world; an image is not
    PARTNER_OBSERVATION_KEYS = tuple((AGENT_GROUP, key) for key in ("state", "goal", "present", "terminated"))

    room_sides = ("width_cells", "length_cells")
    STATE_WIDTH = 5  # cell row, col, goal row, col (scaled to [0, 1] by the grid's extent), present

    @staticmethod
    def _room(p: DiscreteParams, given: tuple[Any, Any], default: tuple[Any, Any]) -> tuple[int, int]:
        return grid_room(p.layout, p.n_agents, *given, default=default, min_start_goal_cells=p.min_start_goal_cells)

    @staticmethod
    def layout_for(p: DiscreteParams) -> GridLayout | RandomGridLayout | JitteredGridLayout:
        """The layout that parameters ``p`` describe (raises on a bad scenario name or agent count, or on jitter
        bounds that put an agent into a wall)."""
        if isinstance(p.layout, (GridLayout, RandomGridLayout, JitteredGridLayout)):
            layout = p.layout
        else:
            layout = grid_layout(p.layout, p.width_cells, p.length_cells, p.n_agents, p.min_start_goal_cells)
        if p.start_jitter_rows or p.goal_jitter_rows or p.start_jitter_cells or p.goal_jitter_cells:
            return JitteredGridLayout(layout, p.start_jitter_rows, p.goal_jitter_rows, p.start_jitter_cells,
                                      p.goal_jitter_cells)
        return layout

    def _make_layout(self) -> GridLayout | RandomGridLayout:
        return self.layout_for(self.params)

    def _init_world(self) -> None:
        layout, device, n = self.layout, self.device, self.n_agents
        self.rows, self.cols = layout.rows, layout.cols
        # global_state's scale of a cell: the grid's extent, at least 1 (a one-row grid).
        extent = torch.tensor([self.rows - 1, self.cols - 1], dtype=torch.float32, device=device)
        self._cell_extent = extent.clamp(min=1)
        self._move_row = torch.tensor([dr for dr, _ in MOVES], dtype=torch.long, device=device)
        self._move_col = torch.tensor([dc for _, dc in MOVES], dtype=torch.long, device=device)
        self._blocked = layout.blocked_mask(device).reshape(-1)
        self._has_blocked = bool(self._blocked.any())
        self._ego_order = (torch.arange(n, device=device)[:, None] + torch.arange(n, device=device)) % n
        shape = (self.num_envs, n)
        self._row = torch.zeros(shape, dtype=torch.long, device=device)
        self._col = torch.zeros(shape, dtype=torch.long, device=device)
        self._goal_row = torch.zeros(shape, dtype=torch.long, device=device)
        self._goal_col = torch.zeros(shape, dtype=torch.long, device=device)
        self._present = torch.zeros(shape, dtype=torch.bool, device=device)

        # The image of a step is a copy of a per-world backdrop (walls and goals, painted on reset) with the agents
        # scattered on top; absent agents are scattered into one spare pixel past the end of the image.
        agent_values, goal_values = role_values(n)
        role = (torch.arange(n, device=device) - torch.arange(n, device=device)[:, None]) % n  # role[i, j]
        self._agent_grey = torch.tensor(agent_values, dtype=torch.uint8, device=device)[role]
        self._goal_grey = torch.tensor(goal_values, dtype=torch.uint8, device=device)[role]
        k = self.params.pixels_per_cell
        pixel_row = torch.arange(self.rows * k, device=device) // k
        pixel_col = torch.arange(self.cols * k, device=device) // k
        self._pixel_cell = (pixel_row[:, None] * self.cols + pixel_col).reshape(-1)  # cell of every pixel
        cell = torch.arange(self.rows * self.cols, device=device)
        first_pixel = (cell // self.cols) * k * self.cols * k + (cell % self.cols) * k
        within = (torch.arange(k, device=device)[:, None] * self.cols * k + torch.arange(k, device=device)).reshape(-1)
        self._n_pixels = self.rows * k * self.cols * k
        # (rows·cols + 1, k²) pixels of every cell; the extra last "cell" is the spare pixel of absent agents.
        self._cell_pixels = torch.cat(
            [first_pixel[:, None] + within, torch.full((1, k * k), self._n_pixels, device=device)]
        )
        self._image_shape = (1, self.rows * k, self.cols * k)
        if self.params.observation == "image":
            # A fixed layout paints one backdrop, shared by all worlds (copying it from cache beats copying a
            # per-world one); otherwise each world's backdrop is repainted on its reset.
            if layout.fixed:
                _, goals = layout.sample(1, self._generator)
                self._backdrop = self._paint_backdrop(goals[..., 0] * self.cols + goals[..., 1])
            else:
                self._backdrop = torch.zeros((self.num_envs, n, self._n_pixels + 1), dtype=torch.uint8, device=device)
            self._agent_grey_pixels = self._agent_grey.repeat_interleave(k * k, dim=1).expand(self.num_envs, n, -1)
        rewards = self.params.rewards
        self._c_center, self._c_progress = float(rewards.c_center), float(rewards.c_progress)
        if self._c_progress != 0.0:
            self._path_length = self._path_length_table()
        self._vector_scale = torch.tensor(
            [max(self.rows - 1, 1), max(self.cols - 1, 1)], dtype=torch.float32, device=device
        )

    MAX_PROGRESS_CELLS = 4096  # the shortest-path table of c_progress holds cells² floats

    def _path_length_table(self) -> torch.Tensor:
        """Float (cells, cells): moves on the shortest path between two free cells around the walls (the table
        behind ``c_progress``); pairs that no path joins get ``rows·cols``, so no step earns progress toward them."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import shortest_path

        rows, cols, cells = self.rows, self.cols, self.rows * self.cols
        if cells > self.MAX_PROGRESS_CELLS:
            raise ValueError(
                f"rewards.c_progress needs a {rows}×{cols} grid's shortest paths ({cells} cells, at most "
                f"{self.MAX_PROGRESS_CELLS}); use a smaller grid or c_progress=0"
            )
        free = ~self._blocked.cpu().numpy()
        cell = np.arange(cells).reshape(rows, cols)
        edges = [
            (a, b)
            for a_cells, b_cells in ((cell[:, :-1], cell[:, 1:]), (cell[:-1, :], cell[1:, :]))
            for a, b in zip(a_cells.ravel(), b_cells.ravel())
            if free[a] and free[b]
        ]
        source, target = np.array(edges, dtype=np.int64).reshape(-1, 2).T
        graph = coo_matrix((np.ones(len(source)), (source, target)), shape=(cells, cells))
        lengths = shortest_path(graph, directed=False, unweighted=True)
        lengths[~np.isfinite(lengths)] = cells
        return torch.tensor(lengths, dtype=torch.float32, device=self.device)

    def _agent_specs(self) -> tuple[dict[str, Any], Any]:
        agents, device, n = (*self.batch_size, self.n_agents), self.device, self.n_agents
        if self.params.observation == "image":
            observation = UniformBounded(0, 255, shape=(*agents, *self._image_shape), dtype=torch.uint8, device=device)
        else:
            observation = Bounded(0.0, 1.0, shape=(*agents, len(VECTOR_FIELDS) * n), dtype=torch.float32, device=device)
        high = torch.tensor([self.rows - 1, self.cols - 1], device=device).expand(*agents, 2)
        cell = Bounded(torch.zeros_like(high), high, shape=(*agents, 2), dtype=torch.long, device=device)
        specs = {"observation": observation, "state": cell, "goal": cell.clone()}
        return specs, Categorical(len(ACTIONS), shape=agents, dtype=torch.long, device=device)

    def _reset_world(self, reset: torch.Tensor) -> None:
        if self.layout.fixed:
            starts, goals = self.layout.sample(self.num_envs, self._generator)
            self._row = torch.where(reset, starts[..., 0], self._row)
            self._col = torch.where(reset, starts[..., 1], self._col)
            self._goal_row = torch.where(reset, goals[..., 0], self._goal_row)
            self._goal_col = torch.where(reset, goals[..., 1], self._goal_col)
        else:
            # A random layout draws only the worlds being reset: with auto-reset, a few worlds a step.
            worlds = reset[:, 0].nonzero().squeeze(-1)
            starts, goals = self.sample_layout(worlds)
            for name, value in (("_row", starts[..., 0]), ("_col", starts[..., 1]),
                                ("_goal_row", goals[..., 0]), ("_goal_col", goals[..., 1])):
                setattr(self, name, getattr(self, name).index_copy(0, worlds, value))
            if self.params.observation == "image":
                goal_cell = self._goal_row[worlds] * self.cols + self._goal_col[worlds]
                self._backdrop[worlds] = self._paint_backdrop(goal_cell)
        self._present = self._present | reset

    def _paint_backdrop(self, goal_cell: torch.Tensor) -> torch.Tensor:
        """Walls and goals of some worlds, as seen by every agent, plus the spare pixel: uint8 (n, N, pixels + 1)."""
        n_worlds, n = goal_cell.shape[0], self.n_agents
        cells = torch.zeros((n_worlds, n, self.rows * self.cols + 1), dtype=torch.uint8, device=self.device)
        cells[..., :-1][..., self._blocked] = WALL
        cells.scatter_(2, goal_cell.unsqueeze(1).expand(-1, n, -1), self._goal_grey.expand(n_worlds, -1, -1))
        spare = torch.full((1,), self.rows * self.cols, device=self.device)
        return cells.index_select(2, torch.cat([self._pixel_cell, spare]))

    def _advance(self, action: torch.Tensor, active: torch.Tensor):
        noise = self.params.noise
        if noise > 0.0:
            replace = self.rand(action.shape) < noise
            random_action = self.randint(len(ACTIONS), action.shape)
            action = torch.where(replace, random_action, action)

        row, col = self._row, self._col
        flat_action = action.reshape(-1)
        target_row = row + self._move_row.index_select(0, flat_action).view_as(row) * active
        target_col = col + self._move_col.index_select(0, flat_action).view_as(col) * active
        inside = (target_row >= 0) & (target_row < self.rows) & (target_col >= 0) & (target_col < self.cols)
        hit_wall = active & ~inside
        if self._has_blocked:
            cell = target_row.clamp(0, self.rows - 1) * self.cols + target_col.clamp(0, self.cols - 1)
            hit_wall = hit_wall | (active & self._blocked[cell])
        mover = active & ~hit_wall
        new_row = torch.where(mover, target_row, row)
        new_col = torch.where(mover, target_col, col)

        # Who is in the world after the move: crashing into a wall removes an agent unless remove_crashed=False.
        present = self._present & ~hit_wall if self.params.remove_crashed else self._present
        # One transposing copy for all four (B, N) planes of the pairwise checks.
        cell_after, cell_before, mover_t, present_t = (
            torch.stack([new_row * self.cols + new_col, row * self.cols + col, mover, present]).transpose(1, 2).contiguous()
        )
        shared = (cell_after.unsqueeze(1) == cell_after.unsqueeze(0)) & present_t.bool().unsqueeze(0)
        swapped = (
            (cell_after.unsqueeze(1) == cell_before.unsqueeze(0))
            & (cell_before.unsqueeze(1) == cell_after.unsqueeze(0))
            & mover_t.bool().unsqueeze(0)
        )
        hit_agent = mover & ((shared | swapped) & self._not_self).any(1).t()
        reached = mover & ~hit_agent & (new_row == self._goal_row) & (new_col == self._goal_col)

        self._row, self._col = new_row, new_col
        self._present = present & ~hit_agent if self.params.remove_crashed else present
        shaping = self._c_center * (new_row.to(torch.float32) - self.layout.center_row).abs()
        if self._c_progress != 0.0:
            goal_cell = self._goal_row * self.cols + self._goal_col
            before = self._path_length[row * self.cols + col, goal_cell]
            after = self._path_length[new_row * self.cols + new_col, goal_cell]
            shaping = shaping + self._c_progress * (before - after)
        return reached, hit_wall, hit_agent, shaping

    def shield_action(self, action: torch.Tensor, shielded: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The grid's shield (see the base class; the rule: ``sidewalk.envs.shield.grid_shield``)."""
        return grid_shield(self, action, shielded)

    def _centres(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self._row.t().to(torch.float32), self._col.t().to(torch.float32)

    def _near(self, gap_sq: torch.Tensor) -> torch.Tensor:
        return gap_sq <= self.params.near_miss_margin**2  # cells: at the margin counts (1: the next cell)

    def _state_features(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        extent = self._cell_extent
        return torch.cat([state.to(torch.float32) / extent, goal.to(torch.float32) / extent], dim=-1)

    def _observe(self, worlds: torch.Tensor | None) -> dict[str, torch.Tensor]:
        # Grid observations are a deterministic function of the state: a reset observes its worlds only.
        state = (self._row, self._col, self._goal_row, self._goal_col, self._present, self._active)
        if worlds is not None:
            state = tuple(tensor.index_select(0, worlds) for tensor in state)
        row, col, goal_row, goal_col, present, active = state
        return {
            "observation": (
                self._image(row, col, present, worlds) if self.params.observation == "image"
                else self._vector(row, col, goal_row, goal_col, present, active)
            ),
            "state": torch.stack([row, col], dim=-1),
            "goal": torch.stack([goal_row, goal_col], dim=-1),
        }

    def observe_as(self, kind: str, tensordict: Any) -> torch.Tensor:
        """The agents' observations an env of ``observation=kind`` (``PARTNER_OBSERVATIONS``: ``"vector"``) gives in
        the worlds of ``tensordict``, this env's output or rows of it (read: ``PARTNER_OBSERVATION_KEYS``, the agents'
        cells, goals, presence and ends), whatever this env's own observation: (rows, N, fields·N)."""
        check_choice("partner observation", kind, self.PARTNER_OBSERVATIONS)
        agents = tensordict.get(AGENT_GROUP)
        state, goal = agents.get("state"), agents.get("goal")
        active = ~agents.get("terminated").squeeze(-1)  # the base ends an agent exactly when it stops being active
        return self._vector(state[..., 0], state[..., 1], goal[..., 0], goal[..., 1],
                            agents.get("present").squeeze(-1), active)

    def _image(
        self, row: torch.Tensor, col: torch.Tensor, present: torch.Tensor, worlds: torch.Tensor | None
    ) -> torch.Tensor:
        """The images of the worlds ``worlds`` (None: all), whose agents stand at ``row``, ``col`` (k, N)."""
        batch, n = row.shape
        cell = torch.where(present, row * self.cols + col, self.rows * self.cols)
        pixels = self._cell_pixels.index_select(0, cell.view(-1)).view(batch, 1, n * self._cell_pixels.shape[1])
        pixels = pixels.expand(batch, n, -1)
        backdrop = self._backdrop if worlds is None or self.layout.fixed else self._backdrop.index_select(0, worlds)
        canvas = new_output((batch, n, self._n_pixels + 1), torch.uint8, self.device)
        canvas.copy_(backdrop.expand(batch, n, -1)).scatter_(2, pixels, self._agent_grey_pixels[:batch])
        return canvas[..., : self._n_pixels].view(batch, n, *self._image_shape)

    def _vector(
        self, row: torch.Tensor, col: torch.Tensor, goal_row: torch.Tensor, goal_col: torch.Tensor, present: torch.Tensor,
        active: torch.Tensor,
    ) -> torch.Tensor:
        scale_row, scale_col = self._vector_scale.tolist()
        shown = present.to(torch.float32)  # a crashed agent removed from the world is all zeros: no obstacle
        per_agent = torch.stack(
            [row * shown / scale_row, col * shown / scale_col, goal_row * shown / scale_row,
             goal_col * shown / scale_col, shown, active.to(torch.float32)],
            dim=-1,
        )
        width = len(VECTOR_FIELDS)
        out = new_output((row.shape[0], self.n_agents * self.n_agents, width), torch.float32, self.device)
        torch.index_select(per_agent, 1, self._ego_order.view(-1), out=out)
        return out.view(row.shape[0], self.n_agents, width * self.n_agents)

    def render(self, env_index: int = 0, pixels_per_cell: int = 24, *, mode: str = "rgb_array") -> np.ndarray:
        """The world ``env_index`` as an RGB uint8 array (rows·px, cols·px, 3): agents as discs, goals as squares.
        ``mode``: ``"rgb_array"`` only (VMAS's keyword, which trainers such as BenchMARL pass)."""
        check_choice("mode", mode, RENDER_MODES)
        check_int("env_index", env_index, 0, self.num_envs - 1)
        from sidewalk.envs.render import draw_grid

        return draw_grid(
            rows=self.rows,
            cols=self.cols,
            blocked=self._blocked.view(self.rows, self.cols).cpu().numpy(),
            positions=torch.stack([self._row[env_index], self._col[env_index]], -1).cpu().numpy(),
            goals=torch.stack([self._goal_row[env_index], self._goal_col[env_index]], -1).cpu().numpy(),
            present=self._present[env_index].cpu().numpy(),
            pixels_per_cell=pixels_per_cell,
        )
