"""The sidewalk's symmetries on observations and actions of both domains: the half turn that maps one agent's role
onto the other's (learned partners playing another role, ``sidewalk.partners.policy``) and the mirror across the
centre line (Other-Play, Hu et al. 2020).

The mirror maps the grid's row r to rows-1-r (UP and DOWN swap) and the plane's y to width-y (heading θ to -θ, the
turn to -turn; a heading of -π shows as π). It is a symmetry of the game when every wall and every agent's own start and goal map onto
themselves: the two-agent sidewalk, for instance, whose agents start and end on the centre line. An agent that plays
mirrored sees the world as the mirror shows it and its action is mirrored back before the world steps, so it cannot
tell a mirrored episode from a plain one and no convention that depends on a side ("pass on the left") survives.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from sidewalk.envs import core_class
from sidewalk.envs.grid import VECTOR_FIELDS
from sidewalk.envs.unicycle import OBSERVATION_FIELDS

UP, DOWN = 0, 1
GRID_HALF_TURN_ACTIONS = (1, 0, 3, 2)  # UP, DOWN, LEFT, RIGHT turned by half a turn: DOWN, UP, RIGHT, LEFT


def turn_observation(observation: torch.Tensor, layout: Any) -> torch.Tensor:
    """Observations (..., obs) of a world of ``layout`` as the world turned by half a turn shows them (grid images
    (..., C, H, W) uint8 or vectors of ``VECTOR_FIELDS`` per agent scaled to [0, 1]; continuous vectors of
    ``OBSERVATION_FIELDS`` per agent). The flags stay, and an agent removed from the world stays all zeros."""
    if hasattr(layout, "rows"):
        if observation.dtype == torch.uint8:
            return observation.flip(-1, -2)
        per_agent = observation.unflatten(-1, (-1, len(VECTOR_FIELDS)))
        present = per_agent[..., VECTOR_FIELDS.index("present"), None]
        turned = per_agent.clone()
        turned[..., :4] = (1.0 - per_agent[..., :4]) * present
        return turned.flatten(-2)
    per_agent = observation.unflatten(-1, (-1, len(OBSERVATION_FIELDS)))
    present = per_agent[..., OBSERVATION_FIELDS.index("present")]
    turned = per_agent.clone()
    for x, y in ((0, 1), (4, 5)):
        turned[..., x] = (layout.length_m - per_agent[..., x]) * present
        turned[..., y] = (layout.width_m - per_agent[..., y]) * present
    turned[..., 3] = (torch.remainder(per_agent[..., 3], 2 * math.pi) - math.pi) * present  # θ + π, in [-π, π)
    return turned.flatten(-2)


def turn_action(action: torch.Tensor, domain: str) -> torch.Tensor:
    """Actions turned by half a turn: grid (...,) UP↔DOWN and LEFT↔RIGHT; a continuous action (acceleration, turn
    rate) is the same in a turned world, so it is unchanged. Its own inverse."""
    if domain == "discrete":
        return torch.tensor(GRID_HALF_TURN_ACTIONS, device=action.device)[action]
    return action


def mirror_observation(observation: torch.Tensor, layout: Any) -> torch.Tensor:
    """Observations (..., obs) of a world of ``layout`` as its mirror shows them: grid images (..., C, H, W) flipped
    top to bottom, grid vectors (``VECTOR_FIELDS`` per agent, rows scaled to [0, 1]) and continuous vectors
    (``OBSERVATION_FIELDS`` per agent) with their lateral coordinates and headings mirrored; an agent removed from the
    world stays all zeros. The mirror is its own inverse."""
    if hasattr(layout, "rows"):
        if observation.dtype == torch.uint8:
            return observation.flip(-2)
        per_agent = observation.unflatten(-1, (-1, len(VECTOR_FIELDS)))
        present = per_agent[..., VECTOR_FIELDS.index("present")]
        mirrored = per_agent.clone()
        for field in ("row", "goal_row"):
            index = VECTOR_FIELDS.index(field)
            mirrored[..., index] = (1.0 - per_agent[..., index]) * present
        return mirrored.flatten(-2)
    per_agent = observation.unflatten(-1, (-1, len(OBSERVATION_FIELDS)))
    present = per_agent[..., OBSERVATION_FIELDS.index("present")]
    mirrored = per_agent.clone()
    for field in ("y", "goal_y"):
        index = OBSERVATION_FIELDS.index(field)
        mirrored[..., index] = (layout.width_m - per_agent[..., index]) * present
    theta = OBSERVATION_FIELDS.index("theta")
    mirrored[..., theta] = -per_agent[..., theta]  # not re-wrapped: an exact inverse, also of noisy headings
    return mirrored.flatten(-2)


def mirror_action(action: torch.Tensor, domain: str) -> torch.Tensor:
    """Actions mirrored: grid (...,) UP and DOWN swapped; continuous (..., 2) the turn negated."""
    if domain == "discrete":
        return torch.where(action == UP, DOWN, torch.where(action == DOWN, UP, action))
    return torch.stack([action[..., 0], -action[..., 1]], dim=-1)


def _close(a: tuple, b: tuple) -> bool:
    return all(math.isclose(x, y, abs_tol=1e-9) for x, y in zip(a, b))


def check_mirror_symmetric(layout: Any) -> None:
    """Raise ``ValueError`` naming the layout unless the mirror maps its walls onto its walls and every agent's own
    start and goal onto themselves (random layouts: the walls; their starts and goals are drawn alike on both sides)."""
    name = type(layout).__name__
    if hasattr(layout, "rows"):
        flip = lambda cell: (layout.rows - 1 - cell[0], cell[1])
        walls_map = {tuple(cell) for cell in layout.blocked} == {flip(cell) for cell in layout.blocked}
        roles_map = all(
            flip(start) == tuple(start) and flip(goal) == tuple(goal) for start, goal in zip(layout.starts, layout.goals)
        )
    else:
        flip = lambda point: (point[0], layout.width_m - point[1])
        boxes = {tuple(round(v, 9) for v in box) for box in layout.boxes}
        mirrored = {tuple(round(v, 9) for v in (x0, layout.width_m - y1, x1, layout.width_m - y0))
                    for x0, y0, x1, y1 in layout.boxes}
        walls_map = boxes == mirrored
        roles_map = all(
            _close(flip(start), start) and _close(flip(goal), goal) and math.isclose(math.sin(heading), 0.0, abs_tol=1e-9)
            for start, goal, heading in zip(layout.starts, layout.goals, layout.headings)
        )
    if not (walls_map and roles_map):
        raise ValueError(
            f"other_play=true needs a layout that its mirror across the centre line maps onto itself, every agent's "
            f"start and goal onto its own; this {name} does not (its walls or an agent's start or goal are off the "
            "centre line): use env.layout=sidewalk, or a random layout with symmetric walls"
        )


def role_map(domain: str, env_params: Any, trained: int, plays: int) -> str | None:
    """How a learner trained as agent ``trained`` sees the game of agent ``plays``: ``"same"`` (the roles are drawn
    alike: a random layout, or the same agent), ``"half_turn"`` (a two-agent layout a half turn maps onto itself
    and ``trained``'s start and goal onto ``plays``'s), or None (no map)."""
    if trained == plays:
        return "same"
    layout = core_class(domain).layout_for(env_params)
    layout = getattr(layout, "nominal", layout)  # jittered starts: their symmetry is the nominal layout's
    if not layout.fixed:
        return "same"
    if layout.n_agents != 2:
        return None
    if domain == "discrete":
        def turn(cell):
            return (layout.rows - 1 - cell[0], layout.cols - 1 - cell[1])

        symmetric = {turn(cell) for cell in layout.blocked} == set(layout.blocked)
        maps = turn(layout.starts[trained]) == layout.starts[plays] and turn(layout.goals[trained]) == layout.goals[plays]
    else:
        def turn(point):
            return (layout.length_m - point[0], layout.width_m - point[1])

        def close(a, b):
            return all(math.isclose(x, y, abs_tol=1e-9) for x, y in zip(a, b))

        boxes = {(round(x0, 9), round(y0, 9), round(x1, 9), round(y1, 9)) for x0, y0, x1, y1 in layout.boxes}
        turned = {
            (round(layout.length_m - x1, 9), round(layout.width_m - y1, 9),
             round(layout.length_m - x0, 9), round(layout.width_m - y0, 9))
            for x0, y0, x1, y1 in layout.boxes
        }
        heading_gap = (layout.headings[trained] + math.pi - layout.headings[plays]) % (2 * math.pi)
        symmetric = boxes == turned
        maps = (
            close(turn(layout.starts[trained]), layout.starts[plays])
            and close(turn(layout.goals[trained]), layout.goals[plays])
            and min(heading_gap, 2 * math.pi - heading_gap) < 1e-9
        )
    return "half_turn" if symmetric and maps else None


def role_turns(domain: str, env_params: Any) -> list[bool]:
    """Whether each agent of a world of ``env_params`` plays through the half turn to see the game as agent 0 does
    (self-play's ``role_frame``): ``role_map`` from agent 0 onto each agent. Raises ``ValueError`` naming the agents
    whose role maps onto agent 0's by no symmetry."""
    maps = [role_map(domain, env_params, 0, agent) for agent in range(core_class(domain).layout_for(env_params).n_agents)]
    if None in maps:
        layout = type(core_class(domain).layout_for(env_params)).__name__
        raise ValueError(
            f"role_frame=true needs every agent's role to map onto agent 0's (a two-agent layout a half turn maps onto "
            f"itself, or roles drawn alike); this {layout} maps agents {[agent for agent, m in enumerate(maps) if m is None]} "
            "onto none: use env.layout=sidewalk"
        )
    return [m == "half_turn" for m in maps]
