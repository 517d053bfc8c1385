"""How a trial stops early: a signal asking it to checkpoint and leave (``StopSignals``, ``RunInterrupted``), or
a learner whose loss or parameters turned non-finite (``divergence``, ``LearnerDiverged``)."""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import torch

if TYPE_CHECKING:
    from sidewalk.algos.base import Algorithm


def how_to_continue(continue_command: str | None) -> str:
    """The end of an interruption's message: the command that continues the run (``runners/main.py`` knows it), or
    what it must say."""
    if continue_command is None:
        return "resume=true on the run's folder continues it"
    return f"continue with:\n  {continue_command}"


class RunInterrupted(Exception):
    """SIGTERM, SIGUSR1 or SIGINT arrived; the run wrote a checkpoint at the end of ``iteration`` and stopped."""

    def __init__(self, signum: int, iteration: int, run_dir: Path, continue_command: str | None = None) -> None:
        self.signum, self.iteration = signum, iteration
        # What happened, without how to go on: a caller that continues the run otherwise says its own way.
        name = signal.Signals(signum).name
        self.checkpointed = f"{name} received: checkpointed at iteration {iteration} in {run_dir}"
        super().__init__(f"{self.checkpointed}; {how_to_continue(continue_command)}")


class LearnerDiverged(RuntimeError):
    """The learner's loss or parameters became non-finite; nothing from that update was written."""


def divergence(algo: Algorithm, logs: dict[str, float], replica: int | None = None) -> str | None:
    """What is non-finite after an update (a loss, or some module's parameters), or None; ``replica``: only that
    replica's parameters of a learner with a replica axis.

    One sum per module: a sum is finite exactly when every parameter is (they are far from overflowing it).
    """
    bad = [f"{key}={value}" for key, value in logs.items() if "loss" in key and not math.isfinite(value)]
    for name, module in algo.modules().items():
        params = (p.detach() if replica is None else p.detach()[replica] for p in module.parameters())
        total = sum((p.sum() for p in params), torch.zeros(()))
        if not math.isfinite(float(total)):
            bad.append(f"parameters of {name!r}")
    return ", ".join(bad) or None


class StopSignals:
    """Record SIGTERM/SIGUSR1 (Slurm's pre-emption and submitit's notice) and a first Ctrl-C instead of dying, so
    the loop can checkpoint at the end of the iteration; a second Ctrl-C stops the process at once, printing
    ``continue_command`` (the command that continues the run from its last checkpoint). Installed only in the main
    thread (Python's rule for handlers)."""

    SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGUSR1", "SIGINT") if hasattr(signal, name))

    def __init__(self, continue_command: str | None = None) -> None:
        self.received: int | None = None
        self.continue_command = continue_command
        # Set once no iteration is left to end at (the last one, the final evaluation and summary): a first Ctrl-C
        # then lets the run finish, and says so.
        self.finishing = False
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            for signum in self.SIGNALS:
                self._previous[signum] = signal.signal(signum, self._record)
        return self

    def _record(self, signum: int, frame: Any) -> None:
        if signum == signal.SIGINT and self.received == signal.SIGINT:
            # The user insists: die of SIGINT now (exit 130). A KeyboardInterrupt raised inside TorchRL's loss
            # surfaced as an unrelated RuntimeError; atomic writes keep the folder whole either way.
            print(f"\nCtrl-C again: stopped at once, from the last checkpoint on; "
                  f"{how_to_continue(self.continue_command)}", file=sys.stderr, flush=True)
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGINT)
        if signum == signal.SIGINT:
            print("\nCtrl-C: " + ("training is over; finishing the run's final evaluation and summary"
                                  if self.finishing else "checkpointing at the end of this iteration")
                  + " (Ctrl-C again to stop at once)", file=sys.stderr, flush=True)
        self.received = signum

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
