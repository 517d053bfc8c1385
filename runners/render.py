"""Render one episode of the Sidewalk as a GIF (or an MP4 where ffmpeg is installed): of a trained run, or of
scripted agents.

    python runners/render.py results/runs/<run>                          # the run's first evaluation episode
    python runners/render.py results/runs/<run> --episode 3 --out ep3.gif
    python runners/render.py --env discrete --opponent dijkstra --ego random
    python runners/render.py --env continuous --opponent prm --ego prm noise=0.5 --out prm.mp4

A run folder is replayed with its checkpoint exactly as its final evaluation ran (same worlds, seed and greedy
policy), and ``--episode`` picks one of those evaluation episodes. Scripted agents play one world seeded with
``--seed``; ``key=value`` arguments are config overrides as for runners/main.py (``noise=0.1``,
``env.width_cells=9``). Frames come from the env's own ``render`` (RGB arrays). The default output is
``episode<N>.gif`` inside the run folder, or ``results/renders/<env>_<ego>_vs_<opponent>_seed<S>.gif``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FORMATS = (".gif", ".mp4")
HOLD_S = 1.0  # the last frame stays this long, so the outcome can be seen before the GIF loops


def parse_args(argv: list[str] | None) -> tuple[argparse.Namespace, argparse.ArgumentParser]:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n".join(__doc__.splitlines()[3:]),
    )
    parser.add_argument(
        "items",
        nargs="*",
        metavar="RUN_DIR | key=value",
        help="a run folder to replay, or config overrides for scripted agents",
    )
    parser.add_argument("--env", choices=("discrete", "continuous"), help="scripted agents: the domain")
    parser.add_argument(
        "--opponent", help="scripted agents: who plays the other agent (random, dijkstra, prm)"
    )
    parser.add_argument("--ego", default=None, help="scripted agents: who plays agent 0 (default: random)")
    parser.add_argument("--seed", type=int, default=0, help="scripted agents: the world's seed")
    parser.add_argument(
        "--episode", type=int, default=0, help="run folder: which evaluation episode (0-based)"
    )
    parser.add_argument("--out", type=Path, help="output file, .gif or .mp4")
    parser.add_argument(
        "--fps", type=float, default=10.0, help="frames per second (the continuous dt is 0.1 s)"
    )
    return parser.parse_args(argv), parser


def rollout_run(run_dir: Path, episode: int) -> tuple[list[np.ndarray], str]:
    """Frames of evaluation episode ``episode`` of a run's final policy, and its outcome in words."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    from sidewalk.experiment import EVAL_SEED_OFFSET, make_view
    from sidewalk.report import load_experiment, load_policy

    experiment = load_experiment(run_dir)
    if not 0 <= episode < experiment.eval_episodes:
        raise ValueError(
            f"--episode={episode} is out of range; the run evaluates episodes 0..{experiment.eval_episodes - 1}"
        )
    seed = experiment.seed + EVAL_SEED_OFFSET
    env = make_view(experiment, experiment.eval_episodes, seed)
    policy = load_policy(run_dir, experiment, env)
    env.set_seed(seed)  # as sidewalk.evaluate.run_episodes does, so the episode is the evaluation's own
    td = env.reset()
    frames = [env.render(episode)]
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.core.params.max_steps + 1):
            td = env.step(policy(td))
            frames.append(env.render(episode))
            if bool(td.get(("next", "done"))[episode]):
                break
            td = step_mdp(td)
    info = td.get(("next", "world", "info"))
    return frames, outcome({key: info.get(key)[episode].squeeze(-1) for key in info.keys()})  # noqa: SIM118 (a TensorDict iterates rows)


def rollout_scripted(
    domain: str, opponent: str, ego: str, seed: int, overrides: list[str]
) -> tuple[list[np.ndarray], str]:
    """Frames of one episode of scripted agents in one world: ``ego`` plays agent 0, ``opponent`` the others."""
    from hydra import compose, initialize_config_dir
    from torchrl.envs.utils import step_mdp

    from sidewalk.config import register_schemas, validate
    from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
    from sidewalk.views import OPPONENTS, make_opponent

    if "centralized" in (opponent, ego):
        raise ValueError(
            "'centralized' is a learner playing every agent: render a run folder trained with it instead"
        )
    if ego not in OPPONENTS:
        raise ValueError(f"--ego={ego!r} is not valid; valid: {', '.join(map(repr, OPPONENTS))}")
    register_schemas()
    # The algorithm is irrelevant here, but validation checks it against the domain, so pick one that fits.
    algo = "dqn" if domain == "discrete" else "trpo"
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=[f"env={domain}", f"opponent={opponent}", f"algo={algo}", f"seed={seed}", *overrides],
        )
    experiment = validate(cfg)
    core_cls = DiscreteSidewalkEnv if domain == "discrete" else ContinuousSidewalkEnv
    core = core_cls(1, device="cpu", seed=seed, params=experiment.env_params)
    others = tuple(agent for agent in range(core.n_agents) if agent != 0)
    players = [
        make_opponent(ego, core, controlled=(0,), ego=others[0] if len(others) == 1 else None),
        make_opponent(opponent, core, controlled=others, ego=0, **experiment.opponent_params),
    ]
    td = core.reset()
    frames = [core.render(0)]
    for _ in range(core.params.max_steps + 1):
        for player in players:
            td = player(td)
        td = core.step(td)
        frames.append(core.render(0))
        if bool(td.get(("next", "done")).all()):
            break
        td = step_mdp(td)
    info = td.get(("next", "agents", "info"))
    return frames, outcome({key: info.get(key)[0].squeeze(-1) for key in info.keys()})  # noqa: SIM118 (a TensorDict iterates rows)


def outcome(info: dict) -> str:
    """Each agent's outcome in words from its sticky info flags (one bool per agent)."""
    words = []
    for agent in range(len(next(iter(info.values())))):
        flags = [
            name
            for name in ("reached_goal", "collided_agent", "collided_wall", "timed_out")
            if bool(info[name][agent])
        ]
        words.append(f"agent{agent}: {flags[0] if flags else 'running'}")
    return ", ".join(words)


def write_video(frames: list[np.ndarray], out: Path, fps: float) -> None:
    """Write ``frames`` (RGB uint8 arrays of one size) as a looping GIF (Pillow) or an H.264 MP4 (ffmpeg)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    frames = frames + [frames[-1]] * round(HOLD_S * fps)
    if out.suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        images[0].save(out, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
        return
    height, width, _ = frames[0].shape
    command = [
        shutil.which("ffmpeg"),
        "-y",
        "-loglevel",
        "error",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{width}x{height}",
        "-r",
        f"{fps}",
        "-i",
        "-",
        "-vf",
        "pad=ceil(iw/2)*2:ceil(ih/2)*2",  # H.264 in yuv420p needs even sides
        "-pix_fmt",
        "yuv420p",
        "-vcodec",
        "libx264",
        str(out),
    ]
    result = subprocess.run(
        command, input=b"".join(frame.tobytes() for frame in frames), capture_output=True, check=False
    )
    if result.returncode != 0:
        raise RuntimeError(
            f"ffmpeg failed ({result.returncode}): {result.stderr.decode(errors='replace').strip()}"
        )


def main(argv: list[str] | None = None) -> int:
    args, parser = parse_args(argv)
    # Sweep job folders have '=' in their names, so an existing path is a run folder whatever its name.
    runs = [item for item in args.items if Path(item).exists() or "=" not in item]
    overrides = [item for item in args.items if item not in runs]
    scripted = args.env is not None or args.opponent is not None or args.ego is not None
    if len(runs) > 1:
        parser.error(f"give one run folder, not {len(runs)}: {' '.join(runs)}")
    if runs and scripted:
        parser.error("give a run folder or --env/--opponent/--ego for scripted agents, not both")
    if runs and overrides:
        parser.error(
            f"config overrides ({' '.join(overrides)}) apply to scripted agents; a run keeps its own config"
        )
    if not runs and not scripted:
        parser.error("give a run folder, or --env and --opponent (and optionally --ego) for scripted agents")
    if scripted and (args.env is None or args.opponent is None):
        parser.error("scripted agents need both --env and --opponent")
    if not args.fps > 0:
        parser.error(f"--fps={args.fps} must be positive")
    if args.out is not None and args.out.suffix not in FORMATS:
        parser.error(f"--out={args.out} must end in {' or '.join(FORMATS)}")
    if runs:
        run_dir = Path(runs[0])
        if not run_dir.is_dir():
            parser.error(f"{run_dir} is not a folder; give a run folder (with config.yaml and policy.pt)")
        from sidewalk.report.runs import CONFIG, POLICY_FILES, policy_file

        if not (run_dir / CONFIG).exists():
            parser.error(f"{run_dir} has no {CONFIG}; give a run folder written by runners/main.py")
        if policy_file(run_dir) is None:
            parser.error(f"{run_dir} has no {POLICY_FILES}; give a run folder written by runners/main.py")
        out = args.out or run_dir / f"episode{args.episode}.gif"
    else:
        ego = args.ego or "random"
        out = (
            args.out
            or ROOT / "results" / "renders" / f"{args.env}_{ego}_vs_{args.opponent}_seed{args.seed}.gif"
        )
    if out.suffix == ".mp4" and shutil.which("ffmpeg") is None:
        parser.error(
            f"--out={out}: MP4 needs ffmpeg on the PATH, which is not installed here; write a .gif instead"
        )

    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        if runs:
            frames, result = rollout_run(run_dir, args.episode)
        else:
            frames, result = rollout_scripted(args.env, args.opponent, ego, args.seed, overrides)
    except (ValueError, TypeError, HydraException, OmegaConfBaseException) as error:
        # Bad names or values (an unknown opponent, noise out of range, a misspelt override): the checks name them.
        print(f"error: {error}", file=sys.stderr)
        return 2
    write_video(frames, out, args.fps)
    print(f"wrote {out}: {len(frames)} frames ({len(frames) - 1} steps), {result}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    import torch

    torch.set_num_threads(1)  # one small network and one world: more threads only contend
    sys.exit(main())
