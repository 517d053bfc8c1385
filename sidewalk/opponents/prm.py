"""The PRM opponent of the continuous Sidewalk (paper §4.2, SPEC §2): a probabilistic roadmap over the free
space, Dijkstra on it with costs raised near the other agents, replanned every step, and a unicycle controller
that steers toward the plan's next waypoint.

The roadmap is sampled once per opponent, from a seeded generator. Each step attaches every controlled agent's
goal to the roadmap, relaxes every world's cost-to-goal over it in one batched Bellman-Ford computation (a fixed
neighbour list, the worlds on the last axis, Gauss-Seidel blocks), then attaches the agent's position to pick
the next waypoint. There is no per-world loop and no graph building per step.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.opponents.base import Opponent

NUM_NODES = 150  # sampled nodes, before those outside the roadmap's largest connected piece are dropped
CONNECTION_RADIUS_M = 0.6  # nodes this close are joined by an edge ...
MAX_NEIGHBORS = 12  # ... keeping each node's nearest few (the graph is then made symmetric)
WALL_CLEARANCE_M = 0.05  # nodes keep this much room beyond the agent radius from every wall
# Nodes keep at least this fraction of the mean spacing sqrt(free area / n_nodes) apart: uniform draws without
# clumps, so fewer gaps in the narrow lanes beside another agent.
NODE_SPACING_FRACTION = 0.75
# Path costs rise within AVOID_RADIUS_M of another agent (4 radii: contact plus 2 radii): a metre walked at its
# centre would cost 1 + AVOID_WEIGHT metres, falling linearly to 1 at the radius.
AVOID_RADIUS_M = 1.2
AVOID_WEIGHT = 4.0
# A point closer than two agent radii plus this margin to another agent counts as touching it, and adds
# CONTACT_CLOSENESS: a plan goes through contact only when nothing else reaches the goal.
CONTACT_MARGIN_M = 0.05
CONTACT_CLOSENESS = 25.0
CONTACT_RAMP_M = 0.01  # the contact term rises from 0 to CONTACT_CLOSENESS over this last distance
WAYPOINT_TOLERANCE_M = 0.2  # an agent this close to its best node steers on to the node after it
# A segment's costs are raised near where the avoided agents will be, at their current velocity, when the
# controlled agent gets there at full speed (straight-line distance to the segment's midpoint / max speed), looking
# at most PREDICT_HORIZON_S ahead. An agent walking toward the planner's goal is then avoided where the two will
# meet, not where it stands now (it stands on that goal at the start, which makes every path equally bad).
PREDICT_HORIZON_S = 2.0
BRAKE_FRACTION = 0.5  # speed caps plan to stop with this share of the deceleration; the rest is margin
WALL_MARGIN_M = 0.02  # the speed cap stops the agent this far before the wall straight ahead
SEGMENT_CHECK_STEP_M = 0.05  # spacing of the points that test a segment against interior boxes
SAMPLING_ROUNDS = 100  # rounds of candidate draws before a too-small free space is reported
# Costs are relaxed slab by slab, each slab of consecutive nodes (in order of x) seeing the slabs relaxed before
# it (Gauss-Seidel): 64 slabs of 2-3 nodes settle the default roadmap in ~3 rounds (the last one confirming)
# instead of ~13 rounds of whole sweeps, at 4 small operations per slab. Below GAUSS_SEIDEL_MIN_LANES (controlled
# agents × worlds; measured crossover 256-512) the per-operation overhead outweighs the rounds saved, and the
# roadmap is relaxed as one block.
GAUSS_SEIDEL_BLOCKS = 64
GAUSS_SEIDEL_MIN_LANES = 512


class Roadmap(NamedTuple):
    """A roadmap: ``nodes`` (M, 2) positions (x, y); ``neighbors`` (M, K) node indices and ``edge_length``
    (M, K) metres of each node's edges, padded with index 0 and length inf where a node has fewer than K."""

    nodes: torch.Tensor
    neighbors: torch.Tensor
    edge_length: torch.Tensor


class RoadmapPlan(NamedTuple):
    """What one planning call computed, world-first.

    ``waypoint`` (B, C, 2): the point each controlled agent steers to; ``cost_to_goal`` (B, C, M): each node's
    cost of the cheapest roadmap path to the agent's goal; ``edge_cost`` (B, C, M, K): the cost of each roadmap
    edge (``Roadmap.neighbors`` order); ``goal_cost`` (B, C, M): the cost of each node's direct edge to the goal
    (inf: not attached).
    """

    waypoint: torch.Tensor
    cost_to_goal: torch.Tensor
    edge_cost: torch.Tensor
    goal_cost: torch.Tensor


class PRMOpponent(Opponent):
    """Follows a probabilistic-roadmap plan to its goal with a unicycle controller (continuous domain only).

    Roadmap, built once: ``n_nodes`` points drawn uniformly where an agent's disc keeps ``wall_clearance_m``
    from every wall and box, a point being dropped if it lands within ``NODE_SPACING_FRACTION`` of the mean
    spacing of one already kept; each joined to its ``max_neighbors`` nearest within ``connection_radius_m``
    (made symmetric; edges that would touch a box are dropped); only the largest connected piece is kept. The
    points come from a generator seeded with ``roadmap_seed``, or, if ``None``, with the seed ``env.generator``
    holds at construction (so the env's seed fixes the roadmap, and no draw from it is spent).

    Plan, every step: a straight segment costs its length times 1 + ``avoid_weight`` × its closeness to the
    other present agents (with two agents, the ego): the closeness of its point nearest an agent, falling
    linearly from 1 at the agent's centre to 0 at ``avoid_radius_m``, plus ``CONTACT_CLOSENESS`` where a disc
    there would touch the agent, so a plan goes through contact only when nothing else reaches the goal. Each
    segment is judged against where the agent will be, at its current velocity, when the controlled agent gets
    to the segment's middle at full speed (a roadmap edge's: its first node's plus half the mean edge length; at
    most ``predict_horizon_s`` ahead; 0: where it is now): without
    it, an ego walking the centre line toward the planner's goal made both ways round it cost the same until
    late, and the planner flipped between them and ran into it (12.5 % of 1000 seeded worlds at the defaults). The
    goal is joined to the nodes within the connection radius (at least the nearest), and so is the agent, also
    straight to the goal when that is within the radius. The waypoint is the first node of the cheapest path, or
    the node after it once the agent is within ``waypoint_tolerance_m`` of it, or the goal.

    Control: turn toward the waypoint as far as ``max_turn_rad`` allows; aim for full speed, scaled by the
    cosine of the heading error (zero when the waypoint is behind) and capped so that half the maximum
    deceleration would stop the agent at its goal and before the wall straight ahead. Done agents get (0, 0).

    Every call plans from scratch and keeps no per-world memory, so ``reset(rows)`` has nothing to do.
    ``roadmap`` holds the roadmap, ``last_rounds`` the number of relaxation rounds of the last call.
    """

    name = "prm"
    domains = ("continuous",)

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled: Sequence[int] = (1,),
        ego: int | None = 0,
        *,
        n_nodes: int = NUM_NODES,
        connection_radius_m: float = CONNECTION_RADIUS_M,
        max_neighbors: int = MAX_NEIGHBORS,
        wall_clearance_m: float = WALL_CLEARANCE_M,
        avoid_radius_m: float = AVOID_RADIUS_M,
        avoid_weight: float = AVOID_WEIGHT,
        waypoint_tolerance_m: float = WAYPOINT_TOLERANCE_M,
        predict_horizon_s: float = PREDICT_HORIZON_S,
        roadmap_seed: int | None = None,
    ) -> None:
        super().__init__(env, controlled, ego)
        params, layout = env.params, env.layout
        self._check_settings(
            env, n_nodes, connection_radius_m, max_neighbors, wall_clearance_m, avoid_radius_m, avoid_weight,
            waypoint_tolerance_m, predict_horizon_s,
        )
        if roadmap_seed is None:
            # The env's seed, read without drawing: the env's random stream is the same with or without a PRM.
            roadmap_seed = int(env.generator.initial_seed())
        check_int("roadmap_seed", roadmap_seed, 0)
        self.connection_radius_m = float(connection_radius_m)
        self.avoid_radius_m = float(avoid_radius_m)
        self.avoid_weight = float(avoid_weight)
        self.waypoint_tolerance_m = float(waypoint_tolerance_m)
        self.predict_horizon_s = float(predict_horizon_s)
        self.roadmap_seed = roadmap_seed
        self._params = params
        self._boxes = torch.tensor(layout.boxes, dtype=torch.float32).reshape(-1, 4)
        self._box_margin_m = params.agent_radius_m  # an agent centre this close to a box touches it
        self._contact_distance_m = 2 * params.agent_radius_m + CONTACT_MARGIN_M
        # The agent's centre stays within these bounds, or its disc touches a wall.
        self._x_limits = (params.agent_radius_m, layout.length_m - params.agent_radius_m)
        self._y_limits = (params.agent_radius_m, layout.width_m - params.agent_radius_m)

        generator = torch.Generator().manual_seed(roadmap_seed)
        self.roadmap = Roadmap(
            *(
                t.to(env.device)
                for t in self._build_roadmap(
                    n_nodes, params.agent_radius_m + wall_clearance_m, max_neighbors, generator
                )
            )
        )
        self._prepare_edges()

        n_agents, n_controlled = env.n_agents, len(self.controlled)
        self._others = torch.ones(n_controlled, n_agents, 1, dtype=torch.bool, device=env.device)
        self._others[torch.arange(n_controlled), self._controlled_index] = False
        # One controlled agent among two avoids just the other one: a slice instead of a reduction.
        self._only_other = 1 - self.controlled[0] if n_agents == 2 and n_controlled == 1 else None

        self.last_rounds = 0
        self._buffers: dict[str, torch.Tensor] = {}

    @staticmethod
    def _check_settings(
        env: SidewalkEnvBase, n_nodes: int, connection_radius_m: float, max_neighbors: int, wall_clearance_m: float,
        avoid_radius_m: float, avoid_weight: float, waypoint_tolerance_m: float, predict_horizon_s: float,
    ) -> None:
        params, layout = env.params, env.layout
        check_int("n_nodes", n_nodes, 2, 10_000)
        check_range("connection_radius_m", connection_radius_m, 0.0, low_open=True)
        check_int("max_neighbors", max_neighbors, 1, n_nodes - 1)
        free_half_width = min(layout.length_m, layout.width_m) / 2 - params.agent_radius_m
        check_range("wall_clearance_m", wall_clearance_m, 0.0, free_half_width)
        check_range("avoid_radius_m", avoid_radius_m, 0.0, low_open=True)
        check_range("avoid_weight", avoid_weight, 0.0, 1000.0)
        check_range("waypoint_tolerance_m", waypoint_tolerance_m, 0.0, connection_radius_m)
        check_range("predict_horizon_s", predict_horizon_s, 0.0, 60.0)

    def _prepare_edges(self) -> None:
        """The roadmap's nodes and edges as the broadcast shapes planning uses, and the solver's node slabs."""
        nodes, neighbors, edge_length = self.roadmap
        n_kept = len(nodes)
        self._node_x, self._node_y = nodes[:, 0, None, None], nodes[:, 1, None, None]  # (M, 1, 1)
        self._neighbors_flat = neighbors.reshape(-1)
        # Edges as segments from each node, (M, K, 1, 1); padding edges have length inf and weight 0 (not
        # inf · 0 = nan), which keeps their cost at inf.
        real = edge_length.isfinite()
        self._edge_x, self._edge_y = nodes[:, 0, None, None, None], nodes[:, 1, None, None, None]
        self._edge_dx = (nodes[neighbors, 0] - nodes[:, 0, None])[:, :, None, None]
        self._edge_dy = (nodes[neighbors, 1] - nodes[:, 1, None])[:, :, None, None]
        self._edge_inverse_sq = torch.where(real, 1.0 / edge_length.square(), 0.0)[:, :, None, None]
        self._edge_length = edge_length[:, :, None, None]
        self._edge_weight = torch.where(real, edge_length * self.avoid_weight, 0.0)[:, :, None, None]
        self._half_edge_m = float(edge_length[real].mean()) / 2
        # Gauss-Seidel blocks: slabs of consecutive nodes (in order of x), with their slice of neighbour lists.
        bounds = torch.linspace(0, n_kept, min(GAUSS_SEIDEL_BLOCKS, n_kept) + 1).round().long().tolist()
        n_neighbors = neighbors.shape[1]
        self._slabs = [
            (start, stop, self._neighbors_flat[start * n_neighbors : stop * n_neighbors])
            for start, stop in itertools.pairwise(bounds)
        ]
        self._whole = [(0, n_kept, self._neighbors_flat)]
        # Each round lowers some cost or ends the solve; a cheapest path visits each node once.
        self._max_rounds = n_kept + 1

    # ---- roadmap ------------------------------------------------------------------------------------------------

    def _build_roadmap(
        self, n_nodes: int, wall_distance_m: float, max_neighbors: int, generator: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sample nodes, join near pairs, keep the largest connected piece: (nodes, neighbors, edge_length)."""
        layout = self.env.layout
        low = torch.tensor([wall_distance_m, wall_distance_m])
        span = torch.tensor([layout.length_m, layout.width_m]) - 2 * low
        if (span <= 0).any():
            raise ValueError(
                f"no free space: walls {wall_distance_m} m away leave a span of {span.tolist()} m"
            )
        # Dart throwing: uniform candidates, each kept if no kept node lies within the minimum spacing.
        probe = low + span * torch.rand(4 * n_nodes, 2, generator=generator)
        free_share = (~self._touches_box(probe[:, 0], probe[:, 1], wall_distance_m)).float().mean()
        spacing = NODE_SPACING_FRACTION * math.sqrt(float(span.prod() * free_share) / n_nodes)
        nodes = torch.empty(n_nodes, 2)
        count = 0
        for _ in range(SAMPLING_ROUNDS):
            candidates = low + span * torch.rand(4 * n_nodes, 2, generator=generator)
            candidates = candidates[~self._touches_box(candidates[:, 0], candidates[:, 1], wall_distance_m)]
            for point in candidates:
                if count == 0 or torch.cdist(point[None], nodes[:count]).min() >= spacing:
                    nodes[count] = point
                    count += 1
                    if count == n_nodes:
                        break
            if count == n_nodes:
                break
        else:
            raise ValueError(
                f"only {count} of n_nodes={n_nodes} nodes fit {spacing:.3f} m apart in the free space; lower n_nodes"
            )

        gap = torch.cdist(nodes, nodes)
        near = (gap <= self.connection_radius_m) & ~torch.eye(n_nodes, dtype=torch.bool)
        if len(self._boxes):
            near &= self._segment_clear(
                nodes[:, None, 0], nodes[:, None, 1], nodes[None, :, 0], nodes[None, :, 1]
            )
        # Keep each node's nearest few, then make the graph symmetric so that every edge can be walked both ways.
        order = torch.where(near, gap, float("inf")).topk(max_neighbors, dim=1, largest=False).indices
        keep = torch.zeros_like(near).scatter_(1, order, True) & near
        adjacency = keep | keep.t()

        # Largest connected piece, by propagating the smallest node index through the edges until it settles.
        label = torch.arange(n_nodes)
        while True:
            reached = torch.where(adjacency, label[None, :], n_nodes).amin(1)
            updated = torch.minimum(label, reached)
            if torch.equal(updated, label):
                break
            label = updated
        largest = label == label.bincount().argmax()
        # Nodes go in order of x, so that blocks of consecutive nodes are slabs across the sidewalk.
        kept = largest.nonzero().squeeze(-1)
        kept = kept[nodes[kept, 0].argsort()]
        nodes, adjacency, gap = nodes[kept], adjacency[kept][:, kept], gap[kept][:, kept]
        if len(nodes) < 2:
            raise ValueError(
                f"the roadmap fell apart (largest connected piece: {len(nodes)} node); "
                f"raise n_nodes or connection_radius_m={self.connection_radius_m}"
            )
        degree = int(adjacency.sum(1).max())
        length = torch.where(adjacency, gap, float("inf"))
        edge_length, neighbors = length.topk(degree, dim=1, largest=False)
        neighbors = torch.where(edge_length.isfinite(), neighbors, 0)
        return nodes, neighbors, edge_length

    def _touches_box(self, x: torch.Tensor, y: torch.Tensor, distance_m: float) -> torch.Tensor:
        """Bool, the shape of ``x``: the point lies within ``distance_m`` of an interior box."""
        boxes = self._boxes.to(x.device)
        if not len(boxes):
            return torch.zeros(x.shape, dtype=torch.bool, device=x.device)
        x_min, y_min, x_max, y_max = boxes.unbind(-1)
        x, y = x.unsqueeze(-1), y.unsqueeze(-1)
        near_x = torch.maximum(torch.minimum(x, x_max), x_min)
        near_y = torch.maximum(torch.minimum(y, y_max), y_min)
        return ((x - near_x).square() + (y - near_y).square() < distance_m**2).any(-1)

    def _segment_clear(
        self, ax: torch.Tensor, ay: torch.Tensor, bx: torch.Tensor, by: torch.Tensor
    ) -> torch.Tensor:
        """Bool, the broadcast shape: an agent moving straight from a to b touches no interior box.

        The test points are spaced for segments of the connection radius; a longer one (an attachment to a
        nearest node beyond it) is tested more coarsely.
        """
        steps = math.ceil(self.connection_radius_m / SEGMENT_CHECK_STEP_M) + 1
        fraction = torch.linspace(0.0, 1.0, steps, device=ax.device)
        ax, ay, bx, by = (t.unsqueeze(-1) for t in (ax, ay, bx, by))
        touches = self._touches_box(ax + (bx - ax) * fraction, ay + (by - ay) * fraction, self._box_margin_m)
        return ~touches.any(-1)

    # ---- planning -----------------------------------------------------------------------------------------------

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        waypoint = self._plan(state, goal, done, present)[0]
        return self._steer(state, goal, done, waypoint)

    def plan(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> RoadmapPlan:
        """Plan every world from the env's ``state`` (B, N, 4), ``goal`` (B, N, 2) and ``done`` (B, N, 1)."""
        waypoint, cost_to_goal, edge_cost, goal_cost = (t.clone() for t in self._plan(state, goal, done, present))
        return RoadmapPlan(
            waypoint.permute(2, 1, 0), cost_to_goal.permute(2, 1, 0), edge_cost.permute(3, 2, 0, 1),
            goal_cost.permute(2, 1, 0),
        )  # fmt: skip

    def _plan(
        self,
        state: torch.Tensor,
        goal: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Worlds last: waypoint (2, C, B), cost_to_goal (M, C, B), edge_cost (M, K, C, B), goal_cost (M, C, B)."""
        controlled = self._controlled_index
        # Worlds last and contiguous, (N, B): results of broadcasts then come out contiguous too.
        agent_x, agent_y = state[..., 0].t().contiguous(), state[..., 1].t().contiguous()
        present = self.present(state, goal, done, present).t().contiguous()
        avoided = self._avoided(state, agent_x, agent_y, present)
        node_x, node_y = self._node_x, self._node_y
        self_x, self_y = agent_x[controlled], agent_y[controlled]  # (C, B)
        from_self_x, from_self_y = node_x - self_x, node_y - self_y
        from_self = torch.hypot(from_self_x, from_self_y)  # (M, C, B)

        edge_cost = self._edge_cost(from_self, avoided)
        goal_x, goal_y, goal_cost = self._goal_cost(goal, from_self, avoided)
        cost_to_goal = self._solve(edge_cost, goal_cost)
        best_cost, waypoint_node, at_goal_node = self._first_node(
            state, self_x, self_y, from_self_x, from_self_y, from_self, avoided, cost_to_goal, edge_cost, goal_cost
        )
        waypoint = self._waypoint(
            self_x, self_y, goal_x, goal_y, avoided, best_cost, waypoint_node, at_goal_node
        )
        return waypoint, cost_to_goal, edge_cost, goal_cost

    def _edge_cost(self, from_self: torch.Tensor, avoided) -> torch.Tensor:
        """(M, K, C, B): each edge's length times 1 + avoid_weight × its closeness to the agents avoided, where they
        will be when the controlled agent reaches the edge's midpoint."""
        # Judged at the edge's start node plus half a typical edge: per node, not per edge, which is ~K times cheaper.
        edge_reach = (from_self + self._half_edge_m).unsqueeze(1)
        edge_near = self._closeness(
            "edge",
            self._edge_x,
            self._edge_y,
            self._edge_dx,
            self._edge_dy,
            self._edge_inverse_sq,
            *avoided(edge_reach),
        )
        edge_cost = self._buffer("edge_cost", edge_near.shape)  # (M, K, C, B)
        torch.addcmul(self._edge_length, self._edge_weight, edge_near, out=edge_cost)
        return edge_cost

    def _goal_cost(self, goal: torch.Tensor, from_self: torch.Tensor, avoided):
        """The goal attached to the nodes within the connection radius, or at least to the nearest: its position
        (C, B) twice and the cost from each node to it (M, C, B)."""
        controlled, radius = self._controlled_index, self.connection_radius_m
        node_x, node_y = self._node_x, self._node_y
        goal_x = goal[:, controlled, 0].t().contiguous()  # (C, B)
        goal_y = goal[:, controlled, 1].t().contiguous()
        to_goal_x, to_goal_y = goal_x - node_x, goal_y - node_y  # (M, C, B)
        to_goal = torch.hypot(to_goal_x, to_goal_y)
        attached = to_goal <= to_goal.amin(0).clamp(min=radius)
        if len(self._boxes):
            attached &= self._segment_clear(node_x, node_y, goal_x, goal_y)
        inverse_sq = to_goal.square().clamp_(min=1e-12).reciprocal_()
        goal_near = self._closeness(
            "goal", node_x, node_y, to_goal_x, to_goal_y, inverse_sq, *avoided(from_self + 0.5 * to_goal)
        )
        goal_cost = torch.where(attached, to_goal * (1 + self.avoid_weight * goal_near), float("inf"))
        return goal_x, goal_y, goal_cost

    def _first_node(
        self, state, self_x, self_y, from_self_x, from_self_y, from_self, avoided, cost_to_goal, edge_cost, goal_cost
    ):
        """The agent attached like the goal: the cheapest cost through a node (C, B), the node its next waypoint is
        (C, B), and whether that waypoint is the goal itself."""
        radius = self.connection_radius_m
        node_x, node_y = self._node_x, self._node_y
        n_nodes, n_neighbors = self.roadmap.neighbors.shape
        n_controlled, n_worlds = self_x.shape
        lanes = n_controlled * n_worlds
        candidate = from_self <= from_self.amin(0).clamp(min=radius)
        if len(self._boxes):
            candidate &= self._segment_clear(self_x, self_y, node_x, node_y)
        inverse_sq = from_self.square().clamp_(min=1e-12).reciprocal_()
        self_near = self._closeness(
            "self", self_x, self_y, from_self_x, from_self_y, inverse_sq, *avoided(0.5 * from_self)
        )
        via_node = torch.where(
            candidate, from_self * (1 + self.avoid_weight * self_near) + cost_to_goal, float("inf")
        )
        best_cost, best_node = via_node.min(0)  # (C, B)
        # An agent already at its best node steers to the node after it (or the goal), not to where it stands.
        lane = torch.arange(lanes, device=state.device)
        at_node = from_self.view(n_nodes, lanes)[best_node.view(-1), lane] < self.waypoint_tolerance_m
        after_ids = self.roadmap.neighbors[best_node.view(-1)].t()  # (K, C·B)
        after_cost = edge_cost.view(n_nodes, n_neighbors, lanes)[best_node.view(-1), :, lane].t()
        after_cost = after_cost + cost_to_goal.view(n_nodes, lanes).gather(0, after_ids)
        after_best, after_slot = after_cost.min(0)
        after_node = after_ids.gather(0, after_slot.unsqueeze(0)).squeeze(0)
        goal_next = goal_cost.view(n_nodes, lanes)[best_node.view(-1), lane] <= after_best
        waypoint_node = torch.where(at_node, after_node, best_node.view(-1)).view(n_controlled, n_worlds)
        at_goal_node = (at_node & goal_next).view(n_controlled, n_worlds)
        return best_cost, waypoint_node, at_goal_node

    def _waypoint(self, self_x, self_y, goal_x, goal_y, avoided, best_cost, waypoint_node, at_goal_node):
        """(2, C, B): the goal where it is reachable straight at no more cost, else the first node's position."""
        radius = self.connection_radius_m
        straight_x, straight_y = goal_x - self_x, goal_y - self_y
        straight = torch.hypot(straight_x, straight_y)
        direct = straight <= radius
        if len(self._boxes):
            direct &= self._segment_clear(self_x, self_y, goal_x, goal_y)
        inverse_sq = straight.square().clamp_(min=1e-12).reciprocal_()
        straight_near = self._closeness(
            "straight", self_x, self_y, straight_x, straight_y, inverse_sq, *avoided(0.5 * straight)
        )
        direct_cost = torch.where(direct, straight * (1 + self.avoid_weight * straight_near), float("inf"))
        to_goal_now = (direct_cost <= best_cost) | at_goal_node
        nodes = self.roadmap.nodes
        waypoint = torch.stack(
            [
                torch.where(to_goal_now, goal_x, nodes[:, 0][waypoint_node]),
                torch.where(to_goal_now, goal_y, nodes[:, 1][waypoint_node]),
            ]
        )
        return waypoint

    def _solve(self, edge_cost: torch.Tensor, goal_cost: torch.Tensor) -> torch.Tensor:
        """Cost-to-goal of every node (M, C, B): Bellman-Ford from scratch, relaxed block by block.

        A round relaxes the slabs of nodes in order of x and then back, each slab seeing the slabs already
        relaxed in that round (Gauss-Seidel), so a path that runs along the sidewalk settles in one round
        rather than one sweep per edge. Rounds repeat until one changes nothing. Costs only decrease from each
        node's direct edge to the goal and each is the cost of some path, so the fixed point is exact.
        """
        n_nodes, n_neighbors, n_controlled, n_worlds = edge_cost.shape
        lanes = n_controlled * n_worlds
        cost = goal_cost.clone().view(n_nodes, lanes)
        goal_flat, edge_flat = goal_cost.view(n_nodes, lanes), edge_cost.view(n_nodes, n_neighbors, lanes)
        gathered = self._buffer("gathered", torch.Size((n_nodes * n_neighbors, lanes)))
        before = self._buffer("before", cost.shape)
        # The views each block works on, made once per call rather than once per round.
        blocks = [
            (
                neighbors,
                gathered[: len(neighbors)],
                gathered[: len(neighbors)].view(stop - start, n_neighbors, lanes),
                edge_flat[start:stop],
                cost[start:stop],
                goal_flat[start:stop],
            )
            for start, stop, neighbors in (self._slabs if lanes >= GAUSS_SEIDEL_MIN_LANES else self._whole)
        ]
        for rounds in range(1, self._max_rounds + 1):
            before.copy_(cost)
            for neighbors, through, through_3d, edge_block, cost_block, goal_block in (
                *blocks,
                *reversed(blocks),
            ):
                # A node's cost: its cheapest edge plus the cost from that neighbour, or its direct edge to the goal.
                torch.index_select(cost, 0, neighbors, out=through)
                through_3d.add_(edge_block)
                torch.amin(through_3d, dim=1, out=cost_block)
                torch.minimum(cost_block, goal_block, out=cost_block)
            if torch.equal(cost, before):
                self.last_rounds = rounds
                return cost.view(goal_cost.shape)
        raise RuntimeError(f"roadmap costs did not settle in {self._max_rounds} rounds")

    def _avoided(
        self, state: torch.Tensor, agent_x: torch.Tensor, agent_y: torch.Tensor, present: torch.Tensor
    ) -> Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """``at(distance)``: where the agents each controlled agent avoids will be when it has gone ``distance``
        metres (..., C, B) at full speed, at most ``predict_horizon_s`` ahead, at their current velocity, kept in
        the world; as (x, y, presence): (..., C, B) when there is one avoided agent per world, else (..., C, N, B)
        with presence (C, N, B)."""
        (x_low, x_high), (y_low, y_high) = self._x_limits, self._y_limits
        if self._only_other is not None:
            other = self._only_other
            x, y, shown = agent_x[other], agent_y[other], present[other].float()  # (B,)
            speed, heading = state[:, other, 2], state[:, other, 3]
        else:
            x, y, shown = agent_x, agent_y, (present & self._others).float()  # (N, B), (C, N, B)
            speed, heading = state[..., 2].t(), state[..., 3].t()
        velocity_x, velocity_y = speed * torch.cos(heading), speed * torch.sin(heading)
        horizon_m = self.predict_horizon_s * self._params.max_speed_mps

        def at(distance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            if self.predict_horizon_s == 0 or not bool(speed.any()):
                return x, y, shown
            seconds = distance.clamp(max=horizon_m).mul_(1.0 / self._params.max_speed_mps)
            if self._only_other is None:
                seconds = seconds.unsqueeze(-2)  # an axis for the avoided agents, before the worlds
            ahead_x = torch.addcmul(x, seconds, velocity_x).clamp_(x_low, x_high)
            ahead_y = torch.addcmul(y, seconds, velocity_y).clamp_(y_low, y_high)
            return ahead_x, ahead_y, shown

        return at

    def _closeness(
        self,
        name: str,
        start_x: torch.Tensor,
        start_y: torch.Tensor,
        delta_x: torch.Tensor,
        delta_y: torch.Tensor,
        inverse_length_sq: torch.Tensor,
        avoid_x: torch.Tensor,
        avoid_y: torch.Tensor,
        avoid_present: torch.Tensor,
    ) -> torch.Tensor:
        """Closeness of straight segments, start + [0, 1] · delta (shapes broadcasting to (..., C, B)), to the
        agents each controlled agent avoids, at the places ``_avoided`` gives, (..., C, B), in buffers ``name`` reuses on
        the next call.

        A segment's closeness is that of its point nearest the avoided point: 1 at the point falling linearly
        to 0 at ``avoid_radius_m``, plus ``CONTACT_CLOSENESS`` where a disc there would touch an agent at the point
        (closer than two radii plus ``CONTACT_MARGIN_M``); the largest over the avoided points.
        """
        one_point = self._only_other is not None
        if one_point:
            from_x, from_y = avoid_x - start_x, avoid_y - start_y
        else:
            # An axis of avoided agents before the worlds: (..., C, N, B).
            from_x, from_y = avoid_x - start_x.unsqueeze(-2), avoid_y - start_y.unsqueeze(-2)
            delta_x, delta_y = delta_x.unsqueeze(-2), delta_y.unsqueeze(-2)
            inverse_length_sq = inverse_length_sq.unsqueeze(-2)
        # In place on reused buffers: a fresh multi-megabyte tensor per operation costs more in page faults
        # than the arithmetic.
        shape = torch.broadcast_shapes(from_x.shape, delta_x.shape, avoid_present.shape)
        along = self._buffer(f"{name}.along", shape).copy_(from_x).mul_(delta_x)
        along.addcmul_(from_y, delta_y).mul_(inverse_length_sq).clamp_(0.0, 1.0)
        gap = torch.mul(along, delta_x, out=self._buffer(f"{name}.gap", shape))
        torch.sub(from_x, gap, out=gap)
        torch.sub(from_y, along.mul_(delta_y), out=along)
        gap.square_().add_(along.square_()).sqrt_()
        # The contact term rises over the last CONTACT_RAMP_M before contact, in floats: a bool mask would cost
        # a slow conversion of the whole tensor.
        contact = torch.sub(self._contact_distance_m, gap, out=along)
        contact.mul_(1.0 / CONTACT_RAMP_M).clamp_(0.0, 1.0)
        closeness = gap.mul_(-1.0 / self.avoid_radius_m).add_(1.0).clamp_(min=0.0)
        closeness.add_(contact, alpha=CONTACT_CLOSENESS).mul_(avoid_present)
        return closeness if one_point else closeness.amax(-2)

    def _buffer(self, name: str, shape: torch.Size, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """A reused tensor of this name and shape; its contents are whatever the last user left."""
        buffer = self._buffers.get(name)
        if buffer is None or buffer.shape != shape or buffer.dtype != dtype:
            buffer = self._buffers[name] = torch.empty(shape, dtype=dtype, device=self.env.device)
        return buffer

    # ---- control ------------------------------------------------------------------------------------------------

    def _steer(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, waypoint: torch.Tensor
    ) -> torch.Tensor:
        """(acceleration, turn) of the controlled agents, (B, C, 2), steering toward ``waypoint`` (2, C, B)."""
        p = self._params
        own = state[:, self._controlled_index].permute(2, 1, 0)  # (4, C, B)
        x, y, speed, heading = own.unbind(0)
        goal_x, goal_y = goal[:, self._controlled_index].permute(2, 1, 0).unbind(0)
        error = torch.atan2(waypoint[1] - y, waypoint[0] - x) - heading
        error = torch.remainder(error + math.pi, 2 * math.pi) - math.pi
        turn = error.clamp(-p.max_turn_rad, p.max_turn_rad)

        # Never faster than what stops the agent at its goal, or before the wall straight ahead.
        cos, sin = torch.cos(heading), torch.sin(heading)
        (x_low, x_high), (y_low, y_high) = self._x_limits, self._y_limits
        room_x = torch.where(cos > 0, (x_high - x) / cos, (x - x_low) / -cos)
        room_y = torch.where(sin > 0, (y_high - y) / sin, (y - y_low) / -sin)
        room = torch.minimum(room_x, room_y) - WALL_MARGIN_M  # division by 0 gives inf: no wall ahead
        room = torch.minimum(room, torch.hypot(goal_x - x, goal_y - y)).clamp(min=0.0)
        stopping_speed = torch.sqrt(2 * BRAKE_FRACTION * p.max_accel_mps2 * room)
        target_speed = stopping_speed.clamp(max=p.max_speed_mps) * torch.cos(error).clamp(min=0.0)
        accel = ((target_speed - speed) / p.dt_s).clamp(-p.max_accel_mps2, p.max_accel_mps2)
        action = torch.stack([accel, turn], dim=-1).transpose(0, 1)  # (B, C, 2)
        return action.masked_fill(done[:, self._controlled_index], 0.0)

    def inferred_present(self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Bool (B, N): not done, done at its goal, or kept after a crash."""
        if not self._params.remove_crashed:
            return torch.ones(state.shape[:2], dtype=torch.bool, device=state.device)
        at_goal = (state[..., :2] - goal).square().sum(-1) <= self._params.goal_radius_m**2
        return ~done.squeeze(-1) | at_goal
