"""Opponents: one file each, all sharing the ``Opponent`` call signature; ``make_opponent(name, env, ...)`` builds
one by its registered name (``sidewalk.registry.OPPONENTS``, where plug-ins from other packages join them)."""

from sidewalk.opponents.base import Opponent, available_opponents, make_opponent, opponent_class
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.opponents.prm import PRMOpponent
from sidewalk.opponents.random import RandomOpponent


def __getattr__(name: str):
    # Built over the views, which import this package's base: loaded on first use, not at import.
    if name == "ScriptedTeam":
        from sidewalk.opponents.team import ScriptedTeam

        return ScriptedTeam
    if name == "PolicyOpponent":
        from sidewalk.opponents.policy import PolicyOpponent

        return PolicyOpponent
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DijkstraOpponent", "Opponent", "PRMOpponent", "PolicyOpponent", "RandomOpponent", "ScriptedTeam",
    "available_opponents", "make_opponent", "opponent_class",
]
