"""Two agents learn the continuous sidewalk in self-play with TorchRL's parts only (docs/multiagent.md).

Nothing of sidewalk's learners is used: the self-play view's per-agent keys -- each agent's own ``done``/
``terminated`` and ``("agents", "info", "mask")`` -- are all TorchRL's ``GAE`` and ``ClipPPOLoss`` need to end each agent's
return at its own crash and to leave its later steps out of the loss. Settings a user may choose: TorchRL's
``mappo_ippo`` example's networks (``MultiAgentMLP``, shared parameters, tanh), ``TanhNormal`` with a bounded mean,
no observation normalisation, and the dense progress shaping of ``reward.c_progress``.

    python docs/examples/torchrl_selfplay_ppo.py                 # ~100 iterations, a few minutes on one core
    python docs/examples/torchrl_selfplay_ppo.py --iterations 2  # smoke test
"""

from __future__ import annotations

import argparse

import torch
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from sidewalk.envs import ContinuousSidewalkEnv
from sidewalk.views import SelfPlayView

OBS, ACTION, MASK = ("agents", "observation"), ("agents", "action"), ("agents", "info", "mask")


def make_env(num_envs: int, seed: int) -> EnvBase:
    return SelfPlayView(ContinuousSidewalkEnv(num_envs=num_envs, seed=seed, rewards={"c_progress": 0.1}))


def team_success(env: EnvBase, actor: ProbabilisticActor) -> float:
    """The share of worlds where every agent reached its goal, acting greedily for one episode."""
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(300, actor, break_when_all_done=True, break_when_any_done=False)
    reached = rollout.get(("next", "world", "info", "reached_goal"))[:, -1]  # sticky flags at the last step
    return float(reached.all(-2).float().mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)

    env = make_env(num_envs=128, seed=args.seed)
    evaluation_env = make_env(num_envs=256, seed=args.seed + 1)  # its own worlds: the collector's stay as they were
    n_agents = env.n_agents
    obs_size = env.full_observation_spec_unbatched[OBS].shape[-1]
    action_spec = env.full_action_spec_unbatched[ACTION]

    policy_net = nn.Sequential(
        MultiAgentMLP(obs_size, 2, n_agents, centralized=False, share_params=True, num_cells=[64, 64],
                      activation_class=nn.Tanh),
        AddStateIndependentNormalScale(2, scale_mapping="exp"),
    )
    actor = ProbabilisticActor(
        TensorDictModule(policy_net, in_keys=[OBS], out_keys=[("agents", "loc"), ("agents", "scale")]),
        in_keys=[("agents", "loc"), ("agents", "scale")],
        out_keys=[ACTION],
        spec=env.full_action_spec_unbatched,
        distribution_class=TanhNormal,
        # tanh_loc bounds the pre-squash mean: unbounded, it ran to where every sample is the bound.
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high, "tanh_loc": True},
        return_log_prob=True,
        log_prob_key=("agents", "action_log_prob"),
    )
    critic = ValueOperator(
        MultiAgentMLP(obs_size, 1, n_agents, centralized=False, share_params=True, num_cells=[64, 64],
                      activation_class=nn.Tanh),
        in_keys=[OBS], out_keys=[("agents", "state_value")],
    )

    keys = {"reward": ("agents", "reward"), "done": ("agents", "done"), "terminated": ("agents", "terminated"),
            "value": ("agents", "state_value"), "advantage": ("agents", "advantage"),
            "value_target": ("agents", "value_target")}
    advantage = GAE(gamma=0.99, lmbda=0.95, value_network=critic, average_gae=False)
    advantage.set_keys(**keys)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.0, normalize_advantage=True,
                       normalize_advantage_exclude_dims=(-2,))  # per agent
    loss.set_keys(action=ACTION, sample_log_prob=("agents", "action_log_prob"), **keys)
    loss.loss_mask_key = MASK  # each agent's steps after its own end carry no learning signal
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-4)

    collector = Collector(env, actor, frames_per_batch=2048, total_frames=2048 * args.iterations,
                          auto_register_policy_transforms=False)
    for iteration, batch in enumerate(collector, start=1):
        with torch.no_grad():
            advantage(batch)
        flat = batch.reshape(-1)
        for _ in range(10):  # epochs of shuffled minibatches of 256 world-steps
            for index in torch.randperm(flat.numel()).split(256):
                losses = loss(flat[index])
                total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                optimizer.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 0.5)
                optimizer.step()
        if iteration % 10 == 0 or iteration == args.iterations:
            success = team_success(evaluation_env, actor)
            print(f"iteration {iteration:4d}  frames {iteration * 2048:8d}  team success {success:.2f}", flush=True)
    collector.shutdown()


if __name__ == "__main__":
    main()
