"""Training speed: wall clock until our DQN's greedy policy succeeds on three evaluations in a row against the Dijkstra
opponent (discrete sidewalk, noise 0.1), beside Stable-Baselines3's DQN; both learners' frames/s and cost per
gradient step at equal settings; and our cost per gradient step beside the same math in plain PyTorch.

Ours is the ``runners/main.py`` path: the experiment composed from ``conf/`` (so the DQN defaults are read at run
time) and run by ``Trial``. SB3's DQN trains on our Gymnasium face (``gymnasium.make_vec("sidewalk/Discrete-v0",
opponent="dijkstra", noise=0.1)``, one batched core) through a thin SB3 ``VecEnv`` adapter, with a features
extractor that is the paper's conv stack plus a dense 256 (SB3's ``NatureCNN`` needs ≥ 36×36 images; ours are
14×30) and SB3's linear Q layer on top. SB3 draws one ε coin per vector step for all worlds, ours one per world.

Both are evaluated alike: every ``eval_every_frames`` training frames, ``sidewalk.evaluate.evaluate`` plays one
greedy episode in each world of the evaluation view ``Trial`` builds (``eval_episodes`` worlds, the same seed). At
noise 0.1 the worlds' episodes differ, so a success rate is not all or nothing. The criterion: CONFIRM + 1
evaluations in a row with ego success ≥ TARGET; ``seconds_to_criterion`` is the training wall clock from building
the learner to the last of them, the evaluations' own time taken out (``seconds_with_eval`` leaves it in);
``seconds_first`` is the first evaluation ≥ TARGET. A run stops after ``seconds`` of training and says it did
not meet the criterion; the median then counts it at its cap (a lower bound).

Setups (rows compare ours with SB3's row of the setup named in ``versus``):
- ``equal``: the same hyper-parameters (worlds, frames an iteration, batch, gradient steps, learning rate, ε
  schedule, Polyak rate, buffer, γ) and the same network: ours without the dueling head and without double DQN
  (SB3's DQN has neither); SB3 at SB3_EQUAL, read from our conf at run time.
- ``dueling``: ours at its defaults (the paper's dueling head, double DQN), against SB3's ``equal`` row.
- ``tuned``: the settings given with ``--ours`` / ``--sb3``; none: ``dueling``'s and ``equal``'s, the best a search
  found (what was tried is said at SETUPS), so it is not run by default.
frames/s and ms per gradient step (``--fps-setups``): ours at ``equal`` and ``dueling``, SB3 at ``equal``, timed after
learning starts, without evaluations. A gradient step's cost is the median over the learner's update calls of a
call's time over its gradient steps, in wall clock and in CPU time (the notes' ratios: CPU time first, steadier on a
shared machine). Ours: ``DQN.update``, with the replay-buffer write, the sampling, the loss, the optimiser and the
Polyak step; SB3: ``DQN.train``, with the sampling, the loss, the optimiser and its logger (its Polyak step runs
outside, once per vector step). ``plain``: the same update in plain PyTorch at the same setup
(``plain_gradient_steps``: our network in ``torch.nn`` layers, tensors for a buffer, the write, the sampling, the
loss, Adam, Polyak), timed in a loop, with its arithmetic counted in the note (MFLOP a step).

    python -m sidewalk.bench.training                          # equal and dueling; seeds 0-4; frames/s
    python -m sidewalk.bench.training --setups equal --seeds 0 --verbose
    python -m sidewalk.bench.training --setups                 # ~1 min: frames/s and ms per gradient step only
"""

from __future__ import annotations

import argparse
import ast
import logging
import math
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from copy import deepcopy
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sidewalk.bench.common import format_table, torch_threads
from sidewalk.bench.common import sb3_vec_env as common_sb3_vec_env
from sidewalk.compose import compose_experiment

TARGET = 0.9
CONFIRM = 2  # further evaluations ≥ TARGET after a first: the criterion is three in a row
NOISE = 0.1  # the grid's action noise: evaluation worlds play different episodes
SECONDS = 240.0  # training-time cap of one run
SEEDS = (0, 1, 2, 3, 4)
EVAL_EVERY_FRAMES = 10_240  # 20 iterations of our default DQN
FPS_FRAMES = 25_600  # timed frames after learning starts, for frames/s
# Every run: the discrete sidewalk against Dijkstra at noise 0.1, no logger, no checkpoint until the end.
BASE_OVERRIDES = ("env=discrete", "opponent=dijkstra", "algo=dqn", f"noise={NOISE}", "logger=none", "checkpoint_every=0")
# SB3's DQN network: no dueling head, no double DQN.
EQUAL_NETWORK = ("algo.dueling=false", "algo.double_dqn=false")
# ``tuned``: a search at noise 0 (median over seeds 0-3 of the time to two evaluations in a row >= 0.9; 32, 64 and 128
# worlds, 128 or 512 frames an iteration, Polyak 0.01/0.05/0.1, ε decay 5k frames, lr 2.5e-4 or 1e-3, l2 loss) found
# 128 worlds, 4 gradient steps per 512 frames and Polyak 0.05 best for both learners: those are now our DQN defaults,
# so without --ours / --sb3 ``tuned`` runs ours at its defaults (the ``dueling`` row) and SB3 at ``equal``.
SETUPS = ("equal", "dueling", "tuned")
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
    "target_update_interval": 1,  # Polyak every vector step: 4 per 512 frames of 128 worlds, as ours per update
    "frames_per_train": None,
    "gradient_steps": None,
}
DEFAULT_SETUPS = ("equal", "dueling")
FPS_SETUPS = ("equal", "dueling")  # the frames/s and cost-per-gradient-step rows: ours and plain at both, SB3 at equal
LEARNERS = ("ours", "sb3", "plain")  # plain: our DQN's update in plain PyTorch (a cost per gradient step only)
COLUMNS = (
    "measure", "setup", "learner", "seed", "num_envs", "threads", "seconds_to_criterion", "min_s", "max_s",
    "frames_to_criterion", "met", "seconds_first", "seconds_with_eval", "best_success", "frames_per_s",
    "ms_per_gradient_step", "cpu_ms_per_gradient_step", "load_1min", "note", "settings",
)
log = logging.getLogger(__name__)  # --verbose: every evaluation and run, to stderr


# ---- our side: the runners/main.py path -------------------------------------------------------------------------


class _Clock:
    """Training time to the criterion: wall clock since ``start`` minus the evaluations' own time.

    ``first``: the first evaluation ≥ target. ``met``: the last of ``confirm + 1`` evaluations in a row ≥ target,
    the moment a user watching the curve would call the policy learned.
    """

    def __init__(self, target: float, seconds: float, eval_every_frames: int, confirm: int) -> None:
        self.target, self.seconds, self.eval_every_frames, self.confirm = target, seconds, eval_every_frames, confirm
        self.start = time.perf_counter()
        self.eval_s = 0.0
        self.evaluations = 0
        self.best = -math.inf
        self.history: list[tuple[int, float, float]] = []  # (frames, training seconds, success)
        self.first: dict[str, float] | None = None
        self.streak = 0
        self.met: dict[str, float] | None = None

    def on_eval(self, success: float, eval_start: float, eval_end: float) -> bool:
        """Record one evaluation; True when the run should stop."""
        self.evaluations += 1
        frames = self.evaluations * self.eval_every_frames
        train_s = eval_start - self.start - self.eval_s
        point = {"seconds": train_s, "seconds_with_eval": eval_start - self.start, "frames": frames}
        self.eval_s += eval_end - eval_start
        self.best = max(self.best, success)
        self.history.append((frames, train_s, success))
        log.info("  eval %d: %d frames, %.1f s training (+%.1f s eval), ego success %.3f, load %.1f",
                 self.evaluations, frames, train_s, self.eval_s, success, os.getloadavg()[0])
        self.streak = self.streak + 1 if success >= self.target else 0
        if self.streak == 1 and self.first is None:
            self.first = point
        if self.streak > self.confirm:
            self.met = point
            return True
        return train_s >= self.seconds

    def row(self) -> dict[str, Any]:
        train_s = self.history[-1][1] if self.history else 0.0
        row: dict[str, Any] = {"best_success": self.best, "evaluations": self.evaluations, "train_seconds": train_s,
                               "met": self.met is not None}
        if self.first is not None:
            row["seconds_first"] = self.first["seconds"]
        if self.met is not None:
            row.update(seconds_to_criterion=self.met["seconds"], seconds_with_eval=self.met["seconds_with_eval"],
                       frames_to_criterion=self.met["frames"])
        else:
            row["note"] = (f"no {self.confirm + 1} evaluations in a row >= {self.target} within {train_s:.0f} s "
                           f"of training (best {self.best:.2f})")
        return row


@contextmanager
def _gradient_step_timer(owner: Any, method: str, steps_of_call) -> Iterator[list[tuple[float, float, int]]]:
    """Wrap ``owner.method`` (a class or an instance) to record (seconds, CPU seconds, gradient steps) of each call that
    takes any: ``steps_of_call(args, kwargs, call)`` runs the timed ``call()`` and returns the gradient steps it
    took."""
    calls: list[tuple[float, float, int]] = []
    original = getattr(owner, method)

    def timed(*args, **kwargs):
        result: dict[str, Any] = {}

        def call():
            start, cpu_start = time.perf_counter(), time.process_time()
            result["value"] = original(*args, **kwargs)
            result["seconds"] = time.perf_counter() - start
            result["cpu_seconds"] = time.process_time() - cpu_start
            return result["value"]

        steps = steps_of_call(args, kwargs, call)
        if steps:
            calls.append((result["seconds"], result["cpu_seconds"], steps))
        return result["value"]

    setattr(owner, method, timed)
    try:
        yield calls
    finally:
        if isinstance(owner, type):
            setattr(owner, method, original)
        else:
            delattr(owner, method)


def _per_step(calls: list[tuple[float, float, int]]) -> dict[str, float]:
    """Wall-clock and CPU milliseconds (this process's threads) per gradient step: the median over timed calls of
    (seconds, CPU seconds, gradient steps). On a shared machine the CPU time and the median are the steadier
    measures of cost: others' work stretches the wall clock, in bursts."""
    return {"ms_per_gradient_step": 1000 * statistics.median(wall / steps for wall, _, steps in calls),
            "cpu_ms_per_gradient_step": 1000 * statistics.median(cpu / steps for _, cpu, steps in calls)}


def our_overrides(num_envs: int | None, threads: int, seed: int, extra: Sequence[str]) -> list[str]:
    worlds = [f"num_envs={num_envs}"] if num_envs else []
    return [*BASE_OVERRIDES, *worlds, f"torch_threads={threads}", f"seed={seed}", *extra]


def ours_time_to_target(
    num_envs: int | None, threads: int, seed: int, seconds: float, eval_every_frames: int, extra: Sequence[str] = ()
) -> dict:
    """Run ``Trial`` until the criterion is met or ``seconds`` of training time."""
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


def ours_frames_per_s(
    num_envs: int | None, threads: int, frames: int = FPS_FRAMES, extra: Sequence[str] = EQUAL_NETWORK
) -> dict:
    """Frames/s of ``Trial`` after learning starts, without evaluations (the slope of metrics.csv), and the
    milliseconds of ``DQN.update`` per gradient step in the same run; at the equal settings (``extra``: the
    defaults with ``()``)."""
    import pandas as pd

    from sidewalk.algos.dqn import DQN
    from sidewalk.experiment import METRICS, Trial, collector_frames_per_batch

    probe = compose_experiment(our_overrides(num_envs, threads, 0, extra))
    frames_per_batch = collector_frames_per_batch(probe)
    warm = math.ceil(max(probe.algo.learning_starts, probe.algo.batch_size) / frames_per_batch) + 1
    iterations = warm + math.ceil(frames / frames_per_batch)
    overrides = [*our_overrides(num_envs, threads, 0, extra), "eval_every=0", "eval_episodes=1",
                 f"iterations={iterations}"]
    experiment = compose_experiment(overrides)

    def steps_of_update(args, kwargs, call):
        algo = args[0]
        before = algo.updates
        call()
        return algo.updates - before

    with tempfile.TemporaryDirectory() as run_dir, _gradient_step_timer(DQN, "update", steps_of_update) as calls:
        Trial(experiment, run_dir).run(progress=False)
        rows = pd.read_csv(Path(run_dir) / METRICS)
    learning = rows[rows["train/loss"].notna()]
    first, last = learning.iloc[0], learning.iloc[-1]
    rate = (last["frames"] - first["frames"]) / (last["time_s"] - first["time_s"])
    return {"learner": "ours", "num_envs": experiment.num_envs, "frames_per_s": rate,
            **_per_step(calls),
            "settings": _our_settings(experiment, extra)}


def _our_settings(experiment, extra: Sequence[str]) -> str:
    algo = experiment.algo
    names = ("frames_per_batch", "batch_size", "updates_per_batch", "lr", "learning_starts", "eps_decay_frames",
             "target_update", "tau", "buffer_size", "gamma", "dueling", "double_dqn")
    values = ", ".join(f"{name}={getattr(algo, name)}" for name in names)
    given = " ".join(extra) if extra else "none"
    return f"num_envs={experiment.num_envs}, DQNConfig({values}); overrides: {given}"


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
    """``gymnasium.make_vec("sidewalk/Discrete-v0", opponent="dijkstra", noise=NOISE, ...)`` (one batched core) as an
    SB3 ``VecEnv`` that resets finished worlds within the step (``sidewalk.bench.common.sb3_vec_env``)."""
    return common_sb3_vec_env("sidewalk/Discrete-v0", num_envs, seed, **{"opponent": "dijkstra", "noise": NOISE, **kwargs})


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
            # net_arch=[]: Q straight from the extractor's 256 (SB3 puts 64-64 layers after any extractor but NatureCNN)
            policy_kwargs={"features_extractor_class": paper_conv_extractor_class(),
                           "features_extractor_kwargs": {"features_dim": 256}, "net_arch": []},
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
    from sidewalk.experiment import EVAL_SEED_OFFSET

    experiment = compose_experiment([*BASE_OVERRIDES, f"seed={seed}"])
    seed += EVAL_SEED_OFFSET
    return experiment.world.make(experiment.eval_episodes, seed, experiment.device), seed


def sb3_time_to_target(
    num_envs: int | None, threads: int, seed: int, seconds: float, eval_every_frames: int,
    overrides: dict | None = None,
) -> dict:
    """Train SB3's DQN until the criterion is met or ``seconds`` of training time."""
    from stable_baselines3.common.callbacks import BaseCallback

    from sidewalk.evaluate import evaluate
    from sidewalk.snapshot import capture_rng, restore_rng

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
    """Frames/s of SB3's DQN at the equal settings after learning starts, without evaluations, and the milliseconds
    of ``DQN.train`` per gradient step in the same run."""
    from stable_baselines3.common.callbacks import BaseCallback

    settings = sb3_settings(num_envs)
    points: list[tuple[int, float]] = []

    class Clock(BaseCallback):
        def _on_rollout_start(self) -> None:
            points.append((self.num_timesteps, time.perf_counter()))

        def _on_step(self) -> bool:
            return True

    warm = settings["learning_starts"] + settings["frames_per_train"]
    def steps_of_train(args, kwargs, call):
        call()
        return kwargs["gradient_steps"] if "gradient_steps" in kwargs else args[0]

    with torch_threads(threads):
        torch.manual_seed(0)
        model = make_sb3_dqn(settings, warm + frames, 0)
        with _gradient_step_timer(model, "train", steps_of_train) as calls:
            model.learn(total_timesteps=warm + frames, callback=Clock())
    learning = [(n, t) for n, t in points if n > warm]
    (n0, t0), (n1, t1) = learning[0], learning[-1]
    return {"learner": "sb3", "num_envs": settings["n_envs"], "frames_per_s": (n1 - n0) / (t1 - t0),
            **_per_step(calls),
            "settings": _sb3_settings_text(settings)}


def _sb3_settings_text(settings: dict[str, Any]) -> str:
    n_envs = settings["n_envs"]
    train_freq = max(1, round(settings["frames_per_train"] / n_envs))
    rest = ", ".join(f"{k}={v}" for k, v in settings.items() if k not in ("n_envs", "frames_per_train"))
    return f"n_envs={n_envs}, DQN(CnnPolicy, PaperConvExtractor(256), train_freq={train_freq}, {rest})"


# ---- plain PyTorch: the same math without a framework -----------------------------------------------------------


class PlainQNetwork(nn.Module):
    """Our Q-network in ``torch.nn`` layers: uint8 images /255 → the paper's convs (channels-last weights, as ours)
    → dense ``hidden`` → a linear Q layer, or the dueling head's value and advantage streams of ``hidden`` each."""

    def __init__(self, observation_shape: torch.Size, n_actions: int, hidden: int, dueling: bool) -> None:
        super().__init__()
        from sidewalk.algos.networks import PAPER_CONV

        layers: list[nn.Module] = []
        channels = observation_shape[0]
        for out, kernel, stride in zip(PAPER_CONV["num_cells"], PAPER_CONV["kernel_sizes"], PAPER_CONV["strides"]):
            layers += [nn.Conv2d(channels, out, kernel_size=kernel, stride=stride), nn.ReLU()]
            channels = out
        self.convs = nn.Sequential(*layers, nn.Flatten()).to(memory_format=torch.channels_last)
        with torch.no_grad():
            n_flat = self.convs(torch.zeros(1, *observation_shape)).shape[1]

        def stream(out: int) -> nn.Sequential:
            return nn.Sequential(nn.Linear(n_flat, hidden), nn.ReLU(), nn.Linear(hidden, out))

        self.dueling = dueling
        self.q = None if dueling else stream(n_actions)
        self.value, self.advantage = (stream(1), stream(n_actions)) if dueling else (None, None)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        features = self.convs(observation.to(torch.float32) / 255.0)
        if not self.dueling:
            return self.q(features)
        advantage = self.advantage(features)
        return self.value(features) + advantage - advantage.mean(-1, keepdim=True)


def plain_gradient_steps(num_envs: int | None, threads: int, extra: Sequence[str], steps: int = 200) -> dict:
    """Milliseconds per gradient step of our DQN's update in plain PyTorch (``PlainQNetwork``, no TorchRL, no
    tensordict), our settings with the ``extra`` overrides: per iteration, ``frames_per_batch`` transitions written
    into preallocated uint8 tensors, then ``updates_per_batch`` steps of a uniform minibatch: Q of the observations
    with gradient, of the next observations without (the target network; and the online one to choose under double
    DQN), the TD(0) target, the loss averaged, backward, gradient-norm clip, Adam (its default, per-tensor loop),
    Polyak (a lerp_ per tensor). Timed in a loop of ``steps`` steps after a warm-up; the arithmetic of one step is
    counted by ``torch.utils.flop_counter``."""
    import torch.nn.functional as F
    from torch.utils.flop_counter import FlopCounterMode

    experiment = compose_experiment(our_overrides(num_envs, threads, 0, extra))
    cfg = experiment.algo
    view = experiment.world.make(1, 0, experiment.device)
    shape = view.full_observation_spec_unbatched["observation"].shape
    n_actions = int(view.full_action_spec_unbatched["action"].space.n)
    loss_function = {"l2": F.mse_loss, "l1": F.l1_loss, "smooth_l1": F.smooth_l1_loss}[cfg.loss_function]
    generator = torch.Generator().manual_seed(0)
    with torch_threads(threads):
        torch.manual_seed(0)
        online = PlainQNetwork(shape, n_actions, cfg.hidden, cfg.dueling)
        target = deepcopy(online).requires_grad_(False)
        optimizer = torch.optim.Adam(online.parameters(), lr=cfg.lr)
        size = min(cfg.buffer_size, 2 * FPS_FRAMES)
        observations = torch.randint(0, 256, (size, *shape), dtype=torch.uint8, generator=generator)
        next_observations = torch.randint(0, 256, (size, *shape), dtype=torch.uint8, generator=generator)
        actions = torch.randint(0, n_actions, (size,), generator=generator)
        rewards = torch.randn(size, generator=generator)
        terminated = torch.rand(size, generator=generator) < 0.01
        frames = cfg.frames_per_batch
        new = {name: data[:frames].clone() for name, data in
               (("observation", observations), ("next", next_observations), ("action", actions),
                ("reward", rewards), ("terminated", terminated))}

        def iteration(cursor: int) -> torch.Tensor:
            rows = torch.arange(cursor, cursor + frames) % size  # the write: a ring buffer
            for data, name in ((observations, "observation"), (next_observations, "next"), (actions, "action"),
                               (rewards, "reward"), (terminated, "terminated")):
                data[rows] = new[name]
            for _ in range(cfg.updates_per_batch):
                index = torch.randint(0, size, (cfg.batch_size,), generator=generator)
                observation, next_observation = observations[index], next_observations[index]
                q_taken = online(observation).gather(-1, actions[index].unsqueeze(-1)).squeeze(-1)
                with torch.no_grad():
                    next_q = target(next_observation)
                    choice = online(next_observation) if cfg.double_dqn else next_q
                    next_value = next_q.gather(-1, choice.argmax(-1, keepdim=True)).squeeze(-1)
                    td_target = rewards[index] + cfg.gamma * (~terminated[index]) * next_value
                loss = loss_function(q_taken, td_target)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(online.parameters(), cfg.max_grad_norm)
                optimizer.step()
                with torch.no_grad():
                    for p_target, p_online in zip(target.parameters(), online.parameters()):
                        p_target.lerp_(p_online, cfg.tau)
            return loss

        iterations = max(1, math.ceil(steps / cfg.updates_per_batch))
        for i in range(5):  # warm-up: oneDNN's kernels, Adam's state
            iteration(i * frames)
        calls = []
        for i in range(iterations):
            start, cpu_start = time.perf_counter(), time.process_time()
            iteration(i * frames)
            calls.append((time.perf_counter() - start, time.process_time() - cpu_start, cfg.updates_per_batch))
        counter = FlopCounterMode(display=False)
        with counter:
            iteration(0)
    per_step = _per_step(calls)
    mflop = counter.get_total_flops() / cfg.updates_per_batch / 1e6
    return {"learner": "plain", "num_envs": experiment.num_envs, **per_step,
            "note": f"{mflop:.0f} MFLOP a step, {mflop / per_step['cpu_ms_per_gradient_step']:.0f} GFLOP/s of CPU time",
            "settings": f"plain PyTorch, {_our_settings(experiment, extra)}"}


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
    setups: Sequence[str] = DEFAULT_SETUPS,
    learners: Sequence[str] = LEARNERS,
    fps: bool = True,
    eval_every_frames: int = EVAL_EVERY_FRAMES,
    ours_overrides: Sequence[str] | None = None,
    sb3_overrides: dict[str, Any] | None = None,
    fps_setups: Sequence[str] = FPS_SETUPS,
) -> list[dict]:
    """Rows of time to the criterion (per seed, then the median with min and max) and of frames/s and ms per gradient
    step, per learner, setup, worlds, threads.

    ``num_envs``: training worlds of both learners for the ``equal``/``dueling`` setups and frames/s (default: the
    config's; the ``tuned`` setups choose their own); ``seconds``: training-time cap of each run;
    ``ours_overrides`` (Hydra overrides) and ``sb3_overrides`` (SB3_EQUAL keys): the ``tuned`` setup's settings
    (none: ours at its defaults, SB3 at ``equal``); ``fps_setups``: the setups of the frames/s and
    cost-per-gradient-step rows (SB3 at ``equal`` only, ``plain`` has no frames/s). ``runners/bench.py`` passes
    ``num_envs`` and ``threads`` as lists.
    """
    unknown = sorted(set(setups) - set(SETUPS)) + sorted(set(fps_setups) - set(FPS_SETUPS))
    if unknown:
        raise ValueError(f"unknown setup(s) {unknown}; valid: {', '.join(SETUPS)} (frames/s: {', '.join(FPS_SETUPS)})")
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        learners = [name for name in learners if name != "sb3"]
        missing_sb3 = True
    else:
        missing_sb3 = False
    tuned_sb3 = dict(sb3_overrides or {})
    ours_extra = {"equal": EQUAL_NETWORK, "dueling": (), "tuned": tuple(ours_overrides or ())}
    rows: list[dict] = []
    for n_threads in _as_list(threads):
        for n in _as_list(num_envs):
            base = {"threads": n_threads}
            for setup in fps_setups if fps else ():
                for learner in learners:
                    if learner == "ours":
                        row = _loaded(ours_frames_per_s, n, n_threads, extra=ours_extra[setup])
                    elif learner == "plain":
                        row = _loaded(plain_gradient_steps, n, n_threads, ours_extra[setup])
                    elif setup == "equal":  # SB3's DQN has neither the dueling head nor double DQN
                        row = _loaded(sb3_frames_per_s, n, n_threads)
                    else:
                        continue
                    rows.append({**base, "measure": "frames_per_s", "setup": setup, **row})
            for setup in setups:
                for learner in learners:
                    if learner == "plain":
                        continue  # a cost per gradient step, not a learner run
                    if learner == "sb3" and setup == "dueling":
                        continue  # SB3's DQN has no dueling head: ours with it is compared with SB3's equal row
                    worlds = None if setup == "tuned" else n
                    per_seed = []
                    for seed in seeds:
                        if learner == "ours":
                            row = _loaded(ours_time_to_target, worlds, n_threads, seed, seconds, eval_every_frames,
                                          ours_extra[setup])
                        else:
                            row = _loaded(sb3_time_to_target, worlds, n_threads, seed, seconds, eval_every_frames,
                                          tuned_sb3 if setup == "tuned" else {})
                        per_seed.append({**base, "measure": "time_to_criterion", "setup": setup, "seed": seed, **row})
                        done = per_seed[-1]
                        log.info("%s %s seed %s: criterion %s s, first %s s, %s", setup, learner, seed,
                                 done.get("seconds_to_criterion"), done.get("seconds_first"), done.get("note") or "")
                    rows += per_seed
                    if len(per_seed) > 1:
                        rows.append(_median(per_seed))
    if missing_sb3:
        rows.append({"learner": "sb3", "note": "skipped: stable-baselines3 is not installed (pip install stable-baselines3)"})
    _add_ratios(rows)
    return [{column: row.get(column) for column in COLUMNS} for row in rows]


def _median(per_seed: list[dict]) -> dict:
    """Median, min and max over seeds; a seed that never met the criterion counts at its training time (a lower
    bound, said in the note)."""
    row = {key: per_seed[0][key] for key in ("threads", "measure", "setup", "learner", "num_envs", "settings")}
    row["seed"] = "median"
    seconds = [r.get("seconds_to_criterion", r["train_seconds"]) for r in per_seed]
    row.update(seconds_to_criterion=statistics.median(seconds), min_s=min(seconds), max_s=max(seconds))
    for key in ("frames_to_criterion", "seconds_first", "seconds_with_eval"):
        values = [r[key] for r in per_seed if r.get(key) is not None]
        if values:
            row[key] = statistics.median(values)
    row["best_success"] = statistics.median(r["best_success"] for r in per_seed)
    met = sum(bool(r.get("met")) for r in per_seed)
    row["met"] = f"{met}/{len(per_seed)}"
    if met < len(per_seed):
        row["note"] = f"{len(per_seed) - met}/{len(per_seed)} seeds did not meet the criterion (counted at their cap)"
    return row


def _cost_ratio(row: dict, other: dict) -> str:
    """``row``'s cost per gradient step over ``other``'s: CPU time, then wall clock."""
    return (f"{row['cpu_ms_per_gradient_step'] / other['cpu_ms_per_gradient_step']:.2f}x "
            f"({row['ms_per_gradient_step'] / other['ms_per_gradient_step']:.2f}x wall)")


def _add_ratios(rows: list[dict]) -> None:
    """Note on each of our median (or single-seed) rows how it compares with the matching SB3 row: the same setup
    (time rows at ``dueling``: SB3's ``equal``; frames/s rows at ``equal`` only), seed and threads; and on our
    frames/s rows, our cost per gradient step beside plain PyTorch's at the same setup."""
    def key(row, setup=None):
        return row.get("measure"), setup or row.get("setup"), row.get("seed"), row.get("threads")

    def match(learner, row, setup=None):
        return next((r for r in rows if r.get("learner") == learner and key(r) == key(row, setup)), None)

    medians = {(r.get("setup"), r.get("threads")) for r in rows if r.get("seed") == "median"}
    for row in rows:
        if row.get("learner") != "ours":
            continue
        parts = []
        if row["measure"] == "frames_per_s":
            sb3, plain = match("sb3", row), match("plain", row)
            if sb3 is not None:
                parts += [f"{row['frames_per_s'] / sb3['frames_per_s']:.2f}x SB3's frames/s",
                          f"{_cost_ratio(row, sb3)} SB3's cost per gradient step"]
            if plain is not None:
                parts.append(f"{_cost_ratio(row, plain)} plain PyTorch's")
        elif row.get("seed") == "median" or (row.get("setup"), row.get("threads")) not in medians:
            versus = "equal" if row.get("setup") == "dueling" else row.get("setup")
            sb3 = match("sb3", row, versus)
            if sb3 is not None and row.get("seconds_to_criterion") and sb3.get("seconds_to_criterion"):
                parts.append(f"{row['seconds_to_criterion'] / sb3['seconds_to_criterion']:.2f}x SB3's time "
                             f"(SB3 {versus})")
        row["note"] = "; ".join(filter(None, [row.get("note"), *parts]))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", help="worlds of the equal setup and frames/s (default: config's)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--seconds", type=float, default=SECONDS, help="training-time cap of each run")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("--setups", nargs="*", default=list(DEFAULT_SETUPS), choices=list(SETUPS))
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=list(LEARNERS))
    parser.add_argument("--no-fps", action="store_true", help="skip the frames/s rows")
    parser.add_argument("--fps-setups", nargs="*", default=list(FPS_SETUPS), choices=list(FPS_SETUPS),
                        help="setups of the frames/s and cost-per-gradient-step rows")
    parser.add_argument("--eval-every-frames", type=int, default=EVAL_EVERY_FRAMES)
    parser.add_argument("--ours", nargs="*", help="Hydra overrides of our tuned run (default: our defaults)")
    parser.add_argument("--sb3", nargs="*", help="SB3 settings key=value of the tuned run (default: equal's)")
    parser.add_argument("--verbose", action="store_true", help="print every evaluation and run to stderr")
    args = parser.parse_args(argv)
    if args.verbose:
        log.addHandler(logging.StreamHandler(sys.stderr))
        log.setLevel(logging.INFO)
    sb3 = None
    if args.sb3 is not None:
        sb3 = {}
        for item in args.sb3:
            name, _, value = item.partition("=")
            if name not in SB3_EQUAL:
                parser.error(f"--sb3 {name}: unknown; valid: {', '.join(SB3_EQUAL)}")
            sb3[name] = ast.literal_eval(value)
    rows = run(args.num_envs, args.threads, args.seconds, args.seeds, args.setups, args.learners, not args.no_fps,
               args.eval_every_frames, args.ours, sb3, args.fps_setups)
    print(format_table(rows))


if __name__ == "__main__":
    main()
