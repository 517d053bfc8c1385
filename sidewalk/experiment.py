"""One trial: env → view → learner → collector → replay buffer → logger, trained, evaluated and checkpointed.

``Trial(experiment, run_dir).run()`` reads top to bottom in ``run``. A run folder holds:

- ``config.yaml`` and ``history.jsonl``: the resolved config and the run's events (``sidewalk.run_folder``);
- ``metrics.csv``: one row per iteration (frames, wall clock, train metrics, eval metrics at eval iterations);
- ``summary.json``: the final evaluation as flat SPEC §6 keys plus seed, the evaluation protocol, the absolute metric
  (``policy.best.pt``, the best evaluation's policy, played on ten times the episodes), wall clock, versions, revision;
- ``checkpoint.pt`` (and the generation before it, ``checkpoint.prev.pt``): everything needed to continue exactly
  where the run was (``resume=true``), kept after the run only with ``keep_checkpoint=all``;
- ``policy.pt``: the learner's networks and the world they learned in (written at every checkpoint and at the end),
  all that a report, a render or a learned partner (``opponent=policy``, ``runners/crossplay.py``) replays;
- the logger's own files (``logs/``).

Files are replaced atomically (written beside, then renamed), so a crash or a kill never leaves one half-written,
and a resumed run rewinds ``metrics.csv`` to its checkpoint before going on, so it ends with the same rows as a
run that was never interrupted. The trial holds the folder's writer lock (``run_folder.writer_lock``): a second
process on the same folder is refused. SIGTERM, SIGUSR1 (a scheduler's pre-emption notice) and a first Ctrl-C
(SIGINT) end the run at the end of its iteration with a checkpoint (``RunInterrupted``); a second Ctrl-C stops at
once (the process dies of SIGINT), which atomic writes make safe for the folder; a learner whose loss or parameters
turn non-finite stops the run before anything is written from it (``LearnerDiverged``): the last checkpoint is good.
"""

from __future__ import annotations

import json
import math
import random
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase, RewardSum, TransformedEnv
from tqdm import tqdm

from sidewalk._torchrl import collector_state, restore_collector_state
from sidewalk.algos.base import Algorithm
from sidewalk.config import Experiment
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate, train_metrics
from sidewalk.loggers import make_logger
from sidewalk.opponents.policy import policy_description
from sidewalk.progress import Best, Progress
from sidewalk.registry import LEARNERS as ALGORITHMS  # Trial's name for the learners
from sidewalk.run_folder import (
    BEST_POLICY,
    METRICS,
    SUMMARY,
    append_history,
    atomic_write,
    drop_training_state,
    git_revision,
    load_checkpoint,
    package_versions,
    record_start,
    save_checkpoint,
    save_policy,
    strict_json,
    writer_lock,
)
from sidewalk.snapshot import capture_env, capture_rng, restore_env, restore_rng
from sidewalk.stops import LearnerDiverged, RunInterrupted, StopSignals, divergence
from sidewalk.views import view_for_opponent

EVAL_SEED_OFFSET = 1_000_003  # evaluation worlds draw from a stream of their own, the same at every evaluation
# The absolute metric (Colas et al. 2018, marl-eval): the best evaluation's policy played on ten times the episodes,
# in worlds of a stream of their own.
ABSOLUTE_EPISODES = 10
ABSOLUTE_SEED_OFFSET = 2_000_003
WALL_CLOCK_COLUMNS = ("time_s", "frames_per_s")


def make_view(experiment: Experiment, num_envs: int, seed: int, env_params: Any = None) -> EnvBase:
    """The env a learner trains or is evaluated on: the core env of ``num_envs`` worlds (``env_params``, by default
    the training worlds') seen through the experiment's view (``sidewalk.views.view_for_opponent``: ego against a
    scripted opponent or a learned partner, centralized, or self-play)."""
    core_cls = DiscreteSidewalkEnv if experiment.domain == "discrete" else ContinuousSidewalkEnv
    params = experiment.env_params if env_params is None else env_params
    core = core_cls(num_envs, device=experiment.device, seed=seed, params=params)
    return view_for_opponent(
        core, experiment.opponent, experiment.ego, shield=experiment.shield,
        end_on_ego_done=experiment.end_on_ego_done, opponent_kwargs=experiment.opponent_params,
        other_play=experiment.other_play,
    )


def make_eval_view(experiment: Experiment, seed: int | None = None) -> EnvBase:
    """The env an evaluation plays: ``eval_episodes`` worlds drawn as the experiment's evaluation protocol says
    (``Experiment.eval_env_params``), seeded from the evaluation's own stream (``seed``: the experiment's)."""
    seed = experiment.seed if seed is None else seed
    return make_view(experiment, experiment.eval_episodes, seed + EVAL_SEED_OFFSET, env_params=experiment.eval_env_params)


def collector_frames_per_batch(experiment: Experiment) -> int:
    """Frames of one iteration: the learner's ``frames_per_batch`` rounded up to whole steps of every world,
    as TorchRL's collector rounds it."""
    return math.ceil(experiment.algo.frames_per_batch / experiment.num_envs) * experiment.num_envs


# ---- the trial --------------------------------------------------------------------------------------------------


@dataclass
class Parts:
    """What one trial is made of, built from its experiment in the order data flows through them."""

    train_env: TransformedEnv
    eval_env: EnvBase
    algo: Algorithm
    collector: Collector
    replay_buffer: TensorDictReplayBuffer | None
    logger: Any
    frames_per_batch: int
    ego: int | None  # the learner's agent in an ego view; None where it plays every agent


class Trial:
    """Train one learner with one seed and write its run folder (see the module docstring)."""

    def __init__(self, experiment: Experiment, run_dir: str | Path, config: dict | None = None) -> None:
        """``config``: the resolved config to write as ``config.yaml`` (and check a resume against); without it
        the folder gets no ``config.yaml`` or ``history.jsonl`` (benchmarks' throwaway runs)."""
        self.experiment = experiment
        self.run_dir = Path(run_dir)
        self.config = config or {}

    def run(
        self,
        progress: bool = True,
        on_evaluation: Callable[[dict[str, float], float, float], bool] | None = None,
    ) -> dict[str, float]:
        """Train, evaluate and write the run folder, holding its writer lock; return the summary.

        ``on_evaluation(metrics, started, ended)`` is called after each periodic evaluation with its metrics and
        its ``time.perf_counter()`` bounds; returning True ends training there (the run folder is completed as
        usual, with the iterations actually run).
        """
        with writer_lock(self.run_dir):
            revision = git_revision()  # the code this process loaded, not what the checkout holds when it ends
            self._seed()
            parts = self._build()
            state = self._start(parts)
            bar = tqdm(total=self.experiment.iterations, initial=state.iteration, disable=not progress,
                       desc="train", unit="it")
            with StopSignals() as signals:
                for batch in parts.collector:
                    row, stop = self._iteration(parts, state, batch, on_evaluation)
                    self._progress(bar, row)
                    if self._after_iteration(parts, state, stop, signals, bar):
                        break
            bar.close()
            return self._finish(parts, state, revision)

    def _seed(self) -> None:
        exp = self.experiment
        torch.set_num_threads(exp.torch_threads)  # small networks: one thread beats contention on 2 cores
        torch.manual_seed(exp.seed)
        np.random.seed(exp.seed)
        random.seed(exp.seed)
        self.run_dir.mkdir(parents=True, exist_ok=True)

    def _build(self) -> Parts:
        """env → view → learner → collector → replay buffer → logger."""
        exp = self.experiment
        train_env = TransformedEnv(make_view(exp, exp.num_envs, exp.seed), RewardSum())
        eval_env = make_eval_view(exp)
        algo: Algorithm = ALGORITHMS[exp.algo.name](exp.algo, train_env, device=exp.device)
        frames_per_batch = collector_frames_per_batch(exp)
        collector = Collector(
            train_env,
            algo.collection_policy(),
            frames_per_batch=frames_per_batch,
            total_frames=frames_per_batch * exp.iterations,
            device=exp.device,
            auto_register_policy_transforms=False,
        )
        replay_buffer = None
        if algo.uses_replay_buffer:
            replay_buffer = TensorDictReplayBuffer(
                storage=LazyTensorStorage(exp.algo.buffer_size, device=exp.device), batch_size=exp.algo.batch_size
            )
        return Parts(train_env, eval_env, algo, collector, replay_buffer, make_logger(exp, self.run_dir),
                     frames_per_batch, getattr(train_env.base_env, "ego", None))

    def _start(self, parts: Parts) -> Progress:
        """A fresh start, or (``resume=true``) every state the checkpoint holds put back, metrics rewound to it."""
        exp = self.experiment
        state = Progress()
        elapsed_before = 0.0
        if exp.resume:
            saved = load_checkpoint(self.run_dir, map_location=exp.device)
            parts.algo.load_state_dict(saved["algorithm"])
            if parts.replay_buffer is not None:
                parts.replay_buffer.load_state_dict(saved["replay_buffer"])
            restore_env(parts.train_env.base_env, saved["env"])
            restore_collector_state(parts.collector, saved)
            restore_rng(saved["rng"])
            state.rows, state.iteration, elapsed_before = saved["rows"], saved["iteration"], saved["elapsed_s"]
            state.load_best_state(saved.get("best"))
        if self.config:  # from runners/main.py: the folder records the config and this start
            record_start(self.run_dir, self.config, exp.resume)
        if exp.resume:
            self._write_metrics(state.rows)
        state.started = time.perf_counter() - elapsed_before
        state.last_write = time.perf_counter()
        return state

    def _iteration(
        self, parts: Parts, state: Progress, batch: TensorDictBase,
        on_evaluation: Callable[[dict[str, float], float, float], bool] | None,
    ) -> tuple[dict[str, float], bool]:
        """One update on a collected batch, its metrics row (with an evaluation when one is due), logged; returns
        the row and whether ``on_evaluation`` asked to stop."""
        logs = parts.algo.update(batch, parts.replay_buffer)
        parts.collector.update_policy_weights_()
        return self._record(parts, state, batch, logs, on_evaluation)

    def _record(
        self, parts: Parts, state: Progress, batch: TensorDictBase, update_logs: dict[str, float],
        on_evaluation: Callable[[dict[str, float], float, float], bool] | None = None,
    ) -> tuple[dict[str, float], bool]:
        """The metrics row of an iteration whose update returned ``update_logs`` (checked finite first), with an
        evaluation when one is due, logged; returns the row and whether ``on_evaluation`` asked to stop."""
        exp, algo = self.experiment, parts.algo
        logs = {f"train/{key}": value for key, value in update_logs.items()}
        self._check_finite(algo, logs, state)
        state.iteration += 1
        row: dict[str, float] = {"iteration": state.iteration, "frames": state.iteration * parts.frames_per_batch}
        row.update(train_metrics(batch, parts.ego))
        previous_cost = state.rows[-1].get("train/cumulative_cost", 0.0) if state.rows else 0.0
        row["train/cumulative_cost"] = previous_cost + row["train/cost"]
        row.update(logs)
        stop = False
        if exp.eval_every and (state.iteration % exp.eval_every == 0 or state.iteration == exp.iterations):
            rng = capture_rng()  # evaluation must not shift the training stream
            eval_started = time.perf_counter()
            metrics = evaluate(parts.eval_env, algo.evaluation_policy(), seed=exp.seed + EVAL_SEED_OFFSET)
            eval_ended = time.perf_counter()
            restore_rng(rng)
            state.keep_if_best(metrics, lambda: self._policy_state(algo))
            row.update({f"eval/{key}": value for key, value in metrics.items()})
            stop = on_evaluation is not None and bool(on_evaluation(metrics, eval_started, eval_ended))
        elapsed = state.elapsed()
        row["time_s"] = elapsed
        row["frames_per_s"] = row["frames"] / max(elapsed, 1e-9)
        state.rows.append(row)
        if parts.logger is not None:
            for key, value in row.items():
                if key != "iteration" and isinstance(value, float) and math.isfinite(value):
                    parts.logger.log_scalar(key, value, step=int(row["frames"]))
        return row, stop

    def _check_finite(self, algo: Algorithm, logs: dict[str, float], state: Progress) -> None:
        """Stop before anything is written from an update whose loss or parameters turned non-finite."""
        diverged = divergence(algo, logs)
        if diverged is None:
            return
        self._write_metrics(state.rows)
        self._history("diverged", iteration=state.iteration + 1, non_finite=diverged)
        raise LearnerDiverged(
            f"the learner diverged at iteration {state.iteration + 1}: non-finite {diverged}. The run stopped; "
            f"{self.run_dir} keeps its last checkpoint and metrics up to iteration {state.iteration} "
            "(try a lower algo.lr or algo.max_grad_norm, or another seed)"
        )

    def _after_iteration(self, parts: Parts, state: Progress, stop: bool, signals: StopSignals, bar: tqdm) -> bool:
        """Checkpoint and write metrics when due; leave on a signal (``RunInterrupted``); True when training is done."""
        done, interrupted, checkpoint, metrics = state.due(self.experiment, stop, signals)
        if checkpoint:
            self._checkpoint(parts, state, state.elapsed())
        if metrics:
            self._write_metrics(state.rows)
            state.last_write = time.perf_counter()
        if interrupted:
            bar.close()
            parts.collector.shutdown()
            self._history("interrupted", iteration=state.iteration, signal=signal.Signals(signals.received).name)
            raise RunInterrupted(signals.received, state.iteration, self.run_dir)
        return done

    def _checkpoint(self, parts: Parts, state: Progress, elapsed: float) -> None:
        saved = {
            "iteration": state.iteration,
            "elapsed_s": elapsed,
            "algorithm": parts.algo.state_dict(),
            "replay_buffer": parts.replay_buffer.state_dict() if parts.replay_buffer is not None else None,
            "env": capture_env(parts.train_env.base_env),
            **collector_state(parts.collector),
            "rng": capture_rng(),
            "rows": state.rows,
            "best": state.best_state(),
        }
        save_checkpoint(self.run_dir, saved)
        save_policy(self.run_dir, self._policy_state(parts.algo))  # a partner can play the run while it trains

    def _finish(self, parts: Parts, state: Progress, revision: str) -> dict[str, Any]:
        """The last checkpoint (``keep_checkpoint=all``), ``policy.pt`` and ``summary.json`` from the final evaluation."""
        exp = self.experiment
        if exp.keep_checkpoint == "all":
            self._checkpoint(parts, state, state.elapsed())
        parts.collector.shutdown()
        summary = self._conclude(parts, state, revision)
        if exp.keep_checkpoint == "final":  # the replay buffer and optimiser state are gigabytes over a sweep
            drop_training_state(self.run_dir)
        self._history("finished", iteration=state.iteration)
        return summary

    def _conclude(self, parts: Parts, state: Progress, revision: str) -> dict[str, Any]:
        """Write ``policy.pt`` and ``summary.json`` (the last evaluation's metrics, or a final one); return the summary."""
        exp, iteration = self.experiment, state.iteration
        save_policy(self.run_dir, self._policy_state(parts.algo))
        rows = state.rows
        last_eval = {key[len("eval/"):]: value for key, value in rows[-1].items() if key.startswith("eval/")}
        final = last_eval
        if not final:  # no periodic evaluation (eval_every=0): the final one is also the best
            final = evaluate(parts.eval_env, parts.algo.evaluation_policy(), seed=exp.seed + EVAL_SEED_OFFSET)
            state.keep_if_best(final, lambda: self._policy_state(parts.algo))
        training_cost = rows[-1].get("train/cumulative_cost", 0.0) if rows else 0.0
        frames = iteration * parts.frames_per_batch
        wall_clock_s = state.elapsed()
        summary = {
            **final,
            "seed": exp.seed,
            "eval_protocol": exp.protocol_summary(),
            "absolute": self._absolute(parts, state.best),
            "iterations": iteration,
            "frames": frames,
            # Safety Gym's third figure: the cost paid over all of training per frame (world-step) collected.
            "train_cost": training_cost,
            "cost_rate": training_cost / max(frames, 1),
            "wall_clock_s": wall_clock_s,
            "versions": package_versions(),
            "git_revision": revision,
        }
        atomic_write(self.run_dir / SUMMARY, lambda tmp: tmp.write_text(json.dumps(strict_json(summary), indent=2,
                                                                                      default=str)))
        return summary

    def _absolute(self, parts: Parts, best: Best | None) -> dict[str, Any] | None:
        """The best evaluation's policy (``policy.best.pt``) on ``ABSOLUTE_EPISODES`` times the evaluation's episodes,
        worlds of their own stream; None without an evaluation. Once training is over: it loads that policy."""
        if best is None:
            return None
        exp = self.experiment
        save_policy(self.run_dir, best.policy, BEST_POLICY)
        parts.algo.load_policy_state_dict(best.policy)
        seed = exp.seed + ABSOLUTE_SEED_OFFSET
        env = make_view(exp, ABSOLUTE_EPISODES * exp.eval_episodes, seed, env_params=exp.eval_env_params)
        metrics = evaluate(env, parts.algo.evaluation_policy(), seed=seed)
        return {"iteration": best.iteration, "frames": best.iteration * parts.frames_per_batch, **metrics}

    def _policy_state(self, algo: Algorithm) -> dict[str, Any]:
        """``policy.pt``: the networks and the description of the world they learned in, all a partner needs."""
        return {**algo.policy_state_dict(), "description": policy_description(self.experiment)}

    def _history(self, event: str, **details: Any) -> None:
        if self.config:
            append_history(self.run_dir, event, **details)

    def _write_metrics(self, rows: list[dict[str, float]]) -> None:
        frame = pd.DataFrame(rows)
        first = [c for c in ("iteration", "frames", *WALL_CLOCK_COLUMNS) if c in frame.columns]
        frame = frame[first + sorted(c for c in frame.columns if c not in first)]
        atomic_write(self.run_dir / METRICS, lambda tmp: frame.to_csv(tmp, index=False))

    @staticmethod
    def _progress(bar: tqdm, row: dict[str, float]) -> None:
        postfix = {"frames": int(row["frames"])}
        for key, label in (
            ("train/ego_success_rate", "train_success"), ("train/team_success_rate", "team_success"),
            ("train/return", "return"), ("eval/ego/success_rate", "eval_success"),
        ):
            if key in row and not (key == "train/team_success_rate" and "train/ego_success_rate" in row):
                postfix[label] = f"{row[key]:.2f}"
        bar.set_postfix(postfix, refresh=False)
        bar.update(1)

