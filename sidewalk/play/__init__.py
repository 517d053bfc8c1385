"""``sidewalk-play``: a person walks the sidewalk against any partner, in a local web page (docs/guide/play.md).

``build_server(overrides, ...)`` makes the server of one game (``Game``: the package's Gymnasium face, stepped by the
page's keys, every episode recorded as a Minari dataset); ``runners/play.py`` is the command.
"""

from sidewalk.play.command import build_server, default_dataset_id
from sidewalk.play.game import Game, GameError, Recording
from sidewalk.play.server import PlayServer

__all__ = ["Game", "GameError", "PlayServer", "Recording", "build_server", "default_dataset_id"]
