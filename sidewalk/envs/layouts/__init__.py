"""Geometry of a world: where the agents start, where their goals are, and what is wall -- the scenarios.

A scenario is one file of this package declaring a ``Scenario`` (``base.Scenario``: its grid and plane factories,
and for any number of agents how many a room holds and its own room for N agents), plus its presets
``conf/experiment/<name>_{discrete,continuous}.yaml``; declaring it registers it under its name in
``sidewalk.registry.LAYOUTS``, which another package's scenarios join through the ``sidewalk.layouts`` entry point
group. It is selected with ``env.layout=NAME`` (paper §7, SPEC §5):

- ``sidewalk``: the paper's two agents walking toward each other's start;
- ``random``: ``n_agents`` agents with starts and goals drawn per world and per episode in an open area;
- ``circle``: ``n_agents`` evenly spaced on a circle (grid: the border of the room), goals diametrically opposite;
- ``teams``: two groups of ``n_agents / 2`` side by side facing each other, goals behind the other group;
- ``door``: a wall across the world with a gap one agent wide; every agent starts on one side, its goal on the other;
- ``zipper``: two cars in adjacent lanes that narrow to one at a merge point; each car's goal lies in the other lane.

``sample`` returns per-world starts and goals; a layout with ``fixed = False`` draws them from the env's generator
on every reset, so random layouts differ between worlds and episodes and repeat exactly for one seed.
"""

from __future__ import annotations

from sidewalk._checks import check_choice
from sidewalk.envs.layouts.base import GridLayout, PlaneLayout, Scenario
from sidewalk.envs.layouts.circle import circle_grid, circle_plane
from sidewalk.envs.layouts.door import door_grid, door_plane
from sidewalk.envs.layouts.random import RandomGridLayout, RandomPlaneLayout, random_grid, random_plane
from sidewalk.envs.layouts.sidewalk import sidewalk_grid, sidewalk_plane
from sidewalk.envs.layouts.teams import teams_grid, teams_plane
from sidewalk.envs.layouts.zipper import zipper_grid, zipper_plane
from sidewalk.registry import LAYOUTS

DOMAIN_FACTORY = {"discrete": "grid", "continuous": "plane"}


def scenario_names(domain: str | None = None) -> list[str]:
    """The registered scenarios (optionally only those of ``domain``), in their ``rank`` order."""
    names = LAYOUTS.names(lambda scenario: domain is None or domain in scenario.domains)
    return sorted(names, key=lambda name: (LAYOUTS[name].rank, name))


def scenario(name: str, domain: str) -> Scenario:
    """The scenario ``name`` of ``domain``; raises naming the valid ones."""
    check_choice("layout", name, scenario_names(domain))
    return LAYOUTS[name]


def grid_layout(
    name: str, rows: int, cols: int, n_agents: int = 2, min_start_goal_cells: int = 4
) -> GridLayout | RandomGridLayout:
    """The grid scenario ``name`` on a ``rows`` × ``cols`` grid (raises naming the valid names or agent counts)."""
    return scenario(name, "discrete").grid(rows, cols, n_agents=n_agents, min_start_goal_cells=min_start_goal_cells)


def _room(
    name: str, domain: str, n_agents: int, given: tuple, default: tuple, capacity_args: tuple, room_args: tuple
) -> tuple:
    """The two sides of scenario ``name``'s room for ``n_agents`` where the user gave at most one (None: not given).
    A given side stays; the others are ``default``'s where that room holds the agents (so a room that held them
    before never changes), else the scenario's own room for ``n_agents``, never shorter than ``default``."""
    declared = scenario(name, domain)
    factory = DOMAIN_FACTORY[domain]
    capacity, own_room = getattr(declared, f"{factory}_capacity"), getattr(declared, f"{factory}_room")
    proposed = tuple(d if g is None else g for g, d in zip(given, default, strict=True))
    if own_room is None or capacity(*proposed, *capacity_args) >= n_agents:
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
    return _room(name, "discrete", n_agents, (rows, cols), default, (min_start_goal_cells,), ())


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
    return _room(name, "continuous", n_agents, (length_m, width_m), default, radii, radii)


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
    return scenario(name, "continuous").plane(
        length_m,
        width_m,
        n_agents=n_agents,
        agent_radius_m=agent_radius_m,
        goal_radius_m=goal_radius_m,
        min_start_goal_m=min_start_goal_m,
    )


__all__ = [
    "DOMAIN_FACTORY",
    "GridLayout",
    "PlaneLayout",
    "RandomGridLayout",
    "RandomPlaneLayout",
    "Scenario",
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
    "scenario",
    "scenario_names",
    "sidewalk_grid",
    "sidewalk_plane",
    "teams_grid",
    "teams_plane",
    "zipper_grid",
    "zipper_plane",
]
