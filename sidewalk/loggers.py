"""The TorchRL logger a run writes beside its ``metrics.csv`` (``logger=csv|tensorboard|wandb|mlflow|none``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sidewalk.config import Experiment


# The backends that need a package of their own (the ``sidewalk-problem[loggers]`` extra installs all three).
BACKEND_PACKAGES = {"tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}


def check_logger(name: str) -> None:
    """Refuse a backend whose package is not installed, before the run starts (its folder is made)."""
    package = BACKEND_PACKAGES.get(name)
    if package is not None and importlib.util.find_spec(package) is None:
        usable = [backend for backend in ("csv", *BACKEND_PACKAGES, "none")
                  if backend not in BACKEND_PACKAGES or importlib.util.find_spec(BACKEND_PACKAGES[backend])]
        raise ValueError(f"logger={name} needs the '{package}' package, which is not installed here: pip install "
                         f"{package} (or 'sidewalk-problem[loggers]' for every backend); usable here: "
                         f"{', '.join(usable)}")


def make_logger(experiment: Experiment, run_dir: Path):
    """The TorchRL logger named by ``logger.name`` (None for ``none``); optional backends fail with the install."""
    cfg, name = experiment.logger, experiment.logger.name
    try:
        if name == "csv":
            from torchrl.record.loggers.csv import CSVLogger

            return CSVLogger(exp_name="logs", log_dir=str(run_dir))
        if name == "tensorboard":
            from torchrl.record.loggers.tensorboard import TensorboardLogger

            return TensorboardLogger(exp_name="logs", log_dir=str(run_dir))
        if name == "wandb":
            from torchrl.record.loggers.wandb import WandbLogger

            return WandbLogger(exp_name=run_dir.name, offline=cfg.offline, save_dir=str(run_dir), project=cfg.project)
        if name == "mlflow":
            from torchrl.record.loggers.mlflow import MLFlowLogger

            uri = cfg.tracking_uri or (run_dir / "mlruns").resolve().as_uri()
            return MLFlowLogger(exp_name=cfg.project, tracking_uri=uri)
    except ImportError as error:
        extra = BACKEND_PACKAGES[name]
        raise ImportError(f"logger={name} needs the '{extra}' package: pip install {extra}") from error
    return None
