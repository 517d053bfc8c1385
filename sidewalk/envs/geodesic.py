"""Shortest-path distances in a room with interior boxes, for the continuous world's progress shaping.

A straight line to the goal pays an agent for walking into a wall that stands between them (the door's); the
shortest path around the boxes does not. The disc's centre keeps its radius r from a box, so each box is grown by r
on every side: a centre on a grown edge or corner is a disc clear of the wall, so the path is one a disc can follow
(growing by r/√2 put the corners exactly r from the box's and the path through the door's gap 0.21 m from its walls:
a path no disc can take, whose shaping led agents into the wall's corner). The shortest path around grown boxes bends
only at their corners, so it is found on a visibility graph: the grown corners are waypoints (those outside the room
a disc can reach are left out), and the distance from a point to a goal is the straight line when no grown box
blocks it, else the best visible waypoint's straight line plus its graph distance to the goal. A centre a disc can
hold inside a grown box's corner (where the box's rounded outline leaves room) sees the waypoints and the goal past
the boxes grown r/√2 (which no such centre enters); the price is that the distance may jump where a line of sight
grazes a corner (0.15 m the most a fine scan of the door found; the property tests allow 2r(√2 − 1), 0.25 m at
r = 0.3). Any potential leaves the optimal policies as they are. Batched over worlds and agents, as the world's step
is.
"""

from __future__ import annotations

import torch


def blocked(start: torch.Tensor, end: torch.Tensor, boxes: torch.Tensor) -> torch.Tensor:
    """Bool (...): the segment from ``start`` to ``end`` (..., 2) crosses the open interior of any of ``boxes`` (M, 4)
    as (x_min, y_min, x_max, y_max). A segment along a box's edge or through its corner is free (slab test)."""
    delta = end - start
    low, high = boxes[:, :2], boxes[:, 2:]  # (M, 2)
    origin = start.unsqueeze(-2)  # (..., 1, 2)
    step = delta.unsqueeze(-2)
    moving = step != 0
    safe_step = torch.where(moving, step, torch.ones_like(step))
    t_low, t_high = (low - origin) / safe_step, (high - origin) / safe_step
    t_enter = torch.minimum(t_low, t_high)
    t_exit = torch.maximum(t_low, t_high)
    # A coordinate that does not move is inside the slab for all t or for none.
    inside = (origin > low) & (origin < high)
    t_enter = torch.where(moving, t_enter, torch.where(inside, -torch.inf, torch.inf))
    t_exit = torch.where(moving, t_exit, torch.where(inside, torch.inf, -torch.inf))
    enter = t_enter.amax(-1).clamp(min=0.0)
    leave = t_exit.amin(-1).clamp(max=1.0)
    return (enter < leave).any(-1)


class GeodesicDistance:
    """Distances from points to goals around the interior ``boxes`` of a ``length_m`` × ``width_m`` room, for a disc
    of ``radius_m``; callable on (x, y, goal_x, goal_y) tensors of one shape."""

    def __init__(self, boxes: torch.Tensor, length_m: float, width_m: float, radius_m: float) -> None:
        outward = torch.tensor([-1.0, -1.0, 1.0, 1.0], device=boxes.device)
        self.boxes = boxes.reshape(-1, 4) + radius_m * outward
        self.inner_boxes = boxes.reshape(-1, 4) + radius_m / 2**0.5 * outward
        corners = []
        for x0, y0, x1, y1 in self.boxes.tolist():
            for x in (x0, x1):
                for y in (y0, y1):
                    if radius_m <= x <= length_m - radius_m and radius_m <= y <= width_m - radius_m:
                        corners.append((x, y))
        self.waypoints = torch.tensor(corners, dtype=torch.float32, device=self.boxes.device).reshape(-1, 2)
        self.between = self._all_pairs()

    def _all_pairs(self) -> torch.Tensor:
        """(K, K) shortest distances between the waypoints over the visibility graph (Floyd–Warshall, K is small)."""
        points = self.waypoints
        hops = torch.cdist(points, points)
        pairs = len(points)
        starts, ends = points[:, None].expand(pairs, pairs, 2), points[None].expand(pairs, pairs, 2)
        hops = hops.masked_fill(blocked(starts, ends, self.boxes), torch.inf)
        for k in range(len(points)):
            hops = torch.minimum(hops, hops[:, k : k + 1] + hops[k : k + 1, :])
        return hops

    def _route(self, x: torch.Tensor, y: torch.Tensor, goal_x: torch.Tensor, goal_y: torch.Tensor):
        """(distance to the goal around the boxes, the first point to head for on that path)."""
        point, goal = torch.stack([x, y], -1), torch.stack([goal_x, goal_y], -1)
        straight = (goal - point).norm(dim=-1)
        if not len(self.boxes):
            return straight, goal
        waypoints = self.waypoints.expand(*x.shape, -1, -1)  # (..., K, 2)
        # From each waypoint to the goal: its straight line where visible, else through the other waypoints.
        last_leg = (goal.unsqueeze(-2) - waypoints).norm(dim=-1)
        hidden = blocked(waypoints, goal.unsqueeze(-2).expand_as(waypoints), self.boxes)
        last_leg = last_leg.masked_fill(hidden, torch.inf)
        to_goal = (self.between + last_leg.unsqueeze(-2)).amin(-1)  # (..., K)
        first_leg = (waypoints - point.unsqueeze(-2)).norm(dim=-1)
        # What a point sees is seen past the boxes grown r/√2, which no centre a disc can hold enters: a centre in the
        # room a rounded corner leaves inside a grown box still sees the waypoints and the goal it can walk to.
        hidden = blocked(point.unsqueeze(-2).expand_as(waypoints), waypoints, self.inner_boxes)
        first_leg = first_leg.masked_fill(hidden, torch.inf)
        around, best = (first_leg + to_goal).min(-1)
        direct = ~blocked(point, goal, self.inner_boxes)
        # A point that sees neither the goal nor a waypoint (not one a disc can reach) keeps the straight line.
        straight_on = direct | torch.isinf(around)
        distance = torch.where(straight_on, straight, around)
        head_for = torch.gather(waypoints, -2, best[..., None, None].expand(*best.shape, 1, 2)).squeeze(-2)
        return distance, torch.where(straight_on.unsqueeze(-1), goal, head_for)

    def __call__(self, x: torch.Tensor, y: torch.Tensor, goal_x: torch.Tensor, goal_y: torch.Tensor) -> torch.Tensor:
        return self._route(x, y, goal_x, goal_y)[0]

    def next_point(self, x: torch.Tensor, y: torch.Tensor, goal_x: torch.Tensor, goal_y: torch.Tensor) -> torch.Tensor:
        """(..., 2): the first point to head for on the shortest path to the goal, the goal itself where visible."""
        return self._route(x, y, goal_x, goal_y)[1]
