"""The Safety-Gymnasium face (sidewalk/interop/safety_gymnasium.py): a constrained-RL client's loop, run unchanged."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch

from sidewalk.interop import safety_gymnasium
from sidewalk.interop.gymnasium import ENV_IDS
from sidewalk.interop.safety_gymnasium import SAFETY_ENV_IDS, SafetySidewalkVectorEnv

torch.set_num_threads(1)

DOMAINS = list(SAFETY_ENV_IDS)


def collided(agents: dict) -> np.ndarray:
    """Bool per agent (leading axes kept): the sticky flag of a collision with a wall or another agent."""
    return agents["collided_wall"] | agents["collided_agent"]


def learner_collisions_now(before: dict, after: dict, opponent: str) -> float:
    """How many of the learner's agents collided in the step from ``before``'s flags to ``after``'s: the ego
    (agent 0) against a scripted opponent, every agent for the centralized view."""
    now = collided(after) & ~collided(before)
    return float(now.sum() if opponent == "centralized" else now[0])


def test_import_registers_both_ids_and_make_takes_only_those():
    assert all(env_id in gymnasium.registry for env_id in SAFETY_ENV_IDS.values())
    with pytest.raises(ValueError, match="sidewalk/SafetyDiscrete-v0"):
        safety_gymnasium.make(ENV_IDS["discrete"])
    with pytest.raises(TypeError, match="max_steps"):
        safety_gymnasium.make(SAFETY_ENV_IDS["discrete"], max_episode_steps=10)
    with pytest.raises(TypeError, match="make_vec"):
        safety_gymnasium.make(SAFETY_ENV_IDS["discrete"], autoreset=True)


@pytest.mark.parametrize("domain", DOMAINS)
def test_spaces_are_the_gymnasium_faces(domain):
    plain = gymnasium.make(ENV_IDS[domain], opponent="centralized")
    safe = safety_gymnasium.make(SAFETY_ENV_IDS[domain], opponent="centralized")
    assert safe.observation_space == plain.observation_space and safe.action_space == plain.action_space
    envs = safety_gymnasium.make_vec(SAFETY_ENV_IDS[domain], num_envs=3)
    assert envs.single_observation_space == gymnasium.make(ENV_IDS[domain]).observation_space


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("opponent", ["random", "centralized"])
def test_client_loop_costs_the_learners_collision_steps(domain, opponent):
    env = safety_gymnasium.make(SAFETY_ENV_IDS[domain], opponent=opponent)
    env.action_space.seed(0)
    # The loop as a Safety-Gymnasium client writes it; the flags only check it.
    obs, info = env.reset(seed=0)
    ep_cost, ep_costs, ep_collisions, collisions = 0.0, [], [], 0
    for _ in range(600):
        before = info["agents"]
        action = env.action_space.sample()
        obs, reward, cost, terminated, truncated, info = env.step(action)  # noqa: RUF059 - the client's own
        assert isinstance(cost, float) and "cost" not in info
        now = learner_collisions_now(before, info["agents"], opponent)
        assert cost == now
        agent_costs = info["agents"]["cost"]
        assert cost == (agent_costs.sum() if opponent == "centralized" else agent_costs[0])
        ep_cost += cost
        collisions += now
        if terminated or truncated:
            ep_costs.append(ep_cost)
            ep_collisions.append(collisions)
            ep_cost, collisions = 0.0, 0
            obs, info = env.reset()  # noqa: RUF059 - the client's own
    learners = 2 if opponent == "centralized" else 1  # a collided agent is done: one collision each at most
    assert ep_costs == ep_collisions and max(ep_costs) <= learners
    assert sum(ep_costs) > 0 and len(ep_costs) > 3


@pytest.mark.parametrize("domain", DOMAINS)
def test_info_cost_of_the_gymnasium_face_is_the_six_tuple_cost(domain):
    plain = gymnasium.make(ENV_IDS[domain], noise=0.1)
    safe = safety_gymnasium.make(SAFETY_ENV_IDS[domain], noise=0.1)
    plain_obs, plain_info = plain.reset(seed=1)
    obs, info = safe.reset(seed=1)
    assert plain_info["cost"] == 0.0 and set(plain_info) - set(info) == {"cost"}
    safe.action_space.seed(1)
    costs = []
    for _ in range(300):
        action = safe.action_space.sample()
        plain_obs, plain_reward, plain_terminated, plain_truncated, plain_info = plain.step(action)
        obs, reward, cost, terminated, truncated, info = safe.step(action)
        assert np.array_equal(obs, plain_obs) and reward == plain_reward
        assert (terminated, truncated) == (plain_terminated, plain_truncated)
        assert isinstance(plain_info["cost"], float) and plain_info["cost"] == cost
        np.testing.assert_array_equal(plain_info["agents"]["cost"], info["agents"]["cost"])
        costs.append(cost)
        if terminated or truncated:
            plain.reset()
            safe.reset()
    assert 0 < sum(costs) < len(costs)


def test_near_miss_cost_adds_steps_close_to_the_other_agent():
    env = safety_gymnasium.make(SAFETY_ENV_IDS["continuous"], cost="near_miss")
    env.action_space.seed(0)
    _, info = env.reset(seed=0)
    near_misses = 0
    for _ in range(600):
        before = info["agents"]
        _, _, cost, terminated, truncated, info = env.step(env.action_space.sample())
        now = learner_collisions_now(before, info["agents"], "ego")
        assert cost in (0.0, 1.0) and cost >= now
        near_misses += cost - now
        if terminated or truncated:
            _, info = env.reset()
    assert near_misses > 0


@pytest.mark.parametrize("domain", DOMAINS)
def test_vector_client_loop_autoresets_in_the_same_step(domain):
    num_envs = 8
    envs = safety_gymnasium.make_vec(SAFETY_ENV_IDS[domain], num_envs=num_envs)
    assert isinstance(envs, SafetySidewalkVectorEnv)  # one batched core, not copies
    assert envs.view.num_envs == num_envs
    envs.action_space.seed(0)
    obs, info = envs.reset(seed=0)
    ep_cost, ep_costs, ep_collisions = np.zeros(num_envs), [], []
    collisions = np.zeros(num_envs)
    for _ in range(150):
        before = collided(info["agents"])[:, 0]
        actions = envs.action_space.sample()
        obs, reward, cost, terminated, truncated, info = envs.step(actions)  # noqa: RUF059 - the client's own
        assert cost.shape == (num_envs,) and cost.dtype == np.float32 and "cost" not in info
        ended = terminated | truncated
        # Ended worlds already show their next episode; their last step is in final_observation / final_info.
        after = collided(info["agents"])[:, 0].copy()
        if ended.any():
            assert np.array_equal(info["_final_info"], ended)
            assert np.array_equal(info["_final_observation"], ended)
            assert all(info["final_observation"][world] is None for world in np.flatnonzero(~ended))
            assert not collided(info["agents"])[ended].any() and (info["agents"]["cost"][ended] == 0).all()
            for world in np.flatnonzero(ended):
                after[world] = collided(info["final_info"][world]["agents"])[0]
                assert info["final_observation"][world] in envs.single_observation_space
                assert info["final_info"][world]["agents"]["cost"][0] == cost[world]
        else:
            assert "final_info" not in info
        now = after & ~before
        np.testing.assert_array_equal(cost, now.astype(np.float32))
        ep_cost += cost
        collisions += now
        ep_costs.extend(ep_cost[ended])
        ep_collisions.extend(collisions[ended])
        ep_cost[ended] = 0.0
        collisions[ended] = 0
    assert ep_costs == ep_collisions and max(ep_costs) <= 1 and sum(ep_costs) > 0


def test_vector_cost_matches_the_gymnasium_vector_faces_until_an_episode_ends():
    plain = gymnasium.make_vec(ENV_IDS["discrete"], num_envs=16)
    safe = safety_gymnasium.make_vec(SAFETY_ENV_IDS["discrete"], num_envs=16)
    plain.reset(seed=2)
    safe.reset(seed=2)
    safe.action_space.seed(2)
    ended = False
    while not ended:  # the two autoreset modes part once a world ends
        actions = safe.action_space.sample()
        *_, plain_info = plain.step(actions)
        _, _, cost, terminated, truncated, _ = safe.step(actions)
        assert plain_info["_cost"].all()
        np.testing.assert_array_equal(plain_info["cost"], cost)
        ended = (terminated | truncated).any()
