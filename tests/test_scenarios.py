"""The scenarios of paper §7 (sidewalk/envs/layouts/): valid and reachable placements, random layouts that vary
yet repeat, N-agent collisions, the door's gap, specs of every view, the Gymnasium and PettingZoo faces at N = 4,
the ``present`` flag and the coordination metrics (makespan, deadlock rate, wait steps)."""

from __future__ import annotations

import dataclasses
import math
from collections import deque

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.layouts import door_grid, door_plane, scenario_names
from sidewalk.evaluate import evaluate
from sidewalk.partners.team import ScriptedTeam
from sidewalk.views import CentralizedView, EgoView

# The settings of each scenario as its preset has them (conf/experiment/<scenario>_<domain>.yaml).
GRID = {
    "sidewalk": {},
    "random": {"n_agents": 4, "min_start_goal_cells": 6},
    "circle": {"n_agents": 4, "width_cells": 9, "length_cells": 9},
    "teams": {"n_agents": 4, "width_cells": 3, "length_cells": 12, "pixels_per_cell": 5},
    "door": {"n_agents": 3},
    "zipper": {"n_agents": 2},
}
PLANE = {
    "sidewalk": {},
    "random": {"n_agents": 4, "length_m": 6.0, "width_m": 6.0, "min_start_goal_m": 2.0},
    "circle": {"n_agents": 4, "length_m": 5.0, "width_m": 5.0},
    "teams": {"n_agents": 4, "length_m": 6.0, "width_m": 2.4},
    "door": {"n_agents": 3, "length_m": 6.0, "width_m": 3.0},
    "zipper": {"n_agents": 2, "length_m": 6.0, "width_m": 2.0},
}
SCENARIOS = scenario_names()
CASES = [("discrete", name) for name in SCENARIOS] + [("continuous", name) for name in SCENARIOS]


def make(domain: str, scenario: str, num_envs: int = 8, seed: int = 0, **overrides):
    if domain == "discrete":
        return DiscreteSidewalkEnv(num_envs, seed=seed, layout=scenario, **{**GRID[scenario], **overrides})
    return ContinuousSidewalkEnv(num_envs, seed=seed, layout=scenario, **{**PLANE[scenario], **overrides})


def grid_reachable(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> bool:
    """Breadth-first search over free cells, 4-connected."""
    seen, queue = {start}, deque([start])
    while queue:
        row, col = queue.popleft()
        if (row, col) == goal:
            return True
        for d_row, d_col in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            nxt = (row + d_row, col + d_col)
            if 0 <= nxt[0] < free.shape[0] and 0 <= nxt[1] < free.shape[1] and free[nxt] and nxt not in seen:
                seen.add(nxt)
                queue.append(nxt)
    return False


def plane_free(env: ContinuousSidewalkEnv, resolution_m: float = 0.05) -> tuple[np.ndarray, float]:
    """Bool image of the centre points where an agent's disc touches no wall, ``resolution_m`` apart."""
    layout, radius = env.layout, env.params.agent_radius_m
    xs = np.arange(0.0, layout.length_m + 1e-9, resolution_m)
    ys = np.arange(0.0, layout.width_m + 1e-9, resolution_m)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    free = (x >= radius) & (x <= layout.length_m - radius) & (y >= radius) & (y <= layout.width_m - radius)
    for x0, y0, x1, y1 in layout.boxes:
        gap = np.hypot(x - np.clip(x, x0, x1), y - np.clip(y, y0, y1))
        free &= gap >= radius
    return free, resolution_m


# ---- placements --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("domain,scenario", CASES)
def test_starts_and_goals_are_valid_and_reachable(domain, scenario):
    env = make(domain, scenario, num_envs=16)
    td = env.reset()
    starts = td["agents", "state"][..., :2].numpy()
    goals = td["agents", "goal"].numpy()
    assert td["agents", "present"].all()
    if domain == "discrete":
        free = ~env.layout.blocked_mask(torch.device("cpu")).numpy()
        for world in range(env.num_envs):
            cells = [tuple(map(int, c)) for c in starts[world]]
            goal_cells = [tuple(map(int, c)) for c in goals[world]]
            assert len(set(cells)) == env.n_agents and len(set(goal_cells)) == env.n_agents
            for start, goal in zip(cells, goal_cells):
                assert free[start] and free[goal] and start != goal
                assert grid_reachable(free, start, goal), (scenario, start, goal)
    else:
        free, step = plane_free(env)
        radius = env.params.agent_radius_m
        for world in range(env.num_envs):
            gaps = np.linalg.norm(starts[world][:, None] - starts[world][None], axis=-1) + np.eye(env.n_agents) * 99
            assert gaps.min() >= 2 * radius, "two agents start touching"
            for start, goal in zip(starts[world], goals[world]):
                start_cell, goal_cell = (tuple(np.round(p / step).astype(int)) for p in (start, goal))
                assert free[start_cell], f"{scenario}: start {start} touches a wall"
                # The goal is reached anywhere within its radius: some free point there must be reachable.
                assert grid_reachable(free, start_cell, goal_cell) or any(
                    grid_reachable(free, start_cell, (goal_cell[0] + dx, goal_cell[1] + dy))
                    for dx in range(-5, 6) for dy in range(-5, 6)
                    if math.hypot(dx, dy) * step < env.params.goal_radius_m
                    and 0 <= goal_cell[0] + dx < free.shape[0] and 0 <= goal_cell[1] + dy < free.shape[1]
                    and free[goal_cell[0] + dx, goal_cell[1] + dy]
                ), (scenario, start, goal)


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
def test_random_layouts_differ_between_worlds_and_episodes_yet_repeat_for_one_seed(domain):
    def placements(seed):
        env = make(domain, "random", num_envs=32, seed=seed)
        first = env.reset()["agents", "state"][..., :2].clone()
        second = env.reset()["agents", "state"][..., :2].clone()
        return first, second

    first, second = placements(3)
    assert not torch.equal(first[0], first[1]), "two worlds got the same placement"
    assert not torch.equal(first, second), "a new episode repeated the last placement"
    again_first, again_second = placements(3)
    assert torch.equal(first, again_first) and torch.equal(second, again_second)
    other_seed, _ = placements(4)
    assert not torch.equal(first, other_seed)


def test_random_grid_goals_keep_their_distance_and_partial_resets_draw_only_reset_worlds():
    env = make("discrete", "random", num_envs=64, min_start_goal_cells=6)
    td = env.reset()
    distance = (td["agents", "state"] - td["agents", "goal"]).abs().sum(-1)
    assert (distance >= 6).all()
    before = td["agents", "state"].clone()
    mask = torch.zeros(64, 1, dtype=torch.bool)
    mask[::2] = True
    after = env.reset(td.set("_reset", mask))["agents", "state"]
    assert torch.equal(after[1::2], before[1::2]), "worlds not asked to reset were moved"
    assert not torch.equal(after[::2], before[::2])


@pytest.mark.parametrize(
    "layout,n_agents,match",
    [("sidewalk", 3, "exactly 2"), ("zipper", 4, "exactly 2"), ("teams", 3, "even"), ("nowhere", 2, "valid:")],
)
def test_a_scenario_refuses_an_agent_count_it_cannot_hold(layout, n_agents, match):
    with pytest.raises(ValueError, match=match):
        DiscreteSidewalkEnv(1, layout=layout, n_agents=n_agents)


def test_a_crowded_random_plane_names_a_size_that_fits():
    # A room the user gives is theirs: too small is refused (given none, the layout picks one that fits).
    with pytest.raises(ValueError, match=r"n_agents=16 crowd the 4.0×3.0 m random layout.*use at least"):
        ContinuousSidewalkEnv(1, layout="random", n_agents=16, length_m=4.0, width_m=3.0)


# ---- dynamics with N agents --------------------------------------------------------------------------------


@pytest.mark.parametrize("remove_crashed", [True, False])
def test_no_two_grid_agents_share_a_cell_unless_both_collided_over_1e5_random_steps(remove_crashed):
    torch.manual_seed(0)
    env = DiscreteSidewalkEnv(1000, seed=0, layout="random", n_agents=8, width_cells=7, length_cells=15,
                              observation="vector", remove_crashed=remove_crashed, max_steps=40)
    td = env.reset()
    pairs = ~torch.eye(8, dtype=torch.bool)
    for _ in range(100):  # 1000 worlds × 100 steps
        td["agents", "action"] = torch.randint(4, (1000, 8))
        td = env.step(td)
        nxt = td["next"]
        cell = nxt["agents", "state"][..., 0] * 15 + nxt["agents", "state"][..., 1]
        info = nxt["agents", "info"]
        collided = (info["collided_agent"] | info["collided_wall"]).squeeze(-1)
        in_world = nxt["agents", "present"].squeeze(-1)
        shared = (cell.unsqueeze(-1) == cell.unsqueeze(-2)) & pairs
        if remove_crashed:
            shared &= in_world.unsqueeze(-1) & in_world.unsqueeze(-2)
        both_collided = collided.unsqueeze(-1) & collided.unsqueeze(-2)
        if remove_crashed:
            assert not (shared & ~both_collided).any()
        else:
            # Kept after a crash, an agent that ran into one parked at its goal shares its cell: the crash is the
            # mover's alone (the parked agent had arrived, and stays arrived).
            parked = info["reached_goal"].squeeze(-1)
            excused = collided.unsqueeze(-1) & parked.unsqueeze(-2) | parked.unsqueeze(-1) & collided.unsqueeze(-2)
            assert not (shared & ~both_collided & ~excused).any()
        # A removed agent has crashed; an agent at its goal stays present.
        assert not (~in_world & ~collided).any()
        td = env.reset(nxt.set("_reset", nxt["done"]).exclude("agents"))


def test_no_two_present_discs_overlap_unless_both_collided():
    env = ContinuousSidewalkEnv(512, seed=1, layout="random", n_agents=8, length_m=6.0, width_m=6.0, max_steps=60)
    td = env.reset()
    pairs = ~torch.eye(8, dtype=torch.bool)
    for _ in range(120):
        td["agents", "action"] = (torch.rand(512, 8, 2) * 2 - 1) * torch.tensor([1.0, math.pi / 8])
        nxt = env.step(td)["next"]
        xy = nxt["agents", "state"][..., :2]
        gap = torch.cdist(xy, xy)
        in_world = nxt["agents", "present"].squeeze(-1)
        info = nxt["agents", "info"]
        collided = (info["collided_agent"] | info["collided_wall"]).squeeze(-1)
        overlap = (gap < 2 * env.params.agent_radius_m) & pairs & in_world.unsqueeze(-1) & in_world.unsqueeze(-2)
        assert not (overlap & ~(collided.unsqueeze(-1) & collided.unsqueeze(-2))).any()
        td = env.reset(nxt.set("_reset", nxt["done"]).exclude("agents"))


def test_two_grid_agents_entering_the_door_in_one_step_collide():
    door = door_grid(7, 15, 2)
    gap_row, wall = 3, 7
    assert (gap_row, wall) not in door.blocked and (gap_row - 1, wall) in door.blocked
    layout = dataclasses.replace(door, starts=((gap_row, wall - 1), (gap_row, wall + 1)))
    env = DiscreteSidewalkEnv(1, seed=0, params=dataclasses.replace(DiscreteSidewalkEnv.Params(), layout=layout))
    td = env.reset()
    td["agents", "action"] = torch.tensor([[3, 2]])  # RIGHT into the gap, LEFT into the gap
    info = env.step(td)["next", "agents", "info"]
    assert info["collided_agent"].all()


def test_two_continuous_agents_abreast_in_the_door_collide_but_one_alone_passes():
    door = door_plane(6.0, 3.0, 2)
    (x0, _, _, y_low), (_, y_high, _, _) = door.boxes
    middle = (y_low + y_high) / 2
    base = ContinuousSidewalkEnv.Params()

    def run(starts):
        layout = dataclasses.replace(door, starts=starts, headings=(0.0, 0.0), goals=((5.5, middle), (5.5, 0.5)))
        env = ContinuousSidewalkEnv(1, seed=0, params=dataclasses.replace(base, layout=layout))
        td = env.reset()
        collided = torch.zeros(2, dtype=torch.bool)
        for _ in range(30):
            td["agents", "action"] = torch.tensor([[[1.0, 0.0], [1.0, 0.0]]])
            td = env.step(td)
            info = td["next", "agents", "info"]
            collided |= (info["collided_agent"] | info["collided_wall"]).view(2)
            td = td["next"]
        return collided

    # Abreast, 0.65 m apart across the 0.9 m gap: at least one hits the wall or the other.
    assert run(((x0 - 1.5, middle - 0.325), (x0 - 1.5, middle + 0.325))).any()
    # One at a time on the gap's centre line, the other far behind in its lane: the first passes untouched.
    assert not run(((x0 - 1.5, middle), (0.4, 0.4)))[0]


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
def test_planner_agents_all_pass_the_door_beside_a_still_ego(domain):
    env = make(domain, "door", num_envs=4, seed=0, max_steps=200)
    view = EgoView(env, "dijkstra" if domain == "discrete" else "prm")
    td = view.reset()
    for step in range(200):
        # Still: zero acceleration in the plane; in the grid (no stay action) up and back down at its start.
        td["action"] = torch.zeros(4, 2) if domain == "continuous" else torch.full((4,), step % 2)
        td = view.step(td)["next"]
        info = td["world", "info"]
        if (info["reached_goal"] | info["collided_agent"] | info["collided_wall"])[:, 1:].all():
            break
    assert info["reached_goal"][:, 1:].all(), "a planner agent did not pass the door"
    assert not info["collided_agent"].any() and not info["collided_wall"].any()


# ---- specs and faces ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("domain,scenario", CASES)
def test_every_view_of_every_scenario_passes_check_env_specs(domain, scenario):
    check_env_specs(make(domain, scenario, num_envs=4))
    check_env_specs(EgoView(make(domain, scenario, num_envs=4), "random"))
    check_env_specs(CentralizedView(make(domain, scenario, num_envs=4)))


def test_centralized_refuses_too_many_grid_agents_naming_the_limit():
    with pytest.raises(ValueError, match="6 agents make 4096 joint actions .more than 1024"):
        CentralizedView(DiscreteSidewalkEnv(1, layout="random", n_agents=6))


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
def test_gymnasium_check_env_with_four_agents(domain):
    from gymnasium.utils.env_checker import check_env

    from sidewalk.interop.gymnasium import SidewalkGymEnv

    params = GRID["teams"] if domain == "discrete" else PLANE["teams"]
    check_env(SidewalkGymEnv(domain=domain, opponent="random", layout="teams", **params))


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
def test_pettingzoo_parallel_api_test_with_four_agents(domain):
    pytest.importorskip("pettingzoo")
    from pettingzoo.test import parallel_api_test

    from sidewalk.interop.pettingzoo import parallel_env

    params = GRID["teams"] if domain == "discrete" else PLANE["teams"]
    env = parallel_env(domain=domain, layout="teams", **params)
    assert len(env.possible_agents) == 4
    parallel_api_test(env, num_cycles=200)


# ---- metrics -------------------------------------------------------------------------------------------------


def test_a_lone_planner_agent_has_the_shortest_makespan_no_waits_and_no_deadlock():
    env = DiscreteSidewalkEnv(64, seed=0, layout="random", n_agents=1, observation="vector")
    team = ScriptedTeam(env, "dijkstra")
    start_goal = env.reset()["agents"]
    distance = (start_goal["state"] - start_goal["goal"]).abs().sum(-1).float()
    metrics = evaluate(team.view, team, seed=0, deterministic=False)
    assert metrics["team/success_rate"] == 1.0
    assert metrics["wait_steps"] == 0.0 and metrics["deadlock_rate"] == 0.0
    assert metrics["path_efficiency"] == pytest.approx(1.0)
    assert metrics["makespan"] >= float(distance.min())


def test_two_planners_that_block_each_other_in_the_zipper_are_a_deadlock():
    env = make("discrete", "zipper", num_envs=8)
    team = ScriptedTeam(env, "dijkstra")
    metrics = evaluate(team.view, team, seed=0, deterministic=False)
    # Noise-free and symmetric, they step aside and back in front of each other until the timeout.
    assert metrics["timeout_rate"] == 1.0 and metrics["deadlock_rate"] == 1.0
    assert metrics["wait_steps"] > 0.9 * env.params.max_steps
    assert math.isnan(metrics["makespan"])


def test_progress_shaping_pays_per_cell_of_shortest_path_around_the_walls():
    env = DiscreteSidewalkEnv(1, seed=0, layout="door", n_agents=2, rewards={"c_progress": 0.01, "c_center": 0.0})
    td = env.reset()
    assert td["agents", "state"][0].tolist() == [[2, 0], [4, 0]]  # goals at the far end of the same rows
    rewards = []
    for actions in ([3, 3], [0, 3], [1, 1]):  # both RIGHT; agent 0 UP (away from the gap row); both DOWN
        td["agents", "action"] = torch.tensor([actions])
        td = env.step(td)["next"]
        rewards.append(td["agents", "reward"].view(-1).tolist())
    step, cell = -0.01, 0.01
    expected = [[step + cell, step + cell], [step - cell, step + cell], [step + cell, step - cell]]
    assert np.allclose(rewards, expected, atol=1e-6)
    with pytest.raises(ValueError, match="c_progress needs a 70×70 grid"):
        DiscreteSidewalkEnv(1, layout="random", width_cells=70, length_cells=70, rewards={"c_progress": 0.01})


def test_continuous_progress_shaping_measures_the_path_through_the_door():
    from sidewalk.envs.geodesic import GeodesicDistance

    env = ContinuousSidewalkEnv(1, seed=0, layout="door", n_agents=3, length_m=6.0, width_m=3.0,
                                rewards={"c_progress": 0.1})
    layout, radius = env.layout, env.params.agent_radius_m
    path = GeodesicDistance(torch.tensor(layout.boxes), layout.length_m, layout.width_m, radius)
    (wall_x0, _, wall_x1, gap_y0), _ = layout.boxes
    # Agent 1 starts below the gap's line: round the gap's lower corners, the wall grown by r (a disc's centre there
    # is clear of the wall).
    (sx, sy), (gx, gy) = layout.starts[1], layout.goals[1]
    grow = radius
    corner_in, corner_out = (wall_x0 - grow, gap_y0 + grow), (wall_x1 + grow, gap_y0 + grow)
    by_hand = math.dist((sx, sy), corner_in) + math.dist(corner_in, corner_out) + math.dist(corner_out, (gx, gy))
    measured = path(*(torch.tensor([v]) for v in (sx, sy, gx, gy)))
    assert measured.item() == pytest.approx(by_hand, abs=1e-5) and by_hand > math.dist((sx, sy), (gx, gy)) + 0.15
    # Every bend of the path is a place a disc can stand: clear of both walls by at least its radius.
    for corner in path.waypoints.tolist():
        for x_min, y_min, x_max, y_max in layout.boxes:
            nearest = (min(max(corner[0], x_min), x_max), min(max(corner[1], y_min), y_max))
            assert math.dist(corner, nearest) >= radius - 1e-6
    # The first point to head for is the gap's near corner on the agent's side, then its far one, then the goal.
    heading_for = path.next_point(*(torch.tensor([v]) for v in (sx, sy, gx, gy)))
    assert heading_for.view(-1).tolist() == pytest.approx(list(corner_in), abs=1e-5)
    # Agent 0 starts on the gap's line: nothing is in its way.
    (x0, y0), (goal_x0, goal_y0) = layout.starts[0], layout.goals[0]
    assert path(*(torch.tensor([v]) for v in (x0, y0, goal_x0, goal_y0))).item() == pytest.approx(goal_x0 - x0)
    # The env pays c_progress per metre of that path: agent 1 driving straight at the wall earns less than the
    # metres it walked (the straight line would pay them all).
    rewards = {}
    for c_progress in (0.0, 0.1):
        env = ContinuousSidewalkEnv(1, seed=0, layout="door", n_agents=3, length_m=6.0, width_m=3.0,
                                    rewards={"c_progress": c_progress})
        td = env.reset()
        for _ in range(3):
            last_x = td["agents", "state"][0, 1, 0].item()
            td["agents", "action"] = torch.tensor([[[0.0, 0.0], [env.params.max_accel_mps2, 0.0], [0.0, 0.0]]])
            td = env.step(td)["next"]
        rewards[c_progress] = td["agents", "reward"][0, 1].item()
        x, y = td["agents", "state"][0, 1, :2].tolist()
    progress = path(*(torch.tensor([v]) for v in (last_x, y, gx, gy))) - path(*(torch.tensor([v]) for v in (x, y, gx, gy)))
    assert rewards[0.1] - rewards[0.0] == pytest.approx(0.1 * progress.item(), abs=1e-5)
    assert 0 < progress.item() < x - last_x


def test_geodesic_distance_is_the_straight_line_in_a_room_without_walls():
    from sidewalk.envs.geodesic import GeodesicDistance, blocked

    path = GeodesicDistance(torch.zeros(0, 4), 9.0, 3.0, 0.3)
    x, y = torch.rand(50) * 9, torch.rand(50) * 3
    torch.testing.assert_close(path(x, y, x.flip(0), y.flip(0)), torch.hypot(x - x.flip(0), y - y.flip(0)))
    box = torch.tensor([[1.0, 1.0, 2.0, 2.0]])
    segments = torch.tensor([[[0.0, 1.5], [3.0, 1.5]], [[0.0, 1.0], [3.0, 1.0]], [[0.0, 0.0], [1.0, 1.0]],
                             [[1.5, 1.5], [1.6, 1.6]], [[0.0, 0.5], [3.0, 0.5]], [[1.5, 0.0], [1.5, 3.0]]])
    assert blocked(segments[:, 0], segments[:, 1], box).tolist() == [True, False, False, True, False, True]


def test_observe_route_shows_the_next_point_of_the_path_around_the_wall():
    from sidewalk.envs.unicycle import OBSERVATION_FIELDS

    goal_fields = [OBSERVATION_FIELDS.index("goal_x"), OBSERVATION_FIELDS.index("goal_y")]
    door = {"layout": "door", "n_agents": 3, "length_m": 6.0, "width_m": 3.0}
    own = ContinuousSidewalkEnv(1, seed=0, observe_route=True, **door).reset()["agents", "observation"][0, :, goal_fields]
    layout, radius = ContinuousSidewalkEnv(1, **door).layout, 0.3
    (wall_x0, _, _, gap_y0), (_, gap_y1, _, _) = layout.boxes
    # Agent 0 starts on the gap's line and sees its goal; agents 1 and 2 see the gap's near corner on their side.
    assert own[0].tolist() == pytest.approx(list(layout.goals[0]))
    assert own[1].tolist() == pytest.approx([wall_x0 - radius, gap_y0 + radius])
    assert own[2].tolist() == pytest.approx([wall_x0 - radius, gap_y1 - radius])
    # Without interior walls the route is the goal: the observation is the default one.
    plain, routed = (ContinuousSidewalkEnv(4, seed=0, layout="circle", n_agents=4, observe_route=flag).reset()
                     for flag in (False, True))
    torch.testing.assert_close(plain["agents", "observation"], routed["agents", "observation"])
