"""Scripted opponents: one file each, all sharing the ``Opponent`` call signature."""

from sidewalk.opponents.base import Opponent
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.opponents.prm import PRMOpponent
from sidewalk.opponents.random import RandomOpponent

__all__ = ["DijkstraOpponent", "Opponent", "PRMOpponent", "RandomOpponent"]
