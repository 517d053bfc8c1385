"""Where the package's Hydra configs and runners are: inside the package in an installed wheel (``sidewalk/conf``,
``sidewalk/runners``), at the top of the repository in a clone or an editable install (``conf/``, ``runners/``)."""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def _shipped(name: str) -> Path:
    installed = PACKAGE_DIR / name
    return installed if installed.is_dir() else PACKAGE_DIR.parent / name


CONFIG_DIR = _shipped("conf")
RUNNERS_DIR = _shipped("runners")
