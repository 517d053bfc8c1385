"""What ``sidewalk-play`` builds from its command line, every check made before the server listens."""

from __future__ import annotations

import errno
from collections.abc import Sequence
from pathlib import Path

from sidewalk.play.game import Game, Recording, check_partner
from sidewalk.play.server import PlayServer


def default_dataset_id(domain: str, opponent: str) -> str:
    """Where a partner's episodes go unless ``--dataset-id`` says otherwise: one dataset per domain and partner."""
    return f"sidewalk-play/{domain}-{opponent.replace('_', '-')}-v0"


def compose_game_world(overrides: Sequence[str]):
    """The validated World of ``overrides`` (as ``runners/main.py`` composes and checks its world and partner);
    Hydra's and the config's errors become one ``ValueError`` line, as ``runners/main.py`` prints them."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from sidewalk.compose import compose, one_line
    from sidewalk.config import DOMAINS, validate_world

    chosen = dict(item.partition("=")[::2] for item in overrides)  # the last of a key wins, as in Hydra
    domain = chosen.get("env", "discrete")
    if "opponent" in chosen and domain in DOMAINS:
        check_partner(chosen["opponent"], domain)  # before Hydra, whose options for an unknown one are not partners
    try:
        cfg = compose(overrides)
    except (HydraException, OmegaConfBaseException) as error:
        raise ValueError(one_line(error)) from None
    check_partner(cfg.opponent.name, cfg.env.domain)
    return validate_world(cfg)


def build_server(
    overrides: Sequence[str] = (),
    host: str = "127.0.0.1",
    port: int = 8765,
    datasets: Path | None = None,
    dataset_id: str | None = None,
    record: bool = True,
    seed: int = 0,
    verbose: bool = False,
) -> PlayServer:
    """The server of one game of the world and partner ``overrides`` name; ``ValueError`` (bad config, partner,
    dataset) or ``OSError`` (the port) before it listens."""
    world = compose_game_world(overrides)
    recording = None
    if record:
        recording = Recording(dataset_id or default_dataset_id(world.domain, world.opponent),
                              None if datasets is None else str(datasets))
    try:
        game = Game(world, recording, seed=seed)
    except ModuleNotFoundError as error:
        if error.name != "minari":
            raise
        raise ValueError("recording episodes needs Minari: pip install 'sidewalk-problem[data]', or pass "
                         "--no-record") from None
    if recording is not None:
        from sidewalk.datasets import check_can_append

        check_can_append(game.env, recording.dataset_id, env_config=game.kwargs, data_path=recording.data_path)
    try:
        return PlayServer(game, host, port, verbose=verbose)
    except OSError as error:
        if error.errno == errno.EADDRINUSE:
            raise OSError(error.errno, f"port {port} on {host} is in use; pick another with --port (0: any free "
                                       "one)") from None
        raise
