"""The scripted planners: Dijkstra on the grid, PRM in the continuous world.

Each is checked three ways: against scipy's Dijkstra on the same graph and costs (the batched planning is exact),
against itself one world at a time (batching changes nothing), and in rollouts with the ego standing still out
of the way (the planner reaches its goal around it and never crashes into a wall). The PRM's plans also equal, to
the bit, those of a plain per-world reference written from its docstring (its fast solver changes nothing).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import pytest
import scipy.sparse
import torch
from scipy.sparse.csgraph import dijkstra

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv, GridLayout, PlaneLayout
from sidewalk.envs.grid import MOVES
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.opponents.prm import PRMOpponent
from sidewalk.opponents.random import RandomOpponent

EGO, OTHER = 0, 1
RIGHT = 3  # grid action index


@pytest.fixture(autouse=True)
def one_thread():
    # The planners run many small operations; on 2 busy cores a second intra-op thread only adds waiting.
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@dataclass(frozen=True)
class ParkedEgoGrid(GridLayout):
    """The default 7 × 15 sidewalk, but the ego starts one cell left of its goal, a random cell per world away
    from the other agent's start and goal: its first move (RIGHT) ends its episode there, and it stays put."""

    fixed = False

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        starts, goals = (t.clone() for t in super().sample(n, generator))
        row = torch.randint(self.rows, (n,), generator=generator)
        col = torch.randint(3, self.cols - 3, (n,), generator=generator)
        goals[:, EGO] = torch.stack([row, col], -1)
        starts[:, EGO] = torch.stack([row, col - 1], -1)
        return starts, goals


@dataclass(frozen=True)
class ParkedEgoPlane(PlaneLayout):
    """The first (narrow) 10 × 1.5 m sidewalk, the ego against a random side wall at a random x in [2, 8] m; with
    zero actions (and no noise) it never moves."""

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        starts, headings, goals = (t.clone() for t in super().sample(n, generator))
        draw = torch.rand(n, 2, generator=generator)
        wall_gap = 0.01
        low, high = 0.3 + wall_gap, self.width_m - 0.3 - wall_gap
        starts[:, EGO, 0] = 2.0 + 6.0 * draw[:, 0]
        starts[:, EGO, 1] = torch.where(draw[:, 1] < 0.5, low, high)
        return starts, headings, goals


def grid_env(num_envs: int, layout: GridLayout | None = None, seed: int = 0) -> DiscreteSidewalkEnv:
    extra = {} if layout is None else {"layout": layout}
    return DiscreteSidewalkEnv(num_envs=num_envs, seed=seed, observation="vector", **extra)


def parked_grid() -> ParkedEgoGrid:
    return ParkedEgoGrid(rows=7, cols=15, starts=((3, 5), (3, 14)), goals=((3, 6), (3, 0)), center_row=3.0)


def random_grid_states(env, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random (state, goal, done) for ``n`` worlds of ``env``: any cells (agents may share one), ~20% done."""
    generator = torch.Generator().manual_seed(seed)
    rows, cols, agents = env.layout.rows, env.layout.cols, env.n_agents

    def cells() -> torch.Tensor:
        return torch.stack(
            [
                torch.randint(rows, (n, agents), generator=generator),
                torch.randint(cols, (n, agents), generator=generator),
            ],
            -1,
        )

    return cells(), cells(), torch.rand(n, agents, 1, generator=generator) < 0.2


# ---- Dijkstra -------------------------------------------------------------------------------------------------------


def scipy_grid_field(costmap: np.ndarray, goal: tuple[int, int]) -> np.ndarray:
    """Cost of the cheapest path from each cell to ``goal``, entering a cell costing ``costmap`` there."""
    rows, cols = costmap.shape
    index = np.arange(rows * cols).reshape(rows, cols)
    sources, targets, weights = [], [], []
    for d_row, d_col in MOVES:
        for row in range(rows):
            for col in range(cols):
                to_row, to_col = row + d_row, col + d_col
                if 0 <= to_row < rows and 0 <= to_col < cols and np.isfinite(costmap[to_row, to_col]):
                    # Edges reversed (to -> from), so one search from the goal gives every cell's distance to it.
                    sources.append(index[to_row, to_col])
                    targets.append(index[row, col])
                    weights.append(costmap[to_row, to_col])
    graph = scipy.sparse.csr_matrix((weights, (sources, targets)), shape=(rows * cols, rows * cols))
    return dijkstra(graph, directed=True, indices=goal[0] * cols + goal[1]).reshape(rows, cols)


@pytest.mark.parametrize(
    "layout, controlled",
    [
        (None, (OTHER,)),
        (
            GridLayout(
                rows=7,
                cols=15,
                starts=((3, 0), (3, 14), (0, 0)),
                goals=((3, 14), (3, 0), (6, 14)),
                center_row=3.0,
                blocked=((2, 5), (3, 5), (4, 5), (1, 9), (5, 9)),
            ),
            (1, 2),
        ),
    ],
    ids=["sidewalk", "three-agents-and-walls"],
)
def test_dijkstra_field_equals_scipy_and_batching_changes_nothing(layout, controlled):
    env = grid_env(4, layout)
    # Fixed tie-breaks: a batch of one draws its ties from another stream position than a batch of 256.
    opponent = DijkstraOpponent(env, controlled=controlled, tie_break="progress")
    state, goal, done = random_grid_states(env, 256, seed=1)
    plan = opponent.plan(state, goal, done)
    for world in range(0, 256, 17):
        for k, agent in enumerate(controlled):
            expected = scipy_grid_field(
                plan.costmap[world, k].double().numpy(), tuple(goal[world, agent].tolist())
            )
            np.testing.assert_array_equal(plan.field[world, k].double().numpy(), expected)
        alone = opponent.plan(state[world : world + 1], goal[world : world + 1], done[world : world + 1])
        assert torch.equal(alone.field[0], plan.field[world])
        assert torch.equal(alone.action[0], plan.action[world])


def test_dijkstra_costmap_raises_cost_near_the_ego_and_blocks_agents():
    env = grid_env(1)
    opponent = DijkstraOpponent(env, avoid_radius_cells=1, avoid_cost=5.0)
    state = torch.tensor([[[2, 7], [3, 12]]])
    goal = torch.tensor([[[3, 14], [3, 0]]])
    costmap = opponent.plan(state, goal, torch.zeros(1, 2, 1, dtype=torch.bool)).costmap[0, 0]
    near_ego = torch.zeros(7, 15, dtype=torch.bool)
    near_ego[1:4, 6:9] = True
    expected = torch.where(near_ego, 6.0, 1.0)
    expected[2, 7] = expected[3, 12] = opponent.occupied_cost
    assert torch.equal(costmap, expected)


def test_dijkstra_moves_stay_on_the_grid_and_out_of_agents():
    layout = GridLayout(
        rows=7, cols=15, starts=((3, 0), (3, 14), (0, 0)), goals=((3, 14), (3, 0), (6, 14)), center_row=3.0,
        blocked=((2, 5), (3, 5), (4, 5)),
    )  # fmt: skip
    env = grid_env(1, layout)
    opponent = DijkstraOpponent(env, controlled=(1, 2))
    state, goal, done = random_grid_states(env, 4096, seed=2)
    action = opponent.act(state, goal, done)  # (B, 2)
    move = torch.tensor(MOVES)[action]  # (B, 2, 2)
    mover = state[:, [1, 2]]
    target = mover + move
    inside = (target[..., 0] >= 0) & (target[..., 0] < 7) & (target[..., 1] >= 0) & (target[..., 1] < 15)
    assert inside.all()
    blocked = env.layout.blocked_mask(torch.device("cpu"))
    assert not blocked[target[..., 0], target[..., 1]].any()

    # Into another present agent's cell only when no free, legal neighbour exists.
    present = ~done.squeeze(-1) | (state == goal).all(-1)

    def occupied(cell: torch.Tensor, agent: int) -> torch.Tensor:
        """Bool (B,): ``cell`` (B, 2) holds a present agent other than ``agent``."""
        return torch.stack(
            [present[:, j] & (cell == state[:, j]).all(-1) for j in range(3) if j != agent], -1
        ).any(-1)

    for k, agent in enumerate((1, 2)):
        into_agent = occupied(target[:, k], agent)
        free_exists = torch.zeros(len(state), dtype=torch.bool)
        for d_row, d_col in MOVES:
            cell = mover[:, k] + torch.tensor([d_row, d_col])
            legal = (cell[:, 0] >= 0) & (cell[:, 0] < 7) & (cell[:, 1] >= 0) & (cell[:, 1] < 15)
            legal &= ~blocked[cell[:, 0].clamp(0, 6), cell[:, 1].clamp(0, 14)]
            free_exists |= legal & ~occupied(cell, agent)
        assert not (into_agent & free_exists).any()


def test_dijkstra_reaches_its_goal_around_a_parked_ego():
    env = grid_env(512, parked_grid(), seed=3)
    opponent = DijkstraOpponent(env)
    tensordict = env.reset()
    parked = tensordict["agents", "goal"][:, EGO]
    for step in range(40):
        tensordict = opponent(tensordict)
        tensordict["agents", "action"][:, EGO] = RIGHT
        tensordict = env.step(tensordict)["next"]
        if step == 0:
            assert tensordict["agents", "info", "reached_goal"][:, EGO].all()  # the ego is parked
        position = tensordict["agents", "state"][:, OTHER]
        chebyshev = (position - parked).abs().amax(-1)
        assert (chebyshev > 1).all(), "the planner stepped next to the ego although a detour exists"
    info = tensordict["agents", "info"]
    assert info["reached_goal"][:, OTHER].all()
    assert not info["collided_wall"].any() and not info["collided_agent"].any()


def test_dijkstra_path_goes_around_an_ego_on_the_centre_line():
    opponent = DijkstraOpponent(grid_env(1), avoid_radius_cells=1)
    state = torch.tensor([[[3, 7], [3, 14]]])
    goal = torch.tensor([[[3, 7], [3, 0]]])  # the ego stands at its own goal: done and present
    done = torch.tensor([[[True], [False]]])
    path = [(3, 14)]
    while path[-1] != (3, 0):
        state[0, OTHER] = torch.tensor(path[-1])
        d_row, d_col = MOVES[int(opponent.act(state, goal, done)[0, 0])]
        path.append((path[-1][0] + d_row, path[-1][1] + d_col))
        assert len(path) < 40, f"no progress: {path}"
    assert all(max(abs(row - 3), abs(col - 7)) > 1 for row, col in path), path
    assert len(path) - 1 == 14 + 4  # the shortest detour around the 3 × 3 zone: two rows out and back


def test_dijkstra_checks_its_arguments():
    env = grid_env(1)
    with pytest.raises(ValueError, match="avoid_radius_cells=-1"):
        DijkstraOpponent(env, avoid_radius_cells=-1)
    with pytest.raises(TypeError, match="avoid_radius_cells=1.5"):
        DijkstraOpponent(env, avoid_radius_cells=1.5)
    with pytest.raises(ValueError, match=r"avoid_cost=-1\.0 is out of range; valid: \[0\.0, 1000\.0\]"):
        DijkstraOpponent(env, avoid_cost=-1.0)
    with pytest.raises(ValueError, match="discrete"):
        DijkstraOpponent(ContinuousSidewalkEnv(num_envs=1, seed=0))


# ---- PRM ------------------------------------------------------------------------------------------------------------


def scipy_roadmap_cost(roadmap, edge_cost: np.ndarray, goal_cost: np.ndarray) -> np.ndarray:
    """Each node's cheapest cost to the goal (an extra node M) over the roadmap's edges and goal edges."""
    n_nodes, n_neighbors = roadmap.neighbors.shape
    sources = np.repeat(np.arange(n_nodes), n_neighbors)
    targets = roadmap.neighbors.numpy().reshape(-1)
    weights = edge_cost.reshape(-1)
    edge, attached = np.isfinite(weights), np.isfinite(goal_cost)
    # Edges reversed (to -> from), so one search from the goal gives every node's cost to it.
    graph = scipy.sparse.csr_matrix(
        (
            np.concatenate([weights[edge], goal_cost[attached]]),
            (np.concatenate([targets[edge], np.full(attached.sum(), n_nodes)]),
             np.concatenate([sources[edge], np.arange(n_nodes)[attached]])),
        ),
        shape=(n_nodes + 1, n_nodes + 1),
    )  # fmt: skip
    return dijkstra(graph, directed=True, indices=n_nodes)[:n_nodes]


def random_plane_states(env, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    agents, (length, width), radius = env.n_agents, (env.layout.length_m, env.layout.width_m), 0.3
    state = torch.zeros(n, agents, 4)
    state[..., 0] = radius + (length - 2 * radius) * torch.rand(n, agents, generator=generator)
    state[..., 1] = radius + (width - 2 * radius) * torch.rand(n, agents, generator=generator)
    state[..., 3] = math.pi * (2 * torch.rand(n, agents, generator=generator) - 1)
    goal = torch.tensor(env.layout.goals).expand(n, -1, -1)
    return state, goal, torch.rand(n, agents, 1, generator=generator) < 0.2


THREE_AGENTS_AND_A_BOX = PlaneLayout(
    length_m=10.0,
    width_m=2.0,
    starts=((0.5, 1.0), (9.5, 1.0), (5.0, 0.4)),
    headings=(0.0, math.pi, 1.0),
    goals=((9.5, 1.0), (0.5, 1.0), (5.0, 1.6)),
    boxes=((4.0, 0.9, 4.5, 1.1),),
)


@pytest.mark.parametrize(
    "layout, controlled, num_worlds",
    [(None, (OTHER,), 8), (None, (OTHER,), 600), (THREE_AGENTS_AND_A_BOX, (1, 2), 8)],
    ids=["sidewalk-one-block", "sidewalk-slabs", "three-agents-and-a-box"],
)
def test_prm_costs_equal_scipy_and_batching_changes_nothing(layout, controlled, num_worlds):
    extra = {} if layout is None else {"layout": layout}
    env = ContinuousSidewalkEnv(num_envs=1, seed=4, **extra)
    opponent = PRMOpponent(env, controlled=controlled)
    state, goal, done = random_plane_states(env, num_worlds, seed=5)
    plan = opponent.plan(state, goal, done)
    for world in range(0, num_worlds, max(1, num_worlds // 6)):
        for k in range(len(controlled)):
            expected = scipy_roadmap_cost(
                opponent.roadmap,
                plan.edge_cost[world, k].double().numpy(),
                plan.goal_cost[world, k].double().numpy(),
            )
            np.testing.assert_allclose(plan.cost_to_goal[world, k].double().numpy(), expected, rtol=1e-5)
        alone = opponent.plan(state[world : world + 1], goal[world : world + 1], done[world : world + 1])
        assert torch.equal(alone.cost_to_goal[0], plan.cost_to_goal[world])
        assert torch.equal(alone.waypoint[0], plan.waypoint[world])


def reference_prm_plan(opponent: PRMOpponent, state, goal, done) -> tuple[torch.Tensor, torch.Tensor]:
    """The PRM's waypoints (B, C, 2) and costs-to-goal (B, C, M) written plainly from its docstring, one world
    and controlled agent at a time: every segment priced against where the other present agents will be,
    Bellman-Ford rounds over the whole roadmap until nothing changes, then the waypoint rules, ties to the first
    node. The arithmetic follows the planner's order (fused multiply-adds where it fuses), so its costs, and so
    its choices, match to the bit."""
    from sidewalk.opponents import prm

    p, layout = opponent.env.params, opponent.env.layout
    w, radius = opponent.avoid_weight, opponent.connection_radius_m
    high = (layout.length_m - p.agent_radius_m, layout.width_m - p.agent_radius_m)
    nodes, neighbors, edge_length = opponent.roadmap
    real = edge_length.isfinite()
    edge_delta = nodes[neighbors] - nodes[:, None]  # (M, K, 2)
    edge_inverse_sq = torch.where(real, 1.0 / edge_length.square(), 0.0)
    half_edge_m = float(edge_length[real].mean()) / 2
    present = opponent.present(state, goal, done)
    boxes = torch.tensor(layout.boxes).reshape(-1, 4)

    def clear(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """Bool: an agent walking straight from a to b (..., 2) touches no interior box."""
        return prm._segment_clear(boxes, p.agent_radius_m, radius, a[..., 0], a[..., 1], b[..., 0], b[..., 1])

    def where_then(world: int, agent: int, metres: torch.Tensor) -> torch.Tensor:
        """(..., 2) where ``agent`` will be when the planner has walked ``metres``."""
        x, y, speed, heading = state[world, agent]
        seconds = metres.clamp(max=opponent.predict_horizon_s * p.max_speed_mps) * (1.0 / p.max_speed_mps)
        ahead_x = torch.addcmul(x, seconds, speed * torch.cos(heading)).clamp(p.agent_radius_m, high[0])
        ahead_y = torch.addcmul(y, seconds, speed * torch.sin(heading)).clamp(p.agent_radius_m, high[1])
        return torch.stack([ahead_x, ahead_y], -1)

    def closeness(world, me, start, delta, inverse_sq, metres) -> torch.Tensor:
        """Of segments start + [0, 1] delta (..., 2) to the other present agents, as the planner defines it."""
        total = torch.zeros(delta.shape[:-1])
        for other in range(state.shape[1]):
            if other == me or not present[world, other]:
                continue
            (dx, dy), (fx, fy) = delta.unbind(-1), (where_then(world, other, metres) - start).unbind(-1)
            along = ((fx * dx).addcmul(fy, dy) * inverse_sq).clamp(0.0, 1.0)
            gap = ((fx - along * dx).square() + (fy - along * dy).square()).sqrt()
            contact_m = 2 * p.agent_radius_m + prm.CONTACT_MARGIN_M
            contact = ((contact_m - gap) * (1.0 / prm.CONTACT_RAMP_M)).clamp(0.0, 1.0)
            near = (gap * (-1.0 / opponent.avoid_radius_m) + 1.0).clamp(min=0.0)
            total = torch.maximum(total, near.add(contact, alpha=prm.CONTACT_CLOSENESS))
        return total

    def attachment(world, me, start, end, walked_m=0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """(length, closeness) of straight walks from start to end (..., 2), judged at their middle, reached
        after ``walked_m`` more."""
        length = torch.hypot(*(end - start).unbind(-1))
        inverse_sq = length.square().clamp(min=1e-12).reciprocal()
        return length, closeness(world, me, start, end - start, inverse_sq, walked_m + 0.5 * length)

    def first_min(values: torch.Tensor) -> int:
        return int((values == values.min()).nonzero()[0])

    waypoints = torch.zeros(state.shape[0], len(opponent.controlled), 2)
    costs = torch.zeros(state.shape[0], len(opponent.controlled), len(nodes))
    for world, (k, me) in itertools.product(range(state.shape[0]), enumerate(opponent.controlled)):
        here, there = state[world, me, :2], goal[world, me]
        from_self, self_near = attachment(world, me, here, nodes)
        edge_reach = from_self[:, None] + half_edge_m
        near = closeness(world, me, nodes[:, None], edge_delta, edge_inverse_sq, edge_reach)
        edge_cost = torch.addcmul(edge_length, torch.where(real, edge_length * w, 0.0), near)
        to_goal, goal_near = attachment(world, me, nodes, there, walked_m=from_self)
        attached = (to_goal <= to_goal.min().clamp(min=radius)) & clear(nodes, there)
        goal_cost = torch.where(attached, to_goal * (1 + w * goal_near), float("inf"))
        cost = goal_cost
        while not torch.equal(relaxed := torch.minimum(goal_cost, (edge_cost + cost[neighbors]).amin(1)), cost):
            cost = relaxed
        costs[world, k] = cost
        candidate = (from_self <= from_self.min().clamp(min=radius)) & clear(here, nodes)
        via = torch.where(candidate, from_self * (1 + w * self_near) + cost, float("inf"))
        best = node = first_min(via)
        goal_after_node = False
        if from_self[best] < opponent.waypoint_tolerance_m:
            after = edge_cost[best] + cost[neighbors[best]]
            node, goal_after_node = int(neighbors[best, first_min(after)]), bool(goal_cost[best] <= after.min())
        straight, straight_near = attachment(world, me, here, there)
        direct = straight <= radius and bool(clear(here, there))
        direct_cost = straight * (1 + w * straight_near) if direct else float("inf")
        waypoints[world, k] = there if bool(direct_cost <= via[best]) or goal_after_node else nodes[node]
    return waypoints, costs


@pytest.mark.parametrize(
    "layout, controlled, num_worlds, moving",
    [(None, (OTHER,), 40, True), (None, (OTHER,), 300, True), (THREE_AGENTS_AND_A_BOX, (1, 2), 24, True),
     (THREE_AGENTS_AND_A_BOX, (1, 2), 300, False)],
    ids=["sidewalk-few-worlds", "sidewalk-many-worlds", "three-agents-and-a-box", "three-agents-standing"],
)  # fmt: skip
def test_prm_plans_as_a_plain_reference_does(layout, controlled, num_worlds, moving):
    # Few and many worlds take the solver's two relaxation orders, and many worlds price edges in several chunks;
    # random states have agents absent, and moving (or all standing, as after a reset: nothing to predict).
    extra = {} if layout is None else {"layout": layout}
    env = ContinuousSidewalkEnv(num_envs=1, seed=21, **extra)
    opponent = PRMOpponent(env, controlled=controlled)
    state, goal, done = random_plane_states(env, num_worlds, seed=22)
    speed = torch.rand(num_worlds, env.n_agents, generator=torch.Generator().manual_seed(23))
    state[..., 2] = env.params.max_speed_mps * speed * moving
    waypoint, cost_to_goal = reference_prm_plan(opponent, state, goal, done)
    plan = opponent.plan(state, goal, done)
    assert torch.equal(plan.cost_to_goal, cost_to_goal)
    assert torch.equal(plan.waypoint, waypoint)
    # The controller, fed the reference's waypoints laid out as the planner's (vectorised cos and atan2 may round
    # differently on other layouts), gives the same actions.
    steered = opponent._steer(state, goal, done, waypoint.permute(2, 1, 0).contiguous())
    assert torch.equal(opponent.act(state, goal, done), steered)


def test_prm_plans_as_a_plain_reference_does_along_a_rollout():
    env = ContinuousSidewalkEnv(num_envs=64, seed=24)
    opponent, ego = PRMOpponent(env), RandomOpponent(env, controlled=(EGO,), ego=None)
    tensordict = env.reset()
    for step in range(40):
        if step % 8 == 0:  # the ego starts on the planner's goal: the solver's hardest worlds come first
            inputs = [tensordict["agents", key] for key in ("state", "goal", "done")]
            plan, (waypoint, cost_to_goal) = opponent.plan(*inputs), reference_prm_plan(opponent, *inputs)
            assert torch.equal(plan.waypoint, waypoint) and torch.equal(plan.cost_to_goal, cost_to_goal)
        _, tensordict = env.step_and_maybe_reset(ego(opponent(tensordict)))


def test_prm_roadmap_is_built_once_per_layout():
    first = PRMOpponent(ContinuousSidewalkEnv(num_envs=1, seed=3))
    second = PRMOpponent(ContinuousSidewalkEnv(num_envs=8, seed=3), controlled=(0,), ego=1)
    assert first.roadmap.nodes is second.roadmap.nodes
    assert PRMOpponent(ContinuousSidewalkEnv(num_envs=1, seed=4)).roadmap.nodes is first.roadmap.nodes  # one default
    from_seed = PRMOpponent(ContinuousSidewalkEnv(num_envs=1, seed=4), roadmap_seed=None)
    assert from_seed.roadmap.nodes is not first.roadmap.nodes


def test_prm_reaches_its_goal_past_a_parked_ego_and_never_hits_a_wall():
    layout = ParkedEgoPlane(
        length_m=10.0, width_m=1.5, starts=((5.0, 0.31), (9.5, 0.75)), headings=(0.0, math.pi),
        goals=((5.0, 0.31), (0.5, 0.75)),
    )  # fmt: skip
    env = ContinuousSidewalkEnv(num_envs=1000, seed=6, layout=layout)
    opponent = PRMOpponent(env)
    tensordict = env.reset()
    parked = tensordict["agents", "state"][:, EGO].clone()
    for _ in range(env.params.max_steps):
        tensordict = opponent(tensordict)
        tensordict["agents", "action"][:, EGO] = 0.0
        tensordict = env.step(tensordict)["next"]
        if tensordict["agents", "done"][:, OTHER].all():
            break
    assert torch.equal(tensordict["agents", "state"][:, EGO], parked)
    info = tensordict["agents", "info"]
    assert info["reached_goal"][:, OTHER].float().mean() >= 0.95
    assert not info["collided_wall"][:, OTHER].any()


def test_prm_seldom_hits_a_wall_beside_a_random_ego():
    # A random ego can corner the planner against a wall: 1-5 of 1024 worlds on the roadmaps of seeds 0-11.
    env = ContinuousSidewalkEnv(num_envs=512, seed=7)
    opponent, ego = PRMOpponent(env), RandomOpponent(env, controlled=(EGO,), ego=None)
    tensordict = env.reset()
    hit = torch.zeros(512, dtype=torch.bool)
    for _ in range(120):
        tensordict = env.step(ego(opponent(tensordict)))["next"]
        hit |= tensordict["agents", "info", "collided_wall"][:, OTHER, 0]
    assert hit.sum() <= 5
    assert tensordict["agents", "info", "reached_goal"][:, OTHER].float().mean() > 0.85


def test_prm_roadmap_keeps_clear_of_walls_and_is_seeded():
    env = ContinuousSidewalkEnv(num_envs=1, seed=8, layout=THREE_AGENTS_AND_A_BOX)
    opponent = PRMOpponent(env, wall_clearance_m=0.05)
    nodes, neighbors, edge_length = opponent.roadmap
    assert len(nodes) > 100
    clear = 0.3 + 0.05
    assert (nodes[:, 0] >= clear).all() and (nodes[:, 0] <= 10.0 - clear).all()
    assert (nodes[:, 1] >= clear).all() and (nodes[:, 1] <= 2.0 - clear).all()
    x_min, y_min, x_max, y_max = THREE_AGENTS_AND_A_BOX.boxes[0]
    to_box = torch.hypot(
        nodes[:, 0] - nodes[:, 0].clamp(x_min, x_max), nodes[:, 1] - nodes[:, 1].clamp(y_min, y_max)
    )
    assert (to_box >= clear).all()
    real = edge_length.isfinite()
    assert (edge_length[real] <= opponent.connection_radius_m).all()
    pairs = {(i, int(j)) for i in range(len(nodes)) for j, ok in zip(neighbors[i], real[i]) if ok}
    assert all((j, i) in pairs for i, j in pairs)  # every edge can be walked both ways

    def roadmap(env_seed: int, **kwargs) -> torch.Tensor:
        return PRMOpponent(ContinuousSidewalkEnv(num_envs=1, seed=env_seed), **kwargs).roadmap.nodes

    assert torch.equal(roadmap(1), roadmap(2))  # the default roadmap does not depend on the env's seed
    assert torch.equal(roadmap(1, roadmap_seed=None), roadmap(1, roadmap_seed=None))
    assert not torch.equal(roadmap(1, roadmap_seed=None), roadmap(2, roadmap_seed=None))
    assert torch.equal(roadmap(1, roadmap_seed=3), roadmap(2, roadmap_seed=3))


def test_prm_same_seed_same_actions():
    def actions(seed: int) -> torch.Tensor:
        env = ContinuousSidewalkEnv(num_envs=16, seed=seed, noise=0.5)
        opponent, ego = PRMOpponent(env), RandomOpponent(env, controlled=(EGO,), ego=None)
        tensordict, taken = env.reset(), []
        for _ in range(30):
            tensordict = ego(opponent(tensordict))
            taken.append(tensordict["agents", "action"][:, OTHER].clone())
            _, tensordict = env.step_and_maybe_reset(tensordict)
        return torch.stack(taken)

    assert torch.equal(actions(9), actions(9))
    assert not torch.equal(actions(9), actions(10))


def test_prm_actions_respect_bounds_and_done_agents_rest():
    env = ContinuousSidewalkEnv(num_envs=1, seed=11)
    opponent = PRMOpponent(env)
    state, goal, done = random_plane_states(env, 512, seed=12)
    action = opponent.act(state, goal, done)
    p = env.params
    assert (action[..., 0].abs() <= p.max_accel_mps2).all() and (action[..., 1].abs() <= p.max_turn_rad).all()
    assert (action[done[:, OTHER, 0]] == 0).all()


def test_prm_checks_its_arguments():
    env = ContinuousSidewalkEnv(num_envs=1, seed=0)
    with pytest.raises(ValueError, match="connection_radius_m=0"):
        PRMOpponent(env, connection_radius_m=0)
    with pytest.raises(ValueError, match="n_nodes=1 is out of range"):
        PRMOpponent(env, n_nodes=1)
    # Free half width of the 4 m × 3 m sidewalk: 1.5 m - 0.3 m radius.
    with pytest.raises(ValueError, match=r"wall_clearance_m=1\.3 is out of range; valid: \[0\.0, 1\.2"):
        PRMOpponent(env, wall_clearance_m=1.3)
    with pytest.raises(ValueError, match=r"predict_horizon_s=-1"):
        PRMOpponent(env, predict_horizon_s=-1)
    with pytest.raises(TypeError, match="roadmap_seed=1.5"):
        PRMOpponent(env, roadmap_seed=1.5)
    with pytest.raises(ValueError, match="continuous"):
        PRMOpponent(grid_env(1))
