"""The multi-agent value learners (IQL, VDN, QMIX): mixers, TD targets on hand-made transitions, learning on a fixed
batch, per-agent parameters, and exact resume of a self-play run."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import RewardSum, TransformedEnv

from sidewalk.algos.dqn import loss_module_step
from sidewalk.algos.iql import ACTION_VALUE_KEY, CHOSEN_ACTION_VALUE_KEY
from sidewalk.algos.qmix import STATE_KEY
from sidewalk.envs import DiscreteSidewalkEnv
from sidewalk.registry import LEARNERS
from sidewalk.views import SelfPlayView

ROOT = Path(__file__).resolve().parents[1]
Q_LEARNERS = ("iql", "vdn", "qmix")
OBS, ACTION, REWARD = ("agents", "observation"), ("agents", "action"), ("agents", "reward")
MASK = ("agents", "info", "mask")
GAMMA = 0.9


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def make_learner(name: str, num_envs: int = 4, **overrides):
    torch.manual_seed(0)
    env = TransformedEnv(SelfPlayView(DiscreteSidewalkEnv(num_envs, seed=0)), RewardSum())
    cls = LEARNERS[name]
    return cls(cls.Config(**overrides), env), env


def random_batch(env, steps: int) -> TensorDict:
    """``steps`` random steps of every world of ``env``, as the collector lays them out: (worlds, steps)."""
    torch.manual_seed(1)
    return env.rollout(steps, break_when_any_done=False)


def test_vdn_mixes_by_summing_the_agents_chosen_q():
    algo, env = make_learner("vdn")
    td = algo.actor(env.reset())
    chosen = td.get(CHOSEN_ACTION_VALUE_KEY)  # (B, N, 1)
    team = algo.mixer(td).get("chosen_action_value")
    torch.testing.assert_close(team, chosen.sum(-2))
    values = torch.randn(64, algo.n_agents, 1)
    in_play = torch.rand(64, algo.n_agents, 1) < 0.7
    out = algo.mixer(TensorDict({CHOSEN_ACTION_VALUE_KEY: values, MASK: in_play}, batch_size=[64]))
    # agents whose own episode ended add nothing to the team's value
    torch.testing.assert_close(out.get("chosen_action_value"), (values * in_play).sum(-2))


def test_qmix_is_monotone_in_each_agents_q():
    algo, _ = make_learner("qmix")
    with torch.no_grad():  # weights far from their initial scale, so a sign error could not hide
        for parameter in algo.mixer.parameters():
            parameter.normal_(0.0, 1.0)
    generator = torch.Generator().manual_seed(0)
    n = 512
    state = torch.rand(n, 5 * algo.n_agents, generator=generator)
    values = torch.randn(n, algo.n_agents, 1, generator=generator) * 3
    in_play = torch.ones(n, algo.n_agents, 1, dtype=torch.bool)
    base = algo.mixer(TensorDict({CHOSEN_ACTION_VALUE_KEY: values, MASK: in_play, STATE_KEY: state}, batch_size=[n]))
    for agent in range(algo.n_agents):
        raised = values.clone()
        raised[:, agent] += torch.rand(n, 1, generator=generator) * 2
        out = algo.mixer(TensorDict({CHOSEN_ACTION_VALUE_KEY: raised, MASK: in_play, STATE_KEY: state}, batch_size=[n]))
        assert bool((out.get("chosen_action_value") >= base.get("chosen_action_value") - 1e-5).all())
    # The same as a derivative: dQ_tot/dQ_i >= 0 everywhere, and > 0 somewhere.
    values.requires_grad_(True)
    team = algo.mixer(TensorDict({CHOSEN_ACTION_VALUE_KEY: values, MASK: in_play, STATE_KEY: state}, batch_size=[n]))
    (grad,) = torch.autograd.grad(team.get("chosen_action_value").sum(), values)
    assert bool((grad >= 0).all()) and bool((grad > 0).any())


def test_qmix_state_is_the_scaled_true_world():
    _, env = make_learner("qmix")
    td = env.reset()
    state = td.get("state")  # the view's root state, (B, 5·N): the mixer's input
    # The sidewalk: agent 0 at (3, 0) with its goal at (3, 14), agent 1 the other way; a 7 × 15 grid.
    expected = torch.tensor([3 / 6, 0.0, 3 / 6, 1.0, 1.0, 3 / 6, 1.0, 3 / 6, 0.0, 1.0])
    torch.testing.assert_close(state, expected.expand_as(state))


def hand_made_transitions(algo, env) -> TensorDict:
    """Two transitions from the start state: in world 0 agent 0 goes on and agent 1 crashes (rewards -0.01 and -0.5;
    agent 1 alone is terminated, its next state out of play), world 1 ends (every agent terminated)."""
    td = env.reset()[:2]
    td.set(ACTION, torch.tensor([[3, 2], [0, 1]]))  # RIGHT, LEFT: toward the goals; UP, DOWN
    nxt = env.step(env.reset().set(ACTION, torch.tensor([[3, 2]] * 4)))["next"][:2]
    nxt.set(REWARD, torch.tensor([[[-0.01], [-0.5]], [[0.25], [-0.5]]]))
    terminated = torch.tensor([[False], [True]])
    agent_terminated = torch.tensor([[[False], [True]], [[True], [True]]])
    for key in ("done", "terminated"):
        nxt.set(key, terminated)
        nxt.set(("agents", key), agent_terminated)
    nxt.set(MASK, ~agent_terminated)
    td.set("next", nxt)
    with torch.no_grad():  # target networks unlike the online ones, so the double-DQN choice matters
        for name in ("target_value_network_params", "target_local_value_network_params", "target_mixer_network_params"):
            for params in getattr(algo.loss, name, TensorDict()).values(True, True):
                params.add_(torch.randn_like(params) * 0.05)
    return td


def q_values(algo, observation: torch.Tensor, params) -> torch.Tensor:
    """The agents' Q-values (B, N, 4) under ``params`` (the loss's online or target parameters of the actor)."""
    with params.to_module(algo.actor):
        return algo.actor(TensorDict({OBS: observation}, batch_size=observation.shape[:1])).get(ACTION_VALUE_KEY)


@torch.no_grad()
def expected_targets(name: str, algo, td: TensorDict):
    """(prediction, TD target) computed by hand from the networks: IQL per agent, VDN and QMIX for the team."""
    loss = algo.loss
    online = loss.value_network_params if name == "iql" else loss.local_value_network_params
    target = loss.target_value_network_params if name == "iql" else loss.target_local_value_network_params
    q_now = q_values(algo, td.get(OBS), online)  # (2, N, 4)
    chosen = q_now.gather(-1, td.get(ACTION).unsqueeze(-1))  # (2, N, 1)
    q_next_target = q_values(algo, td.get(("next", *OBS)), target)
    if name == "iql":
        # Double DQN: the online network picks the next action, the target network values it.
        greedy = q_values(algo, td.get(("next", *OBS)), online).argmax(-1, keepdim=True)
        bootstrap = q_next_target.gather(-1, greedy)
        reward, terminated = td.get(("next", *REWARD)), td.get(("next", "agents", "terminated"))
        return chosen, reward + GAMMA * (~terminated) * bootstrap  # each agent's own end stops its target
    reward = td.get(("next", *REWARD)).sum(-2)  # the team reward: the agents' rewards summed
    terminated = td.get(("next", "terminated"))
    # agents out of play in the next state (agent 1 of world 0 crashed) add nothing to the team's next value
    next_chosen = q_next_target.max(-1, keepdim=True).values * td.get(("next", *MASK))
    if name == "vdn":
        return chosen.sum(-2), reward + GAMMA * (~terminated) * next_chosen.sum(-2)
    mixer = algo.mixer.module.mixer
    state, next_state = td.get("state"), td.get(("next", "state"))
    with loss.target_mixer_network_params.to_module(algo.mixer):
        next_team = mixer(next_chosen, next_state)
    return mixer(chosen, state), reward + GAMMA * (~terminated) * next_team


@pytest.mark.parametrize("name", Q_LEARNERS)
def test_td_target_on_a_hand_made_transition(name):
    algo, env = make_learner(name, gamma=GAMMA, loss_function="l2")
    td = hand_made_transitions(algo, env)
    prediction, target = expected_targets(name, algo, td)
    # Spelled out for world 1 (terminated) and, in IQL, agent 1's crash in world 0: the target is the reward alone.
    if name == "iql":
        torch.testing.assert_close(target[1], torch.tensor([[0.25], [-0.5]]))
        torch.testing.assert_close(target[0, 1], torch.tensor([-0.5]))
    else:
        torch.testing.assert_close(target[1], torch.tensor([0.25 - 0.5]))
    stored = algo.transitions(td.unsqueeze(1))  # what the replay buffer would keep, (2,)
    torch.testing.assert_close(algo.loss(stored)["loss"], ((prediction - target) ** 2).mean())


def test_iql_leaves_an_agents_steps_after_its_end_out_of_the_loss():
    algo, env = make_learner("iql", gamma=GAMMA, loss_function="l2")
    td = hand_made_transitions(algo, env)
    prediction, target = expected_targets("iql", algo, td)
    td.set(MASK, torch.tensor([[[True], [False]], [[True], [True]]]))  # agent 1 of world 0 had already ended
    td.set(("next", *REWARD), td.get(("next", *REWARD)).index_put((torch.tensor(0), torch.tensor(1)), torch.tensor([9.0])))
    in_play = td.get(MASK).squeeze(-1)
    stored = algo.transitions(td.unsqueeze(1))
    # the out-of-play step's reward (9, made up) moves nothing: the loss is the mean over the other three
    expected = ((prediction - target) ** 2).squeeze(-1)[in_play].mean()
    torch.testing.assert_close(algo.loss(stored)["loss"], expected)


@pytest.mark.parametrize("name", Q_LEARNERS)
def test_loss_decreases_on_a_fixed_batch(name):
    algo, env = make_learner(name, lr=2e-3)
    batch = algo.transitions(random_batch(env, 8))  # 32 transitions
    first = algo.loss(batch)["loss"].item()
    for _ in range(40):
        loss = algo.loss(batch)["loss"]
        algo.optimizer.zero_grad()
        loss.backward()
        algo.optimizer.step()
    assert algo.loss(batch)["loss"].item() < 0.5 * first


@pytest.mark.parametrize("name", ["iql", "vdn"])
def test_advantage_learning_is_the_loss_on_rewards_less_the_action_gaps(name):
    ours, env = make_learner(name, advantage_learning=0.9)
    theirs, _ = make_learner(name)
    batch = ours.transitions(random_batch(env, 8))
    gaps = theirs.action_gaps(batch)  # (32, 2)
    assert bool((gaps > 0).any())
    shifted = batch.clone()
    if name == "iql":
        shifted["next", *REWARD] = batch["next", *REWARD] - 0.9 * gaps.unsqueeze(-1)
    else:  # Q_tot's gap: the in-play agents' gaps summed
        shifted["next", "reward"] = batch["next", "reward"] - 0.9 * (gaps * batch[MASK].squeeze(-1)).sum(-1, True)
    torch.testing.assert_close(ours._advantage_learning_step(batch.clone()), loss_module_step(theirs, shifted))
    torch.testing.assert_close(ours.loss.state_dict(), theirs.loss.state_dict())


def test_qmix_advantage_learning_pays_the_mixed_gap_to_the_greedy_joint_action():
    ours, env = make_learner("qmix", advantage_learning=0.9)
    theirs, _ = make_learner("qmix")
    batch = ours.transitions(random_batch(env, 8))
    key, gaps = ours.reward_gaps(batch)
    assert bool((gaps >= 0).all()) and bool((gaps > 0).any())  # the mixer is monotone in every agent's Q
    greedy = batch.clone()  # every in-play agent taking its best action under the target network: no gap
    with torch.no_grad(), ours.loss.target_local_value_network_params.to_module(ours.loss.local_value_network):
        greedy[ACTION] = ours.q_network(batch[OBS]).argmax(-1)
    torch.testing.assert_close(ours.reward_gaps(greedy)[1], torch.zeros_like(gaps))
    shifted = batch.clone()
    shifted[key] = batch[key] - 0.9 * gaps
    torch.testing.assert_close(ours._advantage_learning_step(batch.clone()), loss_module_step(theirs, shifted))


@pytest.mark.parametrize("name", Q_LEARNERS)
def test_share_params_false_gives_agents_their_own_q(name):
    observation = SelfPlayView(DiscreteSidewalkEnv(1, seed=0)).reset().get(OBS)[:, :1]  # agent 0's view
    same_view = observation.expand(1, 2, *observation.shape[2:])  # both agents see it
    for share in (True, False):
        algo, _ = make_learner(name, share_params=share)
        q = algo.actor(TensorDict({OBS: same_view}, batch_size=[1])).get(ACTION_VALUE_KEY)
        assert torch.allclose(q[:, 0], q[:, 1], rtol=1e-4, atol=1e-6) == share
        if not share:  # and they learn apart: one network's parameters per agent
            n_per_agent = sum(p[0].numel() for p in algo.q_network.params.values(True, True))
            assert sum(p.numel() for p in algo.q_network.parameters()) == 2 * n_per_agent


@pytest.mark.parametrize("name", ["vdn", "qmix"])
def test_mixers_refuse_double_dqn(name):
    with pytest.raises(ValueError, match="double_dqn"):
        LEARNERS[name].Config(double_dqn=True)


# ---- a self-play run resumes exactly ---------------------------------------------------------------------------

TINY = [
    "env=discrete", "opponent=self", "num_envs=4", "eval_every=4", "eval_episodes=8", "checkpoint_every=4",
    "logger=none", "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=2000",
    "algo.learning_starts=0", "algo.updates_per_batch=1", "env.max_steps=40",
]


def trial(run_dir: Path, *overrides: str) -> pd.DataFrame:
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from sidewalk.config import validate
    from sidewalk.experiment import Trial
    from sidewalk.schema import register_schemas
    from sidewalk.trial_state import WALL_CLOCK_COLUMNS

    register_schemas()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, *overrides])
    Trial(validate(cfg), run_dir, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    return pd.read_csv(run_dir / "metrics.csv").drop(columns=list(WALL_CLOCK_COLUMNS))


@pytest.mark.parametrize("name", ["iql", "qmix"])
def test_a_self_play_run_resumes_exactly(tmp_path, name):
    whole = trial(tmp_path / "whole", f"algo={name}", "iterations=8")
    trial(tmp_path / "resumed", f"algo={name}", "iterations=4", "keep_checkpoint=all")
    resumed = trial(tmp_path / "resumed", f"algo={name}", "iterations=8", "resume=true")
    assert whole["train/loss"].notna().all()
    assert whole["eval/team/success_rate"].notna().sum() == 2
    pd.testing.assert_frame_equal(resumed, whole)


@pytest.mark.parametrize("name", Q_LEARNERS)
def test_greedy_worlds_explore_not_at_all_and_the_others_at_epsilon(name):
    """``greedy_worlds``: the first share of the worlds acts greedily in training (every agent of them, the pair an
    evaluation plays); the rest explore at ε. At ε 1 the others' actions are uniform, so some differ from greedy."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    algo, env = make_learner(name, num_envs=8, greedy_worlds=0.25, eps_start=1.0, eps_end=1.0)
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        greedy = algo.actor(td.clone())[ACTION]
        torch.manual_seed(3)
        explored = [algo.explorer(td.clone())[ACTION] for _ in range(20)]
    for actions in explored:
        assert torch.equal(actions[:2], greedy[:2])  # round(0.25 × 8) = 2 greedy worlds, both agents greedy
    assert any(not torch.equal(actions[2:], greedy[2:]) for actions in explored)
    with pytest.raises(ValueError, match=r"algo.greedy_worlds=1.5 .* valid: \[0.0, 1.0\]"):
        LEARNERS[name].Config(greedy_worlds=1.5)
