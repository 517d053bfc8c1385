"""The learner's views (sidewalk/views.py): specs, keys, the joint action, episode ends, opponents, stock losses."""

from __future__ import annotations

import warnings

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs.utils import check_env_specs

from sidewalk.envs import AGENT_GROUP, INFO_KEYS, ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.opponents.base import Opponent, available_opponents, make_opponent
from sidewalk.opponents.random import RandomOpponent
from sidewalk.views import CentralizedView, EgoView, make_view

UP, DOWN, LEFT, RIGHT = range(4)
MOVES = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}
DOMAINS = {"discrete": DiscreteSidewalkEnv, "continuous": ContinuousSidewalkEnv}
# A noise level of each domain that changes what happens (action replacement / uniform ±ε).
NOISE = {"discrete": 0.2, "continuous": 0.5}
PLANNER = {"discrete": "dijkstra", "continuous": "prm"}


def core(domain: str, num_envs: int = 4, **kwargs) -> DiscreteSidewalkEnv | ContinuousSidewalkEnv:
    return DOMAINS[domain](num_envs=num_envs, seed=0, **kwargs)


def planner_or_skip(domain: str) -> str:
    """The domain's planner opponent; skips the test while its module is not in the tree."""
    name = PLANNER[domain]
    if name not in available_opponents(domain):
        pytest.skip(f"opponent {name!r} is not registered")
    return name


VIEWS = {
    "ego": lambda env: EgoView(env),
    "ego1-end-on-ego-done": lambda env: EgoView(env, ego=1, end_on_ego_done=True),
    "centralized": CentralizedView,
}


# ---- specs and collectors ----------------------------------------------------------------------------------


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("view", VIEWS)
@pytest.mark.parametrize("num_envs", [1, 8])
@pytest.mark.parametrize("noisy", [False, True])
def test_view_specs(domain, view, num_envs, noisy):
    env = VIEWS[view](core(domain, num_envs, noise=NOISE[domain] if noisy else 0.0))
    check_env_specs(env, break_when_any_done="both")


@pytest.mark.parametrize("domain", DOMAINS)
def test_planner_ego_view_specs(domain):
    env = EgoView(core(domain, 8, noise=NOISE[domain]), opponent=planner_or_skip(domain))
    check_env_specs(env, break_when_any_done="both")


def test_vector_observation_specs():
    check_env_specs(EgoView(core("discrete", 8, observation="vector")))
    check_env_specs(CentralizedView(core("discrete", 8, observation="vector")))


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("view", VIEWS)
def test_collector_runs_a_random_policy(domain, view):
    env = VIEWS[view](core(domain, 8))
    collector = Collector(
        env, None, frames_per_batch=64, total_frames=256, auto_register_policy_transforms=False
    )
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 4
    batch = batches[-1]
    assert batch["next", "reward"].shape == (8, 8, 1)
    assert batch["next", "done"].shape == (8, 8, 1)
    assert batch["next", "world", "state"].shape[:3] == (8, 8, 2)


@pytest.mark.parametrize("view", VIEWS)
def test_views_compose_with_torchrl_transforms(view):
    from torchrl.envs import Compose, InitTracker, RewardSum, StepCounter, TransformedEnv

    env = TransformedEnv(VIEWS[view](core("discrete", 8)), Compose(StepCounter(), RewardSum(), InitTracker()))
    check_env_specs(env)
    rollout = env.rollout(120, break_when_any_done=False)
    # Episodes ended and restarted along the way.
    assert rollout["next", "step_count"].max() > 1 and rollout["is_init"].sum() > 8


def test_all_agents_view_is_the_core_env():
    env = core("discrete")
    assert make_view("all", env) is env


# ---- the ego view ------------------------------------------------------------------------------------------


class ScriptedDetour(Opponent):
    """Grid agent 1: one step DOWN off the centre line, then LEFT to column 0, then UP onto its goal (16 steps)."""

    domains = ("discrete",)

    def act(self, state, goal, done):
        row, col = state[:, 1, 0], state[:, 1, 1]
        center = self.env.layout.rows // 2
        action = torch.where(col > 0, LEFT, UP)
        action = torch.where((row == center) & (col == self.env.layout.cols - 1), DOWN, action)
        return action.unsqueeze(-1)


class RecordingRandom(RandomOpponent):
    """A random opponent that records the masks its ``reset`` was called with."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.resets: list[torch.Tensor] = []

    def reset(self, rows=None):
        self.resets.append(rows.clone())


def ego_rollout(view, actions):
    """Step the view with one action per step (the same in every world); return the stacked "next" entries."""
    td = view.reset()
    outputs = []
    for action in actions:
        td.set("action", torch.full(view.full_action_spec["action"].shape, action))
        td = view.step(td)
        outputs.append(td["next"])
        td = view.step_mdp(td)
    return torch.stack(outputs, 1)


def test_ego_view_keys_are_flat_single_agent_keys():
    view = EgoView(core("discrete", 3), opponent="random", ego=1)
    td = view.reset()
    assert td["observation"].shape == (3, 1, 14, 30)
    td = view.rand_step(td)
    assert td["next", "reward"].shape == (3, 1)
    for key in ("done", "terminated", "truncated"):
        assert td["next", key].shape == (3, 1)
    for key in INFO_KEYS:
        assert torch.equal(td["next", "info", key], td["next", "world", "info", key][:, 1])


def test_ego_action_moves_the_ego_and_the_opponent_moves_the_other():
    env = core("discrete", 6)
    view = EgoView(env, opponent=ScriptedDetour(env, controlled=(1,), ego=0))
    out = ego_rollout(view, [UP])
    state = out["world", "state"][:, 0]
    assert torch.equal(state[:, 0], torch.tensor([2, 0]).expand(6, 2))  # ego: UP from (3, 0)
    assert torch.equal(state[:, 1], torch.tensor([4, 14]).expand(6, 2))  # opponent: DOWN from (3, 14)


def test_ego_observation_is_the_ego_agents_observation():
    env = core("continuous", 4, noise=0.5)
    view = EgoView(env, ego=1)
    td = view.reset()
    assert torch.equal(td["observation"], view._last[AGENT_GROUP, "observation"][:, 1])
    td = view.rand_step(td)
    assert torch.equal(td["next", "observation"], view._last[AGENT_GROUP, "observation"][:, 1])


def test_cooperative_reward_reaches_the_ego_after_it_is_done():
    # The ego walks straight (14 steps); the scripted other takes a 16-step detour. With the world's episode the
    # ego gets alpha * c_goal = 0.5 when the other arrives, two steps after its own arrival.
    env = core("discrete", 2)
    view = EgoView(env, opponent=ScriptedDetour(env))
    out = ego_rollout(view, [RIGHT] * 16)
    reward, done = out["reward"][0, :, 0], out["done"][0, :, 0]
    assert out["info", "reached_goal"][0, 13, 0] and not done[13]
    assert reward[14].item() == 0.0
    assert reward[15].item() == pytest.approx(0.5)
    assert done[15] and out["terminated"][0, 15, 0]
    assert out["world", "info", "reached_goal"][:, 15].all()


def test_end_on_ego_done_ends_the_episode_with_the_ego():
    env = core("discrete", 2)
    view = EgoView(env, opponent=ScriptedDetour(env), end_on_ego_done=True)
    out = ego_rollout(view, [RIGHT] * 14)
    done = out["done"][:, :, 0]
    assert not done[:, :13].any() and done[:, 13].all()
    assert out["terminated"][:, 13].all()
    assert out["reward"][0, 13, 0].item() == pytest.approx(-0.01 + 0.5)


def test_end_on_ego_done_resets_the_world_when_the_ego_crashes():
    env = core("discrete", 4)
    opponent = RecordingRandom(env)
    view = EgoView(env, opponent=opponent, end_on_ego_done=True)
    td = view.reset()
    td.set("action", torch.full((4,), LEFT))  # off the grid at once
    out, td = view.step_and_maybe_reset(td)
    assert out["next", "done"].all() and out["next", "info", "collided_wall"].all()
    assert not td["done"].any() and torch.equal(td["world", "state"][:, 0], torch.tensor([3, 0]).expand(4, 2))
    assert len(opponent.resets) == 2 and opponent.resets[-1].all()


def test_partial_reset_keeps_other_worlds_and_resets_the_opponent():
    env = core("continuous", 4, noise=0.5)
    opponent = RecordingRandom(env)
    view = EgoView(env, opponent=opponent)
    td = view.rand_step(view.reset())
    stepped = td["next", "observation"].clone()
    rows = torch.tensor([True, False, True, False])
    reset = view.reset(TensorDict({"_reset": rows.unsqueeze(-1)}, batch_size=[4]))
    # Worlds not reset see exactly what the step showed them, noise included.
    assert torch.equal(reset["observation"][~rows], stepped[~rows])
    assert not torch.equal(reset["observation"][rows], stepped[rows])
    assert torch.equal(opponent.resets[-1], rows)


def test_seeded_views_are_reproducible():
    def trajectory():
        view = EgoView(core("continuous", 4, noise=0.5))
        view.set_seed(7)
        return view.rollout(20, break_when_any_done=False)["next", "world", "state"]

    torch.manual_seed(0)
    first = trajectory()
    torch.manual_seed(0)
    assert torch.equal(first, trajectory())


# ---- the centralized view ----------------------------------------------------------------------------------


def test_centralized_maps_all_16_joint_actions_to_their_pair():
    env = core("discrete", 16)
    view = CentralizedView(env)
    assert view.full_action_spec["action"].space.n == 16
    td = view.reset()
    td.set("action", torch.arange(16))
    nxt = view.step(td)["next"]
    starts = torch.tensor([[3, 0], [3, 14]])
    for joint in range(16):
        pair = (joint // 4, joint % 4)  # documented: joint = a0 * 4 + a1
        assert view.decode_action(torch.tensor(joint)).tolist() == list(pair)
        assert view.encode_action(torch.tensor(pair)).item() == joint
        for agent, action in enumerate(pair):
            target = starts[agent] + torch.tensor(MOVES[action])
            off_grid = not (0 <= target[0] < 7 and 0 <= target[1] < 15)
            state = nxt["world", "state"][joint, agent]
            assert nxt["world", "info", "collided_wall"][joint, agent, 0].item() == off_grid
            assert torch.equal(state, starts[agent] if off_grid else target), (joint, agent)


def test_centralized_continuous_action_is_the_concatenation():
    env = core("continuous", 2)
    view = CentralizedView(env)
    spec = view.full_action_spec["action"]
    assert spec.shape == (2, 4)
    assert torch.allclose(spec.space.high[0], torch.tensor([1.0, torch.pi / 8, 1.0, torch.pi / 8]))
    td = view.reset()
    td.set("action", torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]))
    state = view.step(td)["next", "world", "state"]
    speed, dv = state[..., 2], env.params.dt_s * 1.0  # one step of 1 m/s² acceleration
    assert speed[0].tolist() == pytest.approx([dv, 0.0]) and speed[1].tolist() == pytest.approx([0.0, dv])


def test_centralized_reward_is_the_team_reward_and_done_the_worlds():
    view = CentralizedView(core("discrete", 8, noise=0.2))
    rollout = view.rollout(40, break_when_any_done=False)
    nxt = rollout["next"]
    assert torch.allclose(nxt["reward"], nxt["world", "reward"].sum(-2))
    world_over = torch.stack([nxt["world", "info", key] for key in INFO_KEYS]).any(0).all(-2)
    assert torch.equal(nxt["done"], world_over)


# ---- the factory and its errors ----------------------------------------------------------------------------


def test_make_view_builds_each_kind():
    assert isinstance(make_view("ego", core("discrete")), EgoView)
    assert isinstance(
        make_view("ego", core("discrete"), opponent="random", ego=1, end_on_ego_done=True), EgoView
    )
    assert isinstance(make_view("centralized", core("continuous")), CentralizedView)


def test_view_for_opponent_builds_the_view_an_experiment_names():
    from sidewalk.views import SelfPlayView, view_for_opponent

    assert isinstance(view_for_opponent(core("discrete"), "centralized", ego=1), CentralizedView)  # ego unread
    assert view_for_opponent(core("discrete"), "self", other_play=True).other_play
    view = view_for_opponent(core("discrete", layout="circle", n_agents=3), "random", 1, end_on_ego_done=True)
    assert isinstance(view, EgoView) and view.ego == 1 and view.end_on_ego_done and view.opponent.controlled == [0, 2]
    assert isinstance(make_view("self", core("discrete")), SelfPlayView)
    with pytest.raises(ValueError, match="other_play=True trains self-play partners"):
        view_for_opponent(core("discrete"), "random", other_play=True)


def test_make_view_names_the_valid_kinds():
    with pytest.raises(ValueError, match="'ego', 'centralized', 'self', 'all'"):
        make_view("joint", core("discrete"))


def test_views_without_an_opponent_reject_one():
    with pytest.raises(ValueError, match="no opponent"):
        make_view("centralized", core("discrete"), opponent="random")
    with pytest.raises(ValueError, match="no ego"):
        make_view("all", core("discrete"), ego=1)
    with pytest.raises(ValueError, match="CentralizedView"):
        EgoView(core("discrete"), opponent="centralized")
    with pytest.raises(ValueError, match=r"use make_view\('self', env\)"):
        make_view("ego", core("discrete"), opponent="self")
    with pytest.raises(TypeError, match="'end_on_ego_done' for the 'self' view"):
        make_view("self", core("discrete"), end_on_ego_done=True)


def test_unknown_opponent_names_the_valid_ones():
    with pytest.raises(ValueError, match="'convention', 'dijkstra', 'policy', 'population', 'prm', 'proxy', 'random', 'salsa'"):
        make_view("ego", core("discrete"), opponent="greedy")


@pytest.mark.parametrize("domain", DOMAINS)
def test_opponent_of_the_other_domain_is_rejected(domain):
    other_planner = PLANNER["continuous" if domain == "discrete" else "discrete"]
    # Either the planner's domain is named, or (while its module is absent) its absence is.
    with pytest.raises(ValueError, match=f"{other_planner!r}"):
        make_view("ego", core(domain), opponent=other_planner)


def test_opponent_instances_must_fit_the_view():
    env = core("discrete")
    with pytest.raises(ValueError, match="another env"):
        EgoView(env, opponent=RandomOpponent(core("discrete")))
    with pytest.raises(ValueError, match="must control"):
        EgoView(env, opponent=RandomOpponent(env, controlled=(0,), ego=1), ego=0)
    with pytest.raises(TypeError, match="must be an Opponent"):
        EgoView(env, opponent=nn.Identity())
    with pytest.raises(ValueError, match="ego=2"):
        EgoView(env, ego=2)


def test_make_opponent_builds_registered_opponents():
    env = core("discrete")
    opponent = make_opponent("random", env, controlled=(1,), ego=0)
    assert isinstance(opponent, RandomOpponent) and opponent.controlled == [1]
    assert "random" in available_opponents("continuous")


@pytest.mark.parametrize("domain", DOMAINS)
def test_planner_ego_view_steps(domain):
    view = make_view("ego", core(domain, 8), opponent=planner_or_skip(domain))
    rollout = view.rollout(30, break_when_any_done=False)
    assert rollout["next", "reward"].shape == (8, 30, 1)


# ---- stock single-agent losses -----------------------------------------------------------------------------


def test_dqn_loss_runs_on_the_ego_view():
    from torchrl.modules import MLP, QValueActor
    from torchrl.objectives import DQNLoss, SoftUpdate

    env = EgoView(core("discrete", 4, observation="vector"))
    net = MLP(in_features=12, out_features=4, num_cells=[16])
    actor = QValueActor(net, in_keys=["observation"], spec=env.full_action_spec_unbatched["action"])
    with torch.no_grad():
        data = env.rollout(5, actor, break_when_any_done=False)
    loss = DQNLoss(actor, action_space=env.full_action_spec_unbatched["action"], delay_value=True)
    SoftUpdate(loss, tau=0.05)
    loss(data.reshape(-1))["loss"].backward()
    assert all(p.grad is not None for p in net.parameters())


def test_ppo_loss_runs_on_the_continuous_ego_view():
    from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.modules.distributions import NormalParamExtractor
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    env = EgoView(core("continuous", 4, noise=0.5))
    spec = env.full_action_spec_unbatched["action"]
    body = nn.Sequential(MLP(in_features=16, out_features=4, num_cells=[16]), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(body, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": spec.space.low, "high": spec.space.high},
        return_log_prob=True,
        spec=spec,
    )
    critic = ValueOperator(MLP(in_features=16, out_features=1, num_cells=[16]), in_keys=["observation"])
    with torch.no_grad():
        data = env.rollout(6, actor, break_when_any_done=False)
        GAE(gamma=0.99, lmbda=0.95, value_network=critic)(data)
    losses = ClipPPOLoss(actor, critic)(data.reshape(-1))
    (losses["loss_objective"] + losses["loss_critic"]).backward()


def test_bench_section_reports_every_view():
    from sidewalk.bench.view_speed import run

    rows = run(num_envs=4, threads=1, seconds=0.01)
    views = {(row["face"], row["view"], row["domain"], row["opponent"]) for row in rows}
    assert ("torchrl", "ego", "discrete", "dijkstra") in views and (
        "torchrl",
        "centralized",
        "continuous",
        "-",
    ) in views
    assert all(row["env_steps_per_s"] or row["note"] for row in rows)


@pytest.mark.parametrize("core_cls", [DiscreteSidewalkEnv, ContinuousSidewalkEnv])
def test_views_answer_what_torchrl_multiagent_trainers_ask_of_a_vmas_env(core_cls):
    from sidewalk.views import SelfPlayView

    core = core_cls(2, seed=0, max_steps=37)
    view = SelfPlayView(core)
    assert core.max_steps == view.max_steps == EgoView(core_cls(2, seed=0, max_steps=37)).max_steps == 37
    assert view.group_map == core.group_map == {"agents": ["agent_0", "agent_1"]}
    view.reset()
    picture = view.render(1, mode="rgb_array")
    assert picture.dtype.name == "uint8" and picture.ndim == 3
    assert (picture == view.render(1)).all()
    with pytest.raises(ValueError, match=r"mode='human' is not valid; valid: 'rgb_array'"):
        view.render(mode="human")


@pytest.mark.parametrize("domain", DOMAINS)
def test_self_play_keys_read_as_vmas_wrapper_keys(domain):
    from sidewalk.views import SelfPlayView

    view = SelfPlayView(core(domain, num_envs=3, layout="teams", n_agents=4))
    check_env_specs(view)
    agents = view.full_observation_spec[AGENT_GROUP]
    # Everything under the group but "info" is the input: a VMAS-style trainer (BenchMARL) drops "info" and is right.
    assert set(agents.keys()) == {"observation", "info"}
    assert set(agents["info"].keys()) == {*INFO_KEYS, "cost", "mask"}
    rollout = view.rollout(300, break_when_any_done=False)
    nxt = rollout.get("next")
    for key in INFO_KEYS:  # the same sticky flags the "world" group reports for evaluation
        assert torch.equal(nxt.get((AGENT_GROUP, "info", key)), nxt.get(("world", "info", key)))
    assert torch.equal(nxt.get((AGENT_GROUP, "info", "mask")), ~nxt.get((AGENT_GROUP, "done")))
    assert torch.equal(nxt.get((AGENT_GROUP, "info", "cost")), nxt.get(("world", "cost")))
    # The root state is every agent's true state, goal and presence: 5 (grid) / 8 (continuous) numbers an agent.
    state, world = nxt.get("state"), nxt.get("world")
    width = {"discrete": 5, "continuous": 8}[domain]
    assert state.shape == (*nxt.batch_size, 4 * width)
    per_agent = state.unflatten(-1, (4, width))
    assert torch.equal(per_agent[..., -1:], world.get("present").float())
    if domain == "continuous":
        p = view.core.params
        x, _, speed, heading = world.get("state").unbind(-1)
        torch.testing.assert_close(per_agent[..., 0], x / p.length_m)
        torch.testing.assert_close(per_agent[..., 2], speed / p.max_speed_mps)
        torch.testing.assert_close(per_agent[..., 3:5], torch.stack([heading.cos(), heading.sin()], -1))
    else:
        rows, cols = view.core.rows, view.core.cols
        torch.testing.assert_close(per_agent[..., 2:4], world.get("goal").float() / torch.tensor([rows - 1, cols - 1]))
    assert 0 <= float(per_agent[..., :2].min()) and float(per_agent[..., :2].max()) <= 1  # positions in the room


def test_a_crashed_agent_past_its_end_is_paid_nothing_and_stays_terminated():
    """What a trainer that ignores the mask sees after an agent's crash: reward 0 and terminated, so its value
    target there is 0 and its actions there change nothing."""
    from sidewalk.views import SelfPlayView

    view = SelfPlayView(DiscreteSidewalkEnv(1, seed=0))
    td = view.reset()
    steps = []
    for _ in range(6):  # agent 0 goes up until it hits the wall, agent 1 keeps walking
        td.set((AGENT_GROUP, "action"), torch.tensor([[UP, LEFT]]))
        td = view.step(td)
        steps.append(td.get("next").clone())
        td = td.get("next")
    crashed = [bool(step.get((AGENT_GROUP, "info", "collided_wall"))[0, 0]) for step in steps]
    first = crashed.index(True)
    for step in steps[first + 1:]:
        assert float(step.get((AGENT_GROUP, "reward"))[0, 0]) == 0.0
        assert bool(step.get((AGENT_GROUP, "terminated"))[0, 0]) and not bool(step.get((AGENT_GROUP, "info", "mask"))[0, 0])
    assert not any(bool(step.get("done")) for step in steps)  # the world goes on: agent 1 still walks


def test_the_earlier_self_play_keys_are_opt_in_and_warn_of_their_removal():
    from sidewalk.views import SelfPlayView

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plain = SelfPlayView(DiscreteSidewalkEnv(2, seed=0))  # the default writes no earlier keys, and warns not
    assert set(plain.full_observation_spec[AGENT_GROUP].keys()) == {"observation", "info"}
    with pytest.warns(DeprecationWarning, match=r"legacy_keys=True.*removed in sidewalk 0\.3") as caught:
        view = SelfPlayView(DiscreteSidewalkEnv(2, seed=0), legacy_keys=True)
    assert {w.filename for w in caught if "legacy_keys" in str(w.message)} == {__file__}  # it names the caller's line
    check_env_specs(view)
    td = view.rollout(5)
    for key in ("cost", "mask"):
        assert torch.equal(td.get(("next", AGENT_GROUP, key)), td.get(("next", AGENT_GROUP, "info", key)))
