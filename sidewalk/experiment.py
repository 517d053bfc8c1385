"""One trial: env → view → learner → collector → replay buffer → logger, trained, evaluated and checkpointed.

``Trial(experiment, run_dir).run()`` reads top to bottom in ``run``. A run folder holds:

- ``config.yaml`` and ``history.jsonl``: the resolved config and the run's events (``sidewalk.run_folder``);
- ``metrics.csv``: one row per iteration (frames, wall clock, train metrics, eval metrics at eval iterations);
- ``summary.json``: the final evaluation as flat SPEC §6 keys plus seed, wall clock, versions, git revision;
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
once (the process dies of SIGINT), which atomic writes make safe for the folder; a learner whose loss or parameters turn non-finite stops the
run before anything is written from it (``LearnerDiverged``), so the last checkpoint is the last good state.
"""

from __future__ import annotations

import json
import math
import os
import platform
import random
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Self

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase, RewardSum, TransformedEnv
from tqdm import tqdm

from sidewalk.algos import ALGORITHMS
from sidewalk.algos.base import Algorithm
from sidewalk.config import Experiment
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate
from sidewalk.opponents.policy import policy_description
from sidewalk.run_folder import (
    METRICS,
    SUMMARY,
    append_history,
    atomic_write,
    drop_training_state,
    git_revision,
    load_checkpoint,
    record_start,
    save_checkpoint,
    save_policy,
    writer_lock,
)
from sidewalk.views import CentralizedView, EgoView, SelfPlayView

EVAL_SEED_OFFSET = 1_000_003  # evaluation worlds draw from a stream of their own, the same at every evaluation
WALL_CLOCK_COLUMNS = ("time_s", "frames_per_s")


def make_view(experiment: Experiment, num_envs: int, seed: int) -> EnvBase:
    """The env a learner trains or is evaluated on: the core env of ``num_envs`` worlds seen through the
    experiment's view (ego against a scripted opponent or a learned partner, centralized, or self-play)."""
    core_cls = DiscreteSidewalkEnv if experiment.domain == "discrete" else ContinuousSidewalkEnv
    core = core_cls(num_envs, device=experiment.device, seed=seed, params=experiment.env_params)
    if experiment.opponent == "centralized":
        return CentralizedView(core, shield=experiment.shield)
    if experiment.opponent == "self":
        return SelfPlayView(core, shield=experiment.shield, other_play=experiment.other_play)
    return EgoView(
        core,
        opponent=experiment.opponent,
        ego=experiment.ego,
        end_on_ego_done=experiment.end_on_ego_done,
        opponent_kwargs=experiment.opponent_params,
        shield=experiment.shield,
    )


def collector_frames_per_batch(experiment: Experiment) -> int:
    """Frames of one iteration: the learner's ``frames_per_batch`` rounded up to whole steps of every world,
    as TorchRL's collector rounds it."""
    return math.ceil(experiment.algo.frames_per_batch / experiment.num_envs) * experiment.num_envs


def package_versions() -> dict[str, str]:
    import tensordict
    import torchrl

    import sidewalk

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "torchrl": torchrl.__version__,
        "tensordict": tensordict.__version__,
        "sidewalk": sidewalk.__version__,
    }


# ---- exact state of a running trial -----------------------------------------------------------------------------


def _tensor_attributes(obj: Any) -> dict[str, Any]:
    """An object's tensor, tensordict and dict-of-tensor attributes, plus its ``None`` ones (unset memories)."""
    state = {}
    for name, value in vars(obj).items():
        if isinstance(value, (torch.Tensor, TensorDictBase)) or (value is None and name.startswith("_")):
            state[name] = value
        elif isinstance(value, dict) and value and all(isinstance(v, torch.Tensor) for v in value.values()):
            state[name] = dict(value)
    return state


def capture_env(view: EnvBase) -> dict[str, Any]:
    """The running state of a view, its core env and its opponent: every world mid-episode, the generator."""
    core = view.core
    state = {"view": _tensor_attributes(view), "core": _tensor_attributes(core), "rng": core.generator.get_state()}
    if getattr(view, "opponent", None) is not None:
        state["opponent"] = _tensor_attributes(view.opponent)
    return state


def restore_env(view: EnvBase, state: dict[str, Any]) -> None:
    for name, value in state["view"].items():
        setattr(view, name, value)
    for name, value in state["core"].items():
        setattr(view.core, name, value)
    for name, value in state.get("opponent", {}).items():
        setattr(view.opponent, name, value)
    view.core.generator.set_state(state["rng"])


def capture_rng() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def restore_rng(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


# ---- logging ----------------------------------------------------------------------------------------------------


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


def train_metrics(batch: TensorDictBase, ego: int | None) -> dict[str, float]:
    """Outcomes of the episodes that ended inside one collected batch, and the safety cost the learner paid in it.

    ``train/cost`` counts every step of the batch, finished episodes or not: the cost the learner's agents (the ego
    in an ego view, every agent otherwise) paid while learning -- the numerator of Safety Gym's training cost rate.
    """
    cost = batch.get(("next", "world", "cost"))  # (..., N, 1)
    learner_cost = cost.select(-2, ego) if ego is not None else cost
    done = batch.get(("next", "done")).squeeze(-1)
    episodes = int(done.sum())
    metrics: dict[str, float] = {"train/episodes": float(episodes), "train/cost": float(learner_cost.sum())}
    shielded = batch.get(("next", "world", "shield"), None)
    if shielded is not None:  # shield=true: the fraction of the learner's steps whose action the shield replaced
        learner_shielded = shielded.select(-2, ego) if ego is not None else shielded
        metrics["train/shield_rate"] = float(learner_shielded.float().mean())
    if episodes == 0:
        return metrics
    reached = batch.get(("next", "world", "info", "reached_goal")).squeeze(-1)[done]  # (episodes, N)
    collided = (
        batch.get(("next", "world", "info", "collided_agent")) | batch.get(("next", "world", "info", "collided_wall"))
    ).squeeze(-1)[done]
    episode_reward = batch.get(("next", "episode_reward"), None)
    if episode_reward is None:  # self-play: every agent's own return, averaged over the agents
        episode_reward = batch.get(("next", "agents", "episode_reward")).mean(-2)
    metrics["train/return"] = float(episode_reward.squeeze(-1)[done].mean())
    metrics["train/success_rate"] = float(reached.float().mean())
    metrics["train/team_success_rate"] = float(reached.all(-1).float().mean())
    if ego is not None:
        metrics["train/ego_success_rate"] = float(reached[:, ego].float().mean())
        metrics["train/ego_collision_rate"] = float(collided[:, ego].float().mean())
    return metrics


# ---- stopping early -------------------------------------------------------------------------------------------


class RunInterrupted(Exception):
    """SIGTERM, SIGUSR1 or SIGINT arrived; the run wrote a checkpoint at the end of ``iteration`` and stopped."""

    def __init__(self, signum: int, iteration: int, run_dir: Path) -> None:
        self.signum, self.iteration = signum, iteration
        super().__init__(
            f"{signal.Signals(signum).name} received: checkpointed at iteration {iteration} in {run_dir}; "
            "continue with the same command and resume=true"
        )


class LearnerDiverged(RuntimeError):
    """The learner's loss or parameters became non-finite; nothing from that update was written."""


def divergence(algo: Algorithm, logs: dict[str, float]) -> str | None:
    """What is non-finite after an update (a loss, or some module's parameters), or None.

    One sum per module: a sum is finite exactly when every parameter is (they are far from overflowing it).
    """
    bad = [f"{key}={value}" for key, value in logs.items() if "loss" in key and not math.isfinite(value)]
    for name, module in algo.modules().items():
        total = sum((p.detach().sum() for p in module.parameters()), torch.zeros(()))
        if not math.isfinite(float(total)):
            bad.append(f"parameters of {name!r}")
    return ", ".join(bad) or None


class StopSignals:
    """Record SIGTERM/SIGUSR1 (Slurm's pre-emption and submitit's notice) and a first Ctrl-C instead of dying, so
    the loop can checkpoint at the end of the iteration; a second Ctrl-C raises ``KeyboardInterrupt`` at once.
    Installed only in the main thread (Python's rule for handlers)."""

    SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGUSR1", "SIGINT") if hasattr(signal, name))

    def __init__(self) -> None:
        self.received: int | None = None
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
            print("Ctrl-C again: stopped at once; resume=true continues from the last checkpoint", file=sys.stderr)
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGINT)
        if signum == signal.SIGINT:
            print("\nCtrl-C: checkpointing at the end of this iteration (Ctrl-C again to stop at once)",
                  file=sys.stderr, flush=True)
        self.received = signum

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)


# ---- the trial --------------------------------------------------------------------------------------------------


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
            return self._train(progress, on_evaluation)

    def _train(
        self, progress: bool, on_evaluation: Callable[[dict[str, float], float, float], bool] | None
    ) -> dict[str, float]:
        exp = self.experiment
        revision = git_revision()  # the code this process loaded, not what the checkout holds when it ends
        torch.set_num_threads(exp.torch_threads)  # small networks: one thread beats contention on 2 cores
        torch.manual_seed(exp.seed)
        np.random.seed(exp.seed)
        random.seed(exp.seed)
        self.run_dir.mkdir(parents=True, exist_ok=True)

        # env → view → learner → collector → replay buffer → logger
        train_env = TransformedEnv(make_view(exp, exp.num_envs, exp.seed), RewardSum())
        eval_env = make_view(exp, exp.eval_episodes, exp.seed + EVAL_SEED_OFFSET)
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
        logger = make_logger(exp, self.run_dir)
        ego = getattr(train_env.base_env, "ego", None)

        rows: list[dict[str, float]] = []
        start_iteration, elapsed_before = 0, 0.0
        if exp.resume:
            state = load_checkpoint(self.run_dir, map_location=exp.device)
            algo.load_state_dict(state["algorithm"])
            if replay_buffer is not None:
                replay_buffer.load_state_dict(state["replay_buffer"])
            restore_env(train_env.base_env, state["env"])
            collector._carrier.update(state["carrier"])
            collector._frames, collector._iter = state["collector_frames"], state["collector_iter"]
            restore_rng(state["rng"])
            rows, start_iteration, elapsed_before = state["rows"], state["iteration"], state["elapsed_s"]
        if self.config:  # from runners/main.py: the folder records the config and this start
            record_start(self.run_dir, self.config, exp.resume)
        if exp.resume:
            self._write_metrics(rows)

        def checkpoint(iteration: int, elapsed: float) -> None:
            state = {
                "iteration": iteration,
                "elapsed_s": elapsed,
                "algorithm": algo.state_dict(),
                "replay_buffer": replay_buffer.state_dict() if replay_buffer is not None else None,
                "env": capture_env(train_env.base_env),
                "carrier": collector._carrier.clone(),
                "collector_frames": collector._frames,
                "collector_iter": collector._iter,
                "rng": capture_rng(),
                "rows": rows,
            }
            save_checkpoint(self.run_dir, state)
            save_policy(self.run_dir, self._policy_state(algo))  # a partner can play the run while it trains

        started = time.perf_counter() - elapsed_before
        bar = tqdm(total=exp.iterations, initial=start_iteration, disable=not progress, desc="train", unit="it")
        iteration = start_iteration
        last_write = time.perf_counter()
        stop = False
        with StopSignals() as signals:
            for batch in collector:
                logs = {f"train/{key}": value for key, value in algo.update(batch, replay_buffer).items()}
                diverged = divergence(algo, logs)
                if diverged is not None:
                    self._write_metrics(rows)
                    self._history("diverged", iteration=iteration + 1, non_finite=diverged)
                    raise LearnerDiverged(
                        f"the learner diverged at iteration {iteration + 1}: non-finite {diverged}. The run stopped; "
                        f"{self.run_dir} keeps its last checkpoint and metrics up to iteration {iteration} "
                        "(try a lower algo.lr or algo.max_grad_norm, or another seed)"
                    )
                iteration += 1
                collector.update_policy_weights_()
                row: dict[str, float] = {"iteration": iteration, "frames": iteration * frames_per_batch}
                row.update(train_metrics(batch, ego))
                row["train/cumulative_cost"] = (rows[-1].get("train/cumulative_cost", 0.0) if rows else 0.0) + row["train/cost"]
                row.update(logs)
                if exp.eval_every and (iteration % exp.eval_every == 0 or iteration == exp.iterations):
                    rng = capture_rng()  # evaluation must not shift the training stream
                    eval_started = time.perf_counter()
                    metrics = evaluate(eval_env, algo.evaluation_policy(), seed=exp.seed + EVAL_SEED_OFFSET)
                    eval_ended = time.perf_counter()
                    restore_rng(rng)
                    row.update({f"eval/{key}": value for key, value in metrics.items()})
                    stop = on_evaluation is not None and bool(on_evaluation(metrics, eval_started, eval_ended))
                elapsed = time.perf_counter() - started
                row["time_s"] = elapsed
                row["frames_per_s"] = row["frames"] / max(elapsed, 1e-9)
                rows.append(row)
                if logger is not None:
                    for key, value in row.items():
                        if key != "iteration" and isinstance(value, float) and math.isfinite(value):
                            logger.log_scalar(key, value, step=int(row["frames"]))
                self._progress(bar, row)
                done = stop or iteration >= exp.iterations
                interrupted = signals.received is not None and not done
                checkpoint_now = interrupted or (exp.checkpoint_every and iteration % exp.checkpoint_every == 0)
                if checkpoint_now and not done:  # the end writes its own (keep_checkpoint=all) or none
                    checkpoint(iteration, elapsed)
                if checkpoint_now or done or time.perf_counter() - last_write > 10.0:
                    self._write_metrics(rows)
                    last_write = time.perf_counter()
                if interrupted:
                    bar.close()
                    collector.shutdown()
                    self._history("interrupted", iteration=iteration,
                                   signal=signal.Signals(signals.received).name)
                    raise RunInterrupted(signals.received, iteration, self.run_dir)
                if done:
                    break
        bar.close()
        if exp.keep_checkpoint == "all":
            checkpoint(iteration, time.perf_counter() - started)
        save_policy(self.run_dir, self._policy_state(algo))
        collector.shutdown()

        last_eval = {key[len("eval/"):]: value for key, value in rows[-1].items() if key.startswith("eval/")}
        final = last_eval or evaluate(eval_env, algo.evaluation_policy(), seed=exp.seed + EVAL_SEED_OFFSET)
        training_cost = rows[-1].get("train/cumulative_cost", 0.0) if rows else 0.0
        summary = {
            **final,
            "seed": exp.seed,
            "iterations": iteration,
            "frames": iteration * frames_per_batch,
            # Safety Gym's third figure: the cost paid over all of training per frame (world-step) collected.
            "train_cost": training_cost,
            "cost_rate": training_cost / max(iteration * frames_per_batch, 1),
            "wall_clock_s": time.perf_counter() - started,
            "versions": package_versions(),
            "git_revision": revision,
        }
        # Strict JSON: an undefined metric (no agent arrived, so no path efficiency) is null, not NaN.
        strict = {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in summary.items()}
        atomic_write(self.run_dir / SUMMARY, lambda tmp: tmp.write_text(json.dumps(strict, indent=2, default=str)))
        if exp.keep_checkpoint == "final":  # the replay buffer and optimiser state are gigabytes over a sweep
            drop_training_state(self.run_dir)
        self._history("finished", iteration=iteration)
        return summary

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
