"""Render one episode of the Sidewalk as a GIF (or an MP4 where ffmpeg is installed): of a trained run, or of
scripted agents; or the gallery of scenarios.

    python runners/render.py results/runs/<run>                          # the run's first evaluation episode
    python runners/render.py results/runs/<run> --episode 3 --out ep3.gif
    python runners/render.py --env discrete --opponent dijkstra --ego random
    python runners/render.py --env continuous --opponent prm --ego prm noise=0.5 --out prm.mp4
    python runners/render.py --env discrete --opponent dijkstra --ego dijkstra env.layout=door env.n_agents=3
    python runners/render.py --gallery docs/scenarios          # a still and a GIF per scenario and domain
    python runners/render.py --gallery /tmp/g --scenario door --env continuous

A run folder is replayed with its checkpoint exactly as its final evaluation ran (same worlds, seed and greedy
policy), and ``--episode`` picks one of those evaluation episodes. Scripted agents play one world seeded with
``--seed``: ``--ego`` plays agent 0 and ``--opponent`` every other agent, whatever ``env.n_agents``; an ego of
the opponent's class (``--ego dijkstra --opponent dijkstra``) makes every agent the same planner.
``key=value`` arguments are config overrides as for runners/main.py (``noise=0.1``, ``env.width_cells=9``,
``env.layout=circle env.n_agents=8``). Frames come from the env's own ``render`` (RGB arrays). The default
output is ``episode<N>.gif`` inside the run folder, or
``results/renders/<env>_<ego>_vs_<opponent>_seed<S>.gif``.

``--gallery DIR`` writes, for every scenario and domain (or those named by ``--scenario`` and ``--env``), a
still PNG and a small GIF of planner agents, and ``DIR/README.md`` tabulating them (settings: ``GALLERY``).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from sidewalk.render.episodes import rollout_run, rollout_scripted
from sidewalk.render.gallery import GALLERY_PLANNERS, run_gallery
from sidewalk.render.video import FORMATS, write_video


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
        "--gallery",
        type=Path,
        metavar="DIR",
        help="write the scenario gallery (stills, GIFs, README.md) into DIR",
    )
    parser.add_argument(
        "--scenario",
        action="append",
        help="gallery: only this scenario (repeatable; default: all); --env limits the domains",
    )
    parser.add_argument(
        "--fps",
        type=float,
        default=10.0,
        help="frames per second (a continuous step is dt_s = 0.2 s by default)",
    )
    return parser.parse_args(argv), parser


def gallery_main(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``--gallery DIR [--scenario NAME ...] [--env DOMAIN]``: check the arguments and write the gallery."""
    if args.gallery is None:
        parser.error("--scenario selects gallery entries: give --gallery DIR too")
    extra = [
        flag
        for flag, given in (
            ("a run folder or overrides", args.items),
            ("--opponent", args.opponent),
            ("--ego", args.ego),
            ("--out", args.out),
        )
        if given
    ]
    if extra:
        parser.error(f"--gallery takes its settings from GALLERY or the presets; drop {', '.join(extra)}")
    from sidewalk.envs.layouts import scenario_names

    SCENARIOS = scenario_names()
    unknown = sorted(set(args.scenario or ()) - set(SCENARIOS))
    if unknown:
        parser.error(f"--scenario {' '.join(unknown)}: not a scenario; valid: {', '.join(SCENARIOS)}")
    scenarios = [s for s in SCENARIOS if s in args.scenario] if args.scenario else list(SCENARIOS)
    domains = [args.env] if args.env else list(GALLERY_PLANNERS)
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        return run_gallery(args.gallery, scenarios, domains)
    except (ValueError, TypeError, HydraException, OmegaConfBaseException) as error:
        # A preset or GALLERY row that does not compose or fit its scenario: the checks name it.
        print(f"error: {error}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    args, parser = parse_args(argv)
    if args.gallery is not None or args.scenario:
        return gallery_main(args, parser)
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
        from sidewalk.report.runs import POLICY_FILES
        from sidewalk.run_folder import CONFIG, GroupFolderGiven, one_run_folder, policy_file

        try:
            one_run_folder(run_dir)  # an episode is one run's: a group folder names its seeds'
        except GroupFolderGiven as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        if not (run_dir / CONFIG).exists():
            parser.error(f"{run_dir} has no {CONFIG}; give a run folder written by runners/main.py")
        if policy_file(run_dir) is None:
            parser.error(f"{run_dir} has no {POLICY_FILES}; give a run folder written by runners/main.py")
        out = args.out or run_dir / f"episode{args.episode}.gif"
    else:
        ego = args.ego or "random"
        out = (
            args.out
            or Path("results") / "renders" / f"{args.env}_{ego}_vs_{args.opponent}_seed{args.seed}.gif"
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
