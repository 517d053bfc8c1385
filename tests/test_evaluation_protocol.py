"""The evaluation protocol: perturbed starts, goals and headings drawn within their bounds, the protocol in the config
and the run folder, the Dijkstra agent's tie-breaks (the "sidewalk salsa") and the absolute metric (the marl-eval files
that carry it: tests/test_marl_eval.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from sidewalk.config import validate
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.grid import ACTIONS
from sidewalk.envs.layouts import grid_layout, plane_layout
from sidewalk.envs.layouts.jitter import (
    JitteredGridLayout,
    JitteredPlaneLayout,
    largest_grid_jitter,
    largest_plane_jitter,
)
from sidewalk.experiment import Trial
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.schema import register_schemas

ROOT = Path(__file__).resolve().parents[1]
RIGHT, LEFT = ACTIONS.index("RIGHT"), ACTIONS.index("LEFT")


def composed(*overrides: str):
    register_schemas()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def train(run_dir: Path, *overrides: str) -> None:
    """A run folder as runners/main.py writes it (less its plots), trained in this process."""
    cfg = composed(*overrides)
    Trial(validate(cfg), run_dir, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)


# ---- the env's jitter ------------------------------------------------------------------------------------------


def test_grid_jitter_moves_starts_and_goals_across_the_sidewalk_within_its_bounds():
    env = DiscreteSidewalkEnv(num_envs=512, seed=0, start_jitter_rows=2, goal_jitter_rows=1, observation="vector")
    nominal = grid_layout("sidewalk", 7, 15)
    td = env.reset()
    start, goal = td["agents", "state"], td["agents", "goal"]
    for agent in range(2):
        (row, col), (goal_row, goal_col) = nominal.starts[agent], nominal.goals[agent]
        assert set(start[:, agent, 0].tolist()) == set(range(row - 2, row + 3))  # every offset is drawn
        assert set(goal[:, agent, 0].tolist()) == set(range(goal_row - 1, goal_row + 2))
        assert (start[:, agent, 1] == col).all() and (goal[:, agent, 1] == goal_col).all()
    assert not (start[:, 0] == start[:, 1]).all(-1).any()  # no two agents start in one cell
    assert not (start == goal).all(-1).any()  # nobody starts on its own goal
    # The image shows each world's own goals: the backdrop is painted per world.
    images = DiscreteSidewalkEnv(num_envs=64, seed=0, goal_jitter_rows=1).reset()["agents", "observation"]
    assert len({image.numpy().tobytes() for image in images[:, 0]}) > 1


@pytest.mark.parametrize("layout, rows, cols, n_agents", [("circle", 9, 9, 4), ("zipper", 7, 15, 2), ("teams", 3, 12, 4)])
def test_cell_jitter_draws_every_free_cell_around_each_start_and_goal_and_no_wall(layout, rows, cols, n_agents):
    """Where the walls hold no row move (one episode a world before), each start and goal goes to a uniform free cell
    within one row and column of its own: every such cell is drawn, none off the grid or in a wall, no two agents
    share a start or a goal, and 256 worlds play far more than 64 distinct episodes."""
    nominal = grid_layout(layout, rows, cols, n_agents)
    env = DiscreteSidewalkEnv(num_envs=1024, seed=0, layout=layout, width_cells=rows, length_cells=cols,
                              n_agents=n_agents, start_jitter_cells=1, goal_jitter_cells=1, observation="vector")
    td = env.reset()
    start, goal = td["agents", "state"], td["agents", "goal"]
    blocked = set(nominal.blocked)
    for agent in range(n_agents):
        for drawn, (row, col) in ((start[:, agent], nominal.starts[agent]), (goal[:, agent], nominal.goals[agent])):
            around = {(r, c) for r in (row - 1, row, row + 1) for c in (col - 1, col, col + 1)
                      if 0 <= r < rows and 0 <= c < cols and (r, c) not in blocked}
            assert set(map(tuple, drawn.tolist())) == around
    for cells in (start, goal):
        flat = cells[..., 0] * cols + cells[..., 1]
        assert (flat.sort(-1).values.diff(dim=-1) != 0).all()  # no two agents in one start (goal) cell
    assert not (start == goal).all(-1).any()
    worlds = torch.cat([start, goal], -1)[:256].flatten(1)
    assert len({tuple(world.tolist()) for world in worlds}) > 64


def test_cell_and_row_jitter_of_one_start_are_refused_together():
    with pytest.raises(ValueError, match=r"start_jitter_rows=1 and start_jitter_cells=1: .* set one of them to 0"):
        DiscreteSidewalkEnv(start_jitter_rows=1, start_jitter_cells=1)


def test_jitter_draws_repeat_for_one_seed_and_each_replica_draws_as_its_lone_env():
    def starts(seed, num_envs=32):
        env = DiscreteSidewalkEnv(num_envs=num_envs, seed=seed, start_jitter_rows=1, goal_jitter_rows=1,
                                  observation="vector")
        td = env.reset()
        return torch.cat([td["agents", "state"], td["agents", "goal"]], -1)

    assert torch.equal(starts(3), starts(3))
    assert not torch.equal(starts(3), starts(4))
    assert torch.equal(starts([3, 4], 64), torch.cat([starts(3), starts(4)]))


def test_continuous_jitter_keeps_starts_in_their_box_and_discs_apart():
    env = ContinuousSidewalkEnv(num_envs=512, seed=0, start_jitter_m=0.2, goal_jitter_m=0.2, heading_jitter_rad=0.3)
    nominal = plane_layout("sidewalk", 4.0, 3.0)
    td = env.reset()
    state, goal = td["agents", "state"], td["agents", "goal"]
    for agent in range(2):
        offset = state[:, agent, :2] - torch.tensor(nominal.starts[agent])
        assert offset.abs().max() <= 0.2 + 1e-6 and offset.abs().max() > 0.15
        turn = torch.remainder(state[:, agent, 3] - nominal.headings[agent] + math.pi, 2 * math.pi) - math.pi
        assert turn.abs().max() <= 0.3 + 1e-5 and turn.abs().max() > 0.25
        assert (goal[:, agent] - torch.tensor(nominal.goals[agent])).abs().max() <= 0.2 + 1e-6
    assert ((state[:, 0, :2] - state[:, 1, :2]).norm(dim=-1) >= 0.6).all()


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: DiscreteSidewalkEnv(start_jitter_rows=4), r"start_jitter_rows=4 puts an agent .*; valid: 0\.\.3"),
        (lambda: DiscreteSidewalkEnv(layout="zipper", goal_jitter_rows=1), r"goal_jitter_rows=1 .*; valid: 0\.\.0"),
        (lambda: ContinuousSidewalkEnv(start_jitter_m=0.3), r"start_jitter_m=0.3 puts an agent's disc into a wall"),
        (lambda: DiscreteSidewalkEnv(layout="random", start_jitter_rows=1), r"draws? its starts|drawn already"),
        (lambda: ContinuousSidewalkEnv(heading_jitter_rad=4.0), r"heading_jitter_rad=4.0 is out of range"),
    ],
)
def test_bounds_that_put_an_agent_into_a_wall_are_refused_naming_the_valid_ones(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_the_largest_bounds_are_those_the_walls_allow():
    assert largest_grid_jitter(grid_layout("sidewalk", 7, 15), "start_jitter_rows") == 3
    assert largest_grid_jitter(grid_layout("zipper", 7, 15), "start_jitter_rows") == 0  # one-cell lanes
    assert largest_plane_jitter(plane_layout("sidewalk", 4.0, 3.0), "start_jitter_m", 0.3) == pytest.approx(0.2)
    door = plane_layout("door", 4.0, 3.0, 3)
    largest = largest_plane_jitter(door, "start_jitter_m", 0.3)
    JitteredPlaneLayout(door, 0.3, 0.3, start_jitter_m=largest)  # the largest bound is accepted
    with pytest.raises(ValueError):
        JitteredPlaneLayout(door, 0.3, 0.3, start_jitter_m=largest + 0.01)
    assert isinstance(DiscreteSidewalkEnv(start_jitter_rows=1).layout, JitteredGridLayout)


# ---- the protocol in the config -----------------------------------------------------------------------------------


def test_the_default_protocol_perturbs_evaluation_and_training_alike():
    experiment = validate(composed())
    assert experiment.evaluation.name == "perturbed"
    assert (experiment.eval_world.env_params.start_jitter_rows, experiment.eval_world.env_params.goal_jitter_rows) == (1, 1)
    assert (experiment.world.env_params.start_jitter_rows, experiment.world.env_params.goal_jitter_rows) == (1, 1)
    apart = validate(composed("eval.train_alike=false"))
    assert apart.world.env_params.start_jitter_rows == 0 and apart.eval_world.env_params.start_jitter_rows == 1
    nominal = validate(composed("eval=nominal"))
    assert nominal.world.env_params.start_jitter_rows == nominal.eval_world.env_params.start_jitter_rows == 0
    continuous = validate(composed("env=continuous"))
    assert (continuous.eval_world.env_params.start_jitter_m, continuous.eval_world.env_params.heading_jitter_rad) == (0.2, 0.3927)


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["env.layout=zipper"], (0, 1)),  # its lanes are one cell wide: no row moves, cells stand in
        (["env.layout=circle", "env.n_agents=4"], (0, 1)),  # corners
        (["+experiment=selfplay_teams_discrete"], (0, 1)),
        (["env.layout=door", "env.n_agents=3"], (1, 0)),
        ([], (1, 0)),  # the sidewalk: rows, and no cell draws (its worlds stay what they were)
        (["env.layout=random"], (1, 0)),  # a scenario that draws its starts keeps its own (the bounds are not applied)
    ],
)
def test_the_protocol_bounds_fit_each_scenario_s_walls(overrides, expected):
    experiment = validate(composed(*overrides))
    assert (experiment.evaluation.start_jitter_rows, experiment.evaluation.start_jitter_cells) == expected
    if "env.layout=random" not in overrides:
        assert experiment.world.env_params.start_jitter_cells == expected[1]  # trained alike
    if "env.layout=random" in overrides:
        assert experiment.eval_world.env_params.start_jitter_rows == 0


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["eval.start_jitter_rows=5"], "error: eval=perturbed: eval.start_jitter_rows=5 puts an agent outside"),
        (["eval=sometimes"], "error: In 'config': Could not find 'eval/sometimes'; valid: nominal, perturbed"),
    ],
)
def test_a_bad_protocol_is_one_error_line_before_any_compute(tmp_path, processes, overrides, message):
    # A process of its own, forked after the imports (conftest.py), as `python runners/main.py ...` runs it.
    result = processes.run("runners/main.py", *overrides, f"hydra.run.dir={tmp_path / 'run'}", timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [result.stderr.strip()]  # one line
    assert result.stderr.startswith(message), result.stderr
    assert not (tmp_path / "run" / "metrics.csv").exists()


def test_a_continuous_protocol_past_the_walls_is_refused_by_the_config_check():
    """The config check main.py refuses with above (its ValueError is the error line), for the continuous bounds."""
    with pytest.raises(ValueError, match=r"^eval=perturbed: eval.goal_jitter_m=0.5 puts an agent's disc into a wall"):
        validate(composed("env=continuous", "eval.goal_jitter_m=0.5"))


def test_a_run_records_its_protocol_its_distinct_episodes_and_its_absolute_metric(tmp_path):
    run = tmp_path / "run"
    train(run, "iterations=2", "eval_every=1", "eval_episodes=128", "num_envs=8", "algo.frames_per_batch=16",
          "algo.learning_starts=0", "algo.batch_size=16", "logger=none")
    summary = json.loads((run / "summary.json").read_text())
    assert summary["eval_protocol"] == {"name": "perturbed", "start_jitter_rows": 1, "goal_jitter_rows": 1,
                                        "start_jitter_cells": 0, "goal_jitter_cells": 0, "train_alike": True,
                                        "epsilon": 0.0}
    assert summary["distinct_episodes"] >= 64  # 81 start and goal rows, and the partner's own tie-breaks
    absolute = summary["absolute"]
    assert absolute["episodes"] == 1280 and absolute["iteration"] in (1, 2)
    assert (run / "policy.best.pt").exists()
    rows = __import__("pandas").read_csv(run / "metrics.csv")
    best = rows["eval/ego/success_rate"].max()
    assert rows.loc[absolute["iteration"] - 1, "eval/ego/success_rate"] == best


# ---- the Dijkstra agent's tie-breaks --------------------------------------------------------------------------------


def salsa(tie_break: str, worlds: int = 32) -> torch.Tensor:
    """Whether the Dijkstra agent reaches its goal in each world against a walker that steps to column 7 and then
    back and forth between 6 and 7 -- the two-cycle a greedy DQN held the version-1 agent in (issue 42)."""
    env = DiscreteSidewalkEnv(num_envs=worlds, seed=0, observation="vector")
    planner = DijkstraOpponent(env, controlled=(1,), ego=0, tie_break=tie_break)
    td = env.reset()
    reached = torch.zeros(worlds, dtype=torch.bool)
    for _ in range(env.params.max_steps):
        state = td["agents", "state"]
        walker = torch.where(state[:, 0, 1] >= 7, LEFT, RIGHT)
        planned = planner.act(state, td["agents", "goal"], td["agents", "done"])[:, 0]
        td["agents", "action"] = torch.stack([walker, planned], dim=1)
        td = env.step(td)["next"]
        reached |= td["agents", "info", "reached_goal"][:, 1, 0]
    return reached


def test_the_version_2_planner_breaks_the_sidewalk_salsa_that_held_version_1():
    assert not salsa("progress").any()  # (3,9) <-> (3,10) in phase with the walker, to the time limit
    assert salsa("random").all()


def test_random_tie_breaks_choose_only_among_the_cheapest_moves_and_repeat_for_a_seed():
    env = DiscreteSidewalkEnv(num_envs=256, seed=1, layout="random", n_agents=4, observation="vector")
    td = env.reset()
    state, goal, done = td["agents", "state"], td["agents", "goal"], td["agents", "done"]
    fixed = DijkstraOpponent(env, controlled=(1,), ego=0, tie_break="progress")
    plan = fixed.plan(state, goal, done)
    chosen = DijkstraOpponent(env, controlled=(1,), ego=0, tie_break="random").act(state, goal, done)
    # Each chosen move costs what the cheapest does (entry cost + distance to goal at the cell it enters).
    moves = torch.tensor([(-1, 0), (1, 0), (0, -1), (0, 1)])

    def cost_of(action):
        cell = state[:, 1] + moves[action[:, 0]]
        inside = ((cell >= 0) & (cell < torch.tensor([env.layout.rows, env.layout.cols]))).all(-1)
        row, col = cell[:, 0].clamp(0, env.layout.rows - 1), cell[:, 1].clamp(0, env.layout.cols - 1)
        worlds = torch.arange(len(cell))
        value = plan.costmap[worlds, 0, row, col] + plan.field[worlds, 0, row, col]
        return torch.where(inside, value, torch.inf)

    assert torch.equal(cost_of(chosen), cost_of(plan.action))
    assert not torch.equal(chosen, plan.action)  # ties exist, and are drawn
    env.set_seed(7)
    first = DijkstraOpponent(env, controlled=(1,), tie_break="random").act(state, goal, done)
    env.set_seed(7)
    assert torch.equal(first, DijkstraOpponent(env, controlled=(1,), tie_break="random").act(state, goal, done))
