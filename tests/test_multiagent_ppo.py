"""IPPO and MAPPO (sidewalk/algos/ippo.py, mappo.py): policies on the self-play view, value targets, learning on a
fixed batch, the centralised critic, parameter sharing and exact resume."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pandas as pd
import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import RewardSum, TransformedEnv

from sidewalk.algos.ippo import IPPO, IPPOConfig
from sidewalk.algos.mappo import MAPPO, MAPPOConfig
from sidewalk.config import validate
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.grid import DiscreteParams
from sidewalk.envs.unicycle import OBSERVATION_FIELDS
from sidewalk.experiment import Trial
from sidewalk.schema import register_schemas
from sidewalk.views import SelfPlayView

torch.set_num_threads(1)  # small networks on a 2-core machine: threads only contend

CONF = Path(__file__).resolve().parents[1] / "conf"
LEARNERS = {"ippo": (IPPO, IPPOConfig), "mappo": (MAPPO, MAPPOConfig)}
DOMAINS = ("continuous", "image", "vector")  # the grid's observation is an image or a vector
OBS, ACTION, VALUE = ("agents", "observation"), ("agents", "action"), ("agents", "state_value")
OBS_WIDTH = 2 * len(OBSERVATION_FIELDS)  # two agents
TINY = {"frames_per_batch": 32, "epochs": 2, "minibatch_size": 16}


def view(domain: str, num_envs: int = 4, seed: int = 0) -> TransformedEnv:
    if domain == "continuous":
        core = ContinuousSidewalkEnv(num_envs, seed=seed)
    else:
        core = DiscreteSidewalkEnv(num_envs, seed=seed, params=DiscreteParams(observation=domain))
    return TransformedEnv(SelfPlayView(core), RewardSum())


def learner(name: str, domain: str, num_envs: int = 4, **config) -> tuple[IPPO, TransformedEnv]:
    torch.manual_seed(0)
    env = view(domain, num_envs)
    cls, config_cls = LEARNERS[name]
    return cls(config_cls(**{**TINY, **config}), env), env


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("name", LEARNERS)
def test_policies_act_for_every_agent_on_the_self_play_view(name, domain):
    algo, env = learner(name, domain)
    n_agents = env.full_observation_spec_unbatched[OBS].shape[0]
    assert algo.n_agents == n_agents == 2
    action_spec = env.full_action_spec[ACTION]
    td = env.reset()
    sampled = algo.collection_policy()(td.clone())
    greedy = algo.evaluation_policy()(td.clone())
    for out in (sampled, greedy):
        assert out.get(ACTION).shape == action_spec.shape and action_spec.is_in(out.get(ACTION))
    assert torch.equal(algo.evaluation_policy()(td.clone()).get(ACTION), greedy.get(ACTION))  # deterministic
    assert algo.critic(td.clone()).get(VALUE).shape == (4, n_agents, 1)
    # A learned partner (sidewalk.partners.policy) calls the policy with the observation alone.
    alone = TensorDict({OBS: td.get(OBS)}, batch_size=[4])
    assert torch.equal(algo.evaluation_policy()(alone).get(ACTION), greedy.get(ACTION))
    # The policies run in the collector, and the update takes its (worlds, time) batches.
    collector = Collector(env, algo.collection_policy(), frames_per_batch=32, total_frames=32,
                          auto_register_policy_transforms=False)
    batch = next(iter(collector))
    collector.shutdown()
    assert batch.batch_size == (4, 8)
    logs = algo.update(batch)
    assert {"loss_objective", "loss_critic"} <= set(logs) and all(torch.isfinite(torch.tensor(list(logs.values()))))
    assert algo.frames_seen == 32


@pytest.mark.parametrize("name", LEARNERS)
def test_value_targets_are_each_agents_own_discounted_return(name):
    # One world, three steps: agent 0 is paid 1 at the last step, agent 1 at the first; the world terminates at
    # the third step. With a zero critic and lambda = 1 the target is the discounted return of each agent's own
    # reward, cut where the world's episode ends: gamma = 0.5 gives [0.25, 0.5, 1] and [1, 0, 0].
    algo, _ = learner(name, "continuous", gamma=0.5, gae_lambda=1.0)
    for parameter in algo.critic.parameters():
        parameter.data.zero_()
    obs = torch.randn(1, 3, 2, OBS_WIDTH)
    reward = torch.tensor([[0.0, 1.0], [0.0, 0.0], [1.0, 0.0]]).reshape(1, 3, 2, 1)
    terminated = torch.tensor([False, False, True]).reshape(1, 3, 1, 1).expand(1, 3, 2, 1)
    batch = TensorDict(
        {"agents": TensorDict({"observation": obs}, batch_size=(1, 3, 2)),
         "next": {"agents": TensorDict({"observation": torch.randn(1, 3, 2, OBS_WIDTH), "reward": reward,
                                        "done": terminated.clone(), "terminated": terminated.clone()},
                                       batch_size=(1, 3, 2))}},
        batch_size=(1, 3),
    )
    with torch.no_grad():
        algo.advantage(batch)
    expected = torch.tensor([[0.25, 1.0], [0.5, 0.0], [1.0, 0.0]]).reshape(1, 3, 2, 1)
    torch.testing.assert_close(batch.get(("agents", "value_target")), expected)


def test_ippo_learns_nothing_from_an_agents_steps_after_its_own_end():
    # Steps an agent takes after its own end (("agents", "info", "mask") false) are out of every loss and statistic: making
    # up their rewards and observations leaves the update exactly as it was. (MAPPO's critic reads every agent's
    # observation for the others' values, so this holds for IPPO's own-observation critic.)
    algo, env = learner("ippo", "continuous", num_envs=16, frames_per_batch=1024, epochs=2, minibatch_size=256)
    collector = Collector(env, algo.collection_policy(), frames_per_batch=1024, total_frames=1024,
                          auto_register_policy_transforms=False)
    batch = next(iter(collector))
    collector.shutdown()
    out_of_play = ~batch.get(("agents", "info", "mask"))
    assert out_of_play.any() and not out_of_play.all()
    made_up = batch.clone()
    noise = torch.randn_like(made_up.get(OBS)) * 10
    made_up.set(OBS, torch.where(out_of_play, noise, made_up.get(OBS)))
    made_up.set(("next", *OBS), torch.where(out_of_play, noise, made_up.get(("next", *OBS))))
    reward = made_up.get(("next", "agents", "reward"))
    made_up.set(("next", "agents", "reward"), torch.where(out_of_play, torch.full_like(reward, 7.0), reward))
    twin, _ = learner("ippo", "continuous", num_envs=16, frames_per_batch=1024, epochs=2, minibatch_size=256)
    algo.update(batch)
    twin.update(made_up)
    for mine, theirs in zip(algo.loss.parameters(), twin.loss.parameters()):
        torch.testing.assert_close(mine, theirs)
    torch.testing.assert_close(algo.obs_norm.mean, twin.obs_norm.mean)


@pytest.mark.parametrize("domain", ["continuous", "image"])
@pytest.mark.parametrize("name", LEARNERS)
def test_updates_on_a_fixed_batch_lower_the_losses(name, domain):
    algo, env = learner(name, domain, num_envs=8, frames_per_batch=128, epochs=4, minibatch_size=32)
    collector = Collector(env, algo.collection_policy(), frames_per_batch=128, total_frames=128,
                          auto_register_policy_transforms=False)
    batch = next(iter(collector))
    collector.shutdown()
    logs = [algo.update(batch.clone()) for _ in range(4)]
    assert logs[-1]["loss_critic"] < logs[0]["loss_critic"]  # the critic moves toward the batch's returns
    # The surrogate starts at 0 (ratio 1, standardised advantages) and every update lowers it on its batch.
    assert all(log["loss_objective"] < 0 for log in logs)


@pytest.mark.parametrize("domain", ["continuous", "image"])
@pytest.mark.parametrize("share_params", [True, False])
def test_only_the_mappo_critic_sees_the_other_agents_observation(domain, share_params):
    td = view(domain).reset()
    changed = td.clone()
    other = changed.get(OBS)[:, 1]
    if other.dtype == torch.uint8:
        changed.get(OBS)[:, 1] = 255 - other
    else:
        changed.get(OBS)[:, 1] = other + 1.0
    for name, sees_other in (("ippo", False), ("mappo", True)):
        algo, _ = learner(name, domain, share_params=share_params)
        with torch.no_grad():
            before, after = algo.critic(td.clone()).get(VALUE), algo.critic(changed.clone()).get(VALUE)
            actions = [algo.actor.get_dist(x.clone()).log_prob(algo.evaluation_policy()(td.clone()).get(ACTION))
                       for x in (td, changed)]
        assert (not torch.equal(before[:, 0], after[:, 0])) == sees_other, name
        assert not torch.equal(before[:, 1], after[:, 1])
        torch.testing.assert_close(actions[0][:, 0], actions[1][:, 0], rtol=0, atol=0)  # each policy: its own view


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("name", LEARNERS)
def test_share_params_is_one_set_of_weights_and_false_one_per_agent(name, domain):
    td = view(domain).reset()
    same = td.clone()
    same.get(OBS)[:, 1] = same.get(OBS)[:, 0]  # both agents see the same thing
    n_params = {}
    for share in (True, False):
        algo, _ = learner(name, domain, share_params=share)
        n_params[share] = sum(p.numel() for p in algo.actor.parameters())
        with torch.no_grad():
            dist = algo.actor.get_dist(same.clone())
            values = algo.critic(same.clone()).get(VALUE)
        params = dist.logits if domain != "continuous" else dist.loc
        if share:
            torch.testing.assert_close(params[:, 0], params[:, 1], rtol=0, atol=0)
            if name == "ippo":
                torch.testing.assert_close(values[:, 0], values[:, 1], rtol=0, atol=0)
        else:
            assert not torch.allclose(params[:, 0], params[:, 1])
            assert not torch.allclose(values[:, 0], values[:, 1])
    assert n_params[False] == 2 * n_params[True]  # one network per agent


def composed(*overrides: str):
    register_schemas()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def metrics(run_dir: Path) -> pd.DataFrame:
    return pd.read_csv(run_dir / "metrics.csv").drop(columns=["time_s", "frames_per_s"])


@pytest.mark.parametrize(
    "setup",
    [["env=continuous", "algo=ippo", "algo.share_params=false"], ["env=continuous", "algo=mappo"],
     ["env=discrete", "algo=mappo"]],
    ids=["ippo-continuous-unshared", "mappo-continuous", "mappo-grid-image"],
)
def test_a_self_play_run_resumes_exactly(tmp_path, setup):
    experiment = validate(composed(
        *setup, "opponent=self", "num_envs=4", "iterations=6", "eval_every=2", "eval_episodes=4", "checkpoint_every=3",
        "logger=none", "algo.frames_per_batch=32", "algo.epochs=2", "algo.minibatch_size=16",
    ))
    Trial(experiment, tmp_path / "whole").run(progress=False, absolute_metric=False)  # metrics and policy compared
    stopped = tmp_path / "stopped"
    # Stopped at an evaluation iteration, so its closing evaluation is one the whole run makes too.
    stopping = Trial(dataclasses.replace(experiment, iterations=4, keep_checkpoint="all"), stopped)
    stopping.run(progress=False, absolute_metric=False)
    Trial(dataclasses.replace(experiment, resume=True), stopped).run(progress=False, absolute_metric=False)
    pd.testing.assert_frame_equal(metrics(stopped), metrics(tmp_path / "whole"))
    whole, resumed = (torch.load(run / "policy.pt", weights_only=True)["modules"]["loss"]
                      for run in (tmp_path / "whole", stopped))
    assert whole.keys() == resumed.keys()
    for key in whole:
        assert torch.equal(whole[key], resumed[key]), key
