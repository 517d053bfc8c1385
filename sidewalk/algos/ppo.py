"""PPO (clipped surrogate) from TorchRL parts: ``ClipPPOLoss`` with a GAE advantage, for both domains.

The networks are TRPO's (``sidewalk.algos.networks.on_policy_networks``), as in CleanRL's continuous PPO: a
state-independent log-std starting at 0, an output layer at 1 % of its default scale, observations standardised by
running statistics.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import NestedKey, TensorDictBase
from torchrl.envs import EnvBase
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from sidewalk._checks import check_int, check_range
from sidewalk.algos.base import AlgoConfig, Algorithm, StochasticActorPolicies
from sidewalk.algos.networks import on_policy_networks
from sidewalk.algos.replicas import broadcast_lead, clip_grad_norm_, logged, sample_mean, sample_std


@dataclass
class PPOConfig(AlgoConfig):
    """PPO settings; defaults after Schulman et al. 2017 / CleanRL's continuous-control preset (``ppo_continuous_action``,
    which also standardises observations)."""

    name: str = "ppo"
    frames_per_batch: int = 2048
    gamma: float = 0.99
    lr: float = 3e-4
    max_grad_norm: float = 0.5
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    epochs: int = 10
    minibatch_size: int = 64
    entropy_coef: float = 0.0
    critic_coef: float = 0.5
    hidden: list[int] = field(default_factory=lambda: [64, 64])
    normalize_observations: bool = True  # CleanRL: gym's NormalizeObservation; vectors only, not images
    mean_bound: float = 5.0  # TanhNormal's pre-squash mean within ±this (TorchRL's tanh_loc upscale); 0: unbounded
    default_num_envs: int = 128  # 16 steps of 128 worlds an iteration, as TRPO

    def __post_init__(self) -> None:
        super().__post_init__()
        check_range("algo.gae_lambda", self.gae_lambda, 0.0, 1.0)
        check_range("algo.clip_epsilon", self.clip_epsilon, 0.0, 1.0, low_open=True)
        check_int("algo.epochs", self.epochs, 1)
        check_int("algo.minibatch_size", self.minibatch_size, 1)
        check_range("algo.entropy_coef", self.entropy_coef, 0.0)
        check_range("algo.critic_coef", self.critic_coef, 0.0)
        check_range("algo.mean_bound", self.mean_bound, 0.0)
        for width in self.hidden:
            check_int("algo.hidden[]", width, 1)
        if not isinstance(self.normalize_observations, bool):
            raise TypeError(f"algo.normalize_observations={self.normalize_observations!r} must be a bool")


LOSS_LOGS = ("loss_objective", "loss_critic", "loss_entropy")


def clipped_ppo_update(
    algo: Algorithm,
    batch: TensorDictBase,
    observation_key: NestedKey,
    action_key: NestedKey,
    log_prob_key: NestedKey,
    log_keys: tuple[str, ...],
    mask_key: NestedKey | None = None,
) -> dict[str, float]:
    """One PPO update of ``algo`` (its ``advantage``, ``obs_norm``, ``actor``, ``loss``, ``optimizer``, minibatch
    ``_generator`` and ``config``) on a collected (worlds, time) batch: advantages, the observation statistics, the
    ratio's reference log-prob, then ``epochs`` passes of shuffled minibatches; returns the mean of each of
    ``log_keys`` the loss reports. Our PPO and the multi-agent IPPO/MAPPO share it, with their own keys.

    With ``mask_key`` (the multi-agent ``("agents", "info", "mask")``, bool (..., N, 1)), the advantages are standardised and
    the observation statistics gathered over the masked-in agent-steps only, and ``algo.loss`` is expected to read
    the same mask (``loss_mask_key``); without it the advantage estimator standardises (``average_gae``)."""
    cfg = algo.config
    lead = algo.lead
    algo.frames_seen += algo.frames_in(batch)
    batch = batch.to(algo.device)
    with torch.no_grad():
        algo.advantage(batch)  # GAE needs the (worlds, time) layout: time is the last batch dimension
        if lead:  # each replica's advantages standardised over its own batch (GAE's average_gae is off)
            advantage = batch.get(algo.advantage.tensor_keys.advantage)
            mean = broadcast_lead(sample_mean(advantage, lead), advantage)
            batch.set(algo.advantage.tensor_keys.advantage, (advantage - mean) / (sample_std(advantage, lead) + 1e-8))
        if mask_key is not None:
            mask = batch.get(mask_key)
            advantage = batch.get(algo.advantage.tensor_keys.advantage)
            kept = advantage[mask.expand_as(advantage)]
            if kept.numel() > 1:
                batch.set(algo.advantage.tensor_keys.advantage, (advantage - kept.mean()) / kept.std().clamp_min(1e-6))
    flat = batch.reshape(*lead, -1)
    if algo.obs_norm is not None:
        observation = flat.get(observation_key)
        if mask_key is not None:
            observation = observation[flat.get(mask_key).squeeze(-1)]
        algo.obs_norm.update(observation)
    with torch.no_grad():
        # The ratio's reference: the policy as it is now, after the statistics moved (TRPO's snapshot does the
        # same), so the first minibatch starts at ratio 1.
        dist = algo.actor.get_dist(flat.copy())
        flat.set(log_prob_key, dist.log_prob(flat.get(action_key)))
    logs: dict[str, list[torch.Tensor]] = {key: [] for key in log_keys}
    samples = flat.shape[len(lead)]
    for _ in range(cfg.epochs):
        order = torch.randperm(samples, generator=algo._generator).to(algo.device)
        for start in range(0, samples, cfg.minibatch_size):
            # The same minibatch places in every replica's batch.
            minibatch = flat[(slice(None),) * len(lead) + (order[start : start + cfg.minibatch_size],)]
            losses = algo.loss(minibatch)
            if lead:  # the loss reduces nothing (reduction="none"): each replica's mean is its own loss
                losses = {key: sample_mean(value, lead) for key, value in losses.items() if key in log_keys
                          or key.startswith("loss_")}
            loss = sum(value for key, value in losses.items() if key.startswith("loss_"))
            algo.optimizer.zero_grad(set_to_none=True)
            loss.sum().backward()
            clip_grad_norm_(algo.loss.parameters(), cfg.max_grad_norm, lead)
            algo.optimizer.step()
            for key, values in logs.items():
                if key in losses:
                    values.append(losses[key].detach())
    return {key: logged(torch.stack(values).mean(0), lead) for key, values in logs.items() if values}


class ClippedPPOMixin(StochasticActorPolicies):
    """What the learners that ``clipped_ppo_update`` updates (PPO, IPPO and theirs) hold alike around their own
    networks and ``loss``: one Adam, the minibatch generator the checkpoint keeps, a sampling and a deterministic
    policy. Mixed in before ``Algorithm`` (or ``MultiAgentAlgorithm``); ``_build`` ends with ``_build_update``."""

    def _build_update(self) -> None:
        # foreach: see TRPO's value optimizer
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=self.config.lr, foreach=True)
        self._generator = torch.Generator().manual_seed(0)
        self._build_policies()

    def modules(self) -> dict[str, torch.nn.Module]:
        return {"loss": self.loss}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"adam": self.optimizer}

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "minibatch_rng": self._generator.get_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self._generator.set_state(state["minibatch_rng"])


class PPO(ClippedPPOMixin, Algorithm):
    """Clipped PPO with a separate critic; advantages by GAE over each collected (worlds, time) batch."""

    name = "ppo"
    domains = ("discrete", "continuous")
    Config = PPOConfig
    replicable = True

    def _build(self, env: EnvBase) -> None:
        cfg: PPOConfig = self.config
        actor, critic, self.obs_norm = on_policy_networks(
            self.observation_spec, self.action_spec, cfg.hidden, cfg.hidden, cfg.normalize_observations, cfg.mean_bound,
            replicas=self.replicas,
        )
        self.actor, self.critic = actor.to(self.device), critic.to(self.device)
        self.advantage = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=self.critic,
                             average_gae=not self.replicas)
        self.loss = ClipPPOLoss(
            self.actor, self.critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coef,
            critic_coeff=cfg.critic_coef, normalize_advantage=False, reduction="none" if self.replicas else "mean",
        )
        self._build_update()

    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        return clipped_ppo_update(self, batch, "observation", "action", self.loss.tensor_keys.sample_log_prob, LOSS_LOGS)
