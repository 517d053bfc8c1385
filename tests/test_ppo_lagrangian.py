"""PPO-Lagrangian (sidewalk/algos/ppo_lagrangian.py): λ's direction, the combined advantage, the per-world episode
cost across batches, and runs through the config on both domains that resume exactly."""

from __future__ import annotations

import dataclasses
import io
import math
from pathlib import Path

import pandas as pd
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from tensordict import TensorDict

from sidewalk.algos.ppo_lagrangian import PPOLagrangian, PPOLagrangianConfig
from sidewalk.config import validate
from sidewalk.envs import ContinuousSidewalkEnv
from sidewalk.experiment import Trial
from sidewalk.schema import register_schemas
from sidewalk.views import EgoView

torch.set_num_threads(1)  # small networks on a 2-core machine: threads only contend

CONF = Path(__file__).resolve().parents[1] / "conf"
TINY = {"frames_per_batch": 8, "epochs": 2, "minibatch_size": 4}


def learner(num_envs: int = 2, **config) -> PPOLagrangian:
    torch.manual_seed(0)
    env = EgoView(ContinuousSidewalkEnv(num_envs, seed=0), opponent="random")
    return PPOLagrangian(PPOLagrangianConfig(**{**TINY, **config}), env)


def hand_made_batch(algo: PPOLagrangian, cost: list[list[float]], done: list[list[bool]]) -> TensorDict:
    """A (worlds, time) batch of random observations and actions with the given costs and episode ends."""
    cost = torch.tensor(cost).unsqueeze(-1)
    done = torch.tensor(done).unsqueeze(-1)
    shape = cost.shape[:2]
    return TensorDict(
        {
            "observation": algo.observation_spec.rand(shape),
            "action": algo.action_spec.rand(shape),
            "next": {
                "observation": algo.observation_spec.rand(shape),
                "reward": torch.randn(*shape, 1),
                "cost": cost,
                "done": done.clone(),
                "terminated": done.clone(),
            },
        },
        batch_size=shape,
    )


def test_yaml_mirrors_the_schema_and_the_defaults_are_omnisafes_but_the_limit():
    yaml = OmegaConf.load(CONF / "algo" / "ppo_lagrangian.yaml")
    defaults = dataclasses.asdict(PPOLagrangianConfig())
    assert {k: v for k, v in yaml.items() if k != "defaults"} == defaults
    config = PPOLagrangianConfig()
    assert (config.lambda_init, config.lambda_lr, config.cost_gamma, config.cost_gae_lambda) == (0.001, 0.035, 0.99, 0.95)
    assert config.lambda_upper_bound == math.inf and config.cost_limit == 0.05


@pytest.mark.parametrize(
    "field, value", [("cost_limit", -0.1), ("lambda_lr", 0.0), ("lambda_init", -1.0), ("lambda_upper_bound", 0.0),
                     ("cost_gamma", 1.5), ("cost_gae_lambda", -0.1)],
)
def test_config_rejects_out_of_range_values(field, value):
    with pytest.raises(ValueError, match=f"algo.{field}"):
        PPOLagrangianConfig(**{field: value})


def test_the_cost_critic_is_the_reward_critics_architecture_with_its_own_weights():
    algo = learner()
    reward_net, cost_net = algo.critic.module, algo.cost_critic.module
    assert [type(m) for m in reward_net.modules()] == [type(m) for m in cost_net.modules()]
    assert cost_net[1] is reward_net[1] is algo.obs_norm  # one set of running statistics, moved by PPO's update
    assert not torch.equal(cost_net[2][0].weight, reward_net[2][0].weight)
    cost_parameters = {id(p) for p in algo.cost_critic.parameters()}
    assert cost_parameters <= {id(p) for p in algo.optimizer.param_groups[0]["params"]}  # trained by PPO's loop
    assert not cost_parameters & {id(p) for p in algo.critic.parameters()}


ENDS = [[False, False, False, True], [False, False, True, False]]  # one episode ends in each world


def test_lambda_rises_while_the_episode_cost_exceeds_the_limit_and_falls_while_it_holds():
    rising = learner(lambda_init=1.0, cost_limit=0.05)
    unsafe = hand_made_batch(rising, [[0, 1, 0, 0], [0, 0, 0, 0]], ENDS)
    logs = rising.update(unsafe)  # J_c = 0.5 > 0.05
    assert logs["episode_cost"] == 0.5 and logs["lagrange_multiplier"] > 1.0
    assert math.isfinite(logs["loss_cost_critic"])

    falling = learner(lambda_init=1.0, cost_limit=0.05)
    safe = hand_made_batch(falling, [[0, 0, 0, 0], [0, 0, 0, 0]], ENDS)
    logs = falling.update(safe)  # J_c = 0 < 0.05
    assert logs["episode_cost"] == 0.0 and 0.0 <= logs["lagrange_multiplier"] < 1.0

    at_zero = learner(lambda_init=0.0)
    for _ in range(3):
        logs = at_zero.update(safe.clone())
        assert logs["lagrange_multiplier"] == 0.0  # clamped: a multiplier never goes negative


def test_without_a_finished_episode_the_last_estimate_stands():
    algo = learner(lambda_init=1.0)
    no_end = hand_made_batch(algo, [[0, 0, 0, 0], [0, 0, 0, 0]], [[False] * 4, [False] * 4])
    logs = algo.update(no_end)  # no episode has ended yet: no estimate, λ stays where it started
    assert math.isnan(logs["episode_cost"]) and logs["lagrange_multiplier"] == 1.0
    logs = algo.update(hand_made_batch(algo, [[0, 1, 0, 0], [0, 0, 0, 0]], ENDS))
    assert logs["episode_cost"] == 0.5
    risen = logs["lagrange_multiplier"]
    logs = algo.update(no_end)  # the batch ends no episode: J_c stays 0.5, and λ keeps rising on it
    assert logs["episode_cost"] == 0.5 and logs["lagrange_multiplier"] > risen


def test_lambda_stops_at_its_upper_bound():
    algo = learner(lambda_init=0.9, lambda_lr=0.5, lambda_upper_bound=1.0)
    unsafe = hand_made_batch(algo, [[1, 0], [1, 0]], [[False, True], [False, True]])
    assert algo.update(unsafe)["lagrange_multiplier"] == 1.0


def test_policy_advantage_is_reward_minus_lambda_cost_over_one_plus_lambda():
    algo = learner(gamma=0.5, gae_lambda=1.0, cost_gamma=0.5, cost_gae_lambda=1.0)
    algo.lagrange.multiplier.data.fill_(0.5)
    reward_advantage, cost_advantage = torch.randn(2, 4, 1), torch.randn(2, 4, 1)
    torch.testing.assert_close(
        algo.combined_advantage(reward_advantage, cost_advantage), (reward_advantage - 0.5 * cost_advantage) / 1.5
    )

    # Through the advantage PPO's update calls: GAE on the reward (standardised) and on the cost (centred), combined.
    # With a zero cost critic and lambda = 1 the cost's value target is its discounted sum: cost 1 at the last step of
    # a 3-step episode gives [0.25, 0.5, 1] at gamma 0.5, then a new episode with no cost.
    for parameter in algo.cost_critic.parameters():
        parameter.data.zero_()
    batch = hand_made_batch(algo, [[0, 0, 1, 0], [0, 0, 0, 0]], [[False, False, True, False], [False] * 4])
    with torch.no_grad():
        algo.advantage(batch)
    torch.testing.assert_close(batch.get("cost_value_target")[0].squeeze(-1), torch.tensor([0.25, 0.5, 1.0, 0.0]))
    cost_advantage = batch.get("cost_advantage")
    assert abs(float(cost_advantage.mean())) < 1e-6  # centred ...
    raw = batch.get("cost_value_target")  # ... but not scaled (a zero critic: the advantage is the target)
    torch.testing.assert_close(cost_advantage, raw - raw.mean())
    reward_advantage = batch.get("reward_advantage")
    assert abs(float(reward_advantage.mean())) < 1e-5 and abs(float(reward_advantage.std()) - 1.0) < 1e-4
    torch.testing.assert_close(batch.get("advantage"), (reward_advantage - 0.5 * cost_advantage) / 1.5)


def test_an_episode_spanning_batches_is_counted_once_with_its_whole_cost():
    algo = learner(num_envs=2)
    # World 0: one episode over both batches, cost 1 + 1 in the first and 1 in the second, ending at step 1 of the
    # second; then a new episode ends at once with cost 1. World 1: an episode of cost 1 ends in the first batch, the
    # next one (cost 1) is still running after the second.
    first = hand_made_batch(algo, [[1, 0, 1], [0, 1, 0]], [[False, False, False], [False, True, False]])
    second = hand_made_batch(algo, [[1, 0, 1], [0, 0, 1]], [[False, True, True], [False, False, False]])
    assert algo.finished_episode_costs(first).tolist() == [1.0]
    torch.testing.assert_close(algo.running_episode_cost, torch.tensor([2.0, 0.0]))
    assert algo.finished_episode_costs(second).tolist() == [3.0, 1.0]
    torch.testing.assert_close(algo.running_episode_cost, torch.tensor([0.0, 1.0]))

    # Through update: J_c is the mean over the episodes that ended in the batch, and a checkpoint keeps the
    # running costs, J_c and λ with its optimiser.
    algo = learner(num_envs=2)
    assert algo.update(first)["episode_cost"] == 1.0
    assert algo.update(second)["episode_cost"] == 2.0
    saved = io.BytesIO()
    torch.save(algo.state_dict(), saved)  # as a checkpoint: the optimisers' state is written, not shared
    saved.seek(0)
    restored = learner(num_envs=2)
    restored.load_state_dict(torch.load(saved, weights_only=False))
    torch.testing.assert_close(restored.running_episode_cost, torch.tensor([0.0, 1.0]))
    assert restored.episode_cost == 2.0 and restored.lagrange_multiplier == algo.lagrange_multiplier
    third = hand_made_batch(algo, [[0, 0, 0], [0, 0, 0]], [[False, False, False], [True, False, False]])
    assert algo.update(third.clone()) == restored.update(third.clone())


def composed(*overrides: str):
    register_schemas()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def metrics(run_dir: Path) -> pd.DataFrame:
    return pd.read_csv(run_dir / "metrics.csv").drop(columns=["time_s", "frames_per_s"])


@pytest.mark.parametrize("domain, opponent", [("discrete", "dijkstra"), ("continuous", "prm")])
def test_a_run_logs_the_multiplier_and_resumes_exactly(tmp_path, domain, opponent):
    experiment = validate(composed(
        f"env={domain}", f"opponent={opponent}", "algo=ppo_lagrangian", "num_envs=8", "iterations=6", "eval_every=2",
        "eval_episodes=4", "checkpoint_every=3", "logger=none", "algo.frames_per_batch=64", "algo.epochs=2",
        "algo.minibatch_size=32",
    ))
    assert isinstance(experiment.algo, PPOLagrangianConfig)
    Trial(experiment, tmp_path / "whole").run(progress=False, absolute_metric=False)  # metrics and policy compared
    frame = metrics(tmp_path / "whole")
    for key in ("train/lagrange_multiplier", "train/episode_cost", "train/loss_cost_critic"):
        assert key in frame.columns, key
    multiplier = frame["train/lagrange_multiplier"]
    assert multiplier.notna().all() and (multiplier >= 0).all()
    assert multiplier.nunique() > 1  # episodes ended and λ moved
    stopped = tmp_path / "stopped"
    # Stopped at an evaluation iteration, so its closing evaluation is one the whole run makes too.
    stopping = Trial(dataclasses.replace(experiment, iterations=4, keep_checkpoint="all"), stopped)
    stopping.run(progress=False, absolute_metric=False)
    Trial(dataclasses.replace(experiment, resume=True), stopped).run(progress=False, absolute_metric=False)
    pd.testing.assert_frame_equal(metrics(stopped), frame)
    whole, resumed = (torch.load(run / "policy.pt", weights_only=True)["modules"] for run in (tmp_path / "whole", stopped))
    assert whole.keys() == resumed.keys() == {"loss", "lagrange"}
    for name in whole:
        for key in whole[name]:
            assert torch.equal(whole[name][key], resumed[name][key]), (name, key)
