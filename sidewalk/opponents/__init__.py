"""Scripted opponents: one file each, all sharing the ``Opponent`` call signature; ``make_opponent(name, env, ...)``
builds one by its registered name (``sidewalk.registry.OPPONENTS``, where plug-ins from other packages join them).
They live below the views; the partners made of a saved run or a dataset live above the learners
(``sidewalk.partners``) and join the same registry."""

from sidewalk.opponents.base import Opponent, available_opponents, make_opponent, opponent_class
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.opponents.prm import PRMOpponent
from sidewalk.opponents.random import RandomOpponent

__all__ = [
    "DijkstraOpponent", "Opponent", "PRMOpponent", "RandomOpponent", "available_opponents", "make_opponent",
    "opponent_class",
]
