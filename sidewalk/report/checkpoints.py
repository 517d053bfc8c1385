"""A run's checkpoint brought back: its config as an ``Experiment``, its learner's greedy policy, and its final
evaluation replayed to record trajectories (Fig. 10). The learners and the training loop are imported inside the
functions, so a report that replays no checkpoint does not load them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sidewalk.report.conditions import Condition
from sidewalk.report.runs import POLICY_FILES, Run
from sidewalk.run_folder import policy_file


def load_experiment(run_dir: str | Path, device: str = "cpu"):
    """The validated ``Experiment`` of a run folder's ``config.yaml``, on ``device``.

    The algorithm and logger sections are merged onto their schemas first, so they come back as their typed
    config dataclasses, exactly as ``runners/main.py`` built them; the top level is merged onto the experiment
    schema, so a folder written before a key existed (``keep_checkpoint``) replays with that key's default.
    """
    from sidewalk.config import validate
    from sidewalk.run_folder import read_saved_config

    cfg = read_saved_config(run_dir)
    cfg.device = device  # before the checks, which refuse a device this machine lacks (a GPU run read on a CPU)
    return validate(cfg)


def load_policy(run_dir: str | Path, experiment, env):
    """The greedy evaluation policy of the learner saved in ``run_dir`` (``policy.pt``, else ``checkpoint.pt``),
    rebuilt for ``env`` (a view built from ``experiment``)."""
    from torchrl.envs import RewardSum, TransformedEnv

    from sidewalk.registry import LEARNERS
    from sidewalk.run_folder import read_torch_file

    path = policy_file(run_dir)
    if path is None:
        raise FileNotFoundError(f"{run_dir} has no {POLICY_FILES}: the run has no learned policy to replay")
    # mmap: a checkpoint's replay buffer can be large and is not needed here.
    state = read_torch_file(path, map_location=experiment.device, mmap=True)
    # The learner is built on the env as training built it (a RewardSum on top), so every spec matches.
    algo = LEARNERS[experiment.algo.name](
        experiment.algo, TransformedEnv(env, RewardSum()), device=experiment.device
    )
    algo.load_policy_state_dict(state.get("algorithm", state))  # a checkpoint, or policy.pt
    return algo.evaluation_policy()


@dataclass
class Replay:
    """Episodes of a run's final policy, replayed exactly as its final evaluation ran them."""

    run: Run
    record: Any  # sidewalk.evaluate.EpisodeRecord with trajectories of the first k worlds
    layout: Any  # GridLayout | PlaneLayout
    domain: str
    matches_summary: bool


def replay(run: Run, episodes: int) -> Replay:
    """Replay the final evaluation of ``run`` (the same worlds, seed and greedy policy as ``Trial``'s) and record
    the first ``episodes`` trajectories. ``matches_summary`` tells whether the replayed success and collision rates
    equal ``summary.json``'s, i.e. the checkpoint is the policy that was evaluated."""
    import torch

    from sidewalk.evaluate import run_episodes, summarize
    from sidewalk.experiment import EVAL_SEED_OFFSET, make_eval_view

    experiment = load_experiment(run.path)
    seed = experiment.seed + EVAL_SEED_OFFSET
    env = make_eval_view(experiment)
    policy = load_policy(run.path, experiment, env)
    with torch.no_grad():
        record = run_episodes(
            env, policy, seed=seed, record_trajectories=min(episodes, experiment.eval_episodes),
            one_world=lambda: make_eval_view(experiment, worlds=1),
        )
    replayed = summarize(record)
    keys = [k for k in replayed if k.endswith(("success_rate", "collision_rate")) and k in run.summary]
    matches = all(math.isclose(replayed[k], float(run.summary[k]), abs_tol=1e-6) for k in keys)
    return Replay(run, record, env.core.layout, experiment.world.domain, matches)


def representative_run(condition: Condition) -> Run | None:
    """The run with a saved policy whose final success (the learner's, or the team's) is the median of the seeds'."""
    candidates = [run for run in condition.runs if policy_file(run.path) is not None]
    if not candidates:
        return None
    key = "ego/success_rate" if condition.agents()[0][0] == "ego" else "team/success_rate"
    ranked = sorted(candidates, key=lambda run: (float(run.summary.get(key, math.nan)), run.seed))
    return ranked[(len(ranked) - 1) // 2]
