"""One trial: env → view → learner → collector → replay buffer → logger, trained, evaluated and checkpointed.

``Trial(experiment, run_dir).run()`` reads top to bottom in ``run``. A run folder holds:

- ``config.yaml`` and ``history.jsonl``: the resolved config and the run's events (``sidewalk.run_folder``);
- ``metrics.csv``: one row per iteration (frames, wall clock, train metrics, eval metrics at eval iterations);
- ``summary.json``: the final evaluation (``sidewalk.evaluate``'s keys), seed, protocol, absolute metric (the best
  evaluation's policy, ``policy.best.pt``, played on ten times the episodes), wall clock, versions, revision;
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

import contextlib
import dataclasses
import json
import math
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase, RewardSum, TransformedEnv
from tqdm import tqdm

from sidewalk.config import Experiment
from sidewalk.evaluate import evaluate, train_metrics
from sidewalk.loggers import make_logger
from sidewalk.progress import Progress
from sidewalk.registry import LEARNERS
from sidewalk.replica_learners import ReplicaSet
from sidewalk.run_folder import (
    BEST_POLICY,
    SUMMARY,
    append_history,
    atomic_write,
    drop_training_state,
    git_revision,
    has_checkpoint,
    package_versions,
    policy_description,
    save_policy,
    strict_json,
    writer_lock,
)
from sidewalk.snapshot import capture_rng, restore_rng
from sidewalk.stops import LearnerDiverged, RunInterrupted, StopSignals
from sidewalk.streams import seed_globals
from sidewalk.trial_state import (
    Parts,
    SeedRun,
    record_starts,
    replica_config,
    restore_trial,
    save_trial,
    seed_dirs,
    show_progress,
    state_dir,
)

EVAL_SEED_OFFSET = 1_000_003  # evaluation worlds draw from a stream of their own, the same at every evaluation
# The absolute metric (Colas et al. 2018, marl-eval): the best evaluation's policy played on ten times the episodes,
# in worlds of a stream of their own.
ABSOLUTE_EPISODES = 10
ABSOLUTE_SEED_OFFSET = 2_000_003


def make_eval_view(experiment: Experiment, seed: int | None = None, worlds: int | None = None) -> EnvBase:
    """The env an evaluation plays: ``eval_episodes`` (or ``worlds``) worlds drawn as its protocol says
    (``Experiment.eval_world.env_params``), seeded from the evaluation's own stream (``seed``: the experiment's)."""
    seed = experiment.seed if seed is None else seed
    worlds = experiment.eval_episodes if worlds is None else worlds
    return experiment.eval_world.make(worlds, seed + EVAL_SEED_OFFSET, experiment.device)


def collector_frames_per_batch(experiment: Experiment) -> int:
    """Frames of one iteration: the learner's ``frames_per_batch`` rounded up to whole steps of every world,
    as TorchRL's collector rounds it."""
    return math.ceil(experiment.algo.frames_per_batch / experiment.num_envs) * experiment.num_envs


# ---- the trial --------------------------------------------------------------------------------------------------


class Trial:
    """Train a learner on ``experiment.replicas`` seeds (``seed``, ``seed+1``, ...) and write a run folder per seed
    (see the module docstring): one seed writes ``run_dir``; several write ``run_dir/seed<S>/`` each and keep their
    one checkpoint in ``run_dir/.group/``. Their worlds live in one env and one collector gathers them; the learner
    trains them as one (``sidewalk.algos.replicas``)."""

    def __init__(self, experiment: Experiment, run_dir: str | Path, config: dict | None = None,
                 continue_command: str | None = None) -> None:
        """``config``: the resolved config to write as ``config.yaml`` (and check a resume against); without it
        the folders get no ``config.yaml`` or ``history.jsonl`` (benchmarks' throwaway runs). ``continue_command``:
        the command line that continues the trial, which an interruption prints."""
        self.experiment = experiment
        self.run_dir = Path(run_dir)
        self.config = config or {}
        self.continue_command = continue_command
        self.seeds = [experiment.seed + replica for replica in range(experiment.replicas)]
        self.state_dir = state_dir(self.run_dir, experiment)
        self.seed_dirs = seed_dirs(self.run_dir, experiment)

    def run(
        self,
        progress: bool = True,
        on_evaluation: Callable[[dict[str, float], float, float], bool] | None = None,
        absolute_metric: bool = True,
    ) -> list[dict[str, Any]]:
        """Train, evaluate and write the run folders, holding their writer locks; return their summaries, one per
        seed (one seed alone: a list of one).

        ``on_evaluation(metrics, started, ended)`` is called after each periodic evaluation with its metrics and
        its ``time.perf_counter()`` bounds; returning True ends training there (the run folder is completed as
        usual, with the iterations actually run). ``absolute_metric=False`` leaves ``summary.json``'s ``absolute``
        None, without its ten-fold evaluation (the reference probes compare ``metrics.csv`` alone).
        """
        with contextlib.ExitStack() as locks:
            for folder in self._folders():
                folder.mkdir(parents=True, exist_ok=True)
                locks.enter_context(writer_lock(folder))
            revision = git_revision()  # the code this process loaded, not what the checkout holds when it ends
            self._seed()
            parts = self._build()
            self._start(parts)
            first = parts.runs[0].state
            bar = tqdm(total=self.experiment.iterations, initial=first.iteration, disable=not progress, unit="it",
                       desc="train" if len(self.seeds) == 1 else f"train ×{len(self.seeds)}")
            with StopSignals(self.continue_command) as signals:
                signals.finishing = first.iteration + 1 >= self.experiment.iterations  # before the last batch
                for batch in parts.collector:
                    rows, stop = self._iteration(parts, batch, on_evaluation)
                    show_progress(bar, rows)
                    if self._after_iteration(parts, stop, signals, bar):
                        break
                    signals.finishing = first.iteration + 1 >= self.experiment.iterations
                bar.close()
                signals.finishing = True
                summaries = self._finish(parts, revision, absolute_metric, progress)
            return summaries

    def _folders(self) -> list[Path]:
        return list(dict.fromkeys([self.state_dir, *self.seed_dirs]))  # one seed: its folder holds the state too

    def _seed(self) -> None:
        exp = self.experiment
        torch.set_num_threads(exp.torch_threads)  # small networks: one thread beats contention on 2 cores
        seed_globals(exp.seed, exp.device)

    def _build(self) -> Parts:
        """env → view → learner → collector → replay buffer → logger."""
        exp, count = self.experiment, len(self.seeds)
        train_env = TransformedEnv(exp.world.make(count * exp.num_envs, self.seeds if count > 1 else exp.seed, exp.device),
                                   RewardSum())
        runs = []  # evaluation envs before the learner, as a lone run has always drawn them
        for seed, run_dir in zip(self.seeds, self.seed_dirs):
            alone = dataclasses.replace(exp, seed=seed, replicas=1)
            config = (self.config if count == 1 else replica_config(self.config, seed)) if self.config else {}
            runs.append(SeedRun(alone, run_dir, config, make_eval_view(alone), None, Progress()))
        learners = ReplicaSet(LEARNERS[exp.algo.name], exp.algo, train_env, exp.device, self.seeds)
        frames_per_batch = collector_frames_per_batch(exp)
        collector = Collector(
            train_env,
            learners.collection_policy(),
            frames_per_batch=count * frames_per_batch,
            total_frames=count * frames_per_batch * exp.iterations,
            device=exp.device,
            auto_register_policy_transforms=False,
        )
        buffers = 1 if len(learners.algos) == 1 else count
        replay_buffers = [
            TensorDictReplayBuffer(storage=LazyTensorStorage(exp.algo.buffer_size, device=exp.device),
                                   batch_size=exp.algo.batch_size) if learners.uses_replay_buffer else None
            for _ in range(buffers)
        ]
        for run in runs:
            run.logger = make_logger(run.experiment, run.run_dir)
        return Parts(train_env, learners, collector, replay_buffers, runs, frames_per_batch,
                     getattr(train_env.base_env, "ego", None))

    def _start(self, parts: Parts) -> None:
        """A fresh start, or (``resume=true``) every state the checkpoint holds put back, metrics rewound to it (a run
        stopped before its first checkpoint trains again from the start)."""
        exp = self.experiment
        restored = exp.resume and has_checkpoint(self.state_dir)
        elapsed_before = restore_trial(parts, self.state_dir, exp.device) if restored else 0.0
        if self.config:  # from runners/main.py: the folders record the config and this start
            record_starts(self.run_dir, self.config, parts.runs, self.experiment.resume)
        started = time.perf_counter() - elapsed_before
        for run in parts.runs:
            if restored:
                run.write_metrics()
            run.state.started, run.state.last_write = started, time.perf_counter()

    def _iteration(
        self, parts: Parts, batch: TensorDictBase,
        on_evaluation: Callable[[dict[str, float], float, float], bool] | None,
    ) -> tuple[list[dict[str, float]], bool]:
        """Every seed's update on its block of the collected batch, then its metrics row (with an evaluation when
        one is due), logged; returns the rows and whether ``on_evaluation`` asked every seed to stop."""
        logs = parts.learners.update(batch, parts.replay_buffers)
        parts.collector.update_policy_weights_()
        blocks = batch.split(len(batch) // len(parts.runs))
        rows, stops = [], []
        for replica, (run, block, update_logs) in enumerate(zip(parts.runs, blocks, logs)):
            with parts.learners.use(replica):
                row, stop = self._record(parts, replica, block, update_logs, on_evaluation)
            rows.append(row)
            stops.append(stop)
        return rows, all(stops)

    def _record(
        self, parts: Parts, replica: int, batch: TensorDictBase, update_logs: dict[str, float],
        on_evaluation: Callable[[dict[str, float], float, float], bool] | None = None,
    ) -> tuple[dict[str, float], bool]:
        """Seed ``replica``'s metrics row of an iteration whose update returned ``update_logs`` (checked finite
        first), with an evaluation when one is due, logged; returns the row and whether ``on_evaluation`` asked to
        stop."""
        run = parts.runs[replica]
        exp, state = run.experiment, run.state
        logs = {f"train/{key}": value for key, value in update_logs.items()}
        self._check_finite(parts, replica, logs)
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
            learner = parts.learners.learner(replica)
            metrics = evaluate(run.eval_env, learner.evaluation_policy(), seed=exp.seed + EVAL_SEED_OFFSET,
                               one_world=lambda: make_eval_view(exp, worlds=1), epsilon=exp.evaluation.epsilon)
            eval_ended = time.perf_counter()
            restore_rng(rng)
            state.keep_if_best(metrics, lambda: self._policy_state(parts, replica))
            row.update({f"eval/{key}": value for key, value in metrics.items()})
            stop = on_evaluation is not None and bool(on_evaluation(metrics, eval_started, eval_ended))
        elapsed = state.elapsed()
        row["time_s"] = elapsed
        row["frames_per_s"] = row["frames"] / max(elapsed, 1e-9)
        state.rows.append(row)
        if run.logger is not None:
            for key, value in row.items():
                if key != "iteration" and isinstance(value, float) and math.isfinite(value):
                    run.logger.log_scalar(key, value, step=int(row["frames"]))
        return row, stop

    def _check_finite(self, parts: Parts, replica: int, logs: dict[str, float]) -> None:
        """Stop before anything is written from an update whose loss or parameters turned non-finite."""
        diverged = parts.learners.divergence(replica, logs)
        if diverged is None:
            return
        run = parts.runs[replica]
        run.write_metrics()
        run.history("diverged", iteration=run.state.iteration + 1, non_finite=diverged)
        raise LearnerDiverged(
            f"the learner diverged at iteration {run.state.iteration + 1}: non-finite {diverged}. The run stopped; "
            f"{run.run_dir} keeps its last checkpoint and metrics up to iteration {run.state.iteration} "
            "(try a lower algo.lr or algo.max_grad_norm, or another seed)"
        )

    def _after_iteration(self, parts: Parts, stop: bool, signals: StopSignals, bar: tqdm) -> bool:
        """Checkpoint and write metrics when due; leave on a signal (``RunInterrupted``); True when training is done."""
        state = parts.runs[0].state
        done, interrupted, checkpoint, metrics = state.due(self.experiment, stop, signals)
        if checkpoint:
            self._checkpoint(parts)
        if metrics:
            for run in parts.runs:
                run.write_metrics()
                run.state.last_write = time.perf_counter()
        if interrupted:
            bar.close()
            parts.collector.shutdown()
            stopped = {"iteration": state.iteration, "signal": signal.Signals(signals.received).name}
            if len(parts.runs) > 1 and self.config:
                append_history(self.state_dir, "interrupted", **stopped)
            for run in parts.runs:
                run.history("interrupted", **stopped)
            raise RunInterrupted(signals.received, state.iteration, self.run_dir, self.continue_command)
        return done

    def _checkpoint(self, parts: Parts) -> None:
        """One file for every seed (they share one env and one collector), then each seed's ``policy.pt``, so a
        partner can play the run while it trains."""
        save_trial(parts, self.state_dir)
        for replica, run in enumerate(parts.runs):
            save_policy(run.run_dir, self._policy_state(parts, replica))

    def _finish(self, parts: Parts, revision: str, absolute_metric: bool, progress: bool) -> list[dict[str, Any]]:
        """The last checkpoint (``keep_checkpoint=all``), then each seed's ``policy.pt`` and ``summary.json``."""
        exp = self.experiment
        if exp.keep_checkpoint == "all":
            self._checkpoint(parts)
        parts.collector.shutdown()
        summaries = []
        for replica, run in enumerate(parts.runs):
            with parts.learners.use(replica):
                summaries.append(self._conclude(parts, replica, revision, absolute_metric, progress))
            run.history("finished", iteration=run.state.iteration)
        if exp.keep_checkpoint == "final":  # the replay buffer and optimiser state are gigabytes over a sweep
            drop_training_state(self.state_dir)
        if len(parts.runs) > 1 and self.config:
            append_history(self.state_dir, "finished", iteration=parts.runs[0].state.iteration)
        return summaries

    def _conclude(self, parts: Parts, replica: int, revision: str, absolute_metric: bool, progress: bool) -> dict:
        """Write a seed's ``policy.pt`` and ``summary.json`` (the last evaluation's metrics, or a final one)."""
        run = parts.runs[replica]
        exp, state = run.experiment, run.state
        save_policy(run.run_dir, self._policy_state(parts, replica))
        rows = state.rows
        final = {key[len("eval/"):]: value for key, value in rows[-1].items() if key.startswith("eval/")}
        if not final:  # no periodic evaluation (eval_every=0): the final one is also the best
            learner = parts.learners.learner(replica)
            final = evaluate(run.eval_env, learner.evaluation_policy(), seed=exp.seed + EVAL_SEED_OFFSET,
                             one_world=lambda: make_eval_view(exp, worlds=1), epsilon=exp.evaluation.epsilon)
            state.keep_if_best(final, lambda: self._policy_state(parts, replica))
        training_cost = rows[-1].get("train/cumulative_cost", 0.0) if rows else 0.0
        frames = state.iteration * parts.frames_per_batch
        summary = {
            **final,
            "seed": exp.seed,
            "eval_protocol": exp.protocol_summary(),
            "absolute": self._absolute(parts, replica, progress) if absolute_metric else None,
            "iterations": state.iteration,
            "frames": frames,
            # Safety Gym's third figure: the cost paid over all of training per frame (world-step) collected.
            "train_cost": training_cost,
            "cost_rate": training_cost / max(frames, 1),
            "wall_clock_s": state.elapsed(),
            "versions": package_versions(),
            "git_revision": revision,
        }
        atomic_write(run.run_dir / SUMMARY, lambda tmp: tmp.write_text(json.dumps(strict_json(summary), indent=2,
                                                                                          default=str)))
        return summary

    def _absolute(self, parts: Parts, replica: int, progress: bool) -> dict[str, Any] | None:
        """The best evaluation's policy (``policy.best.pt``) on ``ABSOLUTE_EPISODES`` times the evaluation's episodes,
        worlds of their own stream; None without an evaluation. Once training is over: it loads that policy."""
        run = parts.runs[replica]
        best = run.state.best
        if best is None:
            return None
        exp = run.experiment
        if progress:  # the one long step after the bar (2,560 worlds by default): say what it is
            print(f"{f'seed {exp.seed}: ' * (len(parts.runs) > 1)}absolute metric: the best evaluation's policy "
                  f"(iteration {best.iteration}) on {ABSOLUTE_EPISODES * exp.eval_episodes:,} worlds...", file=sys.stderr)
        save_policy(run.run_dir, best.policy, BEST_POLICY)
        learner = parts.learners.learner(replica)
        learner.load_policy_state_dict(best.policy)
        seed = exp.seed + ABSOLUTE_SEED_OFFSET
        env = exp.eval_world.make(ABSOLUTE_EPISODES * exp.eval_episodes, seed, exp.device)
        metrics = evaluate(env, learner.evaluation_policy(), seed=seed,
                           one_world=lambda: exp.eval_world.make(1, seed, exp.device), epsilon=exp.evaluation.epsilon)
        return {"iteration": best.iteration, "frames": best.iteration * parts.frames_per_batch, **metrics}

    def _policy_state(self, parts: Parts, replica: int) -> dict[str, Any]:
        """``policy.pt``: the networks and the description of the world they learned in, all a partner needs."""
        experiment = parts.runs[replica].experiment
        description = policy_description(experiment.algo, experiment.world)
        return {**parts.learners.policy_state(replica), "description": description}
