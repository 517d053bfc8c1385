"""The scenario gallery: for every scenario and domain, a still PNG and a small GIF of planner agents, and a README
tabulating them (``python runners/render.py --gallery DIR``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sidewalk.paths import CONFIG_DIR
from sidewalk.render.episodes import play_scripted
from sidewalk.render.video import HOLD_S, paletted

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
