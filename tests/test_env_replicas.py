"""Replicas: a core env built with several seeds steps each replica's block of worlds bit for bit as a lone env of that
seed (noise, random layouts, partial resets, opponents, the self-play mirror, the shield), through every view, and a
snapshot of a replicated env resumes exactly; one replica is today's env."""

from __future__ import annotations

import copy

import pytest
import torch

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.opponents.base import Opponent, ReplicaOpponent, make_opponent, opponent_class
from sidewalk.opponents.dijkstra import DijkstraOpponent
from sidewalk.opponents.prm import PRMOpponent
from sidewalk.opponents.random import RandomOpponent
from sidewalk.opponents.replicas import ReplicaEnv
from sidewalk.snapshot import capture_env, restore_env
from sidewalk.views import CentralizedView, EgoView, SelfPlayView

torch.set_num_threads(1)

SEEDS = (3, 7, 11)
REPLICA = 1  # the lone env of SEEDS[REPLICA] is compared with this block of the replicated one


def grid(num_envs: int, seed, **kwargs) -> DiscreteSidewalkEnv:
    kwargs = {"layout": "random", "noise": 0.2, "max_steps": 12, **kwargs}
    return DiscreteSidewalkEnv(num_envs, seed=seed, **kwargs)


def plane(num_envs: int, seed, **kwargs) -> ContinuousSidewalkEnv:
    kwargs = {"layout": "random", "noise": 0.1, "max_steps": 15, **kwargs}
    return ContinuousSidewalkEnv(num_envs, seed=seed, **kwargs)


def draw_action(env, generator: torch.Generator) -> torch.Tensor:
    """A uniform action of every world of ``env`` (the view's action key), from ``generator``."""
    spec = env.full_action_spec[env.action_keys[0]]
    if spec.dtype == torch.int64:
        return torch.randint(spec.space.n, spec.shape, generator=generator)
    low, high = spec.space.low, spec.space.high
    return low + (high - low) * torch.rand(spec.shape, generator=generator)


def assert_block_equal(replicated, lone, block: slice, what: str) -> None:
    mine = dict(replicated.items(include_nested=True, leaves_only=True))
    theirs = dict(lone.items(include_nested=True, leaves_only=True))
    assert mine.keys() == theirs.keys(), f"{what}: keys {mine.keys() ^ theirs.keys()}"
    differ = [key for key in mine if not torch.equal(mine[key][block], theirs[key])]
    assert not differ, f"{what}: {differ} differ"


def step_both(replicated, lone, worlds: int, steps: int, generator: torch.Generator, block: slice):
    """Step both envs with the same actions (block ``block`` of the replicated env's), auto-resetting; compare every
    output. Returns the number of partial resets the lone env went through."""
    key = replicated.action_keys[0]
    big, small = replicated.reset(), lone.reset()
    assert_block_equal(big, small, block, "reset")
    partial = 0
    for t in range(steps):
        action = draw_action(replicated, generator)
        big.set(key, action)
        small.set(key, action[block].clone())
        out_big, big = replicated.step_and_maybe_reset(big)
        out_small, small = lone.step_and_maybe_reset(small)
        assert_block_equal(out_big, out_small, block, f"step {t}")
        assert_block_equal(big, small, block, f"reset after step {t}")
        done = out_small["next", "done"]
        partial += int(bool(done.any()) and not bool(done.all()))
    return partial


CASES = {
    "grid": lambda n, seed: grid(n, seed),
    "grid-vector-3": lambda n, seed: grid(n, seed, observation="vector", n_agents=3),
    "plane": lambda n, seed: plane(n, seed),
    "plane-door-progress": lambda n, seed: plane(n, seed, layout="door", n_agents=3, rewards={"c_progress": 0.1}),
    "ego-random-grid": lambda n, seed: EgoView(grid(n, seed), "random"),
    "ego-random-plane-shield": lambda n, seed: EgoView(plane(n, seed), "random", shield=True),
    "ego-dijkstra-grid": lambda n, seed: EgoView(grid(n, seed, n_agents=3), "dijkstra"),
    "ego-prm-plane": lambda n, seed: EgoView(plane(n, seed), "prm", opponent_kwargs={"roadmap_seed": None}),
    "ego-prm-seeded-plane": lambda n, seed: EgoView(plane(n, seed), "prm", opponent_kwargs={"roadmap_seed": 4}),
    "ego-prm-seeded-door": lambda n, seed: EgoView(
        plane(n, seed, layout="door", n_agents=3), "prm", opponent_kwargs={"roadmap_seed": 4}
    ),
    "self-other-play-grid": lambda n, seed: SelfPlayView(grid(n, seed), other_play=True),
    "self-other-play-plane-shield": lambda n, seed: SelfPlayView(plane(n, seed), other_play=True, shield=True),
    "centralized-grid-shield": lambda n, seed: CentralizedView(grid(n, seed), shield=True),
    "centralized-plane": lambda n, seed: CentralizedView(plane(n, seed)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_replica_steps_as_the_lone_env_of_its_seed(case):
    make, worlds = CASES[case], 3
    replicated, lone = make(len(SEEDS) * worlds, list(SEEDS)), make(worlds, SEEDS[REPLICA])
    block = slice(REPLICA * worlds, (REPLICA + 1) * worlds)
    partial = step_both(replicated, lone, worlds, 60, torch.Generator().manual_seed(0), block)
    assert partial > 0  # the comparison went through partial resets


@pytest.mark.parametrize("replica", range(len(SEEDS)))
def test_every_replica_matches_its_lone_env(replica):
    make, worlds = CASES["ego-prm-plane"], 2
    replicated, lone = make(len(SEEDS) * worlds, list(SEEDS)), make(worlds, SEEDS[replica])
    block = slice(replica * worlds, (replica + 1) * worlds)
    step_both(replicated, lone, worlds, 40, torch.Generator().manual_seed(1), block)


def test_one_replica_is_the_env_of_that_seed():
    for make in (CASES["grid"], CASES["ego-prm-plane"], CASES["self-other-play-plane-shield"]):
        listed, plain = make(4, [5]), make(4, 5)
        assert getattr(listed, "core", listed).replicas == 1
        step_both(listed, plain, 4, 30, torch.Generator().manual_seed(2), slice(None))


def test_replica_attributes_and_generators():
    env = grid(6, list(SEEDS))
    assert (env.replicas, env.worlds_per_replica, env.num_envs) == (3, 2, 6)
    assert [g.initial_seed() for g in env.generators] == list(SEEDS)
    assert env.generator is env.generators[0]
    lone = grid(2, 7)
    assert (lone.replicas, lone.worlds_per_replica, len(lone.generators)) == (1, 2, 1)
    assert lone.generator is lone.generators[0]


def test_world_count_must_divide_among_replicas():
    with pytest.raises(ValueError, match=r"num_envs=10.*3 replicas.*\[3, 7, 11\]"):
        grid(10, list(SEEDS))
    with pytest.raises(ValueError, match="seed"):
        grid(3, [])
    with pytest.raises(TypeError, match="seed"):
        grid(3, [1.5, 2, 3])


def test_set_seed_of_a_replicated_env_takes_one_seed_per_replica():
    env = plane(6, list(SEEDS))
    with pytest.raises(ValueError, match="3 replicas"):
        env.set_seed(5)
    with pytest.raises(ValueError, match="3 replicas"):
        env.set_seed([1, 2], static_seed=True)
    torch.manual_seed(0)  # the rollout's random actions come from the global generator
    first = env.rollout(20, break_when_any_done=False)
    env.set_seed([3, 7, 11], static_seed=True)
    torch.manual_seed(0)
    again = env.rollout(20, break_when_any_done=False)
    assert_block_equal(first, again, slice(None), "after set_seed")


def test_draw_helpers():
    env = grid(6, list(SEEDS))
    draws = env.rand((6, 4))
    for r, seed in enumerate(SEEDS):
        assert torch.equal(draws[2 * r : 2 * r + 2], torch.rand((2, 4), generator=torch.Generator().manual_seed(seed)))
    states = [g.get_state() for g in env.generators]
    rows = torch.tensor([False, False, True, False, False, False])
    partly = env.randint(4, (6, 3), rows)
    assert torch.equal(partly[:2], torch.zeros(2, 3, dtype=torch.long)) and torch.equal(partly[4:], partly[:2])
    assert torch.equal(env.generators[0].get_state(), states[0]) and torch.equal(env.generators[2].get_state(), states[2])
    assert not torch.equal(env.generators[1].get_state(), states[1])
    with pytest.raises(ValueError, match="6 worlds"):
        env.rand((4, 2))
    lone = grid(2, 3)  # one replica: the plain draw, any shape
    assert torch.equal(lone.rand((5,)), torch.rand(5, generator=torch.Generator().manual_seed(3)))


def test_opponents_are_planned_once_unless_the_seed_or_the_batch_decides():
    discrete, continuous = grid(6, list(SEEDS)), plane(6, list(SEEDS))
    assert type(make_opponent("random", discrete)) is RandomOpponent
    assert type(make_opponent("dijkstra", discrete)) is DijkstraOpponent
    assert type(make_opponent("prm", continuous, roadmap_seed=4)) is PRMOpponent
    assert type(make_opponent("prm", continuous)) is PRMOpponent  # the default roadmap is every seed's
    per_replica = make_opponent("prm", continuous, roadmap_seed=None)  # each env's seed draws its roadmap
    assert isinstance(per_replica, ReplicaOpponent)
    assert [o.roadmap_seed for o in per_replica.opponents] == list(SEEDS)
    assert [o.env.num_envs for o in per_replica.opponents] == [2, 2, 2]
    policy = opponent_class("policy")
    assert not policy.replicated() and not policy.batch_invariant  # one network, played block by block
    assert type(make_opponent("prm", plane(2, 7))) is PRMOpponent  # one replica: as ever


class Coin(Opponent):
    """A plug-in opponent written for lone envs: it draws from ``env.generator`` and records its batch sizes."""

    def __init__(self, env, controlled=(1,), ego=0) -> None:
        super().__init__(env, controlled, ego)
        self.batches: list[int] = []

    def act(self, state, goal, done, present=None):
        self.batches.append(state.shape[0])
        return torch.randint(4, (state.shape[0], len(self.controlled)), generator=self.env.generator)


def test_a_replica_opponent_plays_each_block_with_its_own_opponent():
    def make(num_envs, seed):
        env = grid(num_envs, seed)
        if env.replicas == 1:
            return EgoView(env, Coin(env))
        return EgoView(env, ReplicaOpponent(env, [Coin(ReplicaEnv(env, r)) for r in range(env.replicas)]))

    replicated, lone = make(6, list(SEEDS)), make(2, 7)
    step_both(replicated, lone, 2, 30, torch.Generator().manual_seed(3), slice(2, 4))
    assert all(set(o.batches) == {2} for o in replicated.opponent.opponents)
    shared = Coin(replicated.core)  # one instance for all replicas, called per block (a network's batch)
    opponent = ReplicaOpponent(replicated.core, [shared] * 3)
    state = torch.zeros(6, 2, 2, dtype=torch.long)
    assert opponent.act(state, state, torch.zeros(6, 2, 1, dtype=torch.bool)).shape == (6, 1)
    assert shared.batches == [2, 2, 2]


def test_prm_plans_each_world_on_its_own():
    # 3 × 90 worlds of 2 controlled agents: 540 lanes, the unpaired sweeps; one replica's 180: the paired ones.
    env = plane(270, list(SEEDS), layout="door", n_agents=3, max_steps=300)
    generator = torch.Generator().manual_seed(4)
    td = env.reset()
    for _ in range(6):
        td.set(("agents", "action"), draw_action(env, generator))
        td = env.step_and_maybe_reset(td)[1]
    inputs = [td["agents", key] for key in ("state", "goal", "done", "present")]
    whole = PRMOpponent(env, controlled=(1, 2), roadmap_seed=4)
    plan, action = whole.plan(*inputs), whole.act(*inputs)
    for block in (slice(0, 90), slice(90, 180), slice(180, 270)):
        alone = PRMOpponent(ReplicaEnv(env, block.start // 90), controlled=(1, 2), roadmap_seed=4)
        part = [x[block] for x in inputs]
        assert all(torch.equal(a[block], b) for a, b in zip(plan, alone.plan(*part)))
        assert torch.equal(action[block], alone.act(*part))


def test_a_replica_opponent_plans_as_lone_planners():
    replicated, lone = plane(6, list(SEEDS), n_agents=3, layout="door"), plane(2, 7, n_agents=3, layout="door")
    team = make_opponent("prm", replicated, controlled=(0, 1, 2), ego=None)
    alone = make_opponent("prm", lone, controlled=(0, 1, 2), ego=None)
    big, small = replicated.reset(), lone.reset()
    inputs = [big["agents", key] for key in ("state", "goal", "done", "present")]
    assert torch.equal(team.act(*inputs)[2:4], alone.act(*[small["agents", key] for key in ("state", "goal", "done", "present")]))


@pytest.mark.parametrize("case", ["ego-prm-plane", "self-other-play-grid", "centralized-grid-shield"])
def test_a_snapshot_of_a_replicated_env_resumes_exactly(case):
    view = CASES[case](9, list(SEEDS))
    key, generator = view.action_keys[0], torch.Generator().manual_seed(5)
    td = view.reset()
    for _ in range(7):
        td.set(key, draw_action(view, generator))
        td = view.step_and_maybe_reset(td)[1]
    saved, saved_td = copy.deepcopy(capture_env(view)), td.clone()
    assert isinstance(saved["rng"], list) and len(saved["rng"]) == 3
    opponents = [saved.get("opponent", {}), *saved.get("opponent_replicas", [])]
    assert not any("_buffers" in state for state in opponents)  # the PRM's work tensors are no state to save
    actions = [draw_action(view, generator) for _ in range(25)]
    first = []
    for action in actions:
        td.set(key, action)
        out, td = view.step_and_maybe_reset(td)
        first.append(out.clone())
    restore_env(view, saved)
    td = saved_td
    for t, action in enumerate(actions):
        td.set(key, action)
        out, td = view.step_and_maybe_reset(td)
        assert_block_equal(out, first[t], slice(None), f"step {t} after restore")
