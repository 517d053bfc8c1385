"""Hydra callbacks: a sweep whose jobs failed ends with a non-zero exit status, after every job has run."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

ERROR_FILE = "error.txt"
log = logging.getLogger(__name__)


class SweepStatus(Callback):
    """After a multirun, lists the jobs that recorded an ``error.txt`` and exits with status 1 if any did.

    ``runners/main.py`` catches a job's exception in a sweep and writes it to the job's own folder, so one failing
    job neither stops nor loses the others; this callback makes the failure visible to the shell and to CI.
    """

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        # A job refused because another process writes its folder leaves <folder>.error.txt beside it.
        failed = sorted({*sweep_dir.rglob(ERROR_FILE), *sweep_dir.rglob(f"*.{ERROR_FILE}")})
        if failed:
            for path in failed:
                first_line = path.read_text().strip().splitlines()[-1] if path.read_text().strip() else "?"
                log.error("job failed: %s: %s", path.parent, first_line)
            raise SystemExit(f"{len(failed)} job(s) of the sweep failed; see {ERROR_FILE} in each job folder")
        log.info("sweep done; its report: python runners/report.py %s", sweep_dir)
