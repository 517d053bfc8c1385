"""Each agent's own life cycle in the self-play view (SPEC §1, docs/multiagent.md), checked on scripted episodes of
the grid sidewalk: a crash ends the crasher alone, an arrival keeps the agent's value open for eq. 2's reward of a
later arrival, and TorchRL's own GAE, pointed at the view's per-agent keys, computes the hand-checked targets."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import step_mdp
from torchrl.objectives.value import GAE

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.grid import VECTOR_FIELDS
from sidewalk.envs.unicycle import OBSERVATION_FIELDS
from sidewalk.views import SelfPlayView

UP, DOWN, LEFT, RIGHT = range(4)
GAMMA = 0.9
KEYS = ("reward", "done", "terminated", "truncated")


def play(view: SelfPlayView, actions: list[list]) -> TensorDict:
    """Step ``view`` (one world) through the joint ``actions``; the transitions as the collector lays them out,
    (1, T). Steps after the world ended replay its last state (the view does not reset on its own)."""
    td = view.reset()
    steps = []
    for joint in actions:
        td.set(("agents", "action"), torch.as_tensor([joint]))
        td = view.step(td)
        steps.append(td.clone())
        td = step_mdp(td, reward_keys=view.reward_keys, done_keys=view.done_keys, action_keys=view.action_keys)
    return torch.stack(steps, dim=1)


def crash_episode(observation: str = "image") -> TensorDict:
    """Agent 1 walks UP off the grid at step 4 (index 3); agent 0 walks RIGHT and arrives alone at step 14."""
    view = SelfPlayView(DiscreteSidewalkEnv(1, seed=0, observation=observation))
    return play(view, [[RIGHT, UP]] * 14)


def later_arrival_episode() -> TensorDict:
    """Agent 1 steps UP out of the way and waits between rows 2 and 1; agent 0 arrives at step 14 (index 13); then
    agent 1 walks LEFT along row 1 and DOWN twice onto its goal, arriving at step 30 (index 29)."""
    view = SelfPlayView(DiscreteSidewalkEnv(1, seed=0))
    wait = [[RIGHT, UP]] + [[RIGHT, UP if step % 2 else DOWN] for step in range(1, 14)]
    return play(view, wait + [[RIGHT, LEFT]] * 14 + [[RIGHT, DOWN]] * 2)


def agent(td: TensorDict, key: str, index: int) -> torch.Tensor:
    return td.get(("next", "agents", key))[0, :, index, 0]


def test_a_crash_terminates_the_crasher_at_its_crash_step_and_masks_it_after_while_its_partner_goes_on():
    td = crash_episode()
    crash = 3
    terminated = agent(td, "terminated", 1)
    assert not terminated[:crash].any() and terminated[crash:].all()
    assert agent(td, "reward", 1)[crash] < -0.5 and (agent(td, "reward", 1)[crash + 1 :] == 0).all()
    mask = td.get(("agents", "info", "mask"))[0, :, 1, 0]  # the state each step is taken from
    assert mask[: crash + 1].all() and not mask[crash + 1 :].any()
    # the partner goes on: not done until it arrives, and the world ends with it
    assert not agent(td, "done", 0)[:13].any() and agent(td, "terminated", 0)[13]
    assert not td.get(("next", "done"))[0, :13].any() and td.get(("next", "terminated"))[0, 13]
    assert td.get(("agents", "info", "mask"))[0, :, 0, 0].all()


def test_the_explicit_reward_of_a_later_arrival_reaches_the_agent_that_arrived_first():
    td = later_arrival_episode()
    first, later = 13, 29
    info = td.get(("next", "world", "info", "reached_goal"))[0, :, :, 0]
    assert info[first, 0] and not info[first, 1] and info[later, 1]
    # agent 0's value stays open from its arrival to the world's end: not done, in play, paid 0 while it waits
    assert not agent(td, "done", 0)[:later].any() and td.get(("agents", "info", "mask"))[0, : later + 1, 0, 0].all()
    assert (agent(td, "reward", 0)[first + 1 : later] == 0).all()
    # the cooperative term of eq. 2 for agent 1's arrival (alpha * c_goal) reaches it at agent 1's arrival step
    assert agent(td, "reward", 0)[later] == pytest.approx(0.5)
    assert agent(td, "terminated", 0)[later] and agent(td, "terminated", 1)[later]


class ConstantValue(torch.nn.Module):
    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return torch.ones(*observation.shape[:-3], 1)


def torchrl_gae(lmbda: float) -> GAE:
    """TorchRL's GAE on the view's per-agent keys, with a critic worth 1 everywhere."""
    critic = TensorDictModule(ConstantValue(), in_keys=[("agents", "observation")], out_keys=[("agents", "state_value")])
    gae = GAE(gamma=GAMMA, lmbda=lmbda, value_network=critic, average_gae=False)
    gae.set_keys(
        reward=("agents", "reward"), done=("agents", "done"), terminated=("agents", "terminated"),
        value=("agents", "state_value"), advantage=("agents", "advantage"), value_target=("agents", "value_target"),
    )
    return gae


def test_torchrl_gae_on_the_views_keys_targets_a_crash_with_the_crash_reward_alone():
    td = crash_episode()
    with torch.no_grad():
        torchrl_gae(lmbda=0.0)(td)
    target = td.get(("agents", "value_target"))[0, :, :, 0]
    reward = td.get(("next", "agents", "reward"))[0, :, :, 0]
    crash = 3
    # TD(0) with V = 1: the crash step's target is its reward, no bootstrap from a crashed agent's next state ...
    assert target[crash, 1] == pytest.approx(float(reward[crash, 1]))
    # ... while the partner, still walking, bootstraps: r + gamma * V
    assert target[crash, 0] == pytest.approx(float(reward[crash, 0]) + GAMMA)


def test_torchrl_gae_on_the_views_keys_targets_an_arrival_with_the_later_arrival_still_to_come():
    td = later_arrival_episode()
    with torch.no_grad():
        torchrl_gae(lmbda=1.0)(td)
    target = td.get(("agents", "value_target"))[0, :, 0, 0]
    first, later = 13, 29
    # lambda = 1: agent 0's target at its arrival is its own goal reward plus the discounted +0.5 of agent 1's
    # arrival, 16 steps later (it is paid nothing in between); at the world's end, that reward alone
    arrival_reward = float(td.get(("next", "agents", "reward"))[0, first, 0, 0])
    assert target[first] == pytest.approx(arrival_reward + GAMMA**16 * 0.5, abs=1e-6)
    assert target[later] == pytest.approx(0.5)


@pytest.mark.parametrize("observation", ["image", "vector"])
def test_a_removed_agent_does_not_appear_in_the_others_grid_observations(observation):
    td = crash_episode(observation)
    crash = 3
    seen = td.get(("next", "agents", "observation"))[0, :, 0]  # agent 0's own view
    if observation == "image":
        alone = SelfPlayView(DiscreteSidewalkEnv(1, seed=0)).core._agent_grey[0, 1]  # agent 1's grey in 0's image
        assert (seen[crash - 1] == alone).any() and not (seen[crash:] == alone).any()
    else:
        other = seen.unflatten(-1, (2, len(VECTOR_FIELDS)))[:, 1]
        assert other[crash - 1].abs().sum() > 0 and (other[crash:] == 0).all()
        active = VECTOR_FIELDS.index("active")
        assert seen.unflatten(-1, (2, len(VECTOR_FIELDS)))[: crash - 1, 0, active].eq(1).all()


def test_continuous_observations_flag_who_is_active_and_present_and_zero_a_removed_agent():
    view = SelfPlayView(ContinuousSidewalkEnv(64, seed=0))
    torch.manual_seed(0)
    rollout = view.rollout(60, break_when_any_done=False)
    observation = rollout.get(("next", "agents", "observation"))
    per_agent = observation.unflatten(-1, (2, len(OBSERVATION_FIELDS)))  # (B, T, viewer, seen, fields)
    active, present = OBSERVATION_FIELDS.index("active"), OBSERVATION_FIELDS.index("present")
    world = rollout.get(("next", "world"))
    true_present = world.get("present")[..., 0]  # (B, T, N) in agent order; agent 0 sees itself first
    torch.testing.assert_close(per_agent[:, :, 0, :, present], true_present.float())
    info = world.get("info")
    done = (info.get("reached_goal") | info.get("collided_agent") | info.get("collided_wall"))[..., 0]
    torch.testing.assert_close(per_agent[:, :, 0, :, active], (~done).float())
    removed = ~true_present
    assert removed.any(), "no agent crashed out of 64 random worlds in 60 steps"
    assert (per_agent[:, :, 0][removed] == 0).all()
