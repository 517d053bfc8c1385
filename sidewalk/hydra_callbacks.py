"""Hydra callbacks: a command whose config (or any point of its sweep) fails the checks is refused before Hydra makes
a folder or starts a job; a sweep whose jobs failed ends with a non-zero exit status, after every job has run."""

from __future__ import annotations

import contextlib
import logging
import sys
from pathlib import Path
from typing import Any, NoReturn

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from sidewalk._hydra import BASIC_SWEEPER, basic_sweeper_points
from sidewalk.config import Experiment, validate
from sidewalk.loggers import check_logger
from sidewalk.partners.policy import check_partner_of
from sidewalk.run_folder import RunFolderError

ERROR_FILE = "error.txt"
# What the checks raise for a bad config or partner folder: refused, exit status 2, nothing computed.
REFUSED = (ValueError, TypeError, FileNotFoundError, NotADirectoryError, RunFolderError)
log = logging.getLogger(__name__)


def checked(cfg: DictConfig) -> Experiment:
    """The validated experiment of ``cfg``, its logger's package, its learned partner's folder and one world of it
    built as training builds it: every check before compute, so a bad partner setting (``tie_break=rnd``), a missing
    dataset or an uninstalled logger is refused with the config's errors, before Hydra makes a folder."""
    experiment = validate(cfg)
    check_logger(experiment.logger.name)
    check_partner_of(experiment)
    # The partner's constructor checks its settings in its world; a learned partner's folder is checked above
    # (rebuilding it costs a learner).
    if experiment.world.opponent != "policy":
        experiment.world.make(1, experiment.seed, experiment.device)
    return experiment


def planned(cfg: DictConfig, run_dir: Path, held: contextlib.ExitStack, in_sweep: bool = False,
            continue_started: bool = False) -> tuple[Experiment, dict[str, Any], str]:
    """The one start sequence of a trial, up to its first compute: the checked experiment of ``cfg`` (``checked``),
    the run folder's writer lock (held in ``held``, taken after the checks so a refused config makes no folder), and
    the plan for ``run_dir`` (``trial_state.check_folders``: ``"start"``, ``"resume"`` or ``"finished"``), with the
    experiment and its resolved config as the plan runs them. ``continue_started``: a run this config started there
    is continued, as ``resume=true`` would (the best responses' cache). Raises one of ``REFUSED`` or ``FolderInUse``
    before any compute. ``runners/main.py`` and ``sidewalk.best_responses`` start their trials through it."""
    import dataclasses

    from omegaconf import OmegaConf

    from sidewalk.run_folder import CONFIG, writer_lock
    from sidewalk.trial_state import check_folders, state_dir

    experiment, config = checked(cfg), OmegaConf.to_container(cfg, resolve=True)
    held.enter_context(writer_lock(run_dir))  # one writer per folder, taken before the folder is read
    if continue_started and (state_dir(run_dir, experiment) / CONFIG).exists():
        experiment, config = dataclasses.replace(experiment, resume=True), {**config, "resume": True}
    plan = check_folders(run_dir, experiment, config, in_sweep)
    if plan == "start" and experiment.resume:  # a sweep's job that the interrupted sweep never reached
        experiment, config = dataclasses.replace(experiment, resume=False), {**config, "resume": False}
    return experiment, config, plan


def refuse(message: Any) -> NoReturn:
    """A command refused before any compute: one ``error:`` line and exit status 2."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def multirun_points(config: DictConfig) -> list[list[str]] | None:
    """The overrides of every job the basic sweeper will launch for the multirun ``config`` (its ``params`` and the
    command line's, as it splits them); None under another sweeper, which may pick its points as it goes."""
    from hydra.core.global_hydra import GlobalHydra

    if config.hydra.sweeper.get("_target_") != BASIC_SWEEPER:
        return None
    return basic_sweeper_points(config.hydra.sweeper.get("params"), list(config.hydra.overrides.task),
                                GlobalHydra.instance().config_loader())


class CheckFirst(Callback):
    """Refuses a run whose config fails the checks before Hydra makes its folder, and a sweep with any such point
    before its first job starts (a bad point otherwise fails only when its job starts, maybe hours in)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        try:
            checked(config)
        except REFUSED as error:
            refuse(error)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from hydra.core.global_hydra import GlobalHydra

        points = multirun_points(config)
        if points is None:
            return
        loader = GlobalHydra.instance().config_loader()
        varying = [index for index in range(len(points[0])) if len({point[index] for point in points}) > 1]
        refused = []
        for number, point in enumerate(points):
            try:
                checked(loader.load_sweep_config(config, list(point)))
            except REFUSED as error:
                refused.append(f"job {number} ({' '.join(point[index] for index in varying) or 'its only point'}): "
                               f"{error}")
        if refused:
            more = f" ({len(refused)} of the sweep's {len(points)} jobs are refused)" if len(refused) > 1 else ""
            refuse(f"{refused[0]}{more}; no job was started")


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
