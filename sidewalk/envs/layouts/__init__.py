"""Geometry of a world: where the agents start, where their goals are, and what is wall -- the scenarios.

A scenario is one factory per domain, registered under its name in ``GRID_LAYOUTS`` / ``PLANE_LAYOUTS`` and
selected with ``env.layout=NAME`` (paper §7, SPEC §5):

- ``sidewalk``: the paper's two agents walking toward each other's start;
- ``random``: ``n_agents`` agents with starts and goals drawn per world and per episode in an open area;
- ``circle``: ``n_agents`` evenly spaced on a circle (grid: the border of the room), goals diametrically opposite;
- ``teams``: two groups of ``n_agents / 2`` side by side facing each other, goals behind the other group;
- ``door``: a wall across the world with a gap one agent wide; every agent starts on one side, its goal on the other;
- ``zipper``: two cars in adjacent lanes that narrow to one at a merge point; each car's goal lies in the other lane.

Each scenario is one file of this package with a grid and a plane factory, ``<name>_grid(rows, cols, n_agents,
min_start_goal_cells)`` and ``<name>_plane(length_m, width_m, n_agents, agent_radius_m, goal_radius_m,
min_start_goal_m)``, plus its presets ``conf/experiment/<name>_{discrete,continuous}.yaml``; a new scenario is a
new file and its name in ``SCENARIOS``. ``sample`` returns per-world starts and goals; a layout with ``fixed = False`` draws them from the env's generator
on every reset, so random layouts differ between worlds and episodes and repeat exactly for one seed.

A scenario for any number of agents also declares, per domain, how many agents a room holds
(``<name>_grid_capacity(rows, cols, min_start_goal_cells)``, ``<name>_plane_capacity(length_m, width_m,
agent_radius_m, goal_radius_m)``; its factory refuses more, naming the room) and its own room for N agents
(``<name>_grid_room(n_agents)``, ``<name>_plane_room(n_agents, agent_radius_m, goal_radius_m)``): from them
``grid_room`` / ``plane_room`` pick the room of an env given no size.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from sidewalk._checks import check_choice
from sidewalk.envs.layouts.base import ANY_N_LAYOUTS, GridLayout, PlaneLayout
from sidewalk.envs.layouts.circle import circle_grid, circle_plane
from sidewalk.envs.layouts.door import door_grid, door_plane
from sidewalk.envs.layouts.random import RandomGridLayout, RandomPlaneLayout, random_grid, random_plane
from sidewalk.envs.layouts.sidewalk import sidewalk_grid, sidewalk_plane
from sidewalk.envs.layouts.teams import teams_grid, teams_plane
from sidewalk.envs.layouts.zipper import zipper_grid, zipper_plane

SCENARIOS = ("sidewalk", "random", "circle", "teams", "door", "zipper")
# Each scenario's module holds <name>_grid and <name>_plane.
_MODULES = {name: importlib.import_module(f"{__name__}.{name}") for name in SCENARIOS}
GRID_LAYOUTS: dict[str, Callable[..., GridLayout | RandomGridLayout]] = {
    name: getattr(module, f"{name}_grid") for name, module in _MODULES.items()
}
PLANE_LAYOUTS: dict[str, Callable[..., PlaneLayout | RandomPlaneLayout]] = {
    name: getattr(module, f"{name}_plane") for name, module in _MODULES.items()
}
# The scenarios whose room sets how many agents they hold: their capacity and their own room for N agents.
GRID_ROOMS: dict[str, tuple[Callable[..., int], Callable[[int], tuple[int, int]]]] = {
    name: (getattr(module, f"{name}_grid_capacity"), getattr(module, f"{name}_grid_room"))
    for name, module in _MODULES.items()
    if hasattr(module, f"{name}_grid_room")
}
PLANE_ROOMS: dict[str, tuple[Callable[..., int], Callable[..., tuple[float, float]]]] = {
    name: (getattr(module, f"{name}_plane_capacity"), getattr(module, f"{name}_plane_room"))
    for name, module in _MODULES.items()
    if hasattr(module, f"{name}_plane_room")
}


def grid_layout(
    name: str, rows: int, cols: int, n_agents: int = 2, min_start_goal_cells: int = 4
) -> GridLayout | RandomGridLayout:
    """The grid scenario ``name`` on a ``rows`` × ``cols`` grid (raises naming the valid names or agent counts)."""
    check_choice("layout", name, GRID_LAYOUTS)
    return GRID_LAYOUTS[name](rows, cols, n_agents=n_agents, min_start_goal_cells=min_start_goal_cells)


def _room(
    rooms: dict, layouts: dict, name: str, n_agents: int, given: tuple, default: tuple,
    capacity_args: tuple, room_args: tuple,
) -> tuple:
    """The two sides of scenario ``name``'s room for ``n_agents`` where the user gave at most one (None: not given).
    A given side stays; the others are ``default``'s where that room holds the agents (so a room that held them
    before never changes), else the scenario's own room for ``n_agents``, never shorter than ``default``."""
    check_choice("layout", name, layouts)
    proposed = tuple(d if g is None else g for g, d in zip(given, default, strict=True))
    if name not in rooms:
        return proposed
    capacity, own_room = rooms[name]
    if capacity(*proposed, *capacity_args) >= n_agents:
        return proposed
    own = own_room(n_agents, *room_args)
    return tuple(max(o, d) if g is None else g for g, o, d in zip(given, own, default, strict=True))


def grid_room(
    name: str,
    n_agents: int,
    rows: int | None,
    cols: int | None,
    default: tuple[int, int],
    min_start_goal_cells: int = 4,
) -> tuple[int, int]:
    """(rows, cols) of the grid scenario ``name`` for ``n_agents`` (``_room``)."""
    return _room(GRID_ROOMS, GRID_LAYOUTS, name, n_agents, (rows, cols), default, (min_start_goal_cells,), ())


def plane_room(
    name: str,
    n_agents: int,
    length_m: float | None,
    width_m: float | None,
    default: tuple[float, float],
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
) -> tuple[float, float]:
    """(length_m, width_m) of the continuous scenario ``name`` for ``n_agents`` (``_room``)."""
    radii = (agent_radius_m, goal_radius_m)
    return _room(PLANE_ROOMS, PLANE_LAYOUTS, name, n_agents, (length_m, width_m), default, radii, radii)


def plane_layout(
    name: str,
    length_m: float,
    width_m: float,
    n_agents: int = 2,
    agent_radius_m: float = 0.3,
    goal_radius_m: float = 0.3,
    min_start_goal_m: float = 1.5,
) -> PlaneLayout | RandomPlaneLayout:
    """The continuous scenario ``name`` in a ``length_m`` × ``width_m`` world."""
    check_choice("layout", name, PLANE_LAYOUTS)
    return PLANE_LAYOUTS[name](
        length_m,
        width_m,
        n_agents=n_agents,
        agent_radius_m=agent_radius_m,
        goal_radius_m=goal_radius_m,
        min_start_goal_m=min_start_goal_m,
    )


__all__ = [
    "ANY_N_LAYOUTS",
    "GRID_LAYOUTS",
    "GRID_ROOMS",
    "PLANE_LAYOUTS",
    "PLANE_ROOMS",
    "SCENARIOS",
    "GridLayout",
    "PlaneLayout",
    "RandomGridLayout",
    "RandomPlaneLayout",
    "circle_grid",
    "circle_plane",
    "door_grid",
    "door_plane",
    "grid_layout",
    "grid_room",
    "plane_layout",
    "plane_room",
    "random_grid",
    "random_plane",
    "sidewalk_grid",
    "sidewalk_plane",
    "teams_grid",
    "teams_plane",
    "zipper_grid",
    "zipper_plane",
]
