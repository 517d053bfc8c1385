"""Scripted opponents: one file each, all sharing the ``Opponent`` call signature."""

from sidewalk.opponents.base import Opponent
from sidewalk.opponents.random import RandomOpponent

__all__ = ["Opponent", "RandomOpponent"]
