"""The command line that continues an interrupted run or sweep of ``runners/main.py``, which its interruption prints:
the command as it was given, pointed at the folder it wrote (a default folder's name holds the time it started, so
the same command again would start another) and with ``resume=true``."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Any

from hydra.types import RunMode
from omegaconf import OmegaConf

# What the command sets itself: the folder, the mode (-m) and the resume flag.
SET_HERE = ("hydra.run.dir", "hydra.sweep.dir", "hydra.mode", "resume")


def continue_command(hydra: Any, resume: bool = True) -> str:
    """The command that continues the job whose Hydra config is ``hydra`` (``HydraConfig.get()``).

    A single run: its own overrides with ``hydra.run.dir=<its folder>`` and ``resume=true`` (``resume=False``: the
    command that starts a folder that holds no run yet). A sweep's job: the sweep's command line, as its
    ``multirun.yaml`` records it, with ``hydra.sweep.dir=<the sweep's folder> resume=true``, which skips the sweep's
    finished jobs, starts those it never reached and resumes the rest.
    """
    in_sweep = hydra.mode == RunMode.MULTIRUN
    if in_sweep:
        folder_key, folder = "hydra.sweep.dir", Path(str(hydra.sweep.dir))
        recorded = folder / "multirun.yaml"  # the sweep's own overrides (a job's hold its point of the sweep)
        overrides = OmegaConf.load(recorded).hydra.overrides if recorded.exists() else hydra.overrides
    else:
        folder_key, folder, overrides = "hydra.run.dir", Path(hydra.runtime.output_dir), hydra.overrides
    given = [*OmegaConf.to_container(overrides.task, resolve=False),
             *OmegaConf.to_container(overrides.hydra, resolve=False)]  # as typed: ${now:...} stays unresolved
    kept = [override for override in given if override.split("=", 1)[0].lstrip("+~") not in SET_HERE]
    words = [*_program(), *(["-m"] if in_sweep else []), *_config_options(hydra), *kept,
             f"{folder_key}={_shown(folder)}", *(["resume=true"] if resume or in_sweep else [])]
    return shlex.join(words)


def _program() -> list[str]:
    script = Path(sys.argv[0])
    if script.name == "main.py":
        return ["python", sys.argv[0]]
    if script.name.startswith("sidewalk-"):  # the installed entry point
        return [script.name]
    return ["python", "runners/main.py"]  # a launcher's worker process (joblib, submitit): the command users type


def _config_options(hydra: Any) -> list[str]:
    """``--config-name`` and ``--config-dir`` as given: they choose which config the overrides apply to."""
    options = [] if hydra.job.config_name == "config" else [f"--config-name={hydra.job.config_name}"]
    for source in hydra.runtime.config_sources:
        if source.provider == "command-line":
            options.append(f"--config-dir={source.path}")
    return options


def _shown(folder: Path) -> str:
    """The folder relative to the working directory when it lies inside it (as a default folder does), else whole."""
    folder = folder.resolve()
    try:
        return str(folder.relative_to(Path.cwd()))
    except ValueError:
        return str(folder)
