"""PPO-Lagrangian (Ray, Achiam & Amodei 2019, "Benchmarking Safe Exploration"), as OmniSafe's ``PPOLag`` builds it.

The learner is our PPO (``sidewalk.algos.ppo``) with three additions, read from OmniSafe's
``omnisafe/algorithms/on_policy/naive_lagrange/ppo_lag.py`` and ``omnisafe/common/lagrange.py``:

- a cost critic, the reward critic's architecture with its own weights, regressed on a GAE value target whose
  reward is the view's safety cost ``("next", "cost")``: TorchRL's ``GAE`` with its reward, value and output keys
  pointed at the cost;
- a Lagrange multiplier λ ≥ 0 on the expected episode cost J_c, stepped by its own Adam on ``-λ·(J_c - cost_limit)``
  once per batch, before the policy moves (OmniSafe's order), then clamped to [0, ``lambda_upper_bound``];
- the policy's advantage ``(A_r - λ·A_c) / (1 + λ)``, so a large λ turns the surrogate towards the cost without
  inflating its scale.

J_c is the mean cost of the episodes that ended in the batch, each counted with its whole cost: a per-world
accumulator carries an unfinished episode's cost across batches (ours are 16 steps of 128 worlds; an episode lasts
longer). PPO's update itself runs unchanged: ``self.advantage`` computes both advantages and combines them, and
``self.loss`` adds the cost critic's term to ``ClipPPOLoss``'s, so PPO's minibatch loop trains all three networks.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs import EnvBase
from torchrl.modules import ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.utils import distance_loss
from torchrl.objectives.value import GAE

from sidewalk._checks import check_range
from sidewalk.algos.ppo import PPO, PPOConfig

COST = "cost"  # the views' per-step safety cost, read at ("next", COST)
COST_VALUE = "state_cost_value"  # the cost critic's output, beside the reward critic's "state_value"
COST_ADVANTAGE = "cost_advantage"
COST_VALUE_TARGET = "cost_value_target"
REWARD_ADVANTAGE = "reward_advantage"  # A_r, kept beside the combined "advantage" the PPO loss reads


@dataclass
class PPOLagrangianConfig(PPOConfig):
    """PPO-Lagrangian settings. The PPO underneath keeps ``PPOConfig``'s defaults, so ``ppo_lagrangian`` differs from
    ``ppo`` by the constraint alone. The Lagrangian's defaults are OmniSafe's ``PPOLag`` preset,
    ``omnisafe/configs/on-policy/PPOLag.yaml`` (``lagrange_cfgs`` and ``algo_cfgs``), but the cost limit:

    - ``cost_limit`` 0.05 (OmniSafe 25.0, Safety Gymnasium's budget of 25 cost-steps in a 1000-step episode). Here
      an episode's cost is 0 or 1 (with ``env.cost=collision`` and ``env.remove_crashed=true``, the defaults, the
      learner's agent collides once or not at all), so J_c is the fraction of episodes in which it collides: 0.05
      allows 5 %.
      The centralized view sums its agents' costs, so there J_c counts colliding agents per episode;
    - ``lambda_init`` 0.001: ``lagrangian_multiplier_init``;
    - ``lambda_lr`` 0.035: ``lambda_lr``, for an Adam (``lambda_optimizer: Adam``);
    - ``lambda_upper_bound`` inf: ``lagrangian_upper_bound`` is absent from the preset and ``Lagrange`` defaults it
      to None, an unbounded λ;
    - ``cost_gamma`` 0.99 and ``cost_gae_lambda`` 0.95: ``cost_gamma`` and ``lam_c``.

    J_c differs in one respect: OmniSafe averages the last ``window_lens`` = 100 finished episodes
    (``logger_cfgs``), across epochs; ours averages the episodes finished since the last update (at 128 worlds ×
    16 steps, 75-125 a batch under the untrained policy against dijkstra and prm: about OmniSafe's window). A batch
    in which no episode ended keeps the last estimate, so λ keeps moving the way it last moved; before the first
    episode ends there is no estimate and λ stays at its start.

    Also as OmniSafe (``standardized_rew_adv``, ``standardized_cost_adv``): A_r is standardised (PPO's GAE already
    does, ``average_gae``), A_c only centred, so λ weighs the cost advantage at its own scale.
    """

    name: str = "ppo_lagrangian"
    cost_limit: float = 0.05
    lambda_init: float = 0.001
    lambda_lr: float = 0.035
    lambda_upper_bound: float = math.inf
    cost_gamma: float = 0.99
    cost_gae_lambda: float = 0.95

    def __post_init__(self) -> None:
        super().__post_init__()
        check_range("algo.cost_limit", self.cost_limit, 0.0)
        check_range("algo.lambda_init", self.lambda_init, 0.0)
        check_range("algo.lambda_lr", self.lambda_lr, 0.0, low_open=True)
        check_range("algo.lambda_upper_bound", self.lambda_upper_bound, 0.0, low_open=True)
        if self.lambda_init > self.lambda_upper_bound:
            raise ValueError(
                f"algo.lambda_init={self.lambda_init} is above algo.lambda_upper_bound={self.lambda_upper_bound}"
            )
        check_range("algo.cost_gamma", self.cost_gamma, 0.0, 1.0)
        check_range("algo.cost_gae_lambda", self.cost_gae_lambda, 0.0, 1.0)


class Lagrange(nn.Module):
    """λ ≥ 0 and its Adam, as OmniSafe's ``Lagrange``: ``step(J_c)`` descends ``-λ·(J_c - cost_limit)`` -- λ grows
    while the constraint is violated and shrinks while it holds -- then clamps λ to [0, ``upper_bound``]."""

    def __init__(self, cost_limit: float, init: float, lr: float, upper_bound: float = math.inf) -> None:
        super().__init__()
        self.cost_limit = cost_limit
        self.upper_bound = upper_bound
        self.multiplier = nn.Parameter(torch.tensor(max(init, 0.0)))
        self.optimizer = torch.optim.Adam([self.multiplier], lr=lr)

    def step(self, episode_cost: float) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        loss = -self.multiplier * (episode_cost - self.cost_limit)
        loss.backward()
        self.optimizer.step()
        with torch.no_grad():
            self.multiplier.clamp_(0.0, self.upper_bound)

    def forward(self) -> torch.Tensor:
        return self.multiplier.detach()


class CostCriticLoss(nn.Module):
    """``ClipPPOLoss``'s terms plus ``loss_cost_critic``: the cost critic against its GAE target, with the reward
    critic's distance and coefficient, so the two critics are trained alike. Each minibatch's cost-critic loss is
    kept in ``cost_critic_losses`` (PPO's loop logs only its own terms)."""

    def __init__(self, ppo_loss: ClipPPOLoss, cost_critic: ValueOperator, critic_coef: float) -> None:
        super().__init__()
        self.ppo = ppo_loss
        self.cost_critic = cost_critic
        self.critic_coef = critic_coef
        self.cost_critic_losses: list[torch.Tensor] = []

    @property
    def tensor_keys(self):
        return self.ppo.tensor_keys

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        losses = self.ppo(tensordict)
        value = self.cost_critic(tensordict.select(*self.cost_critic.in_keys)).get(COST_VALUE)
        distance = distance_loss(tensordict.get(COST_VALUE_TARGET), value, loss_function=self.ppo.loss_critic_type)
        loss = self.critic_coef * distance.mean()
        self.cost_critic_losses.append(loss.detach())
        losses.set("loss_cost_critic", loss)
        return losses


class PPOLagrangian(PPO):
    """PPO with a cost critic and a Lagrange multiplier on the episode cost (see the module docstring)."""

    name = "ppo_lagrangian"
    domains = ("discrete", "continuous")
    Config = PPOLagrangianConfig
    replicable = False  # its multiplier and cost critic have no replica axis yet: replicas train one after another

    def _build(self, env: EnvBase) -> None:
        super()._build(env)
        cfg: PPOLagrangianConfig = self.config
        # The reward critic's architecture with fresh weights; the running observation statistics stay one object,
        # which PPO's update moves for all three networks.
        shared = {id(self.obs_norm): self.obs_norm} if self.obs_norm is not None else {}
        cost_net = copy.deepcopy(self.critic.module, memo=shared)
        for layer in cost_net.modules():
            if layer is not self.obs_norm and hasattr(layer, "reset_parameters"):
                layer.reset_parameters()
        self.cost_critic = ValueOperator(cost_net, in_keys=["observation"], out_keys=[COST_VALUE]).to(self.device)
        self.cost_gae = GAE(
            gamma=cfg.cost_gamma, lmbda=cfg.cost_gae_lambda, value_network=self.cost_critic, average_gae=False
        )
        self.cost_gae.set_keys(
            reward=COST, value=COST_VALUE, advantage=COST_ADVANTAGE, value_target=COST_VALUE_TARGET
        )
        self.reward_gae = self.advantage
        self.advantage = self._advantages  # what PPO's update calls on the (worlds, time) batch
        self.loss = CostCriticLoss(self.loss, self.cost_critic, cfg.critic_coef)
        # One Adam and one gradient clip over policy and both critics, as PPO has for policy and critic.
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.lr, foreach=True)
        self.lagrange = Lagrange(cfg.cost_limit, cfg.lambda_init, cfg.lambda_lr, cfg.lambda_upper_bound).to(self.device)
        # Per world, since its last reset; sized by the first batch: the learner's own worlds, a replica's block of a
        # group's env (replicas=R) or the whole env alone.
        self.running_episode_cost: torch.Tensor | None = None
        self.episode_cost = math.nan  # J_c: none until an episode ends

    @property
    def lagrange_multiplier(self) -> float:
        return float(self.lagrange())

    def combined_advantage(self, reward_advantage: torch.Tensor, cost_advantage: torch.Tensor) -> torch.Tensor:
        """OmniSafe's ``_compute_adv_surrogate``: ``(A_r - λ·A_c) / (1 + λ)`` at the current λ."""
        penalty = self.lagrange()
        return (reward_advantage - penalty * cost_advantage) / (1 + penalty)

    def _advantages(self, batch: TensorDictBase) -> TensorDictBase:
        self.reward_gae(batch)
        self.cost_gae(batch)
        reward_advantage = batch.get("advantage")
        cost_advantage = batch.get(COST_ADVANTAGE)
        cost_advantage = cost_advantage - cost_advantage.mean()  # centred, not scaled: OmniSafe's standardized_cost_adv
        batch.set(COST_ADVANTAGE, cost_advantage)
        batch.set(REWARD_ADVANTAGE, reward_advantage)
        batch.set("advantage", self.combined_advantage(reward_advantage, cost_advantage))
        return batch

    def finished_episode_costs(self, batch: TensorDictBase) -> torch.Tensor:
        """The whole cost of every episode that ended in ``batch`` (worlds, time), in order of ending step; the cost
        of an episode still running carries over to the next batch."""
        cost = batch.get(("next", COST)).squeeze(-1).to(self.device, torch.float32)
        done = batch.get(("next", "done")).squeeze(-1).to(self.device)
        if self.running_episode_cost is None:
            self.running_episode_cost = torch.zeros(cost.shape[:-1], device=self.device)
        if cost.shape[:-1] != self.running_episode_cost.shape:
            raise ValueError(
                f"a batch of {tuple(cost.shape[:-1])} worlds × {cost.shape[-1]} steps, but this learner keeps the "
                f"running episode cost of {tuple(self.running_episode_cost.shape)} worlds (its first batch's)"
            )
        running, finished = self.running_episode_cost, []
        for t in range(cost.shape[-1]):
            running = running + cost[..., t]
            finished.append(running[done[..., t]])
            running = torch.where(done[..., t], torch.zeros_like(running), running)
        self.running_episode_cost = running
        return torch.cat(finished)

    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        finished = self.finished_episode_costs(batch)
        if finished.numel():
            self.episode_cost = float(finished.mean())
        if not math.isnan(self.episode_cost):
            self.lagrange.step(self.episode_cost)  # λ first, so this update's advantages weigh the cost by it
        self.loss.cost_critic_losses.clear()
        logs = super().update(batch)
        logs["loss_cost_critic"] = float(torch.stack(self.loss.cost_critic_losses).mean())
        logs["lagrange_multiplier"] = self.lagrange_multiplier
        logs["episode_cost"] = self.episode_cost
        return logs

    def modules(self) -> dict[str, nn.Module]:
        return {**super().modules(), "lagrange": self.lagrange}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {**super().optimizers(), "lagrange_adam": self.lagrange.optimizer}

    def state_dict(self) -> dict[str, Any]:
        return {
            **super().state_dict(),
            "running_episode_cost": None if self.running_episode_cost is None else self.running_episode_cost.clone(),
            "episode_cost": self.episode_cost,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        held = state["running_episode_cost"]
        self.running_episode_cost = None if held is None else held.to(self.device).clone()
        self.episode_cost = state["episode_cost"]
