"""The PRM opponent of the continuous Sidewalk (paper §4.2): a probabilistic roadmap over the free
space, shortest paths on it with costs raised near the other agents, replanned every step, and a unicycle
controller that steers toward the plan's next waypoint.

The roadmap and everything planning reads of its graph (edges as segments, the order in which the solver relaxes
the nodes) are built once per layout and seed and shared by every opponent on it. Each step prices every edge of
every world (worlds on the last axis, in chunks of nodes that stay in cache), then relaxes all worlds'
costs-to-goal together by Bellman-Ford sweeps over groups of nodes, forward and back (Gauss-Seidel), each sweep
over only the edges it can still lower. There is no loop over worlds and no graph building per step.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.envs.unicycle import touches_box
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
# Slabs of consecutive nodes (in order of x), relaxed in turn so that costs run along the sidewalk in one sweep.
SLABS = 32
# Up to PAIRED_MAX_LANES worlds a call costs more than its arithmetic: slabs go two at a time, from both ends
# inward and back out, which carries costs both ways along the sidewalk in half the calls.
PAIRED_SLABS = 24
PAIRED_MAX_LANES = 256
# Edge-world elements priced per chunk: the chunk's temporaries (~2 MB at 2^17) stay in a core's L2 cache.
CHUNK_ELEMENTS = 2**17
ROADMAP_SEED = 0  # the default roadmap, every run's: the opponent does not change with the learner's seed
FAR_M = 1e6  # absent agents are avoided here: far enough that no segment comes near, finite so no inf - inf


class Roadmap(NamedTuple):
    """A roadmap: ``nodes`` (M, 2) positions (x, y); ``neighbors`` (M, K) node indices and ``edge_length``
    (M, K) metres of each node's edges, nearest first, padded with index 0 and length inf where a node has fewer
    than K."""

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


class Scene(NamedTuple):
    """One planning call's controlled agents and what they avoid, worlds last: ``self_x``, ``self_y``,
    ``goal_x``, ``goal_y`` (C, B); ``from_self_x``, ``from_self_y``, ``from_self`` (M, C, B) from each agent to
    each node; ``avoided`` as ``PRMOpponent._avoided`` returns it."""

    self_x: torch.Tensor
    self_y: torch.Tensor
    goal_x: torch.Tensor
    goal_y: torch.Tensor
    from_self_x: torch.Tensor
    from_self_y: torch.Tensor
    from_self: torch.Tensor
    avoided: Callable[[torch.Tensor, str], tuple[torch.Tensor, torch.Tensor]]


class SweepGroup(NamedTuple):
    """Solver rows ``start:stop``, relaxed together, and their edges: ``width`` columns per row from entry
    ``offset`` of the solver's edge table on. ``full``, ``forward``, ``backward``: (first column, end column,
    neighbour rows of those columns, flattened) of the edges the first sweep, a forward and a backward sweep
    relax them over."""

    start: int
    stop: int
    offset: int
    width: int
    full: tuple[int, int, torch.Tensor]
    forward: tuple[int, int, torch.Tensor]
    backward: tuple[int, int, torch.Tensor]


class SweepOrder(NamedTuple):
    """How the solver stores and relaxes the roadmap's nodes.

    The solver's rows hold the nodes group by group; ``rank`` (M,) is each roadmap node's row (``None``: roadmap
    order). Its edge table lays each group's rows out as [edges to earlier groups | the node itself (cost 0) |
    edges within the group | edges to later groups], padded with inf: a forward sweep relaxes a group over the
    first three parts, a backward sweep over the last three, the first sweep over all. ``source`` is the row of
    the priced table (``PRMOpponent._edge_rows``) each entry copies and ``goal_rows`` (M,) the row of each solver
    row's goal edge.
    """

    rank: torch.Tensor | None
    goal_rows: torch.Tensor
    source: torch.Tensor
    groups: tuple[SweepGroup, ...]

    def to(self, device: torch.device | str) -> SweepOrder:
        def moved(columns: tuple[int, int, torch.Tensor]) -> tuple[int, int, torch.Tensor]:
            return columns[0], columns[1], columns[2].to(device)

        groups = tuple(
            group._replace(full=moved(group.full), forward=moved(group.forward), backward=moved(group.backward))
            for group in self.groups
        )
        rank = None if self.rank is None else self.rank.to(device)
        return SweepOrder(rank, self.goal_rows.to(device), self.source.to(device), groups)


class RoadmapGraph(NamedTuple):
    """What planning reads of a roadmap, built with it.

    ``sweeps``: the solver's order for up to ``PAIRED_MAX_LANES`` worlds (slabs relaxed in pairs) and for more
    (one slab at a time). Edges as segments from each node, broadcasting over (M, K, C, B): ``edge_x``,
    ``edge_y`` their start, ``edge_dx``, ``edge_dy`` their extent, ``edge_inverse_sq`` 1 / length² (0 for
    padding), ``edge_length`` (inf for padding). ``node_x``, ``node_y`` (M, 1, 1) broadcast over (M, C, B).
    """

    roadmap: Roadmap
    sweeps: tuple[SweepOrder, SweepOrder]
    node_x: torch.Tensor
    node_y: torch.Tensor
    edge_x: torch.Tensor
    edge_y: torch.Tensor
    edge_dx: torch.Tensor
    edge_dy: torch.Tensor
    edge_inverse_sq: torch.Tensor
    edge_length: torch.Tensor
    half_edge_m: float

    def to(self, device: torch.device | str) -> RoadmapGraph:
        roadmap = Roadmap(*(t.to(device) for t in self.roadmap))
        sweeps = tuple(order.to(device) for order in self.sweeps)
        tensors = (t.to(device) for t in self[2:-1])
        return RoadmapGraph(roadmap, sweeps, *tensors, self.half_edge_m)


class PRMOpponent(Opponent):
    """Follows a probabilistic-roadmap plan to its goal with a unicycle controller (continuous domain only).

    Roadmap, built once per layout: ``n_nodes`` points drawn uniformly where an agent's disc keeps
    ``wall_clearance_m`` from every wall and box, a point being dropped if it lands within
    ``NODE_SPACING_FRACTION`` of the mean spacing of one already kept; each joined to its ``max_neighbors``
    nearest within ``connection_radius_m`` (made symmetric; edges that would touch a box are dropped); only the
    largest connected piece is kept. The points come from a generator seeded with ``roadmap_seed`` (0 by default:
    one roadmap for every run, so the opponent is the same whatever the learner's seed, and one call plans every
    replica of a group), or, if ``None``, with the seed ``env.generator`` holds at construction (so the env's seed
    fixes the roadmap, and no draw from it is spent). Opponents on the same layout, agent radius, roadmap parameters
    and seed share it.

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
    the node after it once the agent is within ``waypoint_tolerance_m`` of it, or the goal. Ties go to the node
    first in ``Roadmap`` order (nodes, then each node's neighbours), and to the goal over a node.

    Control: turn toward the waypoint as far as ``max_turn_rad`` allows; aim for full speed, scaled by the
    cosine of the heading error (zero when the waypoint is behind) and capped so that half the maximum
    deceleration would stop the agent at its goal and before the wall straight ahead. Done agents get (0, 0).

    Every call plans from scratch and keeps no per-world memory, so ``reset(rows)`` has nothing to do.
    ``roadmap`` holds the roadmap, ``last_rounds`` the number of relaxation sweeps of the last call.
    """

    scratch = ("_buffers",)  # reused work tensors (``_buffer``), rewritten before read: most of a checkpoint, no state

    name = "prm"
    domains = ("continuous",)
    batch_invariant = True  # each world's plan is its own; steering splits by replica (tests/test_env_replicas.py)

    @classmethod
    def replicated(cls, **kwargs: Any) -> bool:
        # With roadmap_seed=None the roadmap comes from the env's seed: each replica needs its own.
        return kwargs.get("roadmap_seed", ROADMAP_SEED) is None

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
        roadmap_seed: int | None = ROADMAP_SEED,
    ) -> None:
        super().__init__(env, controlled, ego)
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
        self._boxes = _box_tensor(layout.boxes)
        self._graph = roadmap_graph(
            layout.length_m, layout.width_m, tuple(map(tuple, layout.boxes)), params.agent_radius_m,
            n_nodes, self.connection_radius_m, max_neighbors, float(wall_clearance_m), roadmap_seed,
        ).to(env.device)  # fmt: skip
        self.roadmap = self._graph.roadmap
        self._set_geometry()
        self.last_rounds = 0
        self._buffers: dict[str, torch.Tensor] = {}
        self._views_cache: tuple[tuple[int, ...] | None, tuple[list, ...]] = (None, ())

    def _set_geometry(self) -> None:
        """What planning reads of the env besides the roadmap: limits, distances, who avoids whom."""
        params, layout, device = self._params, self.env.layout, self.env.device
        self._contact_distance_m = 2 * params.agent_radius_m + CONTACT_MARGIN_M
        # The agent's centre stays within these bounds, or its disc touches a wall.
        self._x_limits = (params.agent_radius_m, layout.length_m - params.agent_radius_m)
        self._y_limits = (params.agent_radius_m, layout.width_m - params.agent_radius_m)
        # Padding edges have length inf and weight 0 (not inf · 0 = nan), which keeps their cost at inf.
        edge_length = self._graph.edge_length
        self._edge_weight = torch.where(edge_length.isfinite(), edge_length * self.avoid_weight, 0.0)
        n_agents, n_controlled = self.env.n_agents, len(self.controlled)
        self._others = torch.ones(n_controlled, n_agents, 1, dtype=torch.bool, device=device)
        self._others[torch.arange(n_controlled), self._controlled_index] = False
        # One controlled agent among two avoids just the other one: a slice instead of a reduction.
        self._only_other = 1 - self.controlled[0] if n_agents == 2 and n_controlled == 1 else None

    # ---- planning -----------------------------------------------------------------------------------------------

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        # Planning never meets autograd: inference mode skips its bookkeeping.
        with torch.inference_mode():
            action = self._steer_replicas(state, goal, done, self._plan(state, goal, done, present)[0])
        return action.clone()  # made outside inference mode: a tensor callers may write into

    def plan(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> RoadmapPlan:
        """Plan every world from the env's ``state`` (B, N, 4), ``goal`` (B, N, 2) and ``done`` (B, N, 1)."""
        with torch.inference_mode():
            waypoint, cost_to_goal, table = self._plan(state, goal, done, present)
        return RoadmapPlan(
            waypoint.permute(2, 1, 0).clone(), cost_to_goal.permute(2, 1, 0).clone(),
            table[:, 1:].permute(3, 2, 0, 1).clone(), table[:, 0].permute(2, 1, 0).clone(),
        )  # fmt: skip

    def _plan(
        self,
        state: torch.Tensor,
        goal: torch.Tensor,
        done: torch.Tensor,
        present: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Worlds last: waypoint (2, C, B), cost_to_goal (M, C, B), and the costs of every node's edges
        (M, 1 + K, C, B): to the goal in column 0 (inf: not attached), then along ``Roadmap.neighbors``."""
        scene = self._scene(state, goal, done, present)
        n_nodes, n_neighbors = self.roadmap.neighbors.shape
        edge_rows = self._edge_rows(scene.self_x.numel())
        table = edge_rows[: n_nodes * (1 + n_neighbors)].view(n_nodes, 1 + n_neighbors, *scene.self_x.shape)
        self._price_edges(scene, table[:, 1:])
        self._price_goal_edges(scene, table[:, 0])
        cost_to_goal = self._solve(edge_rows).view(n_nodes, *scene.self_x.shape)
        return self._waypoint(scene, table, cost_to_goal), cost_to_goal, table

    def _edge_rows(self, lanes: int) -> torch.Tensor:
        """The priced edge table as rows of ``lanes``: M · (1 + K) of them, then a row of zeros and one of inf
        for the solver's own entries and padding."""
        n_rows = self.roadmap.neighbors.numel() + len(self.roadmap.nodes)
        rows = self._buffers.get("edge_rows")
        if rows is None or rows.shape != (n_rows + 2, lanes):
            rows = self._buffers["edge_rows"] = torch.empty(n_rows + 2, lanes, device=self.env.device)
            rows[n_rows] = 0.0
            rows[n_rows + 1] = float("inf")
        return rows

    def _scene(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None
    ) -> Scene:
        """The controlled agents, their goals and the agents they avoid, worlds last."""
        controlled, graph = self._controlled_index, self._graph
        # Worlds last and contiguous, (N, B): results of broadcasts then come out contiguous too.
        agent_x, agent_y = state[..., 0].t().contiguous(), state[..., 1].t().contiguous()
        present = self.present(state, goal, done, present).t().contiguous()
        self_x, self_y = agent_x[controlled], agent_y[controlled]  # (C, B)
        shape = (len(graph.node_x), *self_x.shape)
        from_self_x = torch.sub(graph.node_x, self_x, out=self._buffer("from_self_x", shape))
        from_self_y = torch.sub(graph.node_y, self_y, out=self._buffer("from_self_y", shape))
        return Scene(
            self_x=self_x,
            self_y=self_y,
            goal_x=goal[:, controlled, 0].t().contiguous(),
            goal_y=goal[:, controlled, 1].t().contiguous(),
            from_self_x=from_self_x,
            from_self_y=from_self_y,
            from_self=torch.hypot(from_self_x, from_self_y, out=self._buffer("from_self", shape)),  # (M, C, B)
            avoided=self._avoided(state, agent_x, agent_y, present),
        )

    def _price_edges(self, scene: Scene, edge_cost: torch.Tensor) -> None:
        """Write each roadmap edge's cost (M, K, C, B): its length times 1 + avoid_weight × its closeness to the
        agents avoided, where they will be when the controlled agent reaches the edge's midpoint."""
        graph = self._graph
        # Judged at the edge's start node plus half a typical edge: per node, not per edge, ~K times cheaper.
        reach = self._buffer("edge.reach", scene.from_self.shape)
        torch.add(scene.from_self, graph.half_edge_m, out=reach)
        avoid_x, avoid_y = scene.avoided(reach.unsqueeze(1), "edge")
        n_nodes, n_neighbors = self.roadmap.neighbors.shape
        nodes_per_chunk = max(1, CHUNK_ELEMENTS // (n_neighbors * avoid_x[0].numel()))
        for start in range(0, n_nodes, nodes_per_chunk):
            part = slice(start, start + nodes_per_chunk)
            near = self._closeness(
                "edge", graph.edge_x[part], graph.edge_y[part], graph.edge_dx[part], graph.edge_dy[part],
                graph.edge_inverse_sq[part], avoid_x[part], avoid_y[part],
            )  # fmt: skip
            # Length, then plus weight × closeness in place: with one operand broadcast over the worlds rather
            # than two, the fused multiply-add runs vectorised.
            edge_cost[part].copy_(graph.edge_length[part]).addcmul_(self._edge_weight[part], near)

    def _price_goal_edges(self, scene: Scene, goal_cost: torch.Tensor) -> None:
        """Write each node's cost (M, C, B) of a straight walk to the goal: attached to the nodes within the
        connection radius, or at least to the nearest; inf elsewhere."""
        node_x, node_y, from_self = self._graph.node_x, self._graph.node_y, scene.from_self
        to_goal_x = torch.sub(scene.goal_x, node_x, out=self._buffer("goal.dx", from_self.shape))  # (M, C, B)
        to_goal_y = torch.sub(scene.goal_y, node_y, out=self._buffer("goal.dy", from_self.shape))
        to_goal = torch.hypot(to_goal_x, to_goal_y, out=self._buffer("goal.length", from_self.shape))
        attached = self._within(to_goal, "goal.attached")
        if len(self._boxes):
            attached.mul_(self._segment_clear(node_x, node_y, scene.goal_x, scene.goal_y))
        # Only the nodes some world attaches its goal to are priced: a handful when the worlds share their goal.
        rows = attached.view(len(attached), -1).amax(1).nonzero().squeeze(1)
        if len(rows) <= len(attached) // 2:
            goal_cost.fill_(float("inf"))
            picked = (node_x, node_y, to_goal_x, to_goal_y, to_goal, attached, from_self)
            node_x, node_y, to_goal_x, to_goal_y, to_goal, attached, from_self = (t[rows] for t in picked)
        inverse_sq = torch.square(to_goal, out=self._buffer("goal.inverse_sq", to_goal.shape))
        inverse_sq.clamp_(min=1e-12).reciprocal_()
        # The goal edge's midpoint: ×0.5 is exact, so this add rounds as from_self + 0.5 * to_goal does.
        reach = torch.add(from_self, to_goal, alpha=0.5, out=self._buffer("goal.reach", to_goal.shape))
        avoid_x, avoid_y = scene.avoided(reach, "goal")
        near = self._closeness("goal", node_x, node_y, to_goal_x, to_goal_y, inverse_sq, avoid_x, avoid_y)
        # Divided by the 0/1 attachment: inf where not attached (the cost is positive there).
        cost = near.mul_(self.avoid_weight).add_(1.0).mul_(to_goal).div_(attached)
        if len(attached) < len(goal_cost):
            goal_cost.index_copy_(0, rows, cost)
        else:
            goal_cost.copy_(cost)

    def _waypoint(self, scene: Scene, table: torch.Tensor, cost_to_goal: torch.Tensor) -> torch.Tensor:
        """The point (2, C, B) each controlled agent steers to: the goal when walking straight there is no dearer
        than the cheapest path through a node, or the goal is next after a node it stands on; else that node."""
        best_cost, waypoint_node, goal_after_node = self._next_node(scene, table, cost_to_goal)
        straight_x, straight_y = scene.goal_x - scene.self_x, scene.goal_y - scene.self_y
        straight = torch.hypot(straight_x, straight_y)
        direct = straight <= self.connection_radius_m
        if len(self._boxes):
            direct &= self._segment_clear(scene.self_x, scene.self_y, scene.goal_x, scene.goal_y)
        inverse_sq = straight.square().clamp_(min=1e-12).reciprocal_()
        straight_near = self._closeness(
            "straight", scene.self_x, scene.self_y, straight_x, straight_y, inverse_sq,
            *scene.avoided(0.5 * straight, "straight"),
        )  # fmt: skip
        direct_cost = torch.where(direct, straight * (1 + self.avoid_weight * straight_near), float("inf"))
        to_goal_now = (direct_cost <= best_cost) | goal_after_node
        nodes = self.roadmap.nodes
        return torch.stack(
            [
                torch.where(to_goal_now, scene.goal_x, nodes[:, 0][waypoint_node]),
                torch.where(to_goal_now, scene.goal_y, nodes[:, 1][waypoint_node]),
            ]
        )

    def _next_node(
        self, scene: Scene, table: torch.Tensor, cost_to_goal: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Attach each agent to the nodes near it: (cost of its cheapest path through a node, the node it steers
        to, whether the goal comes right after a node it stands on), each (C, B)."""
        n_nodes, n_neighbors = self.roadmap.neighbors.shape
        n_controlled, n_worlds = scene.self_x.shape
        lanes = n_controlled * n_worlds
        from_self = scene.from_self
        candidate = self._within(from_self, "self.candidate")
        if len(self._boxes):
            graph = self._graph
            candidate.mul_(self._segment_clear(scene.self_x, scene.self_y, graph.node_x, graph.node_y))
        inverse_sq = torch.square(from_self, out=self._buffer("self.inverse_sq", from_self.shape))
        inverse_sq.clamp_(min=1e-12).reciprocal_()
        reach = torch.mul(from_self, 0.5, out=self._buffer("self.reach", from_self.shape))
        near = self._closeness(
            "self", scene.self_x, scene.self_y, scene.from_self_x, scene.from_self_y, inverse_sq,
            *scene.avoided(reach, "self"),
        )  # fmt: skip
        # Divided by the 0/1 candidate mask: inf off the candidates (the cost is positive there).
        via_node = near.mul_(self.avoid_weight).add_(1.0).mul_(from_self).add_(cost_to_goal).div_(candidate)
        best_cost, best_node = _first_min(via_node)  # (C, B)
        # An agent already at its best node steers to the node after it (or the goal), not to where it stands.
        best, lane = best_node.view(-1), torch.arange(lanes, device=best_node.device)
        at_node = from_self.view(n_nodes, lanes)[best, lane] < self.waypoint_tolerance_m
        edges = table.view(n_nodes, 1 + n_neighbors, lanes)
        after_ids = self.roadmap.neighbors[best].t()  # (K, C·B)
        after_cost = edges[best, 1:, lane].t() + cost_to_goal.view(n_nodes, lanes).gather(0, after_ids)
        after_best, after_slot = _first_min(after_cost)
        after_node = after_ids.gather(0, after_slot.unsqueeze(0)).squeeze(0)
        goal_next = edges[best, 0, lane] <= after_best
        waypoint_node = torch.where(at_node, after_node, best).view(n_controlled, n_worlds)
        return best_cost, waypoint_node, (at_node & goal_next).view(n_controlled, n_worlds)

    # ---- shortest paths -----------------------------------------------------------------------------------------

    def _solve(self, edge_rows: torch.Tensor) -> torch.Tensor:
        """Cost-to-goal (M, L) of every node from the priced edge table as rows (``_edge_rows``): Bellman-Ford
        from scratch.

        Each sweep relaxes the groups of ``RoadmapGraph.sweeps`` in turn, forward and back on alternate sweeps,
        each group seeing the groups already relaxed (Gauss-Seidel), over its edges to those groups and within
        itself, and its own cost: the edges to groups after it were relaxed by the sweep before, from the costs
        they still hold (the first sweep relaxes all edges). The costs are settled when a sweep changes none.
        Costs only decrease from each node's direct edge to the goal and each is the cost of some path, so the
        fixed point is exact, and the same whatever the order of relaxation.
        """
        n_nodes, lanes = len(self.roadmap.nodes), edge_rows.shape[1]
        order = self._graph.sweeps[lanes > PAIRED_MAX_LANES]
        edges = self._buffer("sweep.edges", (len(order.source), lanes))
        torch.index_select(edge_rows, 0, order.source, out=edges)
        settled = self._buffer("sweep.cost", (n_nodes + 1, lanes))
        torch.index_select(edge_rows, 0, order.goal_rows, out=settled[:n_nodes])
        settled[n_nodes] = 0.0  # the goal
        first, forward, backward = self._group_views(order, settled, edges)
        before = self._buffer("sweep.before", settled.shape)
        # Two sweeps lower every cost at least as far as a whole-roadmap (Jacobi) round; M + 1 of those suffice.
        for sweep in range(1, 2 * n_nodes + 5):
            if sweep > 1:
                before.copy_(settled)
            groups = first if sweep == 1 else forward if sweep % 2 else backward
            for index, gathered, through, edge, cost in groups:
                # A node's cost: its cheapest edge plus the cost from that neighbour (its own: edge 0).
                torch.index_select(settled, 0, index, out=gathered)
                through.add_(edge)
                torch.amin(through, 1, out=cost)
            if sweep > 1 and torch.equal(settled, before):
                break
        else:
            raise RuntimeError(f"roadmap costs did not settle in {sweep} sweeps")
        self.last_rounds = sweep
        if order.rank is None:
            return settled[:n_nodes]
        return torch.index_select(settled, 0, order.rank, out=self._buffer("cost_to_goal", (n_nodes, lanes)))

    def _group_views(
        self, order: SweepOrder, cost: torch.Tensor, edges: torch.Tensor
    ) -> tuple[list[tuple[torch.Tensor, ...]], ...]:
        """Per group, in the order the first, a forward and a backward sweep relax them, what it is relaxed
        with: (neighbour rows, gathered costs as rows and as (nodes, columns, lanes), edge costs, the group's
        costs). Kept for the next call on the same buffers: slicing once per call costs more than relaxing a
        group of a hundred worlds."""
        lanes = cost.shape[1]
        key = (len(order.source), cost.data_ptr(), edges.data_ptr(), lanes)  # the cached views keep these alive
        if self._views_cache[0] == key:
            return self._views_cache[1]
        scratch = self._buffer("sweep.gathered", (len(order.source) * lanes,))
        views: tuple[list[tuple[torch.Tensor, ...]], ...] = ([], [], [])
        for sweep, groups, part in zip(views, (order.groups, order.groups, order.groups[::-1]), range(3)):
            for group in groups:
                first, end, index = (group.full, group.forward, group.backward)[part]
                n_rows = group.stop - group.start
                block = edges[group.offset : group.offset + n_rows * group.width]
                block = block.view(n_rows, group.width, lanes)
                through = scratch[: len(index) * lanes].view(n_rows, end - first, lanes)
                rows = cost[group.start : group.stop]
                sweep.append((index, through.view(-1, lanes), through, block[:, first:end], rows))
        self._views_cache = (key, views)
        return views

    # ---- closeness to the avoided agents ------------------------------------------------------------------------

    def _avoided(
        self, state: torch.Tensor, agent_x: torch.Tensor, agent_y: torch.Tensor, present: torch.Tensor
    ) -> Callable[[torch.Tensor, str], tuple[torch.Tensor, torch.Tensor]]:
        """``at(distance, name)``: where the agents each controlled agent avoids will be when it has gone
        ``distance`` metres (..., C, B) at full speed, at most ``predict_horizon_s`` ahead, at their current
        velocity, kept in the world; as (x, y): (..., C, B) when there is one avoided agent per world, else
        (..., C, N, B), in buffers ``name`` reuses. Agents absent, and each controlled agent itself, are put
        ``FAR_M`` away."""
        (x_low, x_high), (y_low, y_high) = self._x_limits, self._y_limits
        if self._only_other is not None:
            other = self._only_other
            x, y, shown = agent_x[other], agent_y[other], present[other]  # (B,)
            speed, heading = state[:, other, 2], state[:, other, 3]
        else:
            x, y, shown = agent_x, agent_y, present & self._others  # (N, B), (C, N, B)
            speed, heading = state[..., 2].t(), state[..., 3].t()
        velocity_x, velocity_y = speed * torch.cos(heading), speed * torch.sin(heading)
        horizon_m = self.predict_horizon_s * self._params.max_speed_mps
        predicts = self.predict_horizon_s > 0 and bool(speed.any())
        far_m = (~shown).float() * FAR_M  # an offset rather than torch.where, which is many times slower

        def at(distance: torch.Tensor, name: str) -> tuple[torch.Tensor, torch.Tensor]:
            # An axis for the avoided agents, before the worlds, when there are several.
            along_agents = distance if self._only_other is not None else distance.unsqueeze(-2)
            shape = _broadcast_shape(along_agents.shape, x.shape, far_m.shape)  # (..., C, B) or (..., C, N, B)
            ahead_x, ahead_y = self._buffer(f"{name}.avoid_x", shape), self._buffer(f"{name}.avoid_y", shape)
            if not predicts:
                return ahead_x.copy_(x).add_(far_m), ahead_y.copy_(y).add_(far_m)
            seconds = self._buffer(f"{name}.seconds", along_agents.shape)
            torch.clamp(along_agents, max=horizon_m, out=seconds).mul_(1.0 / self._params.max_speed_mps)
            torch.addcmul(x, seconds, velocity_x, out=ahead_x).clamp_(x_low, x_high).add_(far_m)
            torch.addcmul(y, seconds, velocity_y, out=ahead_y).clamp_(y_low, y_high).add_(far_m)
            return ahead_x, ahead_y

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
    ) -> torch.Tensor:
        """Closeness of straight segments, start + [0, 1] · delta (shapes broadcasting to (..., C, B)), to the
        agents each controlled agent avoids, at the places ``_avoided`` gives, (..., C, B), in buffers ``name``
        reuses on the next call.

        A segment's closeness is that of its point nearest the avoided point: 1 at the point falling linearly
        to 0 at ``avoid_radius_m``, plus ``CONTACT_CLOSENESS`` where a disc there would touch an agent at the point
        (closer than two radii plus ``CONTACT_MARGIN_M``); the largest over the avoided points.
        """
        one_point = self._only_other is not None
        if not one_point:
            # An axis of avoided agents before the worlds: (..., C, N, B).
            start_x, start_y = start_x.unsqueeze(-2), start_y.unsqueeze(-2)
            delta_x, delta_y = delta_x.unsqueeze(-2), delta_y.unsqueeze(-2)
            inverse_length_sq = inverse_length_sq.unsqueeze(-2)
        start_shape = _broadcast_shape(avoid_x.shape, start_x.shape)
        from_x = torch.sub(avoid_x, start_x, out=self._buffer(f"{name}.from_x", start_shape))
        from_y = torch.sub(avoid_y, start_y, out=self._buffer(f"{name}.from_y", start_shape))
        shape = _broadcast_shape(start_shape, delta_x.shape)
        along = torch.mul(from_x, delta_x, out=self._buffer(f"{name}.along", shape))
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
        closeness.add_(contact, alpha=CONTACT_CLOSENESS)
        return closeness if one_point else closeness.amax(-2)

    def _within(self, distance: torch.Tensor, name: str) -> torch.Tensor:
        """1.0 where ``distance`` (M, C, B) to a node is within the connection radius or the least of all nodes,
        else 0.0: a float mask, since bool masks and ``torch.where`` run several times slower at this size."""
        reach = distance.amin(0).clamp(min=self.connection_radius_m)
        return torch.le(distance, reach, out=self._buffer(name, distance.shape))

    def _segment_clear(
        self, ax: torch.Tensor, ay: torch.Tensor, bx: torch.Tensor, by: torch.Tensor
    ) -> torch.Tensor:
        radius_m = self._params.agent_radius_m
        return _segment_clear(self._boxes, radius_m, self.connection_radius_m, ax, ay, bx, by)

    def _buffer(self, name: str, shape: Sequence[int]) -> torch.Tensor:
        """A reused float tensor of this shape under this name, its contents whatever the last user left; shapes
        that take turns under one name (chunks) share its largest allocation. A fresh tensor costs more than the
        arithmetic on it: its memory comes in cold from outside the cache."""
        numel = math.prod(shape)
        flat = self._buffers.get(name)
        if flat is None or len(flat) < numel:
            flat = self._buffers[name] = torch.empty(numel, device=self.env.device)
        return flat[:numel].view(shape)

    # ---- control ------------------------------------------------------------------------------------------------

    def _steer_replicas(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, waypoint: torch.Tensor
    ) -> torch.Tensor:
        """``_steer`` of every world, on a replicated env (several seeds, one core) in one call per replica:
        torch.atan2 rounds an angle by where it sits in the call (vectorised body or scalar tail), so each replica's
        worlds are steered in a call of its lone env's shape. Plans are each world's own, whatever the batch."""
        replicas = getattr(self.env, "replicas", 1)
        if replicas == 1 or len(state) != self.env.num_envs:
            return self._steer(state, goal, done, waypoint)
        return torch.cat([
            self._steer(state[block], goal[block], done[block], waypoint[..., block].contiguous())
            for block in self.env.replica_blocks()
        ])

    def _steer(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, waypoint: torch.Tensor
    ) -> torch.Tensor:
        """(acceleration, turn) of the controlled agents, (B, C, 2), steering toward ``waypoint`` (2, C, B)."""
        own = state[:, self._controlled_index].permute(2, 1, 0)  # (4, C, B)
        own_goal = goal[:, self._controlled_index].permute(2, 1, 0)
        accel, turn = steer_toward(own, own_goal, waypoint, self._params, self._x_limits, self._y_limits)
        action = torch.stack([accel, turn], dim=-1).transpose(0, 1)  # (B, C, 2)
        return action.masked_fill(done[:, self._controlled_index], 0.0)

    def inferred_present(self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Bool (B, N): not done, done at its goal, or kept after a crash."""
        if not self._params.remove_crashed:
            return torch.ones(state.shape[:2], dtype=torch.bool, device=state.device)
        at_goal = (state[..., :2] - goal).square().sum(-1) <= self._params.goal_radius_m**2
        return ~done.squeeze(-1) | at_goal


def steer_toward(
    own: torch.Tensor,
    goal: torch.Tensor,
    waypoint: torch.Tensor,
    params: Any,
    x_limits: tuple[float, float],
    y_limits: tuple[float, float],
    speed_scale: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The PRM's unicycle controller: (acceleration, turn), each (C, B), of agents ``own`` (4, C, B) = (x, y, speed,
    heading) steering toward ``waypoint`` (2, C, B), their goals ``goal`` (2, C, B).

    Turn toward the waypoint as far as ``params.max_turn_rad`` allows; aim for full speed, scaled by the cosine of
    the heading error (zero when the waypoint is behind) and by ``speed_scale`` (C, B) when given (0: brake to a
    stop), capped so that half the maximum deceleration stops the agent at its goal and before the wall straight
    ahead (the centre's ``x_limits``, ``y_limits``)."""
    p = params
    x, y, speed, heading = own.unbind(0)
    goal_x, goal_y = goal.unbind(0)
    error = torch.atan2(waypoint[1] - y, waypoint[0] - x) - heading
    error = torch.remainder(error + math.pi, 2 * math.pi) - math.pi
    turn = error.clamp(-p.max_turn_rad, p.max_turn_rad)

    # Never faster than what stops the agent at its goal, or before the wall straight ahead.
    cos, sin = torch.cos(heading), torch.sin(heading)
    (x_low, x_high), (y_low, y_high) = x_limits, y_limits
    room_x = torch.where(cos > 0, (x_high - x) / cos, (x - x_low) / -cos)
    room_y = torch.where(sin > 0, (y_high - y) / sin, (y - y_low) / -sin)
    room = torch.minimum(room_x, room_y) - WALL_MARGIN_M  # division by 0 gives inf: no wall ahead
    room = torch.minimum(room, torch.hypot(goal_x - x, goal_y - y)).clamp(min=0.0)
    stopping_speed = torch.sqrt(2 * BRAKE_FRACTION * p.max_accel_mps2 * room)
    target_speed = stopping_speed.clamp(max=p.max_speed_mps) * torch.cos(error).clamp(min=0.0)
    if speed_scale is not None:
        target_speed = target_speed * speed_scale
    accel = ((target_speed - speed) / p.dt_s).clamp(-p.max_accel_mps2, p.max_accel_mps2)
    return accel, turn


# ---- roadmap, built once per layout -------------------------------------------------------------------------------


@functools.lru_cache(maxsize=32)
def roadmap_graph(
    length_m: float,
    width_m: float,
    boxes: tuple[tuple[float, float, float, float], ...],
    agent_radius_m: float,
    n_nodes: int,
    connection_radius_m: float,
    max_neighbors: int,
    wall_clearance_m: float,
    seed: int,
) -> RoadmapGraph:
    """The roadmap of a ``length_m`` × ``width_m`` world with interior ``boxes`` (see ``PRMOpponent``) and what
    planning reads of it, on the CPU; built once per set of arguments and shared, so never to be written to."""
    box_tensor = _box_tensor(boxes)
    generator = torch.Generator().manual_seed(seed)
    wall_distance_m = agent_radius_m + wall_clearance_m
    nodes = _sample_nodes(length_m, width_m, box_tensor, wall_distance_m, n_nodes, generator)
    gap = torch.cdist(nodes, nodes)
    near = (gap <= connection_radius_m) & ~torch.eye(n_nodes, dtype=torch.bool)
    if len(box_tensor):
        near &= _segment_clear(
            box_tensor, agent_radius_m, connection_radius_m,
            nodes[:, None, 0], nodes[:, None, 1], nodes[None, :, 0], nodes[None, :, 1],
        )  # fmt: skip
    # Keep each node's nearest few, then make the graph symmetric so that every edge can be walked both ways.
    order = torch.where(near, gap, float("inf")).topk(max_neighbors, dim=1, largest=False).indices
    keep = torch.zeros_like(near).scatter_(1, order, True) & near
    roadmap = _largest_piece(nodes, keep | keep.t(), gap, connection_radius_m)
    return _graph(roadmap)


def _sample_nodes(
    length_m: float,
    width_m: float,
    boxes: torch.Tensor,
    wall_distance_m: float,
    n_nodes: int,
    generator: torch.Generator,
) -> torch.Tensor:
    """``n_nodes`` points (n_nodes, 2) ``wall_distance_m`` clear of walls and boxes, by dart throwing: uniform
    candidates, each kept if no kept point lies within the minimum spacing."""
    low = torch.tensor([wall_distance_m, wall_distance_m])
    span = torch.tensor([length_m, width_m]) - 2 * low
    if (span <= 0).any():
        raise ValueError(f"no free space: walls {wall_distance_m} m away leave a span of {span.tolist()} m")
    probe = low + span * torch.rand(4 * n_nodes, 2, generator=generator)
    free_share = (~touches_box(boxes, probe[:, 0], probe[:, 1], wall_distance_m)).float().mean()
    spacing = NODE_SPACING_FRACTION * math.sqrt(float(span.prod() * free_share) / n_nodes)
    nodes = torch.empty(n_nodes, 2)
    count = 0
    for _ in range(SAMPLING_ROUNDS):
        candidates = low + span * torch.rand(4 * n_nodes, 2, generator=generator)
        candidates = candidates[~touches_box(boxes, candidates[:, 0], candidates[:, 1], wall_distance_m)]
        for point in candidates:
            if count == 0 or torch.cdist(point[None], nodes[:count]).min() >= spacing:
                nodes[count] = point
                count += 1
                if count == n_nodes:
                    return nodes
    raise ValueError(
        f"only {count} of n_nodes={n_nodes} nodes fit {spacing:.3f} m apart in the free space; lower n_nodes"
    )


def _largest_piece(
    nodes: torch.Tensor, adjacency: torch.Tensor, gap: torch.Tensor, connection_radius_m: float
) -> Roadmap:
    """The roadmap of the largest connected piece of ``adjacency`` (M, M), its nodes in order of x."""
    n_nodes = len(nodes)
    # Propagate the smallest node index through the edges until it settles.
    label = torch.arange(n_nodes)
    while True:
        reached = torch.where(adjacency, label[None, :], n_nodes).amin(1)
        updated = torch.minimum(label, reached)
        if torch.equal(updated, label):
            break
        label = updated
    largest = label == label.bincount().argmax()
    # Nodes go in order of x, so that slabs of consecutive nodes lie across the sidewalk.
    kept = largest.nonzero().squeeze(-1)
    kept = kept[nodes[kept, 0].argsort()]
    nodes, adjacency, gap = nodes[kept], adjacency[kept][:, kept], gap[kept][:, kept]
    if len(nodes) < 2:
        raise ValueError(
            f"the roadmap fell apart (largest connected piece: {len(nodes)} node); "
            f"raise n_nodes or connection_radius_m={connection_radius_m}"
        )
    degree = int(adjacency.sum(1).max())
    length = torch.where(adjacency, gap, float("inf"))
    edge_length, neighbors = length.topk(degree, dim=1, largest=False)
    neighbors = torch.where(edge_length.isfinite(), neighbors, 0)
    return Roadmap(nodes, neighbors, edge_length)


def _graph(roadmap: Roadmap) -> RoadmapGraph:
    """What planning reads of ``roadmap``: the solver's orders, and edges as segments."""
    nodes, neighbors, edge_length = roadmap
    real = edge_length.isfinite()
    edge_dx = nodes[neighbors, 0] - nodes[:, 0, None]
    edge_dy = nodes[neighbors, 1] - nodes[:, 1, None]
    paired = _slabs(len(nodes), PAIRED_SLABS)
    # Pairs from both ends inward; with an odd count the middle slab goes alone.
    pairs = [[paired[i], paired[-1 - i]] for i in range(len(paired) // 2)]
    pairs += [[paired[len(paired) // 2]]] * (len(paired) % 2)
    return RoadmapGraph(
        roadmap=roadmap,
        sweeps=(_sweep_order(roadmap, pairs), _sweep_order(roadmap, [[s] for s in _slabs(len(nodes), SLABS)])),
        node_x=nodes[:, 0, None, None],
        node_y=nodes[:, 1, None, None],
        edge_x=nodes[:, 0, None, None, None],
        edge_y=nodes[:, 1, None, None, None],
        edge_dx=edge_dx[:, :, None, None],
        edge_dy=edge_dy[:, :, None, None],
        edge_inverse_sq=torch.where(real, 1.0 / edge_length.square(), 0.0)[:, :, None, None],
        edge_length=edge_length[:, :, None, None],
        half_edge_m=float(edge_length[real].mean()) / 2,
    )


def _slabs(n_nodes: int, count: int) -> list[tuple[int, int]]:
    """(start, stop) of ``count`` slabs of consecutive nodes, as equal as may be (fewer in a small roadmap)."""
    bounds = torch.linspace(0, n_nodes, min(count, n_nodes) + 1).round().long().tolist()
    return list(itertools.pairwise(bounds))


def _sweep_order(roadmap: Roadmap, groups: list[list[tuple[int, int]]]) -> SweepOrder:
    """The solver's order for ``groups``, each a list of (start, stop) ranges of roadmap nodes."""
    n_nodes, n_neighbors = roadmap.neighbors.shape
    neighbors, real = roadmap.neighbors.tolist(), roadmap.edge_length.isfinite().tolist()
    members = [[node for start, stop in group for node in range(start, stop)] for group in groups]
    order = [node for nodes in members for node in nodes]
    rank = {node: row for row, node in enumerate(order)}
    group_of = {node: g for g, nodes in enumerate(members) for node in nodes}
    zero_row, inf_row = n_nodes * (1 + n_neighbors), n_nodes * (1 + n_neighbors) + 1
    source: list[int] = []
    sweep_groups = []
    for g, nodes in enumerate(members):
        # Each node's edges (as columns of Roadmap.neighbors) to earlier groups, within this one, to later ones.
        parts = [([], [], []) for _ in nodes]
        for node_parts, node in zip(parts, nodes):
            for k in (k for k in range(n_neighbors) if real[node][k]):
                other = group_of[neighbors[node][k]]
                node_parts[0 if other < g else 1 if other == g else 2].append(k)
        earlier, within, later = (max(len(node_parts[part]) for node_parts in parts) for part in range(3))
        width, start = earlier + 1 + within + later, rank[nodes[0]]
        index = torch.full((len(nodes), width), n_nodes)  # padding reads the goal's row, 0, plus an inf edge
        cells = torch.full((len(nodes), width), inf_row)
        for row, (node, (to_earlier, to_within, to_later)) in enumerate(zip(nodes, parts)):
            columns = [
                *range(earlier - len(to_earlier), earlier),
                *range(earlier + 1, earlier + 1 + len(to_within)),
                *range(earlier + 1 + within, earlier + 1 + within + len(to_later)),
            ]
            for column, k in zip(columns, to_earlier + to_within + to_later):
                cells[row, column] = node * (1 + n_neighbors) + 1 + k
                index[row, column] = rank[neighbors[node][k]]
            cells[row, earlier], index[row, earlier] = zero_row, start + row  # the node itself, at cost 0

        spans = ((0, width), (0, earlier + 1 + within), (earlier, width))  # all, forward, backward
        full, forward, backward = ((first, end, index[:, first:end].reshape(-1)) for first, end in spans)
        sweep_groups.append(SweepGroup(start, start + len(nodes), len(source), width, full, forward, backward))
        source += cells.view(-1).tolist()
    return SweepOrder(
        rank=None if order == list(range(n_nodes)) else torch.tensor([rank[node] for node in range(n_nodes)]),
        goal_rows=torch.tensor(order) * (1 + n_neighbors),
        source=torch.tensor(source),
        groups=tuple(sweep_groups),
    )


# ---- small tools --------------------------------------------------------------------------------------------------


def _broadcast_shape(*shapes: Sequence[int]) -> torch.Size:
    """``torch.broadcast_shapes`` without its checks, which cost more than a small tensor operation."""
    ndim = max(len(shape) for shape in shapes)
    padded = [(1,) * (ndim - len(shape)) + tuple(shape) for shape in shapes]
    return torch.Size(max(sizes) for sizes in zip(*padded))


def _first_min(values: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``values.min(0)``: the least value along the first axis and its first index, in float steps that run
    many times faster than min with indices (or bool masks) along a leading axis."""
    n = len(values)
    least = values.amin(0)
    ties = torch.eq(values, least, out=torch.empty_like(values))
    # n - ties · (n - index): the index where tied, n elsewhere.
    past_index = torch.arange(n, 0, -1, dtype=values.dtype, device=values.device)
    past_index = past_index.view(-1, *[1] * (values.dim() - 1))
    first = ties.mul_(past_index).neg_().add_(n).amin(0)
    return least, first.long()


def _box_tensor(boxes: Sequence[Sequence[float]]) -> torch.Tensor:
    return torch.tensor(boxes, dtype=torch.float32).reshape(-1, 4)


def _segment_clear(
    boxes: torch.Tensor,
    agent_radius_m: float,
    connection_radius_m: float,
    ax: torch.Tensor,
    ay: torch.Tensor,
    bx: torch.Tensor,
    by: torch.Tensor,
) -> torch.Tensor:
    """Bool, the broadcast shape: an agent moving straight from a to b touches no interior box.

    The test points are spaced for segments of the connection radius; a longer one (an attachment to a nearest
    node beyond it) is tested more coarsely.
    """
    steps = math.ceil(connection_radius_m / SEGMENT_CHECK_STEP_M) + 1
    fraction = torch.linspace(0.0, 1.0, steps, device=ax.device)
    ax, ay, bx, by = (t.unsqueeze(-1) for t in (ax, ay, bx, by))
    touches = touches_box(boxes.to(ax.device), ax + (bx - ax) * fraction, ay + (by - ay) * fraction, agent_radius_m)
    return ~touches.any(-1)
