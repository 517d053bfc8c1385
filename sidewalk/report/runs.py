"""Run folders: finding them under the paths given, and reading each one's config, metrics and summary, or saying
why it cannot be used (a failed job, a missing, empty, truncated or unreadable file)."""

from __future__ import annotations

import io
import json
import lzma
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import OmegaConf

from sidewalk.run_folder import (
    CHECKPOINT,
    CONFIG,
    METRICS,
    METRICS_COMPRESSED,
    POLICY,
    SUMMARY,
    RunFolderError,
    flatten,
    is_group_folder,
    seed_folders,
)

ERROR = "error.txt"
# A folder holding any of these is a run folder, complete or not (".hydra" alone: a job killed while starting).
RUN_MARKERS = (CONFIG, METRICS, METRICS_COMPRESSED, SUMMARY, CHECKPOINT, POLICY, ERROR, ".hydra")
POLICY_FILES = f"{POLICY} or {CHECKPOINT}"
SWEEP_MARKER = "multirun.yaml"


@dataclass
class Run:
    """One usable run folder: its resolved config (nested and flattened to dotted keys), metrics and summary."""

    path: Path
    family: str
    config: dict[str, Any]
    flat: dict[str, Any]
    metrics: pd.DataFrame
    summary: dict[str, Any]

    @property
    def seed(self) -> int:
        return int(self.flat.get("seed", -1))


@dataclass
class Skipped:
    """A run folder left out of the report, with the reason."""

    path: Path
    reason: str


def find_run_folders(paths: Iterable[str | Path]) -> list[Path]:
    """Every run folder under ``paths`` (each a run folder or a folder of them, searched recursively), sorted.

    Hidden folders (``.hydra``) are not searched, nor are a run folder's own subfolders (its logger's files).
    Raises ``FileNotFoundError`` / ``NotADirectoryError`` naming a path that is missing or not a folder.
    """
    found: set[Path] = set()
    for path in map(Path, paths):
        if not path.exists():
            raise FileNotFoundError(f"{path} does not exist; give run folders or sweep folders")
        if not path.is_dir():
            raise NotADirectoryError(f"{path} is not a folder; give run folders or sweep folders")
        for root, dirs, files in os.walk(path):
            if is_group_folder(root):  # several seeds trained together: its run folders are its seeds'
                dirs[:] = [folder.name for folder in seed_folders(root)]
            elif any(marker in files or marker in dirs for marker in RUN_MARKERS):
                found.add(Path(root))
                dirs[:] = []
            else:
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
    return sorted(found)


def family_of(run_dir: Path) -> str:
    """The name of the sweep folder holding ``run_dir`` (the nearest ancestor with ``multirun.yaml``), or of
    ``run_dir``'s parent folder for a run outside a sweep."""
    for parent in run_dir.resolve().parents:
        if (parent / SWEEP_MARKER).exists():
            return parent.name
    return run_dir.resolve().parent.name


def read_metrics(path: Path) -> pd.DataFrame:
    """``metrics.csv`` checked to be whole: one row per iteration 1..N with its frames and wall clock.

    ``Trial`` writes the file atomically, so a file that fails these checks was copied or written by something
    else half-way; it raises ``RunFolderError`` naming what is wrong.
    """
    compressed = path.with_name(METRICS_COMPRESSED)
    if not path.exists() and compressed.exists():  # a committed reference run (sidewalk.reference collect)
        try:
            raw = lzma.decompress(compressed.read_bytes())
        except lzma.LZMAError as error:
            raise RunFolderError(f"{METRICS_COMPRESSED} is unreadable: {error}") from error
    elif not path.exists():
        raise RunFolderError(f"no {METRICS}")
    else:
        raw = path.read_bytes()
    if not raw.strip():
        raise RunFolderError(f"{METRICS} is empty")
    if not raw.endswith(b"\n"):
        raise RunFolderError(f"{METRICS} is truncated (its last line is incomplete)")
    try:
        frame = pd.read_csv(io.BytesIO(raw))
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        raise RunFolderError(f"{METRICS} is unreadable: {str(error).strip()}") from error
    missing = [column for column in ("iteration", "frames", "time_s") if column not in frame.columns]
    if missing:
        raise RunFolderError(f"{METRICS} lacks the column(s) {', '.join(missing)}")
    if frame.empty:
        raise RunFolderError(f"{METRICS} has a header but no rows")
    if frame[["iteration", "frames", "time_s"]].isna().any().any():
        raise RunFolderError(f"{METRICS} has rows without iteration, frames or time_s (truncated)")
    if list(frame["iteration"]) != list(range(1, len(frame) + 1)):
        raise RunFolderError(f"{METRICS} iterations are not 1..{len(frame)} in order")
    return frame


def load_run(run_dir: Path, family: str | None = None) -> Run:
    """Read one run folder, raising ``RunFolderError`` that says why it cannot be used (a failed job, a missing,
    empty, truncated or unreadable file, or a ``summary.json`` that does not match ``metrics.csv``)."""
    run_dir = Path(run_dir)
    error_file = run_dir / ERROR
    if error_file.exists():
        lines = [line for line in error_file.read_text(errors="replace").splitlines() if line.strip()]
        raise RunFolderError(f"the job failed: {lines[-1].strip() if lines else '(empty error.txt)'}")
    if not (run_dir / CONFIG).exists():
        raise RunFolderError(f"no {CONFIG} (the job stopped before training)")
    try:
        config = OmegaConf.to_container(OmegaConf.load(run_dir / CONFIG), resolve=True)
    except Exception as error:  # any YAML or interpolation error means the same: the config is unusable
        raise RunFolderError(f"{CONFIG} is unreadable: {str(error).splitlines()[0]}") from error
    if not isinstance(config, dict) or not {"env", "opponent", "algo", "seed"} <= set(config):
        raise RunFolderError(f"{CONFIG} is not a run's config (it lacks env, opponent, algo or seed)")
    metrics = read_metrics(run_dir / METRICS)
    summary_path = run_dir / SUMMARY
    if not summary_path.exists():
        raise RunFolderError(f"no {SUMMARY} (still running, or stopped before the end)")
    try:
        summary = json.loads(summary_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise RunFolderError(f"{SUMMARY} is unreadable: {error}") from error
    if not isinstance(summary, dict):
        raise RunFolderError(f"{SUMMARY} is not a JSON object")
    # Undefined metrics are written as null (strict JSON); the statistics read them as NaN.
    summary = {k: math.nan if v is None else v for k, v in summary.items()}
    last = int(metrics["iteration"].iloc[-1])
    if "iterations" in summary and int(summary["iterations"]) != last:
        raise RunFolderError(
            f"{METRICS} ends at iteration {last} but {SUMMARY} is of iteration {summary['iterations']}"
        )
    return Run(run_dir, family or family_of(run_dir), config, flatten(config), metrics, summary)


def shown_path(path: Path, out: Path) -> str:
    """``path`` relative to the report folder when that is shorter and names a folder (a report inside its run
    folder would read "``..``"), so a moved report still reads well; else as ``readable_path`` shows it."""
    relative = os.path.relpath(path.resolve(), out.resolve())
    named = any(part != os.pardir for part in Path(relative).parts)
    return relative if named and len(relative) < len(str(path)) else readable_path(path)


def readable_path(path: Path) -> str:
    """``path`` relative to the current folder where it lies under it (``results/runs/...``, as the user typed it),
    else as given: a report does not open with the machine's absolute paths."""
    resolved = Path(path).resolve()
    return str(resolved.relative_to(Path.cwd().resolve())) if resolved.is_relative_to(Path.cwd().resolve()) \
        else str(path)
