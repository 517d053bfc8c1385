"""The project's config composed from ``conf/`` and overrides outside a Hydra app, as ``runners/main.py`` composes it:
the one composition the reproduction, the reference probes, the benchmarks and the renders share."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException

from sidewalk.config import Experiment, unknown_override, validate
from sidewalk.paths import CONFIG_DIR
from sidewalk.schema import register_schemas


def compose(overrides: Sequence[str], conf_dir: Path | None = None, hydra_config: bool = False) -> DictConfig:
    """The config ``runners/main.py`` would compose from ``overrides`` (from ``conf_dir``, default the package's
    ``conf/``); ``hydra_config`` keeps Hydra's own node (``cfg.hydra``: a preset's sweep parameters)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    register_schemas()
    GlobalHydra.instance().clear()  # a composition earlier in the process must not hold the config folder
    with initialize_config_dir(config_dir=str(conf_dir or CONFIG_DIR), version_base="1.3"):
        return hydra_compose("config", overrides=list(overrides), return_hydra_config=hydra_config)


def compose_experiment(overrides: Sequence[str], conf_dir: Path | None = None) -> Experiment:
    """The validated ``Experiment`` that ``runners/main.py`` would run with ``overrides``."""
    return validate(compose(overrides, conf_dir))


def one_line(error: BaseException) -> str:
    """A config error (Hydra's or OmegaConf's) as the one line ``runners/main.py`` and ``sidewalk-play`` print:
    Hydra's own reports span many (options one per line, the search path)."""
    from hydra.errors import MissingConfigException

    cause = error.__cause__
    if isinstance(cause, OmegaConfBaseException) and (unknown := unknown_override(cause)):
        return unknown  # Hydra advises adding the typo with "+"; the schema's nearest key is what was meant
    first = str(error).strip().split("\n\n")[0]
    text = " ".join(line.strip() for line in first.splitlines() if line.strip())
    if isinstance(error, MissingConfigException) and error.options:
        # The per-domain defaults (*_default, *_selfplay) are no choice of the user's.
        valid = [option for option in error.options if not option.endswith(("_default", "_selfplay"))]
        text += f"; valid: {', '.join(valid)}"
    if isinstance(cause, OmegaConfBaseException):
        text += f": {str(cause).strip().splitlines()[0]}"
    return text
