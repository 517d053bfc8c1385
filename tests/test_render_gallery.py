"""Every scenario renders in both domains with up to 16 agents told apart by colour, scripted N-agent episodes
render (``sidewalk.render``), and ``runners/render.py`` writes the scenario gallery."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.layouts import scenario_names
from sidewalk.envs.render import AGENT_COLOURS, BACKGROUND, CELL_LINE, TICK, WALL, colour
from sidewalk.render import episodes, gallery

SCENARIOS = scenario_names()  # the built-in scenarios, in the paper's order

ROOT = Path(__file__).resolve().parents[1]
PIXELS_PER_CELL, PIXELS_PER_M = 24, 60
MAX_AGENTS = 16

# Each scenario with as many agents as it takes, up to 16, in a world that fits them.
GRID_CASES = {
    "sidewalk": {"n_agents": 2},
    "random": {"n_agents": 16},
    "circle": {"n_agents": 16, "width_cells": 9, "length_cells": 9},
    "teams": {"n_agents": 16, "width_cells": 8, "length_cells": 12},
    "door": {"n_agents": 16, "width_cells": 16},
    "zipper": {"n_agents": 2},
}
PLANE_CASES = {
    "sidewalk": {"n_agents": 2},
    "random": {"n_agents": 16, "length_m": 9, "width_m": 9},
    "circle": {"n_agents": 16, "length_m": 5, "width_m": 5},
    "teams": {"n_agents": 16, "length_m": 8, "width_m": 7},
    "door": {"n_agents": 16, "length_m": 6, "width_m": 13},
    "zipper": {"n_agents": 2, "length_m": 6, "width_m": 2},
}


def test_cases_cover_every_scenario():
    assert set(GRID_CASES) == set(PLANE_CASES) == set(SCENARIOS)


def test_sixteen_agent_colours_are_distinct_from_each_other_and_the_scenery():
    colours = [colour(agent) for agent in range(MAX_AGENTS)]
    assert len(AGENT_COLOURS) >= MAX_AGENTS and len(set(colours)) == MAX_AGENTS
    assert not set(colours) & {BACKGROUND, WALL, CELL_LINE, TICK}
    # Apart by more than rounding: at least 60 of 3·255 in summed channel differences.
    for a, b in itertools.combinations(colours, 2):
        assert sum(abs(x - y) for x, y in zip(a, b)) >= 60, (a, b)


def assert_every_agent_drawn(frame: np.ndarray, centres_px: list[tuple[int, int]]) -> None:
    """Each agent's colour is at the pixel given for it and covers a disc's worth of pixels."""
    for agent, (row, col) in enumerate(centres_px):
        assert tuple(frame[row, col]) == colour(agent), f"agent {agent} is not drawn at its position"
        count = int((frame == np.array(colour(agent), dtype=np.uint8)).all(-1).sum())
        assert count >= 50, f"agent {agent}'s colour covers only {count} px"


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_grid_scenario_renders_every_agent_and_wall(scenario):
    env = DiscreteSidewalkEnv(num_envs=2, seed=0, layout=scenario, **GRID_CASES[scenario])
    state = env.reset()["agents", "state"][1].numpy()
    frame = env.render(1, pixels_per_cell=PIXELS_PER_CELL)
    k = PIXELS_PER_CELL
    assert frame.shape == (env.rows * k, env.cols * k, 3) and frame.dtype == np.uint8
    assert_every_agent_drawn(frame, [(row * k + k // 2, col * k + k // 2) for row, col in state])
    for row, col in env.layout.blocked:
        assert tuple(frame[row * k + k // 2, col * k + k // 2]) == WALL
    assert bool(env.layout.blocked) == (scenario in ("door", "zipper"))


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_continuous_scenario_renders_every_agent_and_wall(scenario):
    env = ContinuousSidewalkEnv(num_envs=2, seed=0, layout=scenario, **PLANE_CASES[scenario])
    state = env.reset()["agents", "state"][1].numpy()
    frame = env.render(1, pixels_per_m=PIXELS_PER_M)
    length_m, width_m, border = env.layout.length_m, env.layout.width_m, 4

    def to_px(x: float, y: float) -> tuple[int, int]:
        return int(border + (width_m - y) * PIXELS_PER_M), int(border + x * PIXELS_PER_M)

    assert frame.shape == (round(width_m * PIXELS_PER_M) + 8, round(length_m * PIXELS_PER_M) + 8, 3)
    # Half a radius behind the centre: the heading tick runs from the centre forward.
    behind_m = env.params.agent_radius_m / 2
    centres = [to_px(x - behind_m * np.cos(theta), y - behind_m * np.sin(theta)) for x, y, _, theta in state]
    assert_every_agent_drawn(frame, centres)
    for x0, y0, x1, y1 in env.layout.boxes:
        assert tuple(frame[to_px((x0 + x1) / 2, (y0 + y1) / 2)]) == WALL
    assert bool(env.layout.boxes) == (scenario in ("door", "zipper"))


def test_scripted_episode_with_n_agents_and_a_planner_ego():
    frames, result = episodes.rollout_scripted(
        "discrete",
        "dijkstra",
        "dijkstra",
        0,
        [
            "env.layout=circle",
            "env.n_agents=6",
            "env.width_cells=9",
            "env.length_cells=9",
            "env.max_steps=12",
        ],
    )
    assert 2 <= len(frames) <= 13 and frames[0].shape == (9 * 24, 9 * 24, 3)
    assert [word.split(":")[0] for word in result.split(", ")] == [f"agent{a}" for a in range(6)]
    assert not np.array_equal(frames[0], frames[-1])  # the planners moved


def test_still_is_the_frame_where_agents_close_in():
    # Two agents walk toward each other and apart again; a third stands beside the first from the start.
    t = np.arange(21, dtype=float)
    gap = np.abs(t - 10) + 0.5
    positions = np.zeros((21, 3, 2))
    positions[:, 1, 0] = gap
    positions[:, 2, 1] = 1.0
    present = np.ones((21, 3), dtype=bool)
    assert gallery.crowded_frame(positions, present) == 10


def test_gallery_covers_every_scenario_in_both_domains():
    for scenario, domain in itertools.product(SCENARIOS, gallery.GALLERY_PLANNERS):
        overrides = gallery.gallery_overrides(scenario, domain)
        assert f"env.layout={scenario}" in overrides
        world, core = episodes.scripted_world(domain, gallery.GALLERY_PLANNERS[domain], 0, overrides)
        assert world.env_params.layout == scenario and core.render(0).ndim == 3


def test_gallery_writes_a_still_a_gif_and_the_readme(tmp_path, runner):
    render = runner("render")
    assert render.main(["--gallery", str(tmp_path), "--scenario", "door", "--env", "discrete"]) == 0
    still, gif = tmp_path / "door_discrete.png", tmp_path / "door_discrete.gif"
    assert still.stat().st_size < 60_000 and gif.stat().st_size < 300_000
    with Image.open(still) as image:
        rgb = np.asarray(image.convert("RGB"))
        assert image.text["scenario"] == "door" and "--ego dijkstra" in image.text["command"]
    _, core = episodes.scripted_world("discrete", "dijkstra", 0, gallery.gallery_overrides("door", "discrete"))
    k = gallery.STILL_SCALE["discrete"]["pixels_per_cell"]
    assert rgb.shape == (core.rows * k, core.cols * k, 3)
    for agent in range(core.n_agents):  # every goal star, at least, is in the agent's colour
        assert (rgb == np.array(colour(agent), dtype=np.uint8)).all(-1).any()
    with Image.open(gif) as image:
        assert 2 <= image.n_frames <= gallery.GIF_MAX_FRAMES
    readme = (tmp_path / "README.md").read_text()
    assert "(door_discrete.png)](door_discrete.gif)" in readme and "--gallery" in readme


def test_gallery_rejects_scripted_options_and_unknown_scenarios(tmp_path, capsys, runner):
    render = runner("render")
    for argv in (
        ["--gallery", str(tmp_path), "--opponent", "prm"],
        ["--gallery", str(tmp_path), "--scenario", "x"],
    ):
        with pytest.raises(SystemExit) as exit_info:
            render.main(argv)
        assert exit_info.value.code == 2
    assert "not a scenario" in capsys.readouterr().err
