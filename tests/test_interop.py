"""The gymnasium and PettingZoo faces (sidewalk/interop): API checkers, spaces, batched make_vec, autoreset."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sidewalk  # noqa: F401 - registers the gymnasium ids
from sidewalk.interop.gymnasium import ENV_IDS, SidewalkGymEnv, SidewalkVectorEnv
from sidewalk.opponents.base import available_opponents

DISCRETE, CONTINUOUS = ENV_IDS["discrete"], ENV_IDS["continuous"]
PLANNER = {DISCRETE: "dijkstra", CONTINUOUS: "prm"}
NOISE = {DISCRETE: 0.2, CONTINUOUS: 1.5}  # the paper's largest noise of each domain


def opponents(env_id: str) -> list[str]:
    """The opponents of ``env_id`` to test: random, centralized and the domain's planner once it is present."""
    domain = "discrete" if env_id == DISCRETE else "continuous"
    names = ["random", "centralized"]
    if PLANNER[env_id] in available_opponents(domain):
        names.append(PLANNER[env_id])
    return names


CASES = [
    (env_id, opponent)
    for env_id in ENV_IDS.values()
    for opponent in ["random", "centralized", PLANNER[env_id]]
]


def skip_if_absent(env_id: str, opponent: str) -> None:
    if opponent not in opponents(env_id):
        pytest.skip(f"opponent {opponent!r} is not registered")


# ---- gymnasium.make ----------------------------------------------------------------------------------------


def test_import_registers_both_ids():
    for env_id in (DISCRETE, CONTINUOUS):
        assert env_id in gymnasium.registry


@pytest.mark.parametrize("env_id,opponent", CASES)
@pytest.mark.parametrize("noisy", [False, True])
def test_check_env_passes(env_id, opponent, noisy):
    skip_if_absent(env_id, opponent)
    env = gymnasium.make(
        env_id, opponent=opponent, render_mode="rgb_array", noise=NOISE[env_id] if noisy else 0.0
    )
    check_env(env.unwrapped)


@pytest.mark.parametrize("env_id,opponent", CASES)
def test_sb3_style_loop_runs_1000_steps(env_id, opponent):
    skip_if_absent(env_id, opponent)
    env = gymnasium.make(env_id, opponent=opponent, noise=NOISE[env_id])
    env.action_space.seed(0)
    obs, info = env.reset(seed=0)
    episodes = 0
    # The planners replan every step (milliseconds each for one world): fewer steps keep the suite quick.
    for _ in range(1000 if opponent in ("random", "centralized") else 300):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert obs in env.observation_space
        assert isinstance(reward, float) and isinstance(info["is_success"], bool)
        if terminated or truncated:
            episodes += 1
            obs, info = env.reset()
    assert episodes > 0


def test_spaces_match_the_observations():
    image = gymnasium.make(DISCRETE)
    assert image.observation_space == gymnasium.spaces.Box(0, 255, (1, 14, 30), np.uint8)
    assert image.reset(seed=0)[0].dtype == np.uint8
    vector = gymnasium.make(DISCRETE, observation="vector")
    assert vector.observation_space.dtype == np.float32 and vector.observation_space.shape == (12,)
    continuous = gymnasium.make(CONTINUOUS)
    assert continuous.observation_space.dtype == np.float32 and continuous.observation_space.shape == (16,)
    assert continuous.action_space.shape == (2,)
    assert gymnasium.make(DISCRETE, opponent="centralized").action_space == gymnasium.spaces.Discrete(16)
    assert gymnasium.make(CONTINUOUS, opponent="centralized").action_space.shape == (4,)


def test_env_kwargs_pass_through_to_the_core():
    env = gymnasium.make(DISCRETE, noise=0.1, max_steps=5, rewards={"alpha": 0.0})
    core = env.unwrapped.view.core
    assert core.params.noise == 0.1 and core.params.rewards.alpha == 0.0
    env.reset(seed=0)
    for step in range(5):
        # UP and DOWN in turn never leave the grid, so only the timeout ends the episode.
        _, _, terminated, truncated, info = env.step(step % 2)
    assert truncated and not terminated and info["agents"]["timed_out"][0]


def test_bad_arguments_name_the_valid_values():
    with pytest.raises(TypeError, match="did you mean 'noise'"):
        gymnasium.make(DISCRETE, noize=0.1)
    with pytest.raises(ValueError, match="'convention', 'dijkstra', 'policy', 'population', 'prm', 'proxy', 'random', 'salsa'"):
        gymnasium.make(DISCRETE, opponent="greedy")
    with pytest.raises(ValueError, match="dijkstra"):
        gymnasium.make(CONTINUOUS, opponent="dijkstra")
    with pytest.raises(ValueError, match="no ego agent"):
        gymnasium.make(DISCRETE, opponent="centralized", ego=1)


def test_reset_seed_makes_episodes_reproducible():
    def episode(env):
        env.reset(seed=3)
        env.action_space.seed(3)
        return [env.step(env.action_space.sample())[0] for _ in range(20)]

    first = episode(gymnasium.make(CONTINUOUS, noise=0.5))
    second = episode(gymnasium.make(CONTINUOUS, noise=0.5))
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


def test_render_returns_an_rgb_frame():
    env = gymnasium.make(CONTINUOUS, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[-1] == 3


HEADLESS = r"render_mode='human' shows no window: this machine has no display \(\$DISPLAY and \$WAYLAND_DISPLAY"


@pytest.fixture
def headless(monkeypatch):
    """A Linux machine without a display, where matplotlib falls back to its non-interactive Agg backend."""
    import sys

    import matplotlib

    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(matplotlib, "get_backend", lambda: "agg")


def test_human_render_mode_says_why_no_window_opens_and_runs_without_one(headless):
    with pytest.warns(UserWarning, match=HEADLESS + r".*render_mode='rgb_array'"):
        env = gymnasium.make(DISCRETE, render_mode="human")
    env.reset(seed=0)
    env.step(0)
    assert env.render() is None  # human mode draws into its window and returns nothing, as gymnasium's envs do
    env.close()
    pytest.importorskip("pettingzoo")
    from sidewalk.interop.pettingzoo import parallel_env

    with pytest.warns(UserWarning, match=HEADLESS):
        env = parallel_env(domain="continuous", render_mode="human")
    env.reset(seed=0)
    env.step({"agent_0": np.zeros(2, np.float32), "agent_1": np.zeros(2, np.float32)})


def test_human_render_mode_with_a_display_but_no_gui_toolkit_names_the_toolkits(headless, monkeypatch):
    from sidewalk.interop.window import window_problem

    monkeypatch.setenv("DISPLAY", ":0")
    assert "found no GUI toolkit (install one, e.g. `apt install python3-tk`" in window_problem()
    import matplotlib

    monkeypatch.setattr(matplotlib, "get_backend", lambda: "TkAgg")
    assert window_problem() is None


def test_human_render_mode_shows_each_frame_in_one_window(monkeypatch):
    import matplotlib.pyplot as plt
    from matplotlib.backend_bases import FigureCanvasBase

    from sidewalk.interop import window

    monkeypatch.setattr(window, "window_problem", lambda: None)  # as where an interactive backend runs
    waits = []
    monkeypatch.setattr(FigureCanvasBase, "start_event_loop", lambda canvas, timeout: waits.append(timeout))
    env = gymnasium.make(DISCRETE, render_mode="human")
    env.reset(seed=0)  # Agg here stands in for a window
    core = env.unwrapped.view
    figure = env.unwrapped._window._figure
    shown = figure.axes[0].images[0]
    np.testing.assert_array_equal(shown.get_array(), core.render(0))
    for _ in range(3):
        env.step(0)
        np.testing.assert_array_equal(shown.get_array(), core.render(0))
    assert env.render() is None and waits == [0.1] * 5
    assert plt.fignum_exists(figure.number) and len(plt.get_fignums()) == 1
    env.close()
    assert not plt.fignum_exists(figure.number)


def test_ego_info_reports_the_ego():
    env = SidewalkGymEnv("discrete", ego=1)
    env.reset(seed=0)
    *_, info = env.step(3)  # agent 1 starts at the right end: RIGHT leaves the grid
    assert info["agents"]["collided_wall"][1] and not info["is_success"]
    assert info["cost"] == 1.0 and info["agents"]["cost"][1] == 1.0
    assert info["state"].shape == (2, 2) and info["goal"].shape == (2, 2)


@pytest.mark.parametrize("env_id", [DISCRETE, CONTINUOUS])
@pytest.mark.parametrize("opponent", ["random", "centralized"])
def test_stable_baselines3_check_env_passes(env_id, opponent):
    sb3_env_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    # Advisory warnings remain: the 14×30 image is below the 36×36 of SB3's default CnnPolicy, and the
    # continuous action Box is not [-1, 1] (wrap with gymnasium.wrappers.RescaleAction).
    sb3_env_checker.check_env(gymnasium.make(env_id, opponent=opponent).unwrapped)


# ---- gymnasium.make_vec ------------------------------------------------------------------------------------


@pytest.mark.parametrize("env_id,opponent", CASES)
def test_make_vec_is_one_batched_core(env_id, opponent):
    skip_if_absent(env_id, opponent)
    envs = gymnasium.make_vec(env_id, num_envs=8, opponent=opponent, noise=NOISE[env_id])
    assert isinstance(envs, SidewalkVectorEnv) and envs.view.core.num_envs == 8
    assert envs.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.NEXT_STEP
    obs, info = envs.reset(seed=0)
    assert obs.shape == (8, *envs.single_observation_space.shape) and obs in envs.observation_space
    envs.action_space.seed(0)
    obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert obs in envs.observation_space
    assert reward.shape == terminated.shape == truncated.shape == (8,)
    assert info["is_success"].shape == (8,) and info["_is_success"].all()
    assert info["agents"]["reached_goal"].shape == (8, 2)


def test_make_vec_autoresets_on_the_next_step():
    envs = gymnasium.make_vec(DISCRETE, num_envs=8, opponent="random")
    first, _ = envs.reset(seed=0)
    envs.action_space.seed(0)
    ended = np.zeros(8, dtype=bool)
    restarts = 0
    for _ in range(200):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        # Worlds that ended on the previous step restart: first observation, no reward, not done, fresh flags.
        assert np.array_equal(obs[ended], first[ended])
        assert (reward[ended] == 0).all() and not (terminated[ended] | truncated[ended]).any()
        assert not info["agents"]["collided_wall"][ended].any() and (info["cost"][ended] == 0).all()
        # The worlds that go on keep their step's reward and cost in info (a reset output zeroes every world's).
        np.testing.assert_array_equal(info["agents"]["reward"][:, 0], reward)
        np.testing.assert_array_equal(info["agents"]["cost"][:, 0], info["cost"])
        restarts += ended.sum()
        ended = terminated | truncated
    assert restarts > 0


def test_make_vec_reset_mask_resets_only_those_worlds():
    envs = gymnasium.make_vec(DISCRETE, num_envs=4)
    first, _ = envs.reset(seed=0)
    moved, *_ = envs.step(np.array([0, 0, 1, 1]))  # UP / DOWN: everyone leaves the start
    mask = np.array([True, False, True, False])
    obs, _ = envs.reset(options={"reset_mask": mask})
    assert np.array_equal(obs[mask], first[mask]) and np.array_equal(obs[~mask], moved[~mask])


def test_make_vec_works_with_gymnasium_vector_wrappers():
    envs = gymnasium.wrappers.vector.RecordEpisodeStatistics(gymnasium.make_vec(DISCRETE, num_envs=16))
    envs.reset(seed=0)
    envs.action_space.seed(0)
    finished = 0
    for _ in range(100):
        *_, info = envs.step(envs.action_space.sample())
        finished += info["_episode"].sum() if "episode" in info else 0
    assert finished > 0


def test_make_vec_renders_one_frame_per_world():
    envs = gymnasium.make_vec(CONTINUOUS, num_envs=3, render_mode="rgb_array")
    envs.reset(seed=0)
    frames = envs.render()
    assert len(frames) == 3 and all(frame.dtype == np.uint8 for frame in frames)


# ---- PettingZoo --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
@pytest.mark.parametrize("noise", [0.0, 0.2])
def test_parallel_api_test_passes(domain, noise):
    pytest.importorskip("pettingzoo")
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    from sidewalk.interop.pettingzoo import parallel_env

    parallel_api_test(parallel_env(domain=domain, noise=noise), num_cycles=1000)
    parallel_seed_test(lambda: parallel_env(domain=domain, noise=noise))


def test_parallel_env_removes_finished_agents_and_exposes_the_state():
    pytest.importorskip("pettingzoo")
    from sidewalk.interop.pettingzoo import parallel_env

    env = parallel_env(domain="discrete", render_mode="rgb_array")
    observations, infos = env.reset(seed=0)
    assert set(observations) == {"agent_0", "agent_1"} and observations["agent_0"].shape == (1, 14, 30)
    assert infos["agent_0"]["cost"] == infos["agent_1"]["cost"] == 0.0
    assert env.state().shape == env.state_space.shape == (4,)
    _, rewards, terminations, _, infos = env.step({"agent_0": 2, "agent_1": 0})  # agent_0 walks off the grid
    assert terminations == {"agent_0": True, "agent_1": False} and infos["agent_0"]["collided_wall"]
    assert infos["agent_0"]["cost"] == 1.0 and infos["agent_1"]["cost"] == 0.0
    assert env.agents == ["agent_1"] and rewards["agent_0"] == pytest.approx(-0.51)
    with pytest.raises(ValueError, match=r"live agents \['agent_1'\]"):
        env.step({})
    with pytest.raises(ValueError, match="name only"):
        env.step({"agent_1": 0, "agent_9": 0})
    assert env.render().dtype == np.uint8
