"""The core environments against SPEC §1: specs, dynamics invariants, rewards, collisions, noise, seeding."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torchrl.envs.utils import check_env_specs

from sidewalk.envs import (
    AGENT_GROUP,
    ContinuousSidewalkEnv,
    DiscreteSidewalkEnv,
    GridLayout,
    PlaneLayout,
    RewardParams,
)

UP, DOWN, LEFT, RIGHT = range(4)
ACTION = (AGENT_GROUP, "action")
SPEC = RewardParams()  # the paper's constants: c_step -0.01, c_goal 0.5, c_collision -0.5, c_center -0.01


def step(env, td, action):
    td.set(ACTION, torch.as_tensor(action).expand_as(env.full_action_spec[ACTION].zero()).clone())
    out, td = env.step_and_maybe_reset(td)
    return out["next"], td


def play(env, actions):
    """Run a scripted episode (one action row per step, applied to every world); return the stacked outputs."""
    td = env.reset()
    outputs = []
    for action in actions:
        nxt, td = step(env, td, action)
        outputs.append(nxt)
    return torch.stack(outputs, dim=1)


# ---- specs ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("num_envs", [1, 64])
@pytest.mark.parametrize("noise", [0.0, 0.1])
@pytest.mark.parametrize("observation", ["image", "vector"])
def test_discrete_specs(num_envs, noise, observation):
    check_env_specs(DiscreteSidewalkEnv(num_envs=num_envs, seed=0, noise=noise, observation=observation), seed=None)


@pytest.mark.parametrize("num_envs", [1, 64])
@pytest.mark.parametrize("noise", [0.0, 0.5])
def test_continuous_specs(num_envs, noise):
    check_env_specs(ContinuousSidewalkEnv(num_envs=num_envs, seed=0, noise=noise), seed=None)


def test_print_env_shows_its_worlds_and_every_spec():
    from sidewalk.views import make_view

    grid, plane = DiscreteSidewalkEnv(num_envs=2, seed=0), ContinuousSidewalkEnv(num_envs=2, seed=0, layout="door")
    text = repr(grid)
    assert text.startswith("DiscreteSidewalkEnv(\n  num_envs=2, n_agents=2, layout='sidewalk', replicas=1, device=cpu\n")
    for line in ("('agents', 'observation'): Bounded(0, 255) uint8 (2, 2, 1, 14, 30)",
                 "('agents', 'action'): Categorical(n=4) int64 (2, 2)",
                 "('agents', 'reward'): Unbounded float32 (2, 2, 1)",
                 "('agents', 'info', 'timed_out'): Categorical(n=2) bool (2, 2, 1)",
                 "'done': Categorical(n=2) bool (2, 1)"):
        assert f"\n    {line}\n" in text
    assert "('agents', 'action'): Bounded(low=[-1, -0.3927], high=[1, 0.3927]) float32 (2, 2, 2)" in repr(plane)
    view = repr(make_view("ego", grid, opponent="dijkstra"))
    assert "\n    'action': Categorical(n=4) int64 (2,)\n" in view  # the view's own specs, then its core's
    assert "(core): DiscreteSidewalkEnv(\n" in view and "env=DiscreteSidewalkEnv, in_keys" in view


def test_multi_agent_layout_shapes():
    env = DiscreteSidewalkEnv(num_envs=5, seed=0)
    td = env.rand_step(env.reset())
    assert td["next", AGENT_GROUP, "reward"].shape == (5, 2, 1)
    assert td["next", AGENT_GROUP, "done"].shape == (5, 2, 1)
    assert td["next", "done"].shape == (5, 1)
    assert td["next", AGENT_GROUP, "observation"].shape == (5, 2, 1, 14, 30)
    assert td["next", AGENT_GROUP, "state"].dtype == torch.long


# ---- dynamics invariants (property tests) ----------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), noise=st.sampled_from([0.0, 0.1, 0.2]), remove=st.booleans())
def test_grid_agents_never_leave_the_world(seed, noise, remove):
    env = DiscreteSidewalkEnv(num_envs=32, seed=seed, noise=noise, remove_crashed=remove)
    td = env.reset()
    actions = torch.randint(4, (60, 32, 2), generator=torch.Generator().manual_seed(seed))
    for action in actions:
        nxt, td = step(env, td, action)
        row, col = nxt[AGENT_GROUP, "state"].unbind(-1)
        active = ~nxt[AGENT_GROUP, "terminated"].squeeze(-1)
        inside = (row >= 0) & (row < env.rows) & (col >= 0) & (col < env.cols)
        assert inside[active].all()
        assert torch.isfinite(nxt[AGENT_GROUP, "reward"]).all()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), noise=st.sampled_from([0.0, 0.01, 0.5, 1.5]))
def test_unicycle_bounds_hold_under_any_actions(seed, noise):
    env = ContinuousSidewalkEnv(num_envs=32, seed=seed, noise=noise)
    generator = torch.Generator().manual_seed(seed)
    td = env.reset()
    previous = td[AGENT_GROUP, "state"].clone()
    for _ in range(60):
        # Far outside the bounds on purpose: the env must clip, whatever the learner sends.
        action = (torch.rand(32, 2, 2, generator=generator) - 0.5) * 10.0
        nxt, td = step(env, td, action)
        state = nxt[AGENT_GROUP, "state"]
        x, y, v, theta = state.unbind(-1)
        active = ~nxt[AGENT_GROUP, "terminated"].squeeze(-1)
        assert not torch.isnan(state).any() and not torch.isnan(nxt[AGENT_GROUP, "observation"]).any()
        assert (v.abs() <= env.params.max_speed_mps + 1e-6).all()
        turn = torch.remainder(theta - previous[..., 3] + math.pi, 2 * math.pi) - math.pi
        assert (turn.abs() <= env.params.max_turn_rad + 1e-5).all()
        r = env.params.agent_radius_m
        inside = (x >= r) & (x <= env.layout.length_m - r) & (y >= r) & (y <= env.layout.width_m - r)
        assert inside[active].all()
        world_done = nxt["done"].squeeze(-1)
        previous = torch.where(world_done.view(-1, 1, 1), td[AGENT_GROUP, "state"], state).clone()


# ---- rewards of scripted episodes --------------------------------------------------------------------------------

# Agent 0 steps up off the centre line, walks 14 cells along row 2 and steps back down onto its goal (16 steps,
# 15 of them one cell off the axis); agent 1 walks straight along the centre line (14 steps). They never meet.
DETOUR = [UP] + [RIGHT] * 14 + [DOWN]
STRAIGHT = [LEFT] * 14 + [LEFT, LEFT]  # its last two actions come after it is done and are ignored


@pytest.mark.parametrize("alpha", [1.0, 0.0])
def test_scripted_grid_episode_returns(alpha):
    env = DiscreteSidewalkEnv(num_envs=3, seed=0, rewards={"alpha": alpha})
    rollout = play(env, list(zip(DETOUR, STRAIGHT)))
    returns = rollout[AGENT_GROUP, "reward"].sum(1).squeeze(-1)
    expected_0 = 16 * SPEC.c_step + 15 * SPEC.c_center * 1 + SPEC.c_goal + alpha * SPEC.c_goal
    expected_1 = 14 * SPEC.c_step + SPEC.c_goal + alpha * SPEC.c_goal
    torch.testing.assert_close(returns, torch.tensor([[expected_0, expected_1]] * 3))
    assert rollout[AGENT_GROUP, "info", "reached_goal"][:, -1].all()
    assert rollout["done"][:, -1].all() and not rollout["done"][:, :-1].any()
    assert rollout["terminated"][:, -1].all() and not rollout["truncated"].any()
    # Agent 1 finished at step 14: terminated from then on, and no reward of its own after that.
    assert rollout[AGENT_GROUP, "terminated"][0, 13:, 1].all() and not rollout[AGENT_GROUP, "terminated"][0, :13, 1].any()
    assert rollout[AGENT_GROUP, "reward"][0, 14, 1].item() == 0.0
    assert rollout[AGENT_GROUP, "reward"][0, 15, 1].item() == pytest.approx(alpha * SPEC.c_goal)


def test_shaping_only_for_listed_agents():
    env = DiscreteSidewalkEnv(num_envs=1, seed=0, rewards={"alpha": 0.0, "shaped_agents": (1,)})
    rollout = play(env, list(zip(DETOUR, STRAIGHT)))
    returns = rollout[AGENT_GROUP, "reward"].sum(1).squeeze()
    assert returns[0].item() == pytest.approx(16 * SPEC.c_step + SPEC.c_goal)


def straight_lanes_plane() -> PlaneLayout:
    """Two agents in separate lanes 0.7 m apart (discs of 0.3 m never touch) walking to the far ends."""
    return PlaneLayout(
        length_m=10.0,
        width_m=1.5,
        starts=((0.5, 0.4), (9.5, 1.1)),
        headings=(0.0, math.pi),
        goals=((9.5, 0.4), (0.5, 1.1)),
    )


def reference_walk(params, distance_m: float) -> list[float]:
    """Distances to goal after each step of full acceleration in a straight line, computed independently."""
    v, travelled, remaining = 0.0, 0.0, []
    while True:
        v = min(v + params.max_accel_mps2 * params.dt_s, params.max_speed_mps)
        travelled += v * params.dt_s
        remaining.append(abs(distance_m - travelled))
        if remaining[-1] <= params.goal_radius_m:
            return remaining


@pytest.mark.parametrize("alpha", [1.0, 0.0])
def test_scripted_continuous_episode_returns(alpha):
    env = ContinuousSidewalkEnv(num_envs=2, seed=0, layout=straight_lanes_plane(), rewards={"alpha": alpha})
    remaining = reference_walk(env.params, 9.0)
    full_ahead = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
    rollout = play(env, [full_ahead] * len(remaining))
    returns = rollout[AGENT_GROUP, "reward"].sum(1).squeeze(-1)
    shaping = SPEC.c_potential * sum(d * d for d in remaining)
    expected = len(remaining) * SPEC.c_step + shaping + SPEC.c_goal + alpha * SPEC.c_goal
    torch.testing.assert_close(returns, torch.full((2, 2), expected), atol=1e-4, rtol=0)
    assert rollout[AGENT_GROUP, "info", "reached_goal"][:, -1].all()
    assert rollout["done"][:, -1].all() and not rollout["done"][:, :-1].any()


def test_continuous_progress_shaping_pays_each_metre_the_distance_to_goal_shrank():
    c_progress = 0.1
    env = ContinuousSidewalkEnv(
        num_envs=1, seed=0, layout=straight_lanes_plane(), rewards={"alpha": 0.0, "c_progress": c_progress}
    )
    remaining = reference_walk(env.params, 9.0)
    rollout = play(env, [torch.tensor([[1.0, 0.0], [1.0, 0.0]])] * len(remaining))
    reward = rollout[AGENT_GROUP, "reward"][0, :, 0, 0]
    before = [9.0, *remaining[:-1]]
    expected = [
        SPEC.c_step + SPEC.c_potential * d * d + c_progress * (b - d) + (SPEC.c_goal if step == len(remaining) - 1 else 0)
        for step, (b, d) in enumerate(zip(before, remaining))
    ]
    torch.testing.assert_close(reward, torch.tensor(expected), atol=1e-5, rtol=0)


def test_crashed_agent_is_not_paid_for_the_others_arrival_in_the_grid():
    # Agent 0 steps off the top of the grid in the very step agent 1 steps onto its goal; SPEC §1 (2026-11-23):
    # the cooperative term goes only to agents that have not crashed, so alpha changes nothing for agent 0.
    layout = GridLayout(rows=7, cols=15, starts=((0, 5), (3, 1)), goals=((0, 14), (3, 0)), center_row=3.0)
    rewards = {}
    for alpha in (1.0, 0.0):
        env = DiscreteSidewalkEnv(num_envs=1, seed=0, layout=layout, rewards={"alpha": alpha})
        nxt, _ = step(env, env.reset(), [UP, LEFT])
        assert nxt[AGENT_GROUP, "info", "collided_wall"][0, 0] and nxt[AGENT_GROUP, "info", "reached_goal"][0, 1]
        rewards[alpha] = nxt[AGENT_GROUP, "reward"][0, :, 0]
    assert rewards[1.0][0].item() == rewards[0.0][0].item() == pytest.approx(SPEC.c_step + SPEC.c_collision + 3 * SPEC.c_center)
    assert rewards[1.0][1].item() == rewards[0.0][1].item() == pytest.approx(SPEC.c_step + SPEC.c_goal)


def test_crashed_agent_is_not_paid_for_a_later_arrival_in_the_continuous_world():
    # Agent 0 turns into the side wall at once; agent 1 walks its free lane to its goal afterwards.
    env = ContinuousSidewalkEnv(num_envs=1, seed=0, layout=straight_lanes_plane(), rewards={"alpha": 1.0})
    remaining = reference_walk(env.params, 9.0)
    rollout = play(env, [[[1.0, -math.pi / 8], [1.0, 0.0]]] * len(remaining))
    info = rollout[AGENT_GROUP, "info"][0, -1]
    assert info["collided_wall"][0] and info["reached_goal"][1]
    reward_0 = rollout[AGENT_GROUP, "reward"][0, :, 0, 0]
    crash_step = int(rollout[AGENT_GROUP, "done"][0, :, 0, 0].float().argmax())
    assert reward_0[crash_step + 1 :].abs().max().item() == 0.0  # nothing at agent 1's arrival
    assert rollout[AGENT_GROUP, "reward"][0, -1, 1, 0].item() > SPEC.c_goal / 2  # agent 1 did arrive then


# ---- collisions --------------------------------------------------------------------------------------------------


def facing_layout(start_0, start_1) -> GridLayout:
    return GridLayout(rows=7, cols=15, starts=(start_0, start_1), goals=((3, 14), (3, 0)), center_row=3.0)


def test_grid_head_on_swap_is_a_collision():
    env = DiscreteSidewalkEnv(num_envs=2, seed=0, layout=facing_layout((3, 5), (3, 6)))
    nxt, _ = step(env, env.reset(), [RIGHT, LEFT])
    assert nxt[AGENT_GROUP, "info", "collided_agent"].all()
    torch.testing.assert_close(
        nxt[AGENT_GROUP, "reward"].squeeze(-1), torch.full((2, 2), SPEC.c_step + SPEC.c_collision)
    )
    assert nxt["terminated"].all()


def test_grid_two_agents_entering_one_cell_collide():
    env = DiscreteSidewalkEnv(num_envs=1, seed=0, layout=facing_layout((3, 5), (3, 7)))
    nxt, _ = step(env, env.reset(), [RIGHT, LEFT])
    assert nxt[AGENT_GROUP, "info", "collided_agent"].all()


def test_grid_following_is_not_a_collision():
    env = DiscreteSidewalkEnv(num_envs=1, seed=0, layout=facing_layout((3, 5), (3, 6)))
    nxt, _ = step(env, env.reset(), [RIGHT, RIGHT])
    assert not nxt[AGENT_GROUP, "done"].any()
    assert nxt[AGENT_GROUP, "state"][0].tolist() == [[3, 6], [3, 7]]


def test_grid_stepping_off_the_grid_hits_the_wall_and_removes_the_agent():
    env = DiscreteSidewalkEnv(num_envs=1, seed=0)
    nxt, _ = step(env, env.reset(), [LEFT, LEFT])  # agent 0 starts at column 0
    info = nxt[AGENT_GROUP, "info"]
    assert info["collided_wall"][0, :, 0].tolist() == [True, False]
    assert nxt[AGENT_GROUP, "reward"][0, 0].item() == pytest.approx(SPEC.c_step + SPEC.c_collision)
    assert not env._present[0, 0]  # removed: no longer drawn nor an obstacle
    image = nxt[AGENT_GROUP, "observation"][0, 1, 0]
    assert not (image == 224).any()  # agent 1's view no longer shows agent 0


def test_agent_at_goal_stays_as_an_obstacle():
    # Agent 1 starts next to its goal (3, 0) and steps onto it; agent 0 then walks into it from (3, 2).
    layout = GridLayout(rows=7, cols=15, starts=((3, 2), (3, 1)), goals=((3, 14), (3, 0)), center_row=3.0)
    env = DiscreteSidewalkEnv(num_envs=1, seed=0, layout=layout)
    td = env.reset()
    nxt, td = step(env, td, [DOWN, LEFT])
    assert nxt[AGENT_GROUP, "info", "reached_goal"][0, 1].item()
    nxt, td = step(env, td, [UP, LEFT])
    nxt, td = step(env, td, [LEFT, LEFT])  # agent 0 to (3, 1)
    nxt, td = step(env, td, [LEFT, LEFT])  # agent 0 into (3, 0), where agent 1 stands
    info = nxt[AGENT_GROUP, "info"]
    assert info["collided_agent"][0, 0].item() and not info["collided_agent"][0, 1].item()
    assert info["reached_goal"][0, 1].item()


def test_continuous_discs_that_touch_collide():
    layout = PlaneLayout(
        length_m=10.0, width_m=1.5, starts=((4.0, 0.75), (4.7, 0.75)), headings=(0.0, math.pi),
        goals=((9.5, 0.75), (0.5, 0.75)),
    )
    env = ContinuousSidewalkEnv(num_envs=1, seed=0, layout=layout)
    td = env.reset()
    for _ in range(10):
        nxt, td = step(env, td, [[1.0, 0.0], [1.0, 0.0]])
        if nxt["done"].any():
            break
    assert nxt[AGENT_GROUP, "info", "collided_agent"].all()


def head_on_plane(gap_m: float, lane_offset_m: float = 0.0) -> PlaneLayout:
    """Two agents facing each other ``gap_m`` apart in the middle of a 10 m × 3 m world, agent 1 shifted across by
    ``lane_offset_m``."""
    return PlaneLayout(
        length_m=10.0, width_m=3.0, starts=((4.5, 1.5), (4.5 + gap_m, 1.5 + lane_offset_m)), headings=(0.0, math.pi),
        goals=((9.5, 1.5), (0.5, 1.5 + lane_offset_m)),
    )


def test_continuous_agents_cannot_pass_through_each_other_at_any_dt():
    # dt 1.0 s: full acceleration brings both to 1 m/s in the first step, closing at 2 m/s; 1 m apart, they end the
    # step swapped and 1 m apart, discs never overlapping at either end of the step -- only the swept check sees it.
    env = ContinuousSidewalkEnv(num_envs=1, seed=0, layout=head_on_plane(1.0), dt_s=1.0)
    nxt, _ = step(env, env.reset(), [[1.0, 0.0], [1.0, 0.0]])
    x0, x1 = nxt[AGENT_GROUP, "state"][0, :, 0].tolist()
    assert x0 > x1 and abs(x0 - x1) >= 2 * env.params.agent_radius_m  # they passed: no overlap at the end
    assert nxt[AGENT_GROUP, "info", "collided_agent"][0].all()
    torch.testing.assert_close(
        nxt[AGENT_GROUP, "reward"][0, :, 0], torch.full((2,), SPEC.c_step + SPEC.c_collision), atol=0.01, rtol=0
    )


def test_continuous_agents_passing_in_adjacent_lanes_do_not_collide_at_any_dt():
    # The same crossing 0.65 m apart across the sidewalk: the discs (2 × 0.3 m) pass with 5 cm to spare.
    env = ContinuousSidewalkEnv(num_envs=1, seed=0, layout=head_on_plane(1.0, lane_offset_m=0.65), dt_s=1.0)
    nxt, _ = step(env, env.reset(), [[1.0, 0.0], [1.0, 0.0]])
    x0, x1 = nxt[AGENT_GROUP, "state"][0, :, 0].tolist()
    assert x0 > x1 and not nxt[AGENT_GROUP, "info", "collided_agent"].any()


def test_continuous_wall_collision():
    env = ContinuousSidewalkEnv(num_envs=1, seed=0)
    td = env.reset()
    for _ in range(40):  # agent 0 turns left towards the wall at y = 1.5 and accelerates into it
        nxt, td = step(env, td, [[1.0, math.pi / 8], [0.0, 0.0]])
        if nxt[AGENT_GROUP, "done"][0, 0]:
            break
    assert nxt[AGENT_GROUP, "info", "collided_wall"][0, 0].item()
    x, y = nxt[AGENT_GROUP, "state"][0, 0, :2].tolist()  # it stays where it was, inside the world
    r = env.params.agent_radius_m
    assert r <= x <= env.layout.length_m - r and r <= y <= env.layout.width_m - r


def test_timeout_truncates():
    env = DiscreteSidewalkEnv(num_envs=2, seed=0, max_steps=4)
    rollout = play(env, [[UP, DOWN], [DOWN, UP]] * 2)
    assert rollout["truncated"][:, -1].all() and not rollout["terminated"][:, -1].any()
    assert rollout[AGENT_GROUP, "truncated"][:, -1].all()
    assert rollout[AGENT_GROUP, "info", "timed_out"][:, -1].all()
    assert not rollout["done"][:, :-1].any()


# ---- noise ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("noise", [0.1, 0.2])
def test_random_action_rate_matches_noise(noise):
    # Agents in open space command RIGHT; a replaced action is uniform over the 4 moves, so it differs from
    # RIGHT with probability 3/4: the observed rate of other moves is 0.75 n.
    layout = GridLayout(rows=7, cols=15, starts=((3, 5), (1, 9)), goals=((3, 14), (1, 0)), center_row=3.0)
    n_worlds = 40_000
    env = DiscreteSidewalkEnv(num_envs=n_worlds, seed=1, noise=noise, layout=layout)
    before = env.reset()[AGENT_GROUP, "state"].clone()
    nxt, _ = step(env, env.reset(), [RIGHT, RIGHT])
    moved = nxt[AGENT_GROUP, "state"] - before
    other = (moved != torch.tensor([0, 1])).any(-1).float()
    expected = 0.75 * noise
    tolerance = 5 * math.sqrt(expected * (1 - expected) / other.numel())
    assert abs(other.mean().item() - expected) < tolerance
    for delta in ([-1, 0], [1, 0], [0, -1]):  # each other move takes a quarter of the replacements
        rate = (moved == torch.tensor(delta)).all(-1).float().mean().item()
        assert abs(rate - noise / 4) < 5 * math.sqrt(noise / 4 / other.numel())


def test_continuous_observation_noise_is_uniform_within_epsilon():
    epsilon = 0.5
    env = ContinuousSidewalkEnv(num_envs=4096, seed=0, noise=epsilon)
    td = env.reset()
    state, goal = td[AGENT_GROUP, "state"], td[AGENT_GROUP, "goal"]
    error = td[AGENT_GROUP, "observation"][:, 0, :6] - torch.cat([state[:, 0], goal[:, 0]], -1)
    assert error.abs().max() <= epsilon + 1e-6
    assert abs(error.mean().item()) < 0.01
    assert abs(error.std().item() - epsilon / math.sqrt(3)) < 0.01


def test_continuous_action_noise_is_applied_before_the_bounds():
    env = ContinuousSidewalkEnv(num_envs=4096, seed=0, noise=1.5)
    nxt, _ = step(env, env.reset(), [[0.0, 0.0], [0.0, 0.0]])
    speed = nxt[AGENT_GROUP, "state"][..., 2]
    dt = env.params.dt_s
    assert speed.abs().max() <= env.params.max_accel_mps2 * dt + 1e-6  # bounds hold
    assert speed.abs().max() >= 0.9 * env.params.max_accel_mps2 * dt  # and the noise reached them
    assert speed.std() > 0.5 * dt


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_action_is_an_error_naming_its_worlds(bad):
    env = ContinuousSidewalkEnv(num_envs=8, seed=0)
    td = env.reset()
    action = torch.zeros(8, 2, 2)
    action[5, 1, 0] = bad
    td.set((AGENT_GROUP, "action"), action)
    with pytest.raises(ValueError, match=r"non-finite action in 1 of 8 worlds \(world 5 agent 1"):
        env.step(td)
    if not math.isnan(bad):
        return  # the bounds clip an infinite action; it is still refused, as the sign of a diverged policy
    # The switch exists for users who measured its cost; without it the world turns NaN (what the check prevents).
    unchecked = ContinuousSidewalkEnv(num_envs=8, seed=0, check_actions=False)
    td = unchecked.reset()
    td.set((AGENT_GROUP, "action"), action)
    state = unchecked.step(td)["next", AGENT_GROUP, "state"]
    assert not torch.isfinite(state[5, 1]).all() and torch.isfinite(state[:5]).all()


# ---- observations ------------------------------------------------------------------------------------------------


def test_grid_image_gives_each_agent_and_goal_its_own_value():
    layout = GridLayout(rows=7, cols=15, starts=((3, 2), (3, 12)), goals=((3, 14), (3, 0)), center_row=3.0)
    env = DiscreteSidewalkEnv(num_envs=1, seed=0, layout=layout)
    image = env.reset()[AGENT_GROUP, "observation"][0, :, 0]  # (observer, H, W)
    k = env.params.pixels_per_cell

    def value(observer, cell):
        return image[observer, cell[0] * k : (cell[0] + 1) * k, cell[1] * k : (cell[1] + 1) * k].unique().tolist()

    # In agent 0's image: itself, the other agent, its goal, the other goal -- four distinct values.
    values = [value(0, c) for c in [(3, 2), (3, 12), (3, 14), (3, 0)]]
    assert all(len(v) == 1 for v in values) and len({v[0] for v in values}) == 4
    # Ego-centric: agent 1 sees itself with the value agent 0 sees itself with.
    assert value(1, (3, 12)) == value(0, (3, 2)) and value(1, (3, 0)) == value(0, (3, 14))
    assert (image == 0).float().mean() > 0.9  # the rest is background


def test_vector_observation_is_ego_ordered_and_normalised():
    env = DiscreteSidewalkEnv(num_envs=1, seed=0, observation="vector")
    obs = env.reset()[AGENT_GROUP, "observation"][0]
    assert obs.shape == (2, 12) and obs.min() >= 0 and obs.max() <= 1
    torch.testing.assert_close(obs[0, :6], obs[1, 6:])
    torch.testing.assert_close(obs[0, :2], torch.tensor([0.5, 0.0]))
    torch.testing.assert_close(obs[0, 4:6], torch.tensor([1.0, 1.0]))  # present, active


def test_render_returns_rgb_arrays():
    for env in (DiscreteSidewalkEnv(num_envs=2, seed=0), ContinuousSidewalkEnv(num_envs=2, seed=0)):
        env.reset()
        frame = env.render(env_index=1)
        assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype.name == "uint8"
        assert len({tuple(px) for px in frame.reshape(-1, 3)[::7].tolist()}) > 3


# ---- resets and seeding --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", [DiscreteSidewalkEnv, ContinuousSidewalkEnv])
def test_same_seed_same_rollout_other_seed_differs(cls):
    noise = 0.2 if cls is DiscreteSidewalkEnv else 0.5

    def rollout(seed):
        env = cls(num_envs=16, seed=seed, noise=noise)
        torch.manual_seed(seed)  # rollout's random policy draws from the global generator
        return env.rollout(120, break_when_any_done=False)

    a, b, c = rollout(3), rollout(3), rollout(4)
    assert (a == b).all()
    assert not (a["next", AGENT_GROUP, "state"] == c["next", AGENT_GROUP, "state"]).all()


def test_set_seed_restarts_the_stream():
    env = ContinuousSidewalkEnv(num_envs=8, noise=0.5)
    env.set_seed(11)
    first = env.reset()[AGENT_GROUP, "observation"].clone()
    env.set_seed(11)
    torch.testing.assert_close(env.reset()[AGENT_GROUP, "observation"], first)


@pytest.mark.parametrize("cls", [DiscreteSidewalkEnv, ContinuousSidewalkEnv])
def test_partial_reset_touches_only_the_masked_worlds(cls):
    env = cls(num_envs=4, seed=0)
    td = env.reset()
    for _ in range(3):
        td = env.rand_step(td)["next"]
    before = td[AGENT_GROUP, "state"].clone()
    mask = torch.tensor([[True], [False], [True], [False]])
    after = env.reset(td.set("_reset", mask))
    start = env.reset()[AGENT_GROUP, "state"]
    torch.testing.assert_close(after[AGENT_GROUP, "state"][[0, 2]], start[[0, 2]])
    torch.testing.assert_close(after[AGENT_GROUP, "state"][[1, 3]], before[[1, 3]])


def test_auto_reset_keeps_terminal_observation_in_next():
    env = DiscreteSidewalkEnv(num_envs=1, seed=0)
    nxt, td = step(env, env.reset(), [LEFT, RIGHT])  # agent 0 off the grid; agent 1 off the far end
    assert nxt["done"].all()
    assert nxt[AGENT_GROUP, "info", "collided_wall"].all()
    assert not td["done"].any() and td[AGENT_GROUP, "state"][0].tolist() == [[3, 0], [3, 14]]


# ---- parameter checks -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "cls, kwargs, message",
    [
        (DiscreteSidewalkEnv, {"noise": 1.5}, "noise=1.5"),
        (DiscreteSidewalkEnv, {"nosie": 0.1}, "did you mean 'noise'"),
        (DiscreteSidewalkEnv, {"observation": "rgb"}, "observation='rgb'"),
        (DiscreteSidewalkEnv, {"pixels_per_cell": 0}, "pixels_per_cell=0"),
        (DiscreteSidewalkEnv, {"layout": "maze"}, "layout='maze'"),
        (DiscreteSidewalkEnv, {"rewards": {"c_gaol": 1.0}}, "did you mean 'c_goal'"),
        (DiscreteSidewalkEnv, {"rewards": {"shaped_agents": (5,)}}, "shaped_agents"),
        (ContinuousSidewalkEnv, {"dt_s": 0.0}, "dt_s=0.0"),
        (ContinuousSidewalkEnv, {"noise": -1.0}, "noise=-1.0"),
        (ContinuousSidewalkEnv, {"max_turn_rad": 4.0}, "max_turn_rad=4.0"),
        (ContinuousSidewalkEnv, {"max_steps": 2.5}, "max_steps=2.5"),
    ],
)
def test_bad_parameters_are_named(cls, kwargs, message):
    with pytest.raises((ValueError, TypeError), match=message.replace("(", r"\(").replace(")", r"\)")):
        cls(num_envs=2, **kwargs)


def test_bad_num_envs_is_named():
    with pytest.raises(ValueError, match="num_envs=0"):
        DiscreteSidewalkEnv(num_envs=0)
