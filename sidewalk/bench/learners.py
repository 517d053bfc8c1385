"""Learners: our TRPO and PPO beside sb3-contrib's TRPO and Stable-Baselines3's PPO, on the continuous sidewalk
against one scripted opponent, with the same seeds, the same frame budget and the same evaluation.

Ours run the ``runners/main.py`` path: ``python runners/main.py env=continuous opponent=X algo=trpo|ppo seed=S
noise=N`` composed from ``conf/`` and run by ``Trial`` (``logger=none``, ``checkpoint_every=0``, the budget as
``iterations``, rounded up to whole iterations of each learner). The peers train ``"MlpPolicy"`` on our Gymnasium face, ``gymnasium.make_vec("sidewalk/Continuous-v0",
...)`` with the env parameters of that same composed experiment (geometry, dt, rewards, noise, the opponent's
settings), one batched core of the config's ``num_envs`` worlds behind an SB3 ``VecEnv`` adapter whose actions are
rescaled to [-1, 1]. Setups of the peers (ours always run the config):

- ``defaults``: the library's own defaults, except ``n_steps`` = our frames per iteration / worlds (one rollout =
  one of our iterations), and ``VecNormalize(norm_obs=True, norm_reward=False)`` (SB3's way of standardising
  observations, as our TRPO does);
- ``matched``: our config's values wherever both have the parameter, read from the composed experiment at run time
  (``matched_settings``); observations are normalised exactly when our learner normalises them.

Every learner is evaluated alike: after training, one deterministic episode in each of ``eval_episodes`` worlds of
the evaluation view ``Trial`` builds (``experiment.world.make(eval_episodes, seed + EVAL_SEED_OFFSET, experiment.device)``), through
``sidewalk.evaluate.evaluate``. ``success``: ``ego/success_rate`` (``team/success_rate`` with ``--opponent
centralized``, where the learner plays every agent); ``return``: the ego's undiscounted return (centralized: the
mean over agents); ``seconds``: wall clock of building and training, evaluation excluded, one torch thread.
Rows: one per (learner, setup, seed), one ``summary`` per learner and setup (mean, min and max over seeds), and
``ours − peer`` per algorithm and setup (differences of the means).

    python runners/bench.py learners                      # hours: 3 seeds × 6 runs of 512k frames each
    python -m sidewalk.bench.learners --opponent prm --seeds 0 --setups matched --learners ours-trpo sb3-contrib-trpo
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from sidewalk._checks import check_choice, check_int
from sidewalk.bench.common import format_table, sb3_vec_env, torch_threads
from sidewalk.compose import compose_experiment
from sidewalk.opponents.base import available_opponents

ENV_ID = "sidewalk/Continuous-v0"
# name → (algorithm, library)
LEARNERS = {
    "ours-trpo": ("trpo", "ours"),
    "sb3-contrib-trpo": ("trpo", "sb3-contrib"),
    "ours-ppo": ("ppo", "ours"),
    "sb3-ppo": ("ppo", "sb3"),
}
SETUPS = ("defaults", "matched")
OPPONENTS = (*available_opponents("continuous", scripted_only=True), "centralized")
SEEDS = (0, 1, 2)
NOISE = 0.01
OURS_SETUP = "conf"  # our learners run the config whatever the peers' setup
COLUMNS = ("row", "algo", "learner", "setup", "seed", "frames", "success", "success_min", "success_max",
           "team_success", "return", "seconds", "settings")
PEER_MODULES = {"sb3-contrib": "sb3_contrib", "sb3": "stable_baselines3"}


# ---- the experiments and the budget -----------------------------------------------------------------------------


def experiment_overrides(
    algo: str, opponent: str, seed: int, noise: float, eval_episodes: int | None = None,
    num_envs: int | None = None, threads: int = 1,
) -> list[str]:
    """The Hydra overrides of ``runners/main.py env=continuous opponent=X algo=Y seed=S noise=N`` as a benchmark
    runs it: no logger, a checkpoint only at the end."""
    overrides = ["env=continuous", f"opponent={opponent}", f"algo={algo}", f"seed={seed}", f"noise={noise}",
                 "logger=none", "checkpoint_every=0", f"torch_threads={threads}"]
    if eval_episodes is not None:
        overrides.append(f"eval_episodes={eval_episodes}")
    if num_envs is not None:
        overrides.append(f"num_envs={num_envs}")
    return overrides


def default_frames() -> int:
    """The frames that ``python runners/main.py env=continuous`` trains: ``iterations`` × frames per batch."""
    from sidewalk.experiment import collector_frames_per_batch

    experiment = compose_experiment(["env=continuous"])
    return experiment.iterations * collector_frames_per_batch(experiment)


def iterations_for(frames: int, frames_per_iteration: int) -> int:
    """Whole iterations covering the budget (at least one)."""
    return max(1, math.ceil(frames / frames_per_iteration))


# ---- ours: the runners/main.py path ----------------------------------------------------------------------------


def run_ours(algo: str, opponent: str, seed: int, noise: float, frames: int, eval_episodes: int | None = None,
             num_envs: int | None = None, threads: int = 1) -> dict[str, Any]:
    """Train our ``algo`` with ``Trial`` for the budget and evaluate it once at the end (inside ``Trial``)."""
    from sidewalk.experiment import Trial, collector_frames_per_batch

    overrides = experiment_overrides(algo, opponent, seed, noise, eval_episodes, num_envs, threads)
    frames_per_batch = collector_frames_per_batch(compose_experiment(overrides))
    iterations = iterations_for(frames, frames_per_batch)
    # eval_every = iterations: the one evaluation runs at the last iteration, timed apart through on_evaluation.
    experiment = compose_experiment([*overrides, f"iterations={iterations}", f"eval_every={iterations}"])
    evaluation: dict[str, Any] = {}

    def on_evaluation(metrics: dict[str, float], started: float, ended: float) -> bool:
        evaluation.update(metrics=metrics, seconds=ended - started)
        return False

    with tempfile.TemporaryDirectory() as run_dir:
        start = time.perf_counter()
        (summary,) = Trial(experiment, run_dir).run(progress=False, on_evaluation=on_evaluation)
        seconds = time.perf_counter() - start - evaluation["seconds"]
    algo_cfg = experiment.algo
    settings = (f"runners/main.py env=continuous opponent={opponent} algo={algo} noise={noise}: "
                f"num_envs={experiment.num_envs}, {type(algo_cfg).__name__}({_fields_text(algo_cfg)})")
    return {"algo": algo.upper(), "learner": "ours", "setup": OURS_SETUP, "seed": seed, "frames": summary["frames"],
            **_outcome(evaluation["metrics"]), "seconds": seconds, "settings": settings}


def _fields_text(config: Any) -> str:
    import dataclasses

    return ", ".join(f"{f.name}={getattr(config, f.name)}" for f in dataclasses.fields(config) if f.name != "name")


# ---- peers: sb3-contrib's TRPO and SB3's PPO on the gymnasium face ---------------------------------------------


def rollout_steps(experiment) -> int:
    """SB3's ``n_steps`` that makes one rollout our iteration: our frames per batch over our worlds."""
    from sidewalk.experiment import collector_frames_per_batch

    return collector_frames_per_batch(experiment) // experiment.num_envs


def default_settings(experiment) -> tuple[dict[str, Any], bool]:
    """The ``defaults`` setup: the library's defaults but ``n_steps``; observations normalised by VecNormalize."""
    return {"n_steps": rollout_steps(experiment)}, True


def matched_settings(experiment) -> tuple[dict[str, Any], bool]:
    """The ``matched`` setup: our config's value of every parameter both libraries have, read from ``experiment``,
    and observation normalisation exactly when our learner has it."""
    algo = experiment.algo
    n_steps = rollout_steps(experiment)
    if algo.name == "trpo":
        settings = {
            "n_steps": n_steps, "gamma": algo.gamma, "gae_lambda": algo.gae_lambda, "target_kl": algo.max_kl,
            "learning_rate": algo.lr, "n_critic_updates": algo.vf_iters, "batch_size": algo.vf_batch_size,
            "cg_max_steps": algo.cg_iters, "cg_damping": algo.cg_damping,
            "line_search_max_iter": algo.line_search_steps, "line_search_shrinking_factor": algo.line_search_shrink,
            "normalize_advantage": True,  # ours standardises the advantages of each batch
            "policy_kwargs": {"net_arch": {"pi": list(algo.policy_hidden), "vf": list(algo.value_hidden)},
                              "activation_fn": nn.Tanh},
        }
    else:
        settings = {
            "n_steps": n_steps, "gamma": algo.gamma, "gae_lambda": algo.gae_lambda, "learning_rate": algo.lr,
            "batch_size": algo.minibatch_size, "n_epochs": algo.epochs, "clip_range": algo.clip_epsilon,
            "ent_coef": algo.entropy_coef, "vf_coef": algo.critic_coef, "max_grad_norm": algo.max_grad_norm,
            "normalize_advantage": True,  # ours standardises advantages over the batch (GAE average_gae=True)
            "policy_kwargs": {"net_arch": {"pi": list(algo.hidden), "vf": list(algo.hidden)}, "activation_fn": nn.Tanh},
        }
    return settings, bool(algo.normalize_observations)


SETTINGS = {"defaults": default_settings, "matched": matched_settings}


def peer_class(library: str):
    if library == "sb3-contrib":
        from sb3_contrib import TRPO

        return TRPO
    from stable_baselines3 import PPO

    return PPO


def peer_settings_text(library: str, settings: dict[str, Any], normalize: bool) -> str:
    def value(v: Any) -> str:
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k}: {value(x)}" for k, x in v.items()) + "}"
        return v.__name__ if isinstance(v, type) else repr(v)

    name = peer_class(library).__name__
    arguments = ", ".join(f"{k}={value(v)}" for k, v in settings.items())
    norm = "VecNormalize(norm_obs=True, norm_reward=False)" if normalize else "no observation normalisation"
    return f"{library} {name}('MlpPolicy', {arguments}), {norm}"


def sb3_deterministic_policy(model, view):
    """An SB3 model's ``predict(..., deterministic=True)`` as a TensorDict module (``observation`` → ``action``) on
    ``view``: observations normalised by the model's VecNormalize (if any), actions mapped back from [-1, 1] to
    the view's physical units."""
    from gymnasium.wrappers.utils import rescale_box
    from tensordict.nn import TensorDictModule

    from sidewalk.interop.gymnasium import view_spaces

    box = view_spaces(view)[1]
    _, _, to_physical = rescale_box(box, -np.ones(box.shape, box.dtype), np.ones(box.shape, box.dtype))
    action_shape = tuple(view.full_action_spec_unbatched["action"].shape)
    normalizer = model.get_vec_normalize_env()

    class Deterministic(nn.Module):
        def forward(self, observation: torch.Tensor) -> torch.Tensor:
            obs = observation.cpu().numpy()
            if normalizer is not None:
                obs = normalizer.normalize_obs(obs)
            action, _ = model.predict(obs, deterministic=True)
            physical = torch.as_tensor(to_physical(action), dtype=torch.float32, device=observation.device)
            return physical.reshape(observation.shape[0], *action_shape)

    return TensorDictModule(Deterministic(), in_keys=["observation"], out_keys=["action"])


def run_peer(algo: str, library: str, setup: str, opponent: str, seed: int, noise: float, frames: int,
             eval_episodes: int | None = None, num_envs: int | None = None, threads: int = 1) -> dict[str, Any]:
    """Train the peer of ``algo`` in ``setup`` for the budget on the gymnasium face, then evaluate it as ``Trial``
    evaluates ours."""
    from stable_baselines3.common.vec_env import VecNormalize

    from sidewalk.evaluate import evaluate
    from sidewalk.experiment import EVAL_SEED_OFFSET
    from sidewalk.interop.gymnasium import world_kwargs

    experiment = compose_experiment(experiment_overrides(algo, opponent, seed, noise, eval_episodes, num_envs, threads))
    settings, normalize = SETTINGS[setup](experiment)
    rollout = settings["n_steps"] * experiment.num_envs
    total = iterations_for(frames, rollout) * rollout
    with torch_threads(threads):
        torch.manual_seed(seed)
        start = time.perf_counter()
        envs = sb3_vec_env(ENV_ID, experiment.num_envs, seed, **world_kwargs(experiment.world))
        if normalize:
            envs = VecNormalize(envs, norm_obs=True, norm_reward=False)
        model = peer_class(library)("MlpPolicy", envs, seed=seed, device="cpu", verbose=0, **settings)
        model.learn(total_timesteps=total)
        seconds = time.perf_counter() - start
        view = experiment.world.make(experiment.eval_episodes, seed + EVAL_SEED_OFFSET, experiment.device)
        metrics = evaluate(view, sb3_deterministic_policy(model, view), seed=seed + EVAL_SEED_OFFSET)
    return {"algo": algo.upper(), "learner": library, "setup": setup, "seed": seed, "frames": model.num_timesteps,
            **_outcome(metrics), "seconds": seconds, "settings": peer_settings_text(library, settings, normalize)}


def _outcome(metrics: dict[str, float]) -> dict[str, float]:
    ego = "ego/success_rate" in metrics
    return {
        "success": metrics["ego/success_rate"] if ego else metrics["team/success_rate"],
        "team_success": metrics["team/success_rate"],
        "return": metrics["ego/return"] if ego else metrics["return"],
    }


# ---- the section ------------------------------------------------------------------------------------------------


def _one(name: str, value: int | Sequence[int] | None) -> int | None:
    """``runners/bench.py`` passes its ``--num-envs``/``--threads`` as lists; this section takes one value."""
    if value is None or isinstance(value, int):
        return value
    values = list(value)
    if len(values) != 1:
        raise ValueError(f"{name}={values} lists several values; the learners section takes one")
    return values[0]


def check_options(opponent: str, frames: int | None, seeds: Sequence[int], setups: Sequence[str],
                  learners: Sequence[str], noise: float, eval_episodes: int | None, num_envs: int | None,
                  threads: int) -> None:
    """Raise ``ValueError``/``TypeError`` naming the first bad value and the valid ones, before any training."""
    check_choice("opponent", opponent, OPPONENTS)
    if not learners:
        raise ValueError(f"learners is empty; valid: {', '.join(LEARNERS)}")
    for name in learners:
        check_choice("learners", name, LEARNERS)
    if not setups and any(LEARNERS[name][1] != "ours" for name in learners):
        raise ValueError(f"setups is empty; valid: {', '.join(SETUPS)}")
    for name in setups:
        check_choice("setups", name, SETUPS)
    if frames is not None:
        check_int("frames", frames, 1)
    if not seeds:
        raise ValueError("seeds is empty; give at least one seed ≥ 0")
    check_int("threads", threads, 1)
    # The config's own checks: seeds, noise, worlds and evaluation episodes, for every algorithm asked for.
    for algo in sorted({LEARNERS[name][0] for name in learners}):
        for seed in seeds:
            compose_experiment(experiment_overrides(algo, opponent, seed, noise, eval_episodes, num_envs, threads))


def run(
    opponent: str = "random",
    frames: int | None = None,
    seeds: Sequence[int] = SEEDS,
    setups: Sequence[str] = SETUPS,
    learners: Sequence[str] = tuple(LEARNERS),
    noise: float = NOISE,
    eval_episodes: int | None = None,
    num_envs: int | Sequence[int] | None = None,
    threads: int | Sequence[int] = 1,
) -> list[dict]:
    """Rows per (learner, setup, seed), a summary per learner and setup, and ``ours − peer`` per algorithm and
    setup (see the module docstring). ``frames``: the budget of every learner (default: what ``runners/main.py
    env=continuous`` trains), rounded up to whole iterations of each; ``eval_episodes``, ``num_envs``: the
    config's unless given; ``threads``: torch intra-op threads of every learner."""
    num_envs, threads = _one("num_envs", num_envs), _one("threads", threads)
    check_options(opponent, frames, seeds, setups, learners, noise, eval_episodes, num_envs, threads)
    frames = default_frames() if frames is None else frames
    missing = [name for name in learners if LEARNERS[name][1] != "ours" and not _installed(LEARNERS[name][1])]
    rows: list[dict] = []
    for name in learners:
        algo, library = LEARNERS[name]
        if name in missing:
            continue
        for setup in ([OURS_SETUP] if library == "ours" else setups):
            per_seed = []
            for seed in seeds:
                if library == "ours":
                    row = run_ours(algo, opponent, seed, noise, frames, eval_episodes, num_envs, threads)
                else:
                    row = run_peer(algo, library, setup, opponent, seed, noise, frames, eval_episodes, num_envs,
                                   threads)
                per_seed.append({"row": "run", **row})
                print(f"learners: {algo} {library} {setup} seed {seed}: {row['frames']} frames, success "
                      f"{row['success']:.3f}, return {row['return']:.3f}, {row['seconds']:.0f} s",
                      file=sys.stderr, flush=True)
            rows += [{**r, "settings": None} for r in per_seed]
            rows.append(_summary(per_seed))
    rows += _differences(rows)
    for name in missing:
        module = PEER_MODULES[LEARNERS[name][1]]
        rows.append({"row": "skipped", "learner": LEARNERS[name][1],
                     "settings": f"{name}: {module} is not installed (pip install {module.replace('_', '-')})"})
    return [{column: row.get(column) for column in COLUMNS} for row in rows]


def _installed(library: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(PEER_MODULES[library]) is not None


def _summary(per_seed: list[dict]) -> dict:
    first = per_seed[0]
    success = [r["success"] for r in per_seed]
    return {
        "row": "summary", "algo": first["algo"], "learner": first["learner"], "setup": first["setup"],
        "seed": " ".join(str(r["seed"]) for r in per_seed), "frames": first["frames"],
        "success": statistics.fmean(success), "success_min": min(success), "success_max": max(success),
        "team_success": statistics.fmean(r["team_success"] for r in per_seed),
        "return": statistics.fmean(r["return"] for r in per_seed),
        "seconds": statistics.fmean(r["seconds"] for r in per_seed),
        "settings": first["settings"],
    }


def _differences(rows: list[dict]) -> list[dict]:
    """``ours − peer`` of the summary means, per algorithm and peer setup."""
    summaries = [r for r in rows if r["row"] == "summary"]
    out = []
    for ours in (r for r in summaries if r["learner"] == "ours"):
        for peer in (r for r in summaries if r["algo"] == ours["algo"] and r["learner"] != "ours"):
            out.append({
                "row": "ours − peer", "algo": ours["algo"], "learner": f"ours − {peer['learner']}",
                "setup": peer["setup"], "seed": ours["seed"] if ours["seed"] == peer["seed"] else None,
                "success": ours["success"] - peer["success"], "team_success": ours["team_success"] - peer["team_success"],
                "return": ours["return"] - peer["return"], "seconds": ours["seconds"] - peer["seconds"],
                "settings": f"ours {ours['success']:.3f} vs {peer['learner']} {peer['success']:.3f} mean success",
            })
    return out


def format_rows(rows: list[dict]) -> str:
    """The rows as a table, each summary's settings (and any skipped learner) listed below it."""
    table = format_table(rows, [column for column in COLUMNS if column != "settings"])
    notes = [f"  {r['algo']} {r['learner']} {r['setup']}: {r['settings']}" for r in rows if r["row"] == "summary"]
    notes += [f"  skipped: {r['settings']}" for r in rows if r["row"] == "skipped"]
    return "\n".join([table, "settings:", *notes]) if notes else table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--opponent", default="random", choices=OPPONENTS, help="the scripted opponent (default: random)")
    parser.add_argument("--frames", type=int, help="training frames of every learner (default: runners/main.py "
                        "env=continuous's iterations × frames per batch)")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    parser.add_argument("--setups", nargs="+", default=list(SETUPS), choices=SETUPS, help="the peers' settings")
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=list(LEARNERS))
    parser.add_argument("--noise", type=float, default=NOISE, help=f"± uniform action/observation noise (default {NOISE})")
    parser.add_argument("--eval-episodes", type=int, help="evaluation worlds (default: the config's eval_episodes)")


def parse_options(argv: Sequence[str], parser: argparse.ArgumentParser | None = None) -> dict[str, Any]:
    """``run``'s keyword arguments from the section's flags, every value checked before any training; a bad one
    exits through ``parser.error`` with the message naming it and the valid ones."""
    if parser is None:
        parser = argparse.ArgumentParser(prog="learners", description=__doc__.splitlines()[0])
        add_arguments(parser)
    args = parser.parse_args(list(argv))
    options = {"opponent": args.opponent, "frames": args.frames, "seeds": args.seeds, "setups": args.setups,
               "learners": args.learners, "noise": args.noise, "eval_episodes": args.eval_episodes}
    for name in ("num_envs", "threads"):
        if getattr(args, name, None) is not None:
            options[name] = getattr(args, name)
    try:
        check_options(**{**options, "num_envs": options.get("num_envs"), "threads": options.get("threads", 1)})
    except (ValueError, TypeError) as error:
        parser.error(str(error))
    return options


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    parser.add_argument("--num-envs", type=int, help="training worlds of every learner (default: the config's)")
    parser.add_argument("--threads", type=int, help="torch intra-op threads of every learner (default 1)")
    options = parse_options(sys.argv[1:] if argv is None else argv, parser)
    print(format_rows(run(**options)))


if __name__ == "__main__":
    main()
