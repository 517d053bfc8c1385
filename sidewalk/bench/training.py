"""Training speed: wall clock until the greedy policy reaches 0.9 ego success against the Dijkstra opponent (discrete
sidewalk, noise 0), our DQN beside Stable-Baselines3's DQN, and both learners' frames/s at equal settings.

Ours is the ``runners/main.py`` path: the experiment composed from ``conf/`` (so the DQN defaults are read at run
time) and run by ``Trial``. SB3's DQN trains on our Gymnasium face (``gymnasium.make_vec("sidewalk/Discrete-v0",
opponent="dijkstra")``, one batched core) through a thin SB3 ``VecEnv`` adapter, with a features extractor that is
the paper's conv stack plus a dense 256 (SB3's ``NatureCNN`` needs ≥ 36×36 images; ours are 14×30). Our network
adds a dueling head (value and advantage streams of 256 each) that SB3's DQN lacks; ours is double DQN, SB3's is
not; SB3 draws one ε coin per vector step for all worlds, ours one per world.

Both are evaluated alike: every ``eval_every_frames`` training frames, ``sidewalk.evaluate.evaluate`` plays one
greedy episode in each world of the evaluation view ``Trial`` builds (``eval_episodes`` worlds, the same seed).
``seconds_to_target``: wall clock from building the learner to the first evaluation ≥ TARGET, the evaluations'
own time taken out (``seconds_to_target_with_eval`` leaves it in). At noise 0 a constant action reaches the goal,
so an untrained network scores 1.0 for some seeds (``solved_at_first_eval``); ``seconds_sustained`` is the first
of CONFIRM + 1 evaluations in a row ≥ TARGET, and each learner runs several seeds. A run stops after ``seconds``
of training and says it did not reach the target.

Setups: ``equal``: our conf defaults, and SB3 with the same hyper-parameters (worlds, batch, updates per frame,
learning rate, ε schedule, Polyak rate, buffer); ``tuned``: the best settings found for each (TUNED_OURS,
TUNED_SB3). frames/s: both at the issue's equal settings (batch 128, 4 gradient steps per 128 frames, the
config's worlds), timed after learning starts, without evaluations.

    python -m sidewalk.bench.training                          # equal + tuned, seeds 0-4, frames/s
    python -m sidewalk.bench.training --setups equal --seeds 0 --verbose
"""

from __future__ import annotations

import argparse
import ast
import math
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sidewalk.bench.common import compose_experiment, format_table, torch_threads
from sidewalk.bench.common import sb3_vec_env as common_sb3_vec_env

TARGET = 0.9
CONFIRM = 2  # further evaluations ≥ TARGET that make a first one "sustained"
SECONDS = 600.0  # training-time cap of one run
SEEDS = (0, 1, 2, 3, 4)
EVAL_EVERY_FRAMES = 2560
FPS_FRAMES = 25_600  # timed frames after learning starts, for frames/s
VERBOSE = False  # print every evaluation to stderr (--verbose)
# Every run: the discrete sidewalk against Dijkstra at noise 0, no logger, no checkpoint until the end.
BASE_OVERRIDES = ("env=discrete", "opponent=dijkstra", "algo=dqn", "noise=0", "logger=none", "checkpoint_every=0")
# The frames/s comparison: batch 128, 4 gradient steps per 128 frames.
FPS_OURS = ("algo.frames_per_batch=128", "algo.batch_size=128", "algo.updates_per_batch=4")
FPS_SB3 = {"batch_size": 128, "frames_per_train": 128, "gradient_steps": 4}
# SB3's DQN arguments, plus n_envs, frames_per_train (train_freq in frames; SB3 counts vector steps) and
# eps_decay_frames (SB3 states exploration as a fraction of total_timesteps, unknown to a capped run). None: our
# DQNConfig's value, read at run time, so that "equal" is equal.
SB3_EQUAL: dict[str, Any] = {
    "n_envs": None,
    "learning_rate": None,
    "buffer_size": None,
    "learning_starts": None,
    "batch_size": None,
    "gamma": None,
    "max_grad_norm": None,
    "eps_decay_frames": None,
    "exploration_initial_eps": None,
    "exploration_final_eps": None,
    "tau": None,
    "target_update_interval": 1,  # Polyak every vector step: with 32 worlds, 4 per 128 frames, as ours per update
    "frames_per_train": None,
    "gradient_steps": None,
}
# The best of the settings tried (median over seeds 0-3 of the sustained time; gamma from conf, 0.95): 128 worlds,
# 4 updates per 512 frames, Polyak 0.05 for both; ours without double DQN. Tried and slower for ours: the defaults,
# tau 0.05 or 0.1 at 32 worlds, 64 worlds, eps decay 5k frames, lr 2.5e-4 or 1e-3, l2 loss.
TUNED_OURS: tuple[str, ...] = (
    "num_envs=128", "algo.frames_per_batch=512", "algo.tau=0.05", "algo.double_dqn=false",
)
TUNED_SB3: dict[str, Any] = {"n_envs": 128, "frames_per_train": 512, "tau": 0.05}
COLUMNS = (
    "measure", "setup", "learner", "seed", "num_envs", "threads", "seconds_to_target", "seconds_to_target_with_eval",
    "frames_to_target", "solved_at_first_eval", "seconds_sustained", "frames_sustained", "best_success",
    "frames_per_s", "load_1min", "note", "settings",
)


# ---- our side: the runners/main.py path -------------------------------------------------------------------------


class _Clock:
    """Training time to target: wall clock since ``start`` minus the evaluations' own time.

    ``first``: the first evaluation ≥ target. ``sustained``: the first of ``confirm + 1`` evaluations in a row
    ≥ target (an untrained network can score 1.0 by chance: a constant action reaches the goal at noise 0).
    """

    def __init__(self, target: float, seconds: float, eval_every_frames: int, confirm: int) -> None:
        self.target, self.seconds, self.eval_every_frames, self.confirm = target, seconds, eval_every_frames, confirm
        self.start = time.perf_counter()
        self.eval_s = 0.0
        self.evaluations = 0
        self.best = -math.inf
        self.history: list[tuple[int, float, float]] = []  # (frames, training seconds, success)
        self.first: dict[str, float] | None = None
        self.streak: list[dict[str, float]] = []
        self.sustained: dict[str, float] | None = None

    def on_eval(self, success: float, eval_start: float, eval_end: float) -> bool:
        """Record one evaluation; True when the run should stop."""
        self.evaluations += 1
        frames = self.evaluations * self.eval_every_frames
        train_s = eval_start - self.start - self.eval_s
        point = {"seconds": train_s, "seconds_with_eval": eval_start - self.start, "frames": frames}
        self.eval_s += eval_end - eval_start
        self.best = max(self.best, success)
        self.history.append((frames, train_s, success))
        if VERBOSE:
            print(f"  eval {self.evaluations}: {frames} frames, {train_s:.1f} s training "
                  f"(+{self.eval_s:.1f} s eval), ego success {success:.3f}, load {os.getloadavg()[0]:.1f}",
                  file=sys.stderr, flush=True)
        if success >= self.target:
            self.first = self.first or point
            self.streak.append(point)
            if len(self.streak) > self.confirm:
                self.sustained = self.streak[0]
                return True
        else:
            self.streak = []
        return train_s >= self.seconds

    def row(self) -> dict[str, Any]:
        row: dict[str, Any] = {"best_success": self.best, "evaluations": self.evaluations}
        if self.first is not None:
            row.update(seconds_to_target=self.first["seconds"], seconds_to_target_with_eval=self.first["seconds_with_eval"],
                       frames_to_target=self.first["frames"], solved_at_first_eval=self.first["frames"] == self.eval_every_frames)
        if self.sustained is not None:
            row.update(seconds_sustained=self.sustained["seconds"], frames_sustained=self.sustained["frames"])
        train_s = self.history[-1][1] if self.history else 0.0
        if self.first is None:
            row["note"] = f"did not reach {self.target} within {train_s:.0f} s of training"
        elif self.sustained is None:
            row["note"] = f"reached {self.target} but not {self.confirm + 1} evaluations in a row within {train_s:.0f} s"
        row["train_seconds"] = train_s
        return row


def our_overrides(num_envs: int | None, threads: int, seed: int, extra: Sequence[str]) -> list[str]:
    worlds = [f"num_envs={num_envs}"] if num_envs else []
    return [*BASE_OVERRIDES, *worlds, f"torch_threads={threads}", f"seed={seed}", *extra]


def ours_time_to_target(
    num_envs: int | None, threads: int, seed: int, seconds: float, eval_every_frames: int, extra: Sequence[str] = ()
) -> dict:
    """Run ``Trial`` until a sustained evaluation ≥ TARGET or ``seconds`` of training time."""
    from sidewalk.experiment import Trial, collector_frames_per_batch

    frames_per_batch = collector_frames_per_batch(compose_experiment(our_overrides(num_envs, threads, seed, extra)))
    eval_every = max(1, round(eval_every_frames / frames_per_batch))
    overrides = [*our_overrides(num_envs, threads, seed, extra), f"eval_every={eval_every}", "iterations=100000000"]
    experiment = compose_experiment(overrides)
    clock = _Clock(TARGET, seconds, eval_every * frames_per_batch, CONFIRM)

    def on_evaluation(metrics, start, end):
        return clock.on_eval(metrics["ego/success_rate"], start, end)

    with tempfile.TemporaryDirectory() as run_dir:
        clock.start = time.perf_counter()
        Trial(experiment, run_dir).run(progress=False, on_evaluation=on_evaluation)
    return {"learner": "ours", "num_envs": experiment.num_envs, **clock.row(),
            "settings": _our_settings(experiment, extra)}


def ours_frames_per_s(num_envs: int | None, threads: int, frames: int = FPS_FRAMES) -> dict:
    """Frames/s of ``Trial`` at FPS_OURS after learning starts, without evaluations: the slope of metrics.csv."""
    import pandas as pd

    from sidewalk.experiment import METRICS, Trial, collector_frames_per_batch

    probe = compose_experiment(our_overrides(num_envs, threads, 0, FPS_OURS))
    frames_per_batch = collector_frames_per_batch(probe)
    warm = math.ceil(max(probe.algo.learning_starts, probe.algo.batch_size) / frames_per_batch) + 1
    iterations = warm + math.ceil(frames / frames_per_batch)
    overrides = [*our_overrides(num_envs, threads, 0, FPS_OURS), "eval_every=0", "eval_episodes=1",
                 f"iterations={iterations}"]
    experiment = compose_experiment(overrides)
    with tempfile.TemporaryDirectory() as run_dir:
        Trial(experiment, run_dir).run(progress=False)
        rows = pd.read_csv(Path(run_dir) / METRICS)
    learning = rows[rows["train/loss"].notna()]
    first, last = learning.iloc[0], learning.iloc[-1]
    rate = (last["frames"] - first["frames"]) / (last["time_s"] - first["time_s"])
    return {"learner": "ours", "num_envs": experiment.num_envs, "frames_per_s": rate,
            "settings": _our_settings(experiment, FPS_OURS)}


def _our_settings(experiment, extra: Sequence[str]) -> str:
    algo = experiment.algo
    names = ("frames_per_batch", "batch_size", "updates_per_batch", "lr", "learning_starts", "eps_decay_frames",
             "target_update", "tau", "buffer_size", "double_dqn")
    values = ", ".join(f"{name}={getattr(algo, name)}" for name in names)
    given = " ".join(extra) if extra else "none"
    return f"num_envs={experiment.num_envs}, DQNConfig({values}), dueling; overrides: {given}"


# ---- Stable-Baselines3 on the Gymnasium face ---------------------------------------------------------------------


def paper_conv_extractor_class():
    """SB3 ``BaseFeaturesExtractor`` subclass: the paper's conv stack (PAPER_CONV, ReLU) + dense ``features_dim``."""
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    from sidewalk.algos.networks import PAPER_CONV

    class PaperConvExtractor(BaseFeaturesExtractor):
        """32×4 s2, 64×4 s2, 64×2 s1 convolutions with ReLU, flattened, then Linear→ReLU of ``features_dim``."""

        def __init__(self, observation_space, features_dim: int = 256) -> None:
            super().__init__(observation_space, features_dim)
            layers: list[nn.Module] = []
            channels = observation_space.shape[0]
            for out, kernel, stride in zip(PAPER_CONV["num_cells"], PAPER_CONV["kernel_sizes"], PAPER_CONV["strides"]):
                layers += [nn.Conv2d(channels, out, kernel_size=kernel, stride=stride), nn.ReLU()]
                channels = out
            self.cnn = nn.Sequential(*layers, nn.Flatten())
            with torch.no_grad():
                n_flat = self.cnn(torch.zeros(1, *observation_space.shape)).shape[1]
            self.linear = nn.Sequential(nn.Linear(n_flat, features_dim), nn.ReLU())

        def forward(self, observations: torch.Tensor) -> torch.Tensor:
            return self.linear(self.cnn(observations))

    return PaperConvExtractor


def sb3_vec_env(num_envs: int, seed: int, **kwargs: Any):
    """``gymnasium.make_vec("sidewalk/Discrete-v0", opponent="dijkstra", ...)`` (one batched core) as an SB3
    ``VecEnv`` that resets finished worlds within the step (``sidewalk.bench.common.sb3_vec_env``)."""
    return common_sb3_vec_env("sidewalk/Discrete-v0", num_envs, seed, opponent="dijkstra", **kwargs)


def sb3_settings(num_envs: int | None, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """SB3_EQUAL with ``None`` filled from our experiment as composed from conf/ (read at run time)."""
    experiment = compose_experiment(BASE_OVERRIDES)
    algo = experiment.algo
    ours = {
        "n_envs": experiment.num_envs, "learning_rate": algo.lr, "buffer_size": algo.buffer_size,
        "learning_starts": algo.learning_starts, "batch_size": algo.batch_size, "gamma": algo.gamma,
        "max_grad_norm": algo.max_grad_norm, "eps_decay_frames": algo.eps_decay_frames,
        "exploration_initial_eps": algo.eps_start, "exploration_final_eps": algo.eps_end, "tau": algo.tau,
        "frames_per_train": algo.frames_per_batch, "gradient_steps": algo.updates_per_batch,
    }
    settings = {key: ours[key] if value is None else value for key, value in SB3_EQUAL.items()}
    settings.update(overrides or {})
    if num_envs:
        settings["n_envs"] = num_envs
    unknown = sorted(set(settings) - set(SB3_EQUAL))
    if unknown:
        raise ValueError(f"unknown SB3 setting(s) {unknown}; valid: {', '.join(SB3_EQUAL)}")
    return settings


def make_sb3_dqn(settings: dict[str, Any], total_frames: int, seed: int):
    """SB3's DQN with the paper's conv stack + dense 256 on ``n_envs`` worlds of the gymnasium face."""
    import warnings

    from stable_baselines3 import DQN

    settings = dict(settings)
    n_envs = settings.pop("n_envs")
    frames_per_train = settings.pop("frames_per_train")
    eps_decay_frames = settings.pop("eps_decay_frames")
    with warnings.catch_warnings():  # "target network updated after each env.step()": meant (see SB3_EQUAL)
        warnings.filterwarnings("ignore", message="The number of environments used is greater than the target")
        return DQN(
            "CnnPolicy",
            sb3_vec_env(n_envs, seed),
            train_freq=(max(1, round(frames_per_train / n_envs)), "step"),
            exploration_fraction=min(1.0, eps_decay_frames / total_frames),
            policy_kwargs={"features_extractor_class": paper_conv_extractor_class(),
                           "features_extractor_kwargs": {"features_dim": 256}},
            seed=seed,
            device="cpu",
            verbose=0,
            **settings,
        )


def sb3_greedy_policy(model):
    """SB3's greedy Q-policy as a TensorDict module (``observation`` → ``action``) for ``sidewalk.evaluate``."""
    from tensordict.nn import TensorDictModule

    class Greedy(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.q_net = model.policy.q_net

        def forward(self, observation: torch.Tensor) -> torch.Tensor:
            return self.q_net(observation).argmax(-1)

    return TensorDictModule(Greedy(), in_keys=["observation"], out_keys=["action"])


def _eval_view(seed: int):
    """The evaluation view and seed that ``Trial`` uses for this seed, built the same way."""
    from sidewalk.experiment import EVAL_SEED_OFFSET, make_view

    experiment = compose_experiment([*BASE_OVERRIDES, f"seed={seed}"])
    return make_view(experiment, experiment.eval_episodes, seed + EVAL_SEED_OFFSET), seed + EVAL_SEED_OFFSET


def sb3_time_to_target(
    num_envs: int | None, threads: int, seed: int, seconds: float, eval_every_frames: int,
    overrides: dict | None = None,
) -> dict:
    """Train SB3's DQN until a sustained evaluation ≥ TARGET or ``seconds`` of training time."""
    from stable_baselines3.common.callbacks import BaseCallback

    from sidewalk.evaluate import evaluate
    from sidewalk.experiment import capture_rng, restore_rng

    settings = sb3_settings(num_envs, overrides)
    eval_env, eval_seed = _eval_view(seed)
    clock = _Clock(TARGET, seconds, eval_every_frames, CONFIRM)
    total_frames = 1_000_000_000  # learn() stops through the callback; only the ε fraction depends on it

    class EvalEvery(BaseCallback):
        """Evaluates when a rollout starts, i.e. after the gradient steps on the frames so far (as ``Trial`` does
        after its update); the next step ends ``learn`` once the clock says stop."""

        stop = False

        def _on_rollout_start(self) -> None:
            if self.num_timesteps < (clock.evaluations + 1) * eval_every_frames:
                return
            start = time.perf_counter()
            rng = capture_rng()  # as Trial does: evaluation must not shift the training streams
            metrics = evaluate(eval_env, sb3_greedy_policy(self.model), seed=eval_seed)
            restore_rng(rng)
            self.stop = clock.on_eval(metrics["ego/success_rate"], start, time.perf_counter())

        def _on_step(self) -> bool:
            return not self.stop

    with torch_threads(threads):
        torch.manual_seed(seed)
        clock.start = time.perf_counter()
        model = make_sb3_dqn(settings, total_frames, seed)
        model.learn(total_timesteps=total_frames, callback=EvalEvery())
    return {"learner": "sb3", "num_envs": settings["n_envs"], **clock.row(),
            "settings": _sb3_settings_text(settings)}


def sb3_frames_per_s(num_envs: int | None, threads: int, frames: int = FPS_FRAMES) -> dict:
    """Frames/s of SB3's DQN at FPS_SB3 after learning starts, without evaluations."""
    from stable_baselines3.common.callbacks import BaseCallback

    settings = sb3_settings(num_envs, FPS_SB3)
    points: list[tuple[int, float]] = []

    class Clock(BaseCallback):
        def _on_rollout_start(self) -> None:
            points.append((self.num_timesteps, time.perf_counter()))

        def _on_step(self) -> bool:
            return True

    warm = settings["learning_starts"] + settings["frames_per_train"]
    with torch_threads(threads):
        torch.manual_seed(0)
        model = make_sb3_dqn(settings, warm + frames, 0)
        model.learn(total_timesteps=warm + frames, callback=Clock())
    learning = [(n, t) for n, t in points if n > warm]
    (n0, t0), (n1, t1) = learning[0], learning[-1]
    return {"learner": "sb3", "num_envs": settings["n_envs"], "frames_per_s": (n1 - n0) / (t1 - t0),
            "settings": _sb3_settings_text(settings)}


def _sb3_settings_text(settings: dict[str, Any]) -> str:
    n_envs = settings["n_envs"]
    train_freq = max(1, round(settings["frames_per_train"] / n_envs))
    rest = ", ".join(f"{k}={v}" for k, v in settings.items() if k not in ("n_envs", "frames_per_train"))
    return f"n_envs={n_envs}, DQN(CnnPolicy, PaperConvExtractor(256), train_freq={train_freq}, {rest})"


# ---- the section ------------------------------------------------------------------------------------------------


def _as_list(value: int | Sequence[int] | None) -> list[int | None]:
    if value is None:
        return [None]
    return [value] if isinstance(value, int) else list(value)


def _load() -> float:
    return os.getloadavg()[0]


def _loaded(fn, *args, **kwargs) -> dict:
    before = _load()
    row = fn(*args, **kwargs)
    return {**row, "load_1min": f"{before:.1f}-{_load():.1f}"}


def run(
    num_envs: int | Sequence[int] | None = None,
    threads: int | Sequence[int] = 1,
    seconds: float = SECONDS,
    seeds: Sequence[int] = SEEDS,
    setups: Sequence[str] = ("equal", "tuned"),
    learners: Sequence[str] = ("ours", "sb3"),
    fps: bool = True,
    eval_every_frames: int = EVAL_EVERY_FRAMES,
    ours_overrides: Sequence[str] | None = None,
    sb3_overrides: dict[str, Any] | None = None,
) -> list[dict]:
    """Rows of time to TARGET (per seed, then the median) and of frames/s, per learner, setup, worlds, threads.

    ``num_envs``: training worlds of both learners for the ``equal`` setup and frames/s (default: the config's;
    the ``tuned`` setups choose their own); ``seconds``: training-time cap of each run; ``ours_overrides`` (Hydra
    overrides) and ``sb3_overrides`` (SB3_EQUAL keys) replace TUNED_OURS / TUNED_SB3 in the ``tuned`` setup.
    ``runners/bench.py`` passes ``num_envs`` and ``threads`` as lists.
    """
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        learners = [name for name in learners if name != "sb3"]
        missing_sb3 = True
    else:
        missing_sb3 = False
    tuned_ours = TUNED_OURS if ours_overrides is None else tuple(ours_overrides)
    tuned_sb3 = TUNED_SB3 if sb3_overrides is None else dict(sb3_overrides)
    rows: list[dict] = []
    for n_threads in _as_list(threads):
        for n in _as_list(num_envs):
            base = {"threads": n_threads}
            if fps:
                for learner in learners:
                    measure = ours_frames_per_s if learner == "ours" else sb3_frames_per_s
                    rows.append({**base, "measure": "frames_per_s", "setup": "fps", **_loaded(measure, n, n_threads)})
            for setup in setups:
                for learner in learners:
                    per_seed = []
                    for seed in seeds:
                        if learner == "ours":
                            extra = () if setup == "equal" else tuned_ours
                            row = _loaded(ours_time_to_target, n if setup == "equal" else None, n_threads, seed,
                                          seconds, eval_every_frames, extra)
                        else:
                            extra = {} if setup == "equal" else tuned_sb3
                            row = _loaded(sb3_time_to_target, n if setup == "equal" else None, n_threads, seed,
                                          seconds, eval_every_frames, extra)
                        per_seed.append({**base, "measure": f"time_to_{TARGET}", "setup": setup, "seed": seed, **row})
                        if VERBOSE:
                            done = per_seed[-1]
                            print(f"{setup} {learner} seed {seed}: first {done.get('seconds_to_target')} s, "
                                  f"sustained {done.get('seconds_sustained')} s, {done.get('note') or ''}",
                                  file=sys.stderr, flush=True)
                    rows += per_seed
                    if len(per_seed) > 1:
                        rows.append(_median(per_seed))
    if missing_sb3:
        rows.append({"learner": "sb3", "note": "skipped: stable-baselines3 is not installed (pip install stable-baselines3)"})
    _add_ratios(rows)
    return [{column: row.get(column) for column in COLUMNS} for row in rows]


def _median(per_seed: list[dict]) -> dict:
    """Median over seeds; a seed that never reached the target counts as its training time (a lower bound)."""
    row = {key: per_seed[0][key] for key in ("threads", "measure", "setup", "learner", "num_envs", "settings")}
    row["seed"] = "median"
    for key, fallback in (("seconds_to_target", "train_seconds"), ("seconds_sustained", "train_seconds"),
                          ("seconds_to_target_with_eval", None), ("frames_to_target", None),
                          ("frames_sustained", None)):
        values = [r.get(key, r.get(fallback) if fallback else None) for r in per_seed]
        values = [v for v in values if v is not None]
        if values:
            row[key] = statistics.median(values)
    row["best_success"] = statistics.median(r["best_success"] for r in per_seed)
    row["solved_at_first_eval"] = f"{sum(bool(r.get('solved_at_first_eval')) for r in per_seed)}/{len(per_seed)}"
    missed = sum(r.get("seconds_sustained") is None for r in per_seed)
    if missed:
        row["note"] = f"{missed}/{len(per_seed)} seeds not sustained within the cap (counted at their cap)"
    return row


def _add_ratios(rows: list[dict]) -> None:
    """Note on each of our median (or single-seed) rows how it compares with the matching SB3 row."""
    def key(row):
        return row.get("measure"), row.get("setup"), row.get("seed"), row.get("threads")

    medians = {(r.get("setup"), r.get("threads")) for r in rows if r.get("seed") == "median"}
    for row in rows:
        if row.get("learner") != "ours" or (row.get("seed") != "median" and (row.get("setup"), row.get("threads")) in medians):
            continue
        other = next((r for r in rows if r.get("learner") == "sb3" and key(r) == key(row)), None)
        if other is None:
            continue
        if row["measure"] == "frames_per_s":
            ratio = f"{row['frames_per_s'] / other['frames_per_s']:.2f}x SB3's frames/s"
        else:
            parts = []
            for name in ("seconds_to_target", "seconds_sustained"):
                if row.get(name) and other.get(name):
                    parts.append(f"{name}: {other[name] / row[name]:.2f}x SB3's speed")
            ratio = "; ".join(parts)
        row["note"] = "; ".join(filter(None, [row.get("note"), ratio]))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", help="worlds of the equal setup and frames/s (default: config's)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--seconds", type=float, default=SECONDS, help="training-time cap of each run")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("--setups", nargs="*", default=["equal", "tuned"], choices=["equal", "tuned"])
    parser.add_argument("--learners", nargs="+", default=["ours", "sb3"], choices=["ours", "sb3"])
    parser.add_argument("--no-fps", action="store_true", help="skip the frames/s rows")
    parser.add_argument("--eval-every-frames", type=int, default=EVAL_EVERY_FRAMES)
    parser.add_argument("--ours", nargs="*", help="Hydra overrides of our tuned run (replace TUNED_OURS)")
    parser.add_argument("--sb3", nargs="*", help="SB3 settings key=value of the tuned run (replace TUNED_SB3)")
    parser.add_argument("--verbose", action="store_true", help="print every evaluation and run to stderr")
    args = parser.parse_args(argv)
    global VERBOSE
    VERBOSE = args.verbose
    sb3 = None
    if args.sb3 is not None:
        sb3 = {}
        for item in args.sb3:
            name, _, value = item.partition("=")
            if name not in SB3_EQUAL:
                parser.error(f"--sb3 {name}: unknown; valid: {', '.join(SB3_EQUAL)}")
            sb3[name] = ast.literal_eval(value)
    rows = run(args.num_envs, args.threads, args.seconds, args.seeds, args.setups, args.learners, not args.no_fps,
               args.eval_every_frames, args.ours, sb3)
    print(format_table(rows))


if __name__ == "__main__":
    main()
