"""DQN's own gradient step is TorchRL's ``DQNLoss`` arithmetic, its target network is the loss's target parameters, and
a checkpoint of either optimiser implementation loads."""

from __future__ import annotations

from copy import deepcopy

import pytest
import torch

from sidewalk.algos.dqn import DQN, TRANSITION_KEYS, loss_module_step
from sidewalk.compose import compose_experiment


def build(*overrides: str, seed: int = 0) -> tuple[DQN, object]:
    # Plain DQN unless told (DQNLoss's arithmetic); a later override wins.
    experiment = compose_experiment(["env=discrete", "opponent=dijkstra", "algo=dqn", "noise=0.1",
                                     "algo.advantage_learning=0", *overrides])
    view = experiment.world.make(8, seed, experiment.device)
    torch.manual_seed(seed)
    return DQN(experiment.algo, view), view


def transitions(view, steps: int = 16):
    """``steps`` random steps of every world, as the replay buffer keeps them."""
    return view.rollout(steps, break_when_any_done=False).select(*TRANSITION_KEYS).reshape(-1)


def target_q(algo: DQN, observation: torch.Tensor) -> torch.Tensor:
    """Q of the loss's target parameters, swapped into the network the way ``DQNLoss`` runs them."""
    with torch.no_grad(), algo.loss.target_value_network_params.to_module(algo.loss.value_network):
        return algo.q_network(observation)


@pytest.mark.parametrize(
    "overrides",
    [(), ("algo.dueling=false", "algo.double_dqn=false"), ("algo.loss_function=l2", "algo.target_update=hard",
                                                           "algo.target_period=1")],
    ids=["dueling-double", "plain-single", "l2-hard"],
)
def test_the_gradient_step_is_dqnloss_arithmetic(overrides):
    ours, view = build(*overrides)
    theirs, _ = build(*overrides)
    sample = transitions(view)
    with torch.no_grad():  # target networks unlike the online ones, so the double-DQN choice and the target matter
        for algo in (ours, theirs):
            for tensor in algo.loss.target_value_network_params.values(True, True):
                tensor.mul_(0.5)
    for _ in range(3):
        torch.testing.assert_close(ours._gradient_step(sample.clone()), loss_module_step(theirs, sample.clone()))
    torch.testing.assert_close(ours.loss.state_dict(), theirs.loss.state_dict())


def test_advantage_learning_is_dqn_on_a_reward_less_the_action_gap():
    ours, view = build("algo.advantage_learning=0.9")
    theirs, _ = build()
    sample = transitions(view)
    for _ in range(3):
        q = target_q(theirs, sample["observation"])
        gap = q.amax(-1) - q.gather(-1, sample["action"].unsqueeze(-1)).squeeze(-1)
        assert bool((gap > 0).any())  # some taken actions are not the target network's best
        shifted = sample.clone()
        shifted["next", "reward"] = sample["next", "reward"] - 0.9 * gap.unsqueeze(-1)
        torch.testing.assert_close(ours._gradient_step(sample.clone()), loss_module_step(theirs, shifted))
    torch.testing.assert_close(ours.loss.state_dict(), theirs.loss.state_dict())


def test_the_target_network_follows_updates_and_loads():
    algo, view = build()
    sample = transitions(view)
    observation = sample["observation"]
    assert not list(algo.target_q_network.parameters())  # nothing of it trains
    for _ in range(2):
        algo._gradient_step(sample)
    torch.testing.assert_close(algo.target_q_network(observation), target_q(algo, observation), rtol=0, atol=0)
    other, _ = build(seed=1)
    algo.load_state_dict(other.state_dict())
    torch.testing.assert_close(algo.target_q_network(observation), target_q(other, observation), rtol=0, atol=0)


def test_a_checkpoint_of_the_per_tensor_adam_loads_and_steps_fused():
    old, view = build()
    old.optimizer = torch.optim.Adam(old.loss.parameters(), lr=old.config.lr)  # the optimiser before fused Adam
    sample = transitions(view)
    loss_module_step(old, sample)
    state = deepcopy(old.state_dict())  # as a checkpoint file holds it: no tensor shared with the old optimiser
    assert state["optimizers"]["adam"]["param_groups"][0]["fused"] is None

    new, _ = build(seed=1)
    new.load_state_dict(state)
    assert new.optimizer.param_groups[0]["fused"] is True
    torch.testing.assert_close(new.loss.state_dict(), old.loss.state_dict())
    torch.testing.assert_close(new._gradient_step(sample.clone()), loss_module_step(old, sample.clone()))
    torch.testing.assert_close(new.loss.state_dict(), old.loss.state_dict())
