"""What a trial (``sidewalk.experiment.Trial``) is made of and keeps: its parts, each seed's run folder, and one
checkpoint of them all. One seed writes its run folder where the trial was pointed; R seeds (``replicas=R``) write
``<run_dir>/seed<S>/`` each, ordinary run folders whose ``config.yaml`` is their lone run's, and keep the group's
config, history and checkpoint in ``<run_dir>/.group/``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import OmegaConf
from torchrl.collectors import Collector
from torchrl.data import TensorDictReplayBuffer
from torchrl.envs import EnvBase, TransformedEnv
from tqdm import tqdm

from sidewalk._torchrl import collector_state, restore_collector_state
from sidewalk.config import Experiment
from sidewalk.progress import Progress
from sidewalk.replica_learners import ReplicaSet
from sidewalk.run_folder import (
    CONFIG,
    GROUP_DIR,
    METRICS,
    SUMMARY,
    RunFolderError,
    append_history,
    atomic_write,
    check,
    check_checkpoint,
    group_seed_dirs,
    group_state_dir,
    has_checkpoint,
    load_checkpoint,
    record_start,
    save_checkpoint,
)
from sidewalk.snapshot import capture_env, capture_rng, restore_env, restore_rng

WALL_CLOCK_COLUMNS = ("time_s", "frames_per_s")


def replica_config(config: dict[str, Any], seed: int) -> dict[str, Any]:
    """A seed's ``config.yaml`` in a run of several: the run's, with its own seed, as a run of that seed alone."""
    return {**config, "seed": seed, "replicas": 1}


def state_dir(run_dir: Path, experiment: Experiment) -> Path:
    """Where the trial keeps its config, history and checkpoint (``run_folder.group_state_dir``)."""
    return group_state_dir(run_dir, experiment.replicas)


def seed_dirs(run_dir: Path, experiment: Experiment) -> list[Path]:
    """Each seed's run folder (``run_folder.group_seed_dirs``)."""
    return group_seed_dirs(run_dir, experiment.seed, experiment.replicas)


def check_folders(run_dir: Path, experiment: Experiment, config: dict[str, Any], in_sweep: bool = False) -> str:
    """Before any compute: every folder of the trial can start (or, ``resume=true``, continue) it; raises
    ``RunFolderError`` naming the folder and why. Several seeds: the group's folder holds the checkpoint, and each
    seed's folder must be new, or (resuming) one of this group's, and a checkpoint, where there is one, must read back.

    Returns what the command does: ``"start"``; ``"resume"`` (from the checkpoint, or from the start when the run
    stopped before its first); or ``"finished"`` (``resume=true`` on a run that finished at this budget: nothing to
    do). In a sweep, ``resume=true`` continues every job, so a job's folder that holds no run yet (the interrupted
    sweep never reached it) is a ``"start"``."""
    run_dir, state = Path(run_dir), state_dir(run_dir, experiment)
    never_started = in_sweep and not (state / CONFIG).exists()
    resume = experiment.resume and not never_started
    grown = check(state, config, resume)
    folders = seed_dirs(run_dir, experiment)
    if experiment.replicas > 1:
        for replica, folder in enumerate(folders):
            if not resume:
                check(folder, replica_config(config, experiment.seed + replica), resume=False)
            elif not (folder / CONFIG).exists():
                raise RunFolderError(f"resume=true but {folder} is not a run folder of this group")
    if not resume:
        return "start"
    if grown is None and all((folder / SUMMARY).exists() for folder in folders):
        return "finished"
    if has_checkpoint(state):
        check_checkpoint(state)  # both generations torn: refused here, before the envs and learners are built
    return "resume"


def read_summaries(run_dir: Path, experiment: Experiment) -> list[dict[str, Any]]:
    """The ``summary.json`` of each seed of a finished trial."""
    return [json.loads((folder / SUMMARY).read_text()) for folder in seed_dirs(run_dir, experiment)]


@dataclass
class SeedRun:
    """One seed of a trial: its run folder, the config it records, its evaluation env, logger and progress."""

    experiment: Experiment  # this seed's experiment alone (replicas=1)
    run_dir: Path
    config: dict[str, Any]
    eval_env: EnvBase
    logger: Any
    state: Progress

    def history(self, event: str, **details: Any) -> None:
        if self.config:
            append_history(self.run_dir, event, **details)

    def write_metrics(self) -> None:
        frame = pd.DataFrame(self.state.rows)
        first = [c for c in ("iteration", "frames", *WALL_CLOCK_COLUMNS) if c in frame.columns]
        frame = frame[first + sorted(c for c in frame.columns if c not in first)]
        atomic_write(self.run_dir / METRICS, lambda tmp: frame.to_csv(tmp, index=False))


@dataclass
class Parts:
    """What one trial is made of, built from its experiment in the order data flows through them."""

    train_env: TransformedEnv
    learners: ReplicaSet
    collector: Collector
    replay_buffers: list[TensorDictReplayBuffer | None]
    runs: list[SeedRun]
    frames_per_batch: int  # one seed's frames an iteration
    ego: int | None  # the learner's agent in an ego view; None where it plays every agent


def save_trial(parts: Parts, state_dir: Path) -> None:
    """One checkpoint for every seed (they share one env and one collector): learners, replay buffers, the worlds
    mid-episode, the collector, the random state, and each seed's metrics and best evaluation. One layout whatever
    the number of seeds (a lone seed is a list of one)."""
    first = parts.runs[0].state
    saved = {
        "iteration": first.iteration,
        "elapsed_s": first.elapsed(),
        "algorithm": parts.learners.state_dict(),
        "replay_buffer": [buffer.state_dict() if buffer is not None else None for buffer in parts.replay_buffers],
        "env": capture_env(parts.train_env.base_env),
        **collector_state(parts.collector),
        "rng": capture_rng(),
        "runs": [{"rows": run.state.rows, "best": run.state.best_state()} for run in parts.runs],
        "seeds": [run.experiment.seed for run in parts.runs],
    }
    save_checkpoint(state_dir, saved)


def restore_trial(parts: Parts, state_dir: Path, device: Any) -> float:
    """Put back every state ``save_trial`` wrote; returns the training time it had taken. A checkpoint written
    before the one layout is read too: a lone seed's rows, best evaluation and replay buffer at its top level, and
    one buffer of a group not in a list."""
    saved = load_checkpoint(state_dir, map_location=device)
    parts.learners.load_state_dict(saved["algorithm"])
    held_buffers = saved["replay_buffer"]
    held_buffers = held_buffers if isinstance(held_buffers, list) else [held_buffers]
    for buffer, held in zip(parts.replay_buffers, held_buffers, strict=True):
        if buffer is not None:
            buffer.load_state_dict(held)
    restore_env(parts.train_env.base_env, saved["env"])
    restore_collector_state(parts.collector, saved)
    restore_rng(saved["rng"])
    for run, held in zip(parts.runs, saved.get("runs", [saved]), strict=True):
        run.state.rows, run.state.iteration = held["rows"], saved["iteration"]
        run.state.load_best_state(held.get("best"))
    return saved["elapsed_s"]


def record_starts(run_dir: Path, config: dict[str, Any], runs: list[SeedRun], resume: bool) -> None:
    """Each folder's ``config.yaml`` and its start in ``history.jsonl``; with several seeds, the group's too (a
    resume may only have grown ``iterations``: the group's own check refused any other change)."""
    if len(runs) == 1:
        record_start(run_dir, config, resume)
        return
    record_start(Path(run_dir) / GROUP_DIR, config, resume)
    seeds = [run.experiment.seed for run in runs]
    for run in runs:
        if resume:
            atomic_write(run.run_dir / CONFIG, lambda tmp, run=run: OmegaConf.save(OmegaConf.create(run.config), tmp))
            append_history(run.run_dir, "resumed", group=str(run_dir))
        else:
            record_start(run.run_dir, run.config, resume=False)
            append_history(run.run_dir, "group", folder=str(run_dir), seeds=seeds)


def show_progress(bar: tqdm, rows: list[dict[str, float]]) -> None:
    """One iteration on the progress bar: frames over every seed, and the seeds' mean success and return."""
    postfix: dict[str, Any] = {"frames": f"{int(sum(row['frames'] for row in rows)):,}"}  # tqdm writes 20000 "2e+4"
    for key, label in (
        ("train/ego_success_rate", "train_success"), ("train/team_success_rate", "team_success"),
        ("train/return", "return"), ("eval/ego/success_rate", "eval_success"),
    ):
        values = [row[key] for row in rows if key in row]
        if values and not (key == "train/team_success_rate" and "train_success" in postfix):
            postfix[label] = f"{sum(values) / len(values):.2f}"
    bar.set_postfix(postfix, refresh=False)
    bar.update(1)
