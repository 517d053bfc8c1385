"""Resets and draws of the core envs: a partial reset observes only its worlds and gives every other world back what
the last step gave it; seeded rollouts, layout draws and pair checks stay the numbers they were (reference
implementations of the earlier, simpler code live here and must agree bit for bit); the image spec builds fast."""

from __future__ import annotations

import hashlib

import pytest
import torch
from torchrl.data import Bounded, Composite

from sidewalk.envs import AGENT_GROUP, ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.grid import UniformBounded
from sidewalk.envs.layouts import RandomGridLayout, random_grid, random_plane
from sidewalk.envs.layouts.base import clear_of

ENTRIES = ("observation", "state", "goal")
# (domain, env kwargs): fixed and random layouts, both grid observations, noise off and on.
CASES = [
    ("grid", {"layout": "sidewalk", "noise": 0.2}),
    ("grid", {"layout": "random", "n_agents": 3}),
    ("grid", {"layout": "random", "n_agents": 3, "observation": "vector", "noise": 0.2}),
    ("grid", {"layout": "door", "n_agents": 3, "observation": "vector"}),
    ("continuous", {"layout": "sidewalk", "noise": 0.3}),
    ("continuous", {"layout": "random", "n_agents": 3, "length_m": 6.0, "width_m": 6.0}),
    ("continuous", {"layout": "random", "n_agents": 3, "length_m": 6.0, "width_m": 6.0, "noise": 0.3}),
    ("continuous", {"layout": "door", "n_agents": 3, "length_m": 6.0}),
]


def make(domain: str, num_envs: int, seed: int = 0, **kwargs):
    cls = DiscreteSidewalkEnv if domain == "grid" else ContinuousSidewalkEnv
    return cls(num_envs=num_envs, seed=seed, max_steps=kwargs.pop("max_steps", 300), **kwargs)


def random_action(env, generator: torch.Generator) -> torch.Tensor:
    spec = env.full_action_spec[AGENT_GROUP, "action"]
    if isinstance(env, DiscreteSidewalkEnv):
        return torch.randint(4, spec.shape, generator=generator)
    low, high = spec.space.low, spec.space.high
    return low + (high - low) * torch.rand(spec.shape, generator=generator)


def rollout(env, steps: int, seed: int = 1, reset_every: int = 0) -> list:
    """Every output of ``steps`` auto-resetting steps with random actions; every ``reset_every`` steps also an
    explicit reset of a random half of the worlds."""
    generator = torch.Generator().manual_seed(seed)
    td = env.reset()
    outputs = [td.clone()]
    for t in range(steps):
        td.set((AGENT_GROUP, "action"), random_action(env, generator))
        out, td = env.step_and_maybe_reset(td)
        outputs += [out.clone(), td.clone()]
        if reset_every and t % reset_every == reset_every - 1:
            td = env.reset(td.set("_reset", torch.rand(env.num_envs, 1, generator=generator) < 0.5))
            outputs.append(td.clone())
    return outputs


def digest(outputs: list) -> str:
    """sha256 of the observations, states, goals and done flags of ``outputs``, bit for bit."""
    sha = hashlib.sha256()
    for td in outputs:
        for key in sorted(td.keys(include_nested=True, leaves_only=True), key=str):
            if key[-1] in (*ENTRIES, "done"):
                sha.update(str(key).encode())
                sha.update(td.get(key).contiguous().numpy().tobytes())
    return sha.hexdigest()[:16]


# ---- partial resets ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("domain, kwargs", CASES)
def test_partial_reset_gives_unreset_worlds_the_last_output(domain, kwargs):
    env = make(domain, 12, **kwargs)
    generator = torch.Generator().manual_seed(0)
    td = env.reset()
    for _ in range(4):
        td.set((AGENT_GROUP, "action"), random_action(env, generator))
        td = env.step(td)["next"]
    last = td.clone()
    held = {key: td[AGENT_GROUP, key] for key in ENTRIES}
    mask = torch.tensor([i % 3 == 0 for i in range(12)]).unsqueeze(-1)
    after = env.reset(td.set("_reset", mask))
    keep = ~mask.squeeze(-1)
    for key in ENTRIES:
        assert torch.equal(after[AGENT_GROUP, key][keep], last[AGENT_GROUP, key][keep]), key
        assert torch.equal(held[key], last[AGENT_GROUP, key]), f"the reset wrote into the last output's {key}"
    assert not torch.equal(after[AGENT_GROUP, "state"][~keep], last[AGENT_GROUP, "state"][~keep])


@pytest.mark.parametrize("domain, kwargs", [case for case in CASES if case[1].get("noise", 0.0) == 0.0])
def test_partial_reset_output_equals_observing_every_world(domain, kwargs):
    # Without noise an observation is a function of the state: what a partial reset assembles from the last output
    # and its own worlds is what observing every world anew gives.
    env = make(domain, 16, max_steps=7, **kwargs)
    generator = torch.Generator().manual_seed(3)
    td = env.reset()
    for _ in range(30):  # worlds time out, crash and arrive at different steps: partial auto-resets
        td.set((AGENT_GROUP, "action"), random_action(env, generator))
        _, td = env.step_and_maybe_reset(td)
        anew = env._observe(None)
        for key in ENTRIES:
            assert torch.equal(td[AGENT_GROUP, key], anew[key]), key


@pytest.mark.parametrize("domain, kwargs", [case for case in CASES if case[1]["layout"] != "random"])
def test_batched_rollout_equals_world_by_world(domain, kwargs):
    # Fixed layouts draw nothing per world, so without noise each world of a batch lives as it would alone:
    # the batch's partial auto-resets must not disturb the other worlds.
    kwargs = {**kwargs, "noise": 0.0}
    n_worlds, steps = 5, 40
    batch = make(domain, n_worlds, max_steps=9, **kwargs)
    alone = [make(domain, 1, max_steps=9, **kwargs) for _ in range(n_worlds)]
    generator = torch.Generator().manual_seed(2)
    td, tds = batch.reset(), [env.reset() for env in alone]
    for _ in range(steps):
        action = random_action(batch, generator)
        td.set((AGENT_GROUP, "action"), action)
        out, td = batch.step_and_maybe_reset(td)
        for world, env in enumerate(alone):
            tds[world].set((AGENT_GROUP, "action"), action[world : world + 1])
            out_alone, tds[world] = env.step_and_maybe_reset(tds[world])
            for key in ENTRIES:
                assert torch.equal(out["next", AGENT_GROUP, key][world], out_alone["next", AGENT_GROUP, key][0])
                assert torch.equal(td[AGENT_GROUP, key][world], tds[world][AGENT_GROUP, key][0])


@pytest.mark.parametrize("domain, kwargs", CASES)
def test_same_seed_same_rollout_with_partial_resets(domain, kwargs):
    # The seed seeds the env and the random actions: a fixed layout without noise draws nothing from the env's.
    first, again, other = (rollout(make(domain, 8, seed=seed, max_steps=11, **kwargs), 40, seed, reset_every=7)
                           for seed in (5, 5, 6))
    assert digest(first) == digest(again)
    assert digest(first) != digest(other)


def test_observation_noise_draws_do_not_depend_on_which_worlds_reset():
    # The noise of a reset is drawn for every world and kept for the reset ones, so the generator's stream after a
    # reset is the same whichever worlds it reset (a fixed layout draws nothing else).
    states = []
    for mask in ([True, False, False, False], [False, True, True, False], [False] * 4, [True] * 4):
        env = ContinuousSidewalkEnv(num_envs=4, seed=0, noise=0.5)
        td = env.reset()
        env.reset(td.set("_reset", torch.tensor(mask).unsqueeze(-1)))
        states.append(env.generator.get_state())
    assert all(torch.equal(state, states[0]) for state in states)


# Digests of seeded rollouts, taken from the code before partial resets observed only their worlds (2026-11-23):
# a change here means an env now produces other numbers for the same seed. Retaken when the vector observations
# gained the active/present flags and stopped showing removed agents (2026-11-24); states, goals, rewards and done
# flags were checked bit-identical to e7a1738's, and its observations equal to the new ones less those changes.
GOLDEN = {
    "grid-random-image": ("grid", {"layout": "random", "n_agents": 4}, "72651dd6421d1bbc"),
    "grid-door-vector-noise": ("grid", {"layout": "door", "n_agents": 3, "observation": "vector", "noise": 0.2},
                               "e97a9af33a630fd6"),
    "continuous-random-noise": ("continuous", {"layout": "random", "n_agents": 4, "length_m": 6.0, "width_m": 6.0,
                                               "noise": 0.3}, "f2a47c87e0a295d0"),
    "continuous-sidewalk": ("continuous", {"layout": "sidewalk"}, "a5dcef22e413e00f"),
}


@pytest.mark.parametrize("name", GOLDEN)
def test_seeded_rollouts_keep_their_numbers(name):
    domain, kwargs, expected = GOLDEN[name]
    assert digest(rollout(make(domain, 16, seed=7, max_steps=23, **kwargs), 60, reset_every=9)) == expected


# ---- layout draws -------------------------------------------------------------------------------------------------


def reference_grid_sample(layout: RandomGridLayout, n: int, generator: torch.Generator):
    """RandomGridLayout.sample as first written: one draw per agent, distances computed per agent."""
    cells, cols = layout.rows * layout.cols, layout.cols
    free = ~layout.blocked_mask(generator.device).view(-1)
    score = torch.rand(n, cells, generator=generator).masked_fill(~free, -1.0)
    start_cell = score.topk(layout.n_agents, dim=1).indices
    cell_row, cell_col = torch.arange(cells) // cols, torch.arange(cells) % cols
    taken = (~free).expand(n, -1).clone()
    goal_cell = torch.empty_like(start_cell)
    for agent in range(layout.n_agents):
        start_row, start_col = start_cell[:, agent : agent + 1] // cols, start_cell[:, agent : agent + 1] % cols
        distance = (cell_row - start_row).abs() + (cell_col - start_col).abs()
        valid = (distance >= layout.min_start_goal_cells) & ~taken
        pick = torch.rand(n, cells, generator=generator).masked_fill(~valid, -1.0).argmax(-1)
        goal_cell[:, agent] = pick
        taken.scatter_(1, pick[:, None], True)
    as_cells = lambda flat: torch.stack([flat // cols, flat % cols], dim=-1)
    return as_cells(start_cell), as_cells(goal_cell)


@pytest.mark.parametrize(
    "layout",
    [
        random_grid(7, 15, 2),
        random_grid(14, 29, 16),
        random_grid(3, 5, 2, 2),
        random_grid(70, 70, 3, 9),  # more cells than the table of near cells holds
        RandomGridLayout(7, 15, 4, 3, 3.0, blocked=tuple((r, c) for r in range(7) for c in range(15) if (r + 2 * c) % 7 == 0)),
    ],
    ids=["7x15-N2", "14x29-N16", "3x5-N2", "70x70-N3", "blocked"],
)
def test_grid_layout_draws_as_first_written(layout):
    ours, theirs = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    for n in (0, 1, 5, 64, 700):  # 700 worlds of 16 agents: their scores are drawn one agent at a time
        for got, expected in zip(layout.sample(n, ours), reference_grid_sample(layout, n, theirs)):
            assert got.dtype == expected.dtype and torch.equal(got, expected)
    assert torch.equal(ours.get_state(), theirs.get_state())


def reference_plane_draw(layout, n: int, generator: torch.Generator):
    """RandomPlaneLayout._draw as first written: every round indexes the pending worlds."""
    low = torch.tensor([layout.wall_gap_m, layout.wall_gap_m])
    span = torch.tensor([layout.length_m, layout.width_m]) - 2 * low

    def place(out, placed, gap_m, own_start=None):
        pending = torch.arange(out.shape[0])
        for _ in range(layout.PLACE_ROUNDS):
            candidates = low + span * torch.rand(pending.numel(), layout.CANDIDATES, 2, generator=generator)
            valid = clear_of(candidates, placed[pending], gap_m)
            if own_start is not None:
                to_start = candidates - own_start[pending].unsqueeze(1)
                valid &= to_start.square().sum(-1) >= layout.min_start_goal_m**2
            found, first = valid.any(-1), valid.to(torch.uint8).argmax(-1)
            out[pending[found]] = candidates[found, first[found]]
            pending = pending[~found]
            if pending.numel() == 0:
                break
        ok = torch.ones(out.shape[0], dtype=torch.bool)
        ok[pending] = False
        return ok

    starts, goals = torch.empty(n, layout.n_agents, 2), torch.empty(n, layout.n_agents, 2)
    ok = torch.ones(n, dtype=torch.bool)
    for agent in range(layout.n_agents):
        ok &= place(starts[:, agent], starts[:, :agent], layout.start_gap_m)
        ok &= place(goals[:, agent], goals[:, :agent], layout.goal_gap_m, starts[:, agent])
    return starts, goals, ok


@pytest.mark.parametrize("side_m, n_agents", [(4.5, 2), (11.2, 16), (4.9, 5), (9.0, 16)])
def test_plane_layout_draws_as_first_written(side_m, n_agents):
    # 4.9 m for 5 agents and 9 m for 16 are near the density limit: candidates run out, rounds and worlds repeat.
    layout = random_plane(side_m, side_m, n_agents)
    ours, theirs = torch.Generator().manual_seed(8), torch.Generator().manual_seed(8)
    for n in (0, 1, 7, 200):
        got, expected = layout._draw(n, ours), reference_plane_draw(layout, n, theirs)
        assert torch.equal(got[2], expected[2])
        valid = expected[2]  # an invalid world's points are left unwritten (it is drawn again)
        for ours_points, their_points in zip(got[:2], expected[:2]):
            assert torch.equal(ours_points[valid], their_points[valid])
        assert torch.equal(ours.get_state(), theirs.get_state())


# ---- pair checks ----------------------------------------------------------------------------------------------------


def reference_swept_contact(x0, y0, x1, y1, radius_m):
    """ContinuousSidewalkEnv._swept_contact as first written: every ordered pair (i, j), (N, N, B)."""
    x0, y0, x1, y1 = (t.t().contiguous() for t in (x0, y0, x1, y1))
    rel_x0, rel_y0 = x0.unsqueeze(1) - x0.unsqueeze(0), y0.unsqueeze(1) - y0.unsqueeze(0)
    rel_dx = x1.unsqueeze(1) - x1.unsqueeze(0) - rel_x0
    rel_dy = y1.unsqueeze(1) - y1.unsqueeze(0) - rel_y0
    approach = (rel_x0 * rel_dx + rel_y0 * rel_dy).neg_()
    closest = (approach / (rel_dx.square() + rel_dy.square()).clamp_min(1e-12)).clamp_(0.0, 1.0)
    gap_sq = (rel_x0 + closest * rel_dx).square() + (rel_y0 + closest * rel_dy).square()
    return gap_sq < (2 * radius_m) ** 2


@pytest.mark.parametrize("n_agents", [1, 2, 5, 16])
def test_swept_contact_is_the_all_pairs_check(n_agents):
    env = ContinuousSidewalkEnv(num_envs=512, seed=0, layout="random", n_agents=n_agents, length_m=12.0, width_m=12.0)
    generator = torch.Generator().manual_seed(n_agents)
    for scale in (0.05, 1.0, 3.0):  # from mostly apart to mostly touching
        x0, y0 = (3 * scale * torch.rand(512, n_agents, generator=generator) for _ in range(2))
        x0[:5], y0[:5] = 1.0, 1.0  # agents on one spot
        moving = torch.rand(512, n_agents, generator=generator) < 0.7  # the others stand still
        x1 = x0 + scale * torch.randn(512, n_agents, generator=generator) * moving
        y1 = y0 + scale * torch.randn(512, n_agents, generator=generator) * moving
        env._x, env._y = x0, y0
        got = env._swept_contact(x1, y1)
        assert torch.equal(got, reference_swept_contact(x0, y0, x1, y1, env.params.agent_radius_m))


# ---- the image spec ---------------------------------------------------------------------------------------------


def test_image_spec_is_bounded_0_255_with_one_items_bounds():
    env = DiscreteSidewalkEnv(num_envs=64, n_agents=4, layout="random", seed=0)
    spec = env.observation_spec[AGENT_GROUP, "observation"]
    assert isinstance(spec, Bounded) and spec.dtype == torch.uint8 and spec.shape == (64, 4, 1, 14, 30)
    assert spec.space.batch_size == (64, 4) and spec.space.low.shape == (64, 4, 1, 14, 30)
    assert (spec.space.low == 0).all() and (spec.space.high == 255).all()
    clone = env.observation_spec.clone()[AGENT_GROUP, "observation"]
    assert type(clone) is UniformBounded and clone.space.batch_size == (64, 4) and clone == spec


def test_uniform_bounded_leaves_unequal_bounds_to_torchrl():
    high = torch.full((3, 2, 4), 9, dtype=torch.uint8)
    high[1] = 7  # bounds differ between batch items: TorchRL keeps them all
    spec = UniformBounded(torch.zeros_like(high), high, shape=high.shape, dtype=torch.uint8)
    composite = Composite(observation=spec, shape=(3,))
    assert composite["observation"].space.batch_size is None
    assert torch.equal(composite["observation"].space.high, high)


def test_large_image_env_keeps_its_uniform_bounds_compact():
    # TorchRL's own check of per-item bounds took ~10 s here (4096 worlds × 16 agents × 28 × 58 pixels); the uniform
    # spec skips it (its speed is the env benchmark's to measure, not a test's).
    env = DiscreteSidewalkEnv(num_envs=4096, n_agents=16, layout="random", width_cells=14, length_cells=29, seed=0)
    spec = env.observation_spec[AGENT_GROUP, "observation"]
    assert type(spec) is UniformBounded and spec.space.batch_size == (4096, 16)
