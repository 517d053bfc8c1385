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
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

from sidewalk.paths import CONFIG_DIR

FORMATS = (".gif", ".mp4")
HOLD_S = 1.0  # the last frame stays this long, so the outcome can be seen before the GIF loops

# ---- the scenario gallery (--gallery DIR): one still and one GIF per scenario and domain ----------------
# Every agent is the domain's planner, in one world of seed GALLERY_SEED without noise. A scenario's settings
# are conf/experiment/<scenario>_<domain>.yaml where that preset exists, else these overrides (none: the env
# defaults).
GALLERY_PLANNERS = {"discrete": "dijkstra", "continuous": "prm"}
GALLERY_SEED = 0
GALLERY: dict[tuple[str, str], tuple[str, ...]] = {
    ("sidewalk", "discrete"): (),  # 7 × 15 cells, 2 agents
    ("random", "discrete"): ("env.n_agents=6",),
    ("circle", "discrete"): ("env.n_agents=8", "env.width_cells=9", "env.length_cells=9"),
    ("teams", "discrete"): ("env.n_agents=4", "env.width_cells=4", "env.length_cells=12"),
    ("door", "discrete"): ("env.n_agents=3",),
    ("zipper", "discrete"): (),
    ("sidewalk", "continuous"): (),  # 4 × 3 m, 2 agents
    ("random", "continuous"): ("env.n_agents=6", "env.length_m=6", "env.width_m=6"),
    ("circle", "continuous"): ("env.n_agents=8", "env.length_m=5", "env.width_m=5"),
    ("teams", "continuous"): ("env.n_agents=4", "env.length_m=6", "env.width_m=3"),
    ("door", "continuous"): ("env.n_agents=3", "env.length_m=6", "env.width_m=3"),
    ("zipper", "continuous"): ("env.length_m=6", "env.width_m=2"),
}
STILL_SCALE = {"discrete": {"pixels_per_cell": 24}, "continuous": {"pixels_per_m": 60}}
GIF_SCALE = {"discrete": {"pixels_per_cell": 16}, "continuous": {"pixels_per_m": 40}}  # small files
GIF_MAX_FRAMES = 60  # longer episodes are shown at evenly spaced frames
GIF_FPS = 8.0
# The still is the frame within this fraction of the episode where the agents have closed in on each other
# most: closeness max(0, 1 - d / CROWD_WIDTHS) of a pair of present agents d agent widths apart (centre to
# centre), less the pair's closeness at the start (teammates side by side do not interact), summed over pairs.
STILL_WINDOW = (0.15, 0.85)
CROWD_WIDTHS = 3.0


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


class Episode(NamedTuple):
    """One episode of scripted agents: frames at each requested scale, where every agent was, the outcome."""

    frames: list[list[np.ndarray]]  # frames[scale][t]: RGB uint8, t = 0 is the reset
    positions: np.ndarray  # (T, N, 2) float, in agent widths (grid cells; continuous: diameters)
    present: np.ndarray  # (T, N) bool: the agent occupies space
    outcome: str
    setting: str  # the world in words: agents and size


def scripted_world(domain: str, opponent: str, seed: int, overrides: list[str]):
    """The validated experiment config of scripted agents, and one world (a core env) built from it."""
    from sidewalk.compose import compose_experiment
    from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv

    # The algorithm is irrelevant here, but validation checks it against the domain, so pick one that fits.
    algo = "dqn" if domain == "discrete" else "trpo"
    experiment = compose_experiment([f"env={domain}", f"opponent={opponent}", f"algo={algo}", f"seed={seed}", *overrides])
    core_cls = DiscreteSidewalkEnv if domain == "discrete" else ContinuousSidewalkEnv
    return experiment, core_cls(1, device="cpu", seed=seed, params=experiment.env_params)


def play_scripted(
    domain: str,
    opponent: str,
    ego: str,
    seed: int,
    overrides: list[str],
    scales: tuple[dict[str, int], ...] = ({},),
) -> Episode:
    """One episode of scripted agents in one world: ``ego`` plays agent 0, ``opponent`` every other agent.

    With ``ego == opponent`` both are the same class with the same parameters, so every agent is scripted
    alike (a planner plans for its own agents and treats all others as obstacles, whatever their number).
    ``scales`` are keyword arguments of the env's ``render`` (``pixels_per_cell`` or ``pixels_per_m``), one
    frame list each.
    """
    from torchrl.envs.utils import step_mdp

    from sidewalk.opponents.base import make_opponent
    from sidewalk.registry import OPPONENTS

    if "centralized" in (opponent, ego):
        raise ValueError(
            "'centralized' is a learner playing every agent: render a run folder trained with it instead"
        )
    if ego not in OPPONENTS:
        raise ValueError(f"--ego={ego!r} is not valid; valid: {', '.join(map(repr, OPPONENTS))}")
    experiment, core = scripted_world(domain, opponent, seed, overrides)
    others = tuple(agent for agent in range(core.n_agents) if agent != 0)
    # The configured parameters belong to the opponent's class; an ego of the same class gets them too.
    ego_params = experiment.opponent_params if ego == opponent else {}
    players = [
        make_opponent(ego, core, controlled=(0,), ego=others[0] if len(others) == 1 else None, **ego_params),
        make_opponent(opponent, core, controlled=others, ego=0, **experiment.opponent_params),
    ]
    # Grid positions are cells, one agent wide; continuous ones metres, an agent 2·radius wide.
    width = 1.0 if domain == "discrete" else 2 * core.params.agent_radius_m
    frames: list[list[np.ndarray]] = [[] for _ in scales]
    positions, present = [], []

    def record(agents) -> None:
        for scale, scale_frames in zip(scales, frames):
            scale_frames.append(core.render(0, **scale))
        positions.append(agents.get("state")[0, :, :2].numpy().astype(np.float64) / width)
        present.append(agents.get("present")[0, :, 0].numpy().copy())

    td = core.reset()
    record(td.get("agents"))
    for _ in range(core.params.max_steps + 1):
        for player in players:
            td = player(td)
        td = core.step(td)
        record(td.get(("next", "agents")))
        if bool(td.get(("next", "done")).all()):
            break
        td = step_mdp(td)
    info = td.get(("next", "agents", "info"))
    layout = core.layout
    size = (
        f"{layout.rows} × {layout.cols} cells"
        if domain == "discrete"
        else f"{layout.length_m:g} × {layout.width_m:g} m"
    )
    return Episode(
        frames=frames,
        positions=np.stack(positions),
        present=np.stack(present),
        outcome=outcome({key: info.get(key)[0].squeeze(-1) for key in info.keys()}),  # noqa: SIM118 (a TensorDict iterates rows)
        setting=f"{core.n_agents} agents, {size}",
    )


def rollout_scripted(
    domain: str, opponent: str, ego: str, seed: int, overrides: list[str]
) -> tuple[list[np.ndarray], str]:
    """Frames of one episode of scripted agents in one world (``play_scripted``), and its outcome in words."""
    episode = play_scripted(domain, opponent, ego, seed, overrides)
    return episode.frames[0], episode.outcome


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


def gallery_overrides(scenario: str, domain: str) -> list[str]:
    """The config overrides of one gallery entry: its preset where it exists, else its row of ``GALLERY``."""
    preset = f"{scenario}_{domain}"
    if (CONFIG_DIR / "experiment" / f"{preset}.yaml").exists():
        return [f"+experiment={preset}", f"env.layout={scenario}", "noise=0"]
    return [f"env.layout={scenario}", *GALLERY.get((scenario, domain), ())]


def crowded_frame(positions: np.ndarray, present: np.ndarray) -> int:
    """Index of the frame within ``STILL_WINDOW`` where the agents have closed in on each other most (see
    ``CROWD_WIDTHS``); the middle of the window where nobody came closer than at the start."""
    last = len(positions) - 1
    first_t, last_t = int(STILL_WINDOW[0] * last), int(np.ceil(STILL_WINDOW[1] * last))
    gap = np.linalg.norm(positions[:, :, None] - positions[:, None, :], axis=-1)  # (T, N, N)
    closeness = np.clip(1.0 - gap / CROWD_WIDTHS, 0.0, None)
    pair = present[:, :, None] & present[:, None, :] & np.triu(np.ones(gap.shape[1:], dtype=bool), 1)
    gain = (np.clip(closeness - closeness[:1], 0.0, None) * pair).sum((1, 2))[first_t : last_t + 1]
    return first_t + int(np.argmax(gain)) if gain.max() > 0 else (first_t + last_t) // 2


def paletted(frames: list[np.ndarray]):
    """The frames as Pillow "P" images sharing one exact palette (renders use a handful of flat colours)."""
    from PIL import Image

    stack = np.stack(frames).astype(np.uint32)
    key = (stack[..., 0] << 16) | (stack[..., 1] << 8) | stack[..., 2]
    colours, index = np.unique(key, return_inverse=True)
    if len(colours) > 256:  # not a flat render: let Pillow pick 256 colours
        return [Image.fromarray(frame).quantize(256) for frame in frames]
    palette = np.stack([colours >> 16, (colours >> 8) & 255, colours & 255], -1).astype(np.uint8)
    images = []
    for frame_index in index.reshape(key.shape).astype(np.uint8):
        image = Image.fromarray(frame_index, mode="P")
        image.putpalette(palette.reshape(-1).tolist())
        images.append(image)
    return images


def write_gallery_entry(out_dir: Path, scenario: str, domain: str) -> tuple[Path, Path, str]:
    """Play one gallery entry and write ``<scenario>_<domain>.png`` (``crowded_frame``) and ``.gif``."""
    from PIL import PngImagePlugin

    planner, overrides = GALLERY_PLANNERS[domain], gallery_overrides(scenario, domain)
    episode = play_scripted(
        domain, planner, planner, GALLERY_SEED, overrides, scales=(STILL_SCALE[domain], GIF_SCALE[domain])
    )
    stills, clip = episode.frames
    command = " ".join(
        ["python runners/render.py", f"--env {domain}", f"--opponent {planner}", f"--ego {planner}"]
        + [f"--seed {GALLERY_SEED}", *overrides]
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    still, gif = out_dir / f"{scenario}_{domain}.png", out_dir / f"{scenario}_{domain}.gif"
    # The README is rebuilt from these text chunks, so a partial run (--scenario) keeps the other rows.
    text = PngImagePlugin.PngInfo()
    for key, value in (("scenario", scenario), ("domain", domain), ("setting", episode.setting)):
        text.add_text(key, value)
    text.add_text("command", command)
    text.add_text("outcome", episode.outcome)
    paletted([stills[crowded_frame(episode.positions, episode.present)]])[0].save(
        still, optimize=True, pnginfo=text
    )
    shown = np.unique(np.linspace(0, len(clip) - 1, min(len(clip), GIF_MAX_FRAMES)).round().astype(int))
    images = paletted([clip[t] for t in shown])
    durations = [round(1000 / GIF_FPS)] * (len(images) - 1) + [round(1000 * HOLD_S)]
    images[0].save(gif, save_all=True, append_images=images[1:], duration=durations, loop=0, optimize=True)
    return still, gif, episode.outcome


def write_gallery_readme(out_dir: Path) -> Path:
    """``README.md`` of the gallery: a table of the stills in ``out_dir``, from the text each PNG carries."""
    from PIL import Image

    from sidewalk.envs.layouts import scenario_names

    SCENARIOS = scenario_names()
    order = {(s, d): i for i, (s, d) in enumerate((s, d) for s in SCENARIOS for d in GALLERY_PLANNERS)}
    entries = []
    for still in sorted(out_dir.glob("*.png")):
        with Image.open(still) as image:
            text = dict(image.text)
        if {"scenario", "domain", "setting", "command", "outcome"} <= text.keys():
            entries.append(text | {"still": still.name, "gif": still.with_suffix(".gif").name})
    entries.sort(key=lambda e: (order.get((e["scenario"], e["domain"]), len(order)), e["still"]))
    domain_words = {"discrete": "grid", "continuous": "continuous"}
    planners = ", ".join(f"{p} in the {domain_words[d]}" for d, p in GALLERY_PLANNERS.items())
    lines = [
        "# Scenarios",
        "",
        "One episode per scenario (`env.layout=NAME`, see `sidewalk/envs/layouts/`) and domain,",
        f"every agent played by the domain's planner ({planners}), seed {GALLERY_SEED}, no noise.",
        "A still is the frame where the agents have closed in on each other most; click it for the GIF.",
        "Goals are stars in their agent's colour; dark cells and boxes are walls.",
        "",
        "Made by",
        "",
        "```",
        f"python runners/render.py --gallery {_shown_path(out_dir)}",
        "```",
        "",
        "with the settings of `GALLERY` in `runners/render.py`, or of",
        "`conf/experiment/<scenario>_<domain>.yaml` where that preset exists.",
        "Each row's command renders the same episode alone, at full size.",
        "",
        "| scenario | domain | setting | still (click for the GIF) | outcome | command |",
        "|---|---|---|---|---|---|",
    ]
    for e in entries:
        lines.append(
            f"| {e['scenario']} | {domain_words.get(e['domain'], e['domain'])} | {e['setting']} "
            f"| [![{e['scenario']}, {e['domain']}]({e['still']})]({e['gif']}) "
            f"| {summarise(e['outcome'])} | `{e['command']}` |"
        )
    readme = out_dir / "README.md"
    readme.write_text("\n".join(lines) + "\n")
    return readme


def summarise(outcome_words: str) -> str:
    """``outcome``'s words counted: ``"2/3 reached_goal, 1 collided_agent"``."""
    flags = [word.split(": ", 1)[1] for word in outcome_words.split(", ")]
    counts = {flag: flags.count(flag) for flag in dict.fromkeys(["reached_goal", *flags])}
    reached = f"{counts.pop('reached_goal')}/{len(flags)} reached_goal"
    return ", ".join([reached, *(f"{count} {flag}" for flag, count in counts.items())])


def _shown_path(path: Path) -> str:
    """``path`` relative to the current folder where it lies inside it, for commands in docs."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def run_gallery(out_dir: Path, scenarios: list[str], domains: list[str]) -> int:
    """Write the gallery entries of ``scenarios`` × ``domains`` into ``out_dir`` and rebuild its README."""
    for scenario in scenarios:
        for domain in domains:
            still, gif, result = write_gallery_entry(out_dir, scenario, domain)
            print(
                f"wrote {still} ({still.stat().st_size / 1e3:.0f} kB) and {gif.name} "
                f"({gif.stat().st_size / 1e3:.0f} kB): {result}",
                file=sys.stderr,
            )
    print(f"wrote {write_gallery_readme(out_dir)}", file=sys.stderr)
    return 0


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
