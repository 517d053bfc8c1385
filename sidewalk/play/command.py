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


def compose_game_experiment(overrides: Sequence[str]):
    """The validated experiment of ``overrides`` (as ``runners/main.py`` composes them), for its world and partner;
    Hydra's and the config's errors become one ``ValueError`` line."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from sidewalk.compose import compose, fitting_algo
    from sidewalk.config import validate

    domain = next((item.split("=", 1)[1] for item in overrides if item.startswith("env=")), "discrete")
    try:
        cfg = compose([f"algo={fitting_algo(domain)}", *overrides])
    except (HydraException, OmegaConfBaseException) as error:
        text = " ".join(str(error).split()).split(" Config search path")[0]  # Hydra's folders say nothing here
        raise ValueError(text) from None
    check_partner(cfg.opponent.name)
    return validate(cfg)


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
    experiment = compose_game_experiment(overrides)
    recording = None
    if record:
        recording = Recording(dataset_id or default_dataset_id(experiment.domain, experiment.opponent),
                              None if datasets is None else str(datasets))
    try:
        game = Game(experiment, recording, seed=seed)
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
