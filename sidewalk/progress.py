"""Where a trial stands between iterations: its metrics rows, iterations done, wall clock, and the best evaluation so
far, whose policy the absolute metric re-evaluates (``sidewalk.experiment.Trial``)."""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sidewalk.config import Experiment
from sidewalk.stops import StopSignals

METRICS_EVERY_S = 10.0  # metrics.csv is rewritten at least this often, so a watcher sees progress

def learner_score(metrics: dict[str, float]) -> tuple[float, float]:
    """What ranks two evaluations of one run: the learner's success rate (the ego's, or the team's where it plays
    every agent), then its return; NaN ranks lowest."""
    success = metrics.get("ego/success_rate", metrics.get("team/success_rate", math.nan))
    episode_return = metrics.get("ego/return", metrics.get("return", math.nan))
    return tuple(-math.inf if math.isnan(value) else value for value in (success, episode_return))


@dataclass
class Best:
    """The run's best evaluation so far (``learner_score``): its score, iteration and a copy of the policy's state."""

    score: tuple[float, float]
    iteration: int
    policy: dict[str, Any]


@dataclass
class Progress:
    """Where a trial stands: the metrics rows so far, the iterations done, the wall clock's origin and the best
    evaluation."""

    rows: list[dict[str, float]] = field(default_factory=list)
    iteration: int = 0
    started: float = 0.0
    last_write: float = 0.0
    best: Best | None = None

    def keep_if_best(self, metrics: dict[str, float], policy_state: Callable[[], dict[str, Any]]) -> None:
        """After an evaluation: keep a copy of the policy (``policy_state()``) if this evaluation is the best so far
        (ties keep the earlier one)."""
        score = learner_score(metrics)
        if self.best is None or score > self.best.score:
            self.best = Best(score, self.iteration, copy.deepcopy(policy_state()))

    def best_state(self) -> dict[str, Any] | None:
        """The best evaluation as a checkpoint keeps it."""
        return None if self.best is None else dataclasses.asdict(self.best)

    def load_best_state(self, saved: dict[str, Any] | None) -> None:
        self.best = None if saved is None else Best(tuple(saved["score"]), saved["iteration"], saved["policy"])

    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    def due(self, experiment: Experiment, stop: bool, signals: StopSignals) -> tuple[bool, bool, bool, bool]:
        """After an iteration: (done, interrupted by a signal, a checkpoint due, metrics.csv due). The end writes
        its own checkpoint (``keep_checkpoint=all``) or none, so a checkpoint is due only before it."""
        done = stop or self.iteration >= experiment.iterations
        interrupted = signals.received is not None and not done
        periodic = bool(experiment.checkpoint_every) and self.iteration % experiment.checkpoint_every == 0
        checkpoint = interrupted or periodic
        metrics = checkpoint or done or time.perf_counter() - self.last_write > METRICS_EVERY_S
        return done, interrupted, checkpoint and not done, metrics
