"""The TorchRL logger a run writes beside its ``metrics.csv`` (``logger=csv|tensorboard|wandb|mlflow|none``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sidewalk.config import Experiment


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
        extra = {"tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}[name]
        raise ImportError(f"logger={name} needs the '{extra}' package: pip install {extra}") from error
    return None
