"""Bad input is refused in words: actions outside their space in every face (the TorchRL envs and views, gymnasium
single and vector, Safety-Gymnasium, PettingZoo), and rooms too small for their agents; good input of every accepted
kind still works."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch

import sidewalk  # noqa: F401 - registers the gymnasium ids
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.interop import safety_gymnasium
from sidewalk.interop.gymnasium import ENV_IDS, InvalidActionError, checked_action
from sidewalk.registry import LAYOUTS

torch.set_num_threads(1)

DISCRETE, CONTINUOUS = ENV_IDS["discrete"], ENV_IDS["continuous"]
SAFETY_DISCRETE, SAFETY_CONTINUOUS = (safety_gymnasium.SAFETY_ENV_IDS[d] for d in ("discrete", "continuous"))
BOX_TEXT = "Box([-1. -0.3926991], [1. 0.3926991], (2,), float32)"
NUM_WORLDS = 4
ENVS = {"discrete": DiscreteSidewalkEnv, "continuous": ContinuousSidewalkEnv}


def make_single(face: str, domain: str) -> gymnasium.Env:
    """One world of ``domain`` through the gymnasium or the Safety-Gymnasium face, reset with seed 0."""
    if face == "gymnasium":
        env = gymnasium.make(ENV_IDS[domain])
    else:
        env = safety_gymnasium.make(safety_gymnasium.SAFETY_ENV_IDS[domain])
    env.reset(seed=0)
    return env


def make_vector(face: str, domain: str) -> gymnasium.vector.VectorEnv:
    """``NUM_WORLDS`` worlds of ``domain`` through the face's ``make_vec``, reset with seed 0."""
    if face == "gymnasium":
        envs = gymnasium.make_vec(ENV_IDS[domain], num_envs=NUM_WORLDS)
    else:
        envs = safety_gymnasium.make_vec(safety_gymnasium.SAFETY_ENV_IDS[domain], num_envs=NUM_WORLDS)
    envs.reset(seed=0)
    return envs


def refusal(step, action) -> str:
    """The message of the ``InvalidActionError`` that ``step(action)`` raises (also an InvalidAction and a
    ValueError)."""
    with pytest.raises(InvalidActionError) as caught:
        step(action)
    assert isinstance(caught.value, gymnasium.error.InvalidAction) and isinstance(caught.value, ValueError)
    return " ".join(str(caught.value).split())  # one line, single spaces (numpy pads its arrays)


FACES = ["gymnasium", "safety"]


# ---- single env: Discrete ----------------------------------------------------------------------------------

@pytest.mark.parametrize("face", FACES)
@pytest.mark.parametrize(
    "action,expected",
    [
        (7, ["action 7 is not in Discrete(4)", "expected an integer in [0, 4)"]),
        (-1, ["action -1 is not in Discrete(4)", "[0, 4)"]),
        (np.int64(4), ["action 4 is not in Discrete(4)", "[0, 4)"]),
        (1.5, ["action 1.5 is not in Discrete(4)", "expected integers, got float"]),
        (np.float32(2.0), ["action 2.0 is not in Discrete(4)", "got float32"]),
        ("up", ["action 'up' is not in Discrete(4)", "got str"]),
        (True, ["action True is not in Discrete(4)", "got bool"]),
        (None, ["action None is not in Discrete(4)", "got NoneType"]),
        (np.array([1]), ["action [1] is not in Discrete(4)", "its shape is (1,), expected ()"]),
    ],
)
def test_a_single_discrete_env_refuses_an_action_outside_its_space_naming_both(face, action, expected):
    env = make_single(face, "discrete")
    message = refusal(env.step, action)
    for part in expected:
        assert part in message, message


@pytest.mark.parametrize("face", FACES)
def test_a_single_discrete_env_takes_python_and_numpy_integers_alike_and_survives_a_refusal(face):
    outcomes = []
    for action in (2, np.int64(2), np.array(2, dtype=np.int32), np.uint8(2)):
        env = make_single(face, "discrete")
        outcomes.append(env.step(action)[0])
    assert all(np.array_equal(outcomes[0], outcome) for outcome in outcomes[1:])
    # A refused action changes nothing: the next good one steps as in a fresh env.
    env = make_single(face, "discrete")
    refusal(env.step, 9)
    assert np.array_equal(env.step(2)[0], outcomes[0])


# ---- single env: Box ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("face", FACES)
@pytest.mark.parametrize(
    "action,expected",
    [
        (np.zeros(3), ["action [0., 0., 0.] is not in " + BOX_TEXT, "its shape is (3,), expected (2,)"]),
        (np.zeros((1, 2)), ["action [[0., 0.]] is not in " + BOX_TEXT, "its shape is (1, 2)"]),
        (np.array([np.nan, 0.0]), ["action [nan, 0.] is not in " + BOX_TEXT, "NaN or infinite"]),
        (np.array([0.0, -np.inf]), ["action [ 0., -inf] is not in " + BOX_TEXT, "NaN or infinite"]),
        ([1e300, 0.0], ["action [1e+300, 0.0] is not in " + BOX_TEXT, "NaN or infinite (as float32)"]),
        ("ab", ["action 'ab' is not in " + BOX_TEXT, "expected real numbers, got str"]),
        (np.array([True, False]), ["action [ True, False] is not in " + BOX_TEXT, "(dtype bool)"]),
    ],
)
def test_a_single_continuous_env_refuses_an_action_outside_its_space_naming_both(face, action, expected):
    env = make_single(face, "continuous")
    message = refusal(env.step, action)
    for part in expected:
        assert part in message, message


@pytest.mark.parametrize("face", FACES)
def test_a_single_continuous_env_takes_float_arrays_and_clamps_finite_actions_beyond_the_bounds(face):
    max_turn = math.pi / 8
    at_bounds = make_single(face, "continuous").step(np.array([1.0, -max_turn], np.float32))[0]
    for action in ([5.0, -3.0], np.array([5.0, -3.0]), np.array([1e30, -1e30], np.float32), [1, -1]):
        observation = make_single(face, "continuous").step(action)[0]
        np.testing.assert_array_equal(observation, at_bounds, err_msg=f"{action!r} was not clamped")
    within = make_single(face, "continuous").step(np.array([0.5, 0.1], np.float64))[0]
    assert not np.array_equal(within, at_bounds)


# ---- vector env --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("face", FACES)
def test_a_vector_discrete_env_names_the_first_bad_world_and_the_space(face):
    envs = make_vector(face, "discrete")
    each = f"Discrete(4), the action space of each of the {NUM_WORLDS} worlds"
    message = refusal(envs.step, np.array([0, 1, 7, -1]))
    assert f"actions[2] = 7 is not in {each}: expected an integer in [0, 4)" in message
    assert message.endswith("(2 worlds' actions are bad)")
    message = refusal(envs.step, np.array([0, 1]))
    assert f"actions [0, 1] is not in {each}: its shape is (2,), expected (4,)" in message
    assert message.endswith("(one action per world)")
    message = refusal(envs.step, np.array([0.0, 1.0, 2.0, 3.0]))
    assert "expected integers, got ndarray (dtype float64)" in message and each in message
    observation, *_ = envs.step(np.array([0, 1, 2, 3], dtype=np.int32))  # a good batch still steps
    assert observation.shape[0] == NUM_WORLDS


@pytest.mark.parametrize("face", FACES)
def test_a_vector_continuous_env_names_the_first_bad_world_and_the_space(face):
    envs = make_vector(face, "continuous")
    each = f"{BOX_TEXT}, the action space of each of the {NUM_WORLDS} worlds"
    actions = np.zeros((NUM_WORLDS, 2))
    actions[1, 1] = np.nan
    message = refusal(envs.step, actions)
    assert f"actions[1] = [ 0., nan] is not in {each}: NaN or infinite" in message and "bad)" not in message
    message = refusal(envs.step, np.zeros((NUM_WORLDS, 3)))
    assert f"is not in {each}: its shape is (4, 3), expected (4, 2) (one action per world)" in message
    message = refusal(envs.step, np.zeros(NUM_WORLDS * 2))
    assert "its shape is (8,), expected (4, 2)" in message
    beyond = np.full((NUM_WORLDS, 2), 3.0)  # finite, beyond the bounds: clamped
    observation, *_ = envs.step(beyond)
    assert observation.shape[0] == NUM_WORLDS and np.isfinite(observation).all()


def test_checked_action_has_no_loop_over_worlds_on_the_happy_path():
    # SB3 trains on 128 worlds: one vectorised check, returned as an array of the space's dtype.
    space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    actions = np.random.default_rng(0).uniform(-2, 2, (128, 2))
    checked = checked_action(actions, space, num_worlds=128, name="actions")
    assert checked.dtype == np.float32 and checked.shape == (128, 2)
    np.testing.assert_array_equal(checked, actions.astype(np.float32))
    discrete = checked_action(np.arange(128) % 4, gymnasium.spaces.Discrete(4), num_worlds=128)
    assert discrete.shape == (128,)


# ---- TorchRL: the core envs and the learners' views --------------------------------------------------------

GRID_EXPECTED = r"expected \('agents', 'action'\): int64 of shape \(2, 2\), indices in \[0, 4\) \(UP, DOWN, LEFT, RIGHT\)"
PLANE_EXPECTED = r"expected \('agents', 'action'\): float32 of shape \(2, 2, 2\), finite values \(clamped to low"


def _grid_action(value) -> torch.Tensor:
    action = torch.zeros(2, 2, dtype=torch.long)
    action[1, 0] = value
    return action


@pytest.mark.parametrize(
    "domain, key, action, match",
    [
        ("discrete", "action", torch.zeros(2, 2, dtype=torch.long),
         r"no action under \('agents', 'action'\); found 'action': put it under \('agents', 'action'\); "
         + GRID_EXPECTED),
        ("discrete", ("agents", "action"), _grid_action(7),
         r"out-of-range action in 1 of 2 worlds \(world 1 agent 0: 7\); " + GRID_EXPECTED),
        ("discrete", ("agents", "action"), _grid_action(-1),
         r"out-of-range action in 1 of 2 worlds \(world 1 agent 0: -1\); " + GRID_EXPECTED),
        ("discrete", ("agents", "action"), torch.ones(2, 2), r"got float32 of shape \(2, 2\) \[1.0, 1.0, 1.0, 1.0\]; "
         + GRID_EXPECTED),
        ("continuous", ("agents", "action"), torch.zeros(2, 2, 3), r"got float32 of shape \(2, 2, 3\) .*; "
         + PLANE_EXPECTED),
        ("continuous", ("agents", "action"), torch.zeros(2, 2, 2, dtype=torch.float64),
         r"got float64 of shape \(2, 2, 2\) .*; " + PLANE_EXPECTED),
    ],
    ids=["flat-key", "grid-7", "grid-negative", "grid-float", "continuous-3-wide", "continuous-float64"],
)
def test_a_torchrl_env_refuses_a_bad_action_naming_its_key_dtype_shape_and_range(domain, key, action, match):
    env = ENVS[domain](num_envs=2, seed=0)
    td = env.reset()
    td.set(key, action)
    with pytest.raises(ValueError, match=f"^{type(env).__name__}.step: {match}"):
        env.step(td)
    # Refused before anything moved: a good action then steps the worlds as it steps a fresh env's.
    fresh = ENVS[domain](num_envs=2, seed=0)
    fresh_td = fresh.reset()
    for tensordict in (td, fresh_td):
        tensordict.set(("agents", "action"), env.full_action_spec["agents", "action"].zero())
    torch.testing.assert_close(env.step(td)["next", "agents", "state"], fresh.step(fresh_td)["next", "agents", "state"])


EGO_GRID = r"expected 'action': int64 of shape \(2,\), indices in \[0, 4\) \(UP, DOWN, LEFT, RIGHT\)"


@pytest.mark.parametrize(
    "domain, kind, bad, match",
    [
        ("discrete", "ego", lambda good: good + 4,
         r"EgoView.step: out-of-range action in 2 of 2 worlds \(world 0: 4; world 1: 4\); " + EGO_GRID),
        ("discrete", "centralized", lambda good: good.float(),
         (r"CentralizedView.step: got float32 of shape \(2,\) .*expected 'action': int64 of shape \(2,\), "
         r"indices in \[0, 16\)$")),
        ("continuous", "ego", lambda good: good[:, :1],
         r"EgoView.step: got float32 of shape \(2, 1\) .*expected 'action': float32 of shape \(2, 2\)"),
        ("continuous", "self", lambda good: torch.cat([good, good[..., :1]], -1),
         (r"SelfPlayView.step: got float32 of shape \(2, 2, 3\) .*expected \('agents', 'action'\): float32 of "
         r"shape \(2, 2, 2\)")),
    ],
    ids=["ego-grid-range", "centralized-grid-float", "ego-continuous-narrow", "self-continuous-wide"],
)
def test_a_view_refuses_a_bad_action_under_its_own_key(domain, kind, bad, match):
    from sidewalk.views import make_view

    view = make_view(kind, ENVS[domain](num_envs=2, seed=0))
    key = ("agents", "action") if kind == "self" else "action"
    td = view.reset()
    td.set(key, bad(view.full_action_spec[key].zero()))
    with pytest.raises(ValueError, match=match):
        view.step(td)


# ---- PettingZoo --------------------------------------------------------------------------------------------

def test_the_parallel_env_names_the_agent_its_action_and_its_space():
    pytest.importorskip("pettingzoo")
    from sidewalk.interop.pettingzoo import parallel_env

    env = parallel_env(domain="discrete")
    env.reset(seed=0)
    message = refusal(env.step, {"agent_0": 1, "agent_1": 9})
    assert "agent_1's action 9 is not in Discrete(4): expected an integer in [0, 4)" in message
    message = refusal(env.step, {"agent_0": 0.5, "agent_1": 0})
    assert "agent_0's action 0.5 is not in Discrete(4): expected integers, got float" in message
    env.step({"agent_0": np.int64(1), "agent_1": np.array(0, dtype=np.int16)})  # numpy integers step

    env = parallel_env(domain="continuous")
    env.reset(seed=0)
    message = refusal(env.step, {"agent_0": np.zeros(2), "agent_1": np.array([np.nan, 0.0])})
    assert f"agent_1's action [nan, 0.] is not in {BOX_TEXT}: NaN or infinite" in message
    message = refusal(env.step, {"agent_0": np.zeros(3), "agent_1": np.zeros(2)})
    assert f"agent_0's action [0., 0., 0.] is not in {BOX_TEXT}: its shape is (3,), expected (2,)" in message
    observations, *_ = env.step({"agent_0": [4.0, 4.0], "agent_1": np.zeros(2, np.float32)})
    assert set(observations) == {"agent_0", "agent_1"}


def test_the_parallel_env_ignores_a_finished_agents_action_unchecked():
    pytest.importorskip("pettingzoo")
    from sidewalk.interop.pettingzoo import parallel_env

    env = parallel_env(domain="discrete")
    env.reset(seed=0)
    env.step({"agent_0": 2, "agent_1": 0})  # agent_0 walks off the grid and is done
    assert env.agents == ["agent_1"]
    env.step({"agent_0": None, "agent_1": 0})
    message = refusal(env.step, {"agent_0": None, "agent_1": 4})
    assert "agent_1's action 4 is not in Discrete(4)" in message


# ---- layouts: a room for their agents ----------------------------------------------------------------------

DEFAULT_ROOM_M = {"length_m": 4.0, "width_m": 3.0}


def room(env) -> tuple:
    """The room ``env`` was built in, as its params say: (width_cells, length_cells) or (length_m,
    width_m)."""
    p = env.params
    if isinstance(env, DiscreteSidewalkEnv):
        return p.width_cells, p.length_cells
    return p.length_m, p.width_m


def test_the_default_sidewalk_keeps_its_room():
    grid = DiscreteSidewalkEnv()
    assert room(grid) == (7, 15) and (grid.rows, grid.cols) == (7, 15)
    plane = ContinuousSidewalkEnv()
    assert room(plane) == (4.0, 3.0) and (plane.layout.length_m, plane.layout.width_m) == (4.0, 3.0)


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
@pytest.mark.parametrize("layout", ["random", "circle", "teams", "door"])
@pytest.mark.parametrize("n_agents", [4, 8])
def test_a_layout_given_no_size_builds_a_room_that_holds_its_agents(domain, layout, n_agents):
    env = ENVS[domain](num_envs=2, seed=0, layout=layout, n_agents=n_agents)
    assert env.n_agents == n_agents
    state = env.reset()["agents", "state"]
    assert state.shape[:2] == (2, n_agents)
    # The params say the room the world is built in.
    if domain == "discrete":
        assert room(env) == (env.layout.rows, env.layout.cols)
    else:
        assert room(env) == (env.layout.length_m, env.layout.width_m)
        assert ((state[..., 0] > 0) & (state[..., 0] < env.layout.length_m)).all()
        assert ((state[..., 1] > 0) & (state[..., 1] < env.layout.width_m)).all()


@pytest.mark.parametrize(
    "domain,layout,n_agents,expected_room",
    [
        # Rooms that held their agents before keep them, so every seeded result there stays.
        ("continuous", "random", 2, (4.0, 3.0)),
        ("continuous", "circle", 8, (4.0, 3.0)),
        ("continuous", "door", 3, (4.0, 3.0)),
        ("continuous", "teams", 6, (4.0, 3.0)),
        ("discrete", "door", 7, (7, 15)),
        ("discrete", "teams", 14, (7, 15)),
        # Too many for the default room: the scenario's own, never shorter than the default.
        ("continuous", "random", 4, (6.0, 6.0)),
        ("continuous", "door", 4, (6.0, 3.8)),
        ("continuous", "teams", 8, (6.0, 3.8)),
        ("continuous", "circle", 16, (8.0, 8.0)),
        ("discrete", "door", 8, (15, 15)),
        ("discrete", "teams", 16, (9, 15)),
    ],
)
def test_the_room_grows_only_where_the_default_is_too_small(domain, layout, n_agents, expected_room):
    assert room(ENVS[domain](layout=layout, n_agents=n_agents)) == expected_room


@pytest.mark.parametrize(
    "domain,sizes,layout,n_agents,match",
    [
        ("continuous", DEFAULT_ROOM_M, "random", 8, "n_agents=8 crowd the 4.0×3.0 m random layout"),
        ("continuous", DEFAULT_ROOM_M, "door", 4, "takes 1..3 agents in the 4.0×3.0 m room"),
        ("continuous", DEFAULT_ROOM_M, "teams", 8, "even number in 2..6 agents in the 4.0×3.0 m room"),
        ("continuous", {"width_m": 3.0}, "door", 8, r"takes 1..3 agents in the 6.0×3.0 m room"),
        ("continuous", {"length_m": 3.0, "width_m": 3.0}, "circle", 16, "takes 2..9 agents in the 3.0×3.0 m"),
        ("discrete", {"width_cells": 7}, "door", 8, "takes 1..7 agents in the 7×15-cell room; got"),
        ("discrete", {"width_cells": 3, "length_cells": 5}, "random", 8, "n_agents=8 crowd the 3×5-cell"),
        ("discrete", {"width_cells": 3, "length_cells": 3}, "circle", 8, "takes 2..4 agents in the 3×3-cell"),
    ],
)
def test_a_room_the_user_gives_too_small_is_refused_naming_it(domain, sizes, layout, n_agents, match):
    with pytest.raises(ValueError, match=match) as caught:
        ENVS[domain](layout=layout, n_agents=n_agents, **sizes)
    assert "the layout then picks one that holds its agents" in str(caught.value)


def test_a_side_the_user_gives_stays_and_the_other_grows():
    env = ContinuousSidewalkEnv(layout="door", n_agents=4, length_m=10.0)
    assert room(env) == (10.0, 3.8)
    env = DiscreteSidewalkEnv(layout="door", n_agents=8, length_cells=9)
    assert room(env) == (15, 9)


def test_the_faces_size_the_room_too():
    env = gymnasium.make(CONTINUOUS, layout="random", n_agents=4)
    assert env.observation_space.shape == (8 * 4,)
    assert env.unwrapped.view.core.layout.length_m == 6.0
    env.reset(seed=0)
    env.step(env.action_space.sample())


@pytest.mark.parametrize("name", LAYOUTS.names(lambda scenario: scenario.any_n_agents))
def test_every_scenario_room_holds_the_agents_it_is_sized_for(name):
    capacity, own_room = LAYOUTS[name].plane_capacity, LAYOUTS[name].plane_room
    for n_agents in range(2, 65, 2 if name == "teams" else 1):
        for radius in (0.2, 0.3, 0.5):
            length_m, width_m = own_room(n_agents, radius, radius)
            assert capacity(length_m, width_m, radius, radius) >= n_agents, (name, n_agents, radius)
    grid_capacity, grid_room = LAYOUTS[name].grid_capacity, LAYOUTS[name].grid_room
    for n_agents in range(2, 65, 2 if name == "teams" else 1):
        assert grid_capacity(*grid_room(n_agents), 4) >= n_agents, (name, n_agents)


@pytest.mark.parametrize(
    "overrides, room",
    [
        ([], {"width_cells": 7, "length_cells": 15}),
        (["env.layout=door", "env.n_agents=8"], {"width_cells": 15, "length_cells": 15}),
        (["env=continuous", "opponent=prm", "algo=trpo", "env.layout=random", "env.n_agents=8"],
         {"length_m": 8.5, "width_m": 8.5}),
        (["env=continuous", "opponent=prm", "algo=trpo", "env.layout=teams", "env.n_agents=8", "env.width_m=5"],
         {"length_m": 4.0, "width_m": 5.0}),
    ],
)
def test_a_hydra_config_that_gives_no_room_gets_one_that_holds_its_agents(overrides, room):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from sidewalk.config import validate
    from sidewalk.schema import register_schemas

    register_schemas()
    with initialize_config_dir(version_base="1.3", config_dir=str(Path(__file__).resolve().parents[1] / "conf")):
        cfg = compose("config", overrides=overrides)
    params = validate(cfg).world.env_params
    assert {side: getattr(params, side) for side in room} == room
    saved = OmegaConf.to_container(cfg, resolve=True)["env"]  # what config.yaml records: numbers
    assert {side: saved[side] for side in room} == room
    with initialize_config_dir(version_base="1.3", config_dir=str(Path(__file__).resolve().parents[1] / "conf")):
        too_small = compose("config", overrides=["env=continuous", "opponent=prm", "algo=trpo",
                                                         "env.layout=door", "env.n_agents=8", "env.width_m=2"])
    with pytest.raises(ValueError, match=r"layout 'door' takes 1..2 agents in the 6.0×2.0 m room; got n_agents=8"):
        validate(too_small)
