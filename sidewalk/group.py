"""Several seeds of one experiment trained in one process: ``replicas=R`` on the command line.

``GroupTrial(experiment, run_dir, config).run()`` trains seeds ``seed .. seed+R-1`` together:

- one core env holds every replica's worlds (replica-major blocks), so a step of all of them is one batch of tensor
  operations, and a scripted opponent that does not depend on the seed plans for all of them in one call
  (``sidewalk.opponents.replicas``); each replica's worlds draw from that replica's generator;
- one collector gathers every replica's batch; each replica's learner acts on its own block of worlds, drawing from
  its own global random stream (``sidewalk.streams``);
- the learners are updated in one vectorised pass where the learner has one (``sidewalk.algos.stacked``), else one
  after another;
- each replica writes an ordinary run folder, ``<run_dir>/seed<S>/`` (``config.yaml`` with its own seed, metrics,
  summary, ``policy.pt``), which reports, cross-play and renders read like any other run; the group's own state
  (its config, history and the one checkpoint of the whole group) lives in ``<run_dir>/.group/``.

A replica draws exactly what it would draw in a group of its own; a group of one replica is a lone trial, bit for
bit, when the learner's update runs per replica. SIGTERM, SIGUSR1 and Ctrl-C checkpoint the group at the end of
the iteration, and ``resume=true`` continues it exactly.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import RewardSum, TransformedEnv
from tqdm import tqdm

from sidewalk._torchrl import collector_state, restore_collector_state
from sidewalk.algos import ALGORITHMS
from sidewalk.algos.base import Algorithm
from sidewalk.algos.stacked import vectorized_update
from sidewalk.config import Experiment
from sidewalk.experiment import (
    Parts,
    Progress,
    Trial,
    collector_frames_per_batch,
    make_eval_view,
    make_view,
)
from sidewalk.loggers import make_logger
from sidewalk.run_folder import (
    CHECKPOINT,
    CONFIG,
    GROUP_DIR,
    PREVIOUS_CHECKPOINT,
    SUMMARY,
    RunFolderError,
    append_history,
    atomic_write,
    check,
    drop_training_state,
    git_revision,
    load_checkpoint,
    record_start,
    save_checkpoint,
    save_policy,
    writer_lock,
)
from sidewalk.snapshot import capture_env, capture_rng, restore_env, restore_rng
from sidewalk.stops import RunInterrupted, StopSignals
from sidewalk.streams import ReplicaStreams


def replica_seeds(experiment: Experiment) -> list[int]:
    return [experiment.seed + replica for replica in range(experiment.replicas)]


def replica_dir(run_dir: Path, seed: int) -> Path:
    return Path(run_dir) / f"seed{seed}"


def replica_config(config: dict[str, Any], seed: int) -> dict[str, Any]:
    """A replica's ``config.yaml``: the group's, with its own seed, as a lone run of that seed would record it."""
    return {**config, "seed": seed, "replicas": 1}


def fallback_reason(experiment: Experiment) -> str | None:
    """Why this group's replicas cannot share a process exactly (they then run one after another), or None."""
    if experiment.opponent == "policy" and experiment.opponent_params.get("sample"):
        return ("a learned partner that samples (opponent.sample=true) draws from the process's one global stream, "
                "so its replicas would not be the runs they are alone")
    return None


def check_group(run_dir: Path, experiment: Experiment, config: dict[str, Any]) -> None:
    """Before any compute: the group's folder and every replica's can start (or, ``resume=true``, continue) this
    group; raises ``RunFolderError`` naming the folder and why."""
    run_dir = Path(run_dir)
    one_after_another = fallback_reason(experiment) is not None
    if not (experiment.resume and one_after_another):  # one after another, the replicas hold the checkpoints
        check(run_dir / GROUP_DIR, config, experiment.resume)
    for seed in replica_seeds(experiment):
        folder = replica_dir(run_dir, seed)
        if experiment.resume:  # a replica's checkpoint is the group's: check only that it belongs to the group
            if not (folder / CONFIG).exists() and not one_after_another:
                raise RunFolderError(f"resume=true but {folder} is not a run folder of this group")
            continue
        check(folder, replica_config(config, seed), resume=False)


class ReplicaPolicy(TensorDictModuleBase):
    """Each replica's policy on its own block of worlds, drawing from its own random stream; one output for all."""

    def __init__(self, policies: list[TensorDictModuleBase], streams: ReplicaStreams, blocks: list[slice]) -> None:
        super().__init__()
        self.policies = torch.nn.ModuleList(policies)
        self.streams, self.blocks = streams, blocks
        self.in_keys = list(policies[0].in_keys)
        self.out_keys = list(policies[0].out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        outputs = []
        for replica, (policy, block) in enumerate(zip(self.policies, self.blocks)):
            with self.streams.use(replica):
                # A copy, laid out as a lone run's batch: a BLAS may round a view at an offset otherwise.
                outputs.append(policy(tensordict[block].clone()))
        return torch.cat(outputs, 0)


@dataclasses.dataclass
class Replica:
    """One seed of the group: its lone-trial twin (for its folder's files), its parts and where it stands."""

    trial: Trial
    parts: Parts
    state: Progress


class GroupTrial:
    """Train ``experiment.replicas`` seeds of ``experiment`` in this process (see the module docstring)."""

    def __init__(
        self, experiment: Experiment, run_dir: str | Path, config: dict | None = None, vectorize: bool = True
    ) -> None:
        """``vectorize=False``: update the replicas one after another even where the learner has a vectorised
        update (the two give the same numbers; tests compare them)."""
        self.experiment = experiment
        self.vectorize = vectorize
        self.run_dir = Path(run_dir)
        self.group_dir = self.run_dir / GROUP_DIR
        self.config = config or {}
        self.seeds = replica_seeds(experiment)
        self.trials = [
            Trial(dataclasses.replace(experiment, seed=seed, replicas=1), replica_dir(self.run_dir, seed),
                  replica_config(self.config, seed) if self.config else None)
            for seed in self.seeds
        ]
        self.streams = ReplicaStreams(self.seeds)

    def run(self, progress: bool = True) -> list[dict[str, Any]]:
        """Train, evaluate and write every replica's run folder; return the replicas' summaries, in seed order."""
        reason = fallback_reason(self.experiment)
        if reason is not None:
            print(f"note: the {len(self.seeds)} replicas run one after another: {reason}", file=sys.stderr)
            return self._one_after_another(progress)
        with contextlib.ExitStack() as locks:
            for folder in (self.group_dir, *(trial.run_dir for trial in self.trials)):
                folder.mkdir(parents=True, exist_ok=True)
                locks.enter_context(writer_lock(folder))
            revision = git_revision()
            torch.set_num_threads(self.experiment.torch_threads)
            replicas, collector = self._build()
            self._start(replicas, collector)
            bar = tqdm(total=self.experiment.iterations, initial=replicas[0].state.iteration, disable=not progress,
                       desc=f"train ×{len(replicas)}", unit="it")
            with StopSignals() as signals:
                for batch in collector:
                    self._iteration(replicas, collector, batch)
                    self._progress(bar, replicas)
                    if self._after_iteration(replicas, collector, signals, bar):
                        break
            bar.close()
            return self._finish(replicas, collector, revision)

    def _one_after_another(self, progress: bool) -> list[dict[str, Any]]:
        """The fallback: each replica a lone trial in its folder; a resume skips finished ones and starts unstarted
        ones."""
        if self.config and not self.experiment.resume:
            record_start(self.group_dir, self.config, resume=False)
        summaries = []
        for trial in self.trials:
            if self.experiment.resume and (trial.run_dir / SUMMARY).exists():
                summaries.append(json.loads((trial.run_dir / SUMMARY).read_text()))
                continue
            started = any((trial.run_dir / name).exists() for name in (CHECKPOINT, PREVIOUS_CHECKPOINT))
            trial.experiment = dataclasses.replace(trial.experiment, resume=self.experiment.resume and started)
            summaries.append(trial.run(progress=progress))
        return summaries

    # ---- building -------------------------------------------------------------------------------------------------

    def _build(self) -> tuple[list[Replica], Collector]:
        """One env of every replica's worlds → each replica's learner (on its stream) → one collector → per-replica
        replay buffers, evaluation envs and loggers."""
        exp, count = self.experiment, len(self.seeds)
        train_env = TransformedEnv(make_view(exp, count * exp.num_envs, self.seeds if count > 1 else self.seeds[0]), RewardSum())
        algos: list[Algorithm] = []
        for replica in range(count):
            with self.streams.use(replica):
                algos.append(ALGORITHMS[exp.algo.name](exp.algo, train_env, device=exp.device))
        self.blocks = train_env.base_env.core.replica_blocks()
        policy = ReplicaPolicy([algo.collection_policy() for algo in algos], self.streams, self.blocks)
        frames_per_batch = collector_frames_per_batch(exp)
        collector = Collector(
            train_env, policy, frames_per_batch=count * frames_per_batch,
            total_frames=count * frames_per_batch * exp.iterations, device=exp.device,
            auto_register_policy_transforms=False,
        )
        ego = getattr(train_env.base_env, "ego", None)
        replicas = []
        for trial, algo in zip(self.trials, algos):
            lone = trial.experiment
            replay_buffer = None
            if algo.uses_replay_buffer:
                replay_buffer = TensorDictReplayBuffer(
                    storage=LazyTensorStorage(exp.algo.buffer_size, device=exp.device), batch_size=exp.algo.batch_size
                )
            eval_env = make_eval_view(lone)
            parts = Parts(train_env, eval_env, algo, collector, replay_buffer, make_logger(lone, trial.run_dir),
                          frames_per_batch, ego)
            replicas.append(Replica(trial, parts, Progress()))
        self.stacked = vectorized_update(algos) if self.vectorize else None
        return replicas, collector

    def _start(self, replicas: list[Replica], collector: Collector) -> None:
        """A fresh start, or (``resume=true``) the group's checkpoint put back: every replica's learner, buffer,
        metrics and stream, the worlds mid-episode and the collector; metrics rewound to it."""
        exp = self.experiment
        elapsed_before = 0.0
        if exp.resume:
            saved = load_checkpoint(self.group_dir, map_location=exp.device)
            for replica, held in zip(replicas, saved["replicas"]):
                replica.parts.algo.load_state_dict(held["algorithm"])
                if replica.parts.replay_buffer is not None:
                    replica.parts.replay_buffer.load_state_dict(held["replay_buffer"])
                replica.state.rows, replica.state.iteration = held["rows"], saved["iteration"]
                replica.state.load_best_state(held.get("best"))
            restore_env(replicas[0].parts.train_env.base_env, saved["env"])
            restore_collector_state(collector, saved)
            self.streams.load_state_dict(saved["streams"])
            restore_rng(saved["rng"])
            elapsed_before = saved["elapsed_s"]
        if self.config:
            record_start(self.group_dir, self.config, exp.resume)
            for replica in replicas:
                self._record_replica_start(replica)
        started = time.perf_counter() - elapsed_before
        for replica in replicas:
            if exp.resume:
                replica.trial._write_metrics(replica.state.rows)
            replica.state.started, replica.state.last_write = started, time.perf_counter()

    def _record_replica_start(self, replica: Replica) -> None:
        """A replica's ``config.yaml`` (rewritten on a resume, which may grow ``iterations``; the group's own check
        refused any other change) and its start in ``history.jsonl``."""
        trial = replica.trial
        if self.experiment.resume:
            atomic_write(trial.run_dir / CONFIG, lambda tmp: OmegaConf.save(OmegaConf.create(trial.config), tmp))
            append_history(trial.run_dir, "resumed", group=str(self.run_dir))
            return
        record_start(trial.run_dir, trial.config, resume=False)
        append_history(trial.run_dir, "group", folder=str(self.run_dir), seeds=self.seeds)

    # ---- one iteration ----------------------------------------------------------------------------------------

    def _iteration(self, replicas: list[Replica], collector: Collector, batch: TensorDictBase) -> None:
        """Every replica's update on its block of the batch (one vectorised pass where the learner has one), then
        each replica's metrics row, with its evaluation when one is due, on its own stream."""
        batches = [batch[block] for block in self.blocks]
        if self.stacked is not None:
            logs = self.stacked.update(batches, self.streams)
        else:
            logs = []
            for index, (replica, own) in enumerate(zip(replicas, batches)):
                with self.streams.use(index):
                    logs.append(replica.parts.algo.update(own, replica.parts.replay_buffer))
        collector.update_policy_weights_()
        for index, (replica, own, update_logs) in enumerate(zip(replicas, batches, logs)):
            with self.streams.use(index):
                replica.trial._record(replica.parts, replica.state, own, update_logs)

    def _after_iteration(
        self, replicas: list[Replica], collector: Collector, signals: StopSignals, bar: tqdm
    ) -> bool:
        """Checkpoint the group and write metrics when due; leave on a signal; True when training is done."""
        state = replicas[0].state
        done, interrupted, checkpoint, metrics = state.due(self.experiment, False, signals)
        if checkpoint:
            self._checkpoint(replicas, collector)
        if metrics:
            for replica in replicas:
                replica.trial._write_metrics(replica.state.rows)
                replica.state.last_write = time.perf_counter()
        if interrupted:
            bar.close()
            collector.shutdown()
            stopped = {"iteration": state.iteration, "signal": signal.Signals(signals.received).name}
            if self.config:
                append_history(self.group_dir, "interrupted", **stopped)
            for replica in replicas:
                replica.trial._history("interrupted", **stopped)
            raise RunInterrupted(signals.received, state.iteration, self.run_dir)
        return done

    def _checkpoint(self, replicas: list[Replica], collector: Collector) -> None:
        """One file for the whole group (its replicas' states are one env and one collector), then each replica's
        ``policy.pt``, so a partner can play any replica while the group trains."""
        first = replicas[0]
        saved = {
            "iteration": first.state.iteration,
            "elapsed_s": first.state.elapsed(),
            "replicas": [
                {
                    "algorithm": replica.parts.algo.state_dict(),
                    "replay_buffer": (replica.parts.replay_buffer.state_dict()
                                      if replica.parts.replay_buffer is not None else None),
                    "rows": replica.state.rows,
                    "best": replica.state.best_state(),
                }
                for replica in replicas
            ],
            "env": capture_env(first.parts.train_env.base_env),
            **collector_state(collector),
            "streams": self.streams.state_dict(),
            "rng": capture_rng(),
            "seeds": self.seeds,
        }
        save_checkpoint(self.group_dir, saved)
        for replica in replicas:
            save_policy(replica.trial.run_dir, replica.trial._policy_state(replica.parts.algo))

    # ---- the end ----------------------------------------------------------------------------------------------------

    def _finish(self, replicas: list[Replica], collector: Collector, revision: str) -> list[dict[str, Any]]:
        """The group's last checkpoint (``keep_checkpoint=all``), then each replica's ``policy.pt`` and
        ``summary.json``, as a lone trial ends."""
        exp = self.experiment
        if exp.keep_checkpoint == "all":
            self._checkpoint(replicas, collector)
        collector.shutdown()
        summaries = []
        for index, replica in enumerate(replicas):
            with self.streams.use(index):
                summaries.append(replica.trial._conclude(replica.parts, replica.state, revision))
            replica.trial._history("finished", iteration=replica.state.iteration)
        if exp.keep_checkpoint == "final":
            drop_training_state(self.group_dir)
        if self.config:
            append_history(self.group_dir, "finished", iteration=replicas[0].state.iteration)
        return summaries

    @staticmethod
    def _progress(bar: tqdm, replicas: list[Replica]) -> None:
        rows = [replica.state.rows[-1] for replica in replicas]
        postfix: dict[str, Any] = {"frames": int(sum(row["frames"] for row in rows))}
        for key, label in (("train/ego_success_rate", "train_success"), ("train/team_success_rate", "team_success"),
                           ("eval/ego/success_rate", "eval_success")):
            values = [row[key] for row in rows if key in row]
            if values and not (key == "train/team_success_rate" and "train_success" in postfix):
                postfix[label] = f"{sum(values) / len(values):.2f}"
        bar.set_postfix(postfix, refresh=False)
        bar.update(1)
