"""The project's config composed from ``conf/`` and overrides outside a Hydra app, as ``runners/main.py`` composes it:
the one composition the reproduction, the reference probes, the benchmarks and the renders share."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig

from sidewalk.config import Experiment, validate
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


def fitting_algo(domain: str) -> str:
    """A learner that fits ``domain``, for configs of scripted play: validation checks the learner against the
    domain even where none learns."""
    return "dqn" if domain == "discrete" else "trpo"
