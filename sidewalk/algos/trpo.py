"""Trust Region Policy Optimization (Schulman et al. 2015), the paper's learner for the continuous domain (§6.1).

TorchRL has no TRPO; this one is built from its parts, following OpenAI baselines' ``trpo_mpi`` (the code the paper
ran) and sb3-contrib's TRPO:

- a ``ProbabilisticActor`` (``TanhNormal`` within the action bounds, or ``Categorical``) over an MLP, and a
  separate ``ValueOperator``; vector observations are standardised by running statistics, images go through the
  paper's conv encoder;
- advantages from TorchRL's ``GAE``, standardised per batch;
- ``TRPOLoss``: the importance-weighted surrogate, the mean KL(old ‖ new) and Fisher-vector products (the Hessian
  of that KL, by double backward);
- ``trpo_step``: conjugate gradient for the natural-gradient direction, the step that reaches the KL bound under
  the quadratic model, and a backtracking line search that keeps only a step whose measured KL is within the
  bound and whose surrogate improves;
- then a few epochs of Adam regression of the value function on the GAE returns.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torch.distributions import kl_divergence
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor
from torchrl.objectives import LossModule
from torchrl.objectives.value import GAE

from sidewalk._checks import check_int, check_range
from sidewalk.algos.base import AlgoConfig, Algorithm, StochasticActorPolicies
from sidewalk.algos.networks import on_policy_networks
from sidewalk.algos.replicas import (
    assign_flat_,
    broadcast_lead,
    clip_grad_norm_,
    flat_vector,
    logged,
    mse_per_replica,
    rowwise_dot,
    sample_mean,
    sample_std,
    sample_var,
)

OLD_POLICY = "old_policy"  # where ``TRPOLoss.snapshot`` keeps the frozen distribution's parameters


@dataclass
class TRPOConfig(AlgoConfig):
    """TRPO's settings. Defaults: OpenAI baselines' ``trpo_mpi`` mujoco preset (``defaults.mujoco()``, the code the
    paper ran) unless a comment says otherwise.

    ``lr`` is the value function's Adam step: the policy moves by the trust-region step, not by a learning rate
    (sb3-contrib's TRPO uses its ``learning_rate`` the same way).
    """

    name: str = "trpo"
    # Ours (baselines: 1024 frames from one env): 128 worlds × 16 steps collect 2048 for the cost of ~16 env steps.
    # The centralized learner still settles on one agent crashing out of the way on some seeds at any batch tried
    # (1024: 2 of 5 at 500 iterations; 2048: 3 of 5 in results/reference/, whose notes give the step cost's part).
    frames_per_batch: int = 2048
    default_num_envs: int = 128
    gamma: float = 0.99  # baselines gamma
    lr: float = 1e-3  # baselines vf_stepsize
    max_grad_norm: float = math.inf  # value-function gradient clip; baselines and sb3-contrib do not clip
    # Paper §6.1 and baselines mlp(num_hidden=32, num_layers=2): two tanh layers of 32; the value MLP mirrors it.
    policy_hidden: list[int] = field(default_factory=lambda: [32, 32])
    value_hidden: list[int] = field(default_factory=lambda: [32, 32])
    max_kl: float = 0.01  # baselines max_kl: the trust region, mean KL(old ‖ new) per step
    cg_iters: int = 10  # baselines cg_iters
    cg_damping: float = 0.1  # baselines cg_damping: F + λI keeps conjugate gradient well posed
    gae_lambda: float = 0.98  # baselines lam
    vf_iters: int = 5  # baselines vf_iters: epochs of value regression per batch
    # Baselines: minibatches of 64 from 1024 frames, i.e. 16 Adam steps an epoch; 128 keeps that count at our 2048
    # frames (at 64 the value fit was half of an iteration's time, with no better learning: 0.84/0.86 vs 0.83/0.86
    # success against the random agent, 2 of 2 hard centralized seeds either way).
    vf_batch_size: int = 128
    entropy_coef: float = 0.0  # baselines entcoeff
    line_search_steps: int = 10  # baselines: at most 10 backtracking steps
    line_search_shrink: float = 0.5  # baselines: the step halves on each backtrack
    fvp_subsample: int = 5  # baselines: Fisher-vector products on every 5th sample (fvpargs = arr[::5])
    normalize_observations: bool = True  # baselines mujoco preset; applies to vector observations, not images

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("policy_hidden", "value_hidden"):
            for index, width in enumerate(getattr(self, name)):
                check_int(f"algo.{name}[{index}]", width, 1)
        check_range("algo.max_kl", self.max_kl, 0.0, low_open=True)
        check_int("algo.cg_iters", self.cg_iters, 1)
        check_range("algo.cg_damping", self.cg_damping, 0.0)
        check_range("algo.gae_lambda", self.gae_lambda, 0.0, 1.0)
        check_int("algo.vf_iters", self.vf_iters, 0)
        check_int("algo.vf_batch_size", self.vf_batch_size, 1)
        check_range("algo.entropy_coef", self.entropy_coef, 0.0)
        check_int("algo.line_search_steps", self.line_search_steps, 1)
        check_range("algo.line_search_shrink", self.line_search_shrink, 0.0, 1.0, low_open=True)
        check_int("algo.fvp_subsample", self.fvp_subsample, 1)
        if not isinstance(self.normalize_observations, bool):
            raise TypeError(f"algo.normalize_observations={self.normalize_observations!r} must be a bool")


def conjugate_gradient(
    matvec: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor, iters: int, residual_tol: float = 1e-10
) -> torch.Tensor:
    """Approximately solve ``A x = b`` for a symmetric positive-definite ``A`` known only through ``x ↦ A x``.

    Plain conjugate gradient from ``x = 0``: exact after ``len(b)`` iterations in exact arithmetic; stops early
    once the squared residual falls below ``residual_tol``. ``b`` (P,), or (R, P) for R systems at once (a replicated
    learner's), each row stopping where it alone would.
    """
    x = torch.zeros_like(b)
    residual = b.clone()
    direction = b.clone()
    residual_sq = rowwise_dot(residual, residual)
    for _ in range(iters):
        running = residual_sq >= residual_tol
        if not running.any():
            break
        a_direction = matvec(direction)
        alpha = (residual_sq / rowwise_dot(direction, a_direction)).unsqueeze(-1)
        new_x, new_residual = x + alpha * direction, residual - alpha * a_direction
        new_residual_sq = rowwise_dot(new_residual, new_residual)
        new_direction = new_residual + (new_residual_sq / residual_sq).unsqueeze(-1) * direction
        keep = running.unsqueeze(-1)
        x, residual = torch.where(keep, new_x, x), torch.where(keep, new_residual, residual)
        direction = torch.where(keep, new_direction, direction)
        residual_sq = torch.where(running, new_residual_sq, residual_sq)
    return x


def _entropy(
    dist: torch.distributions.Distribution, log_prob: torch.Tensor, ratio: torch.Tensor
) -> torch.Tensor:
    """The analytic entropy where the distribution has one; else the importance-weighted estimate at the taken
    actions, E_old[ratio · (−log π)], which equals the entropy in expectation and has no sampling noise of its own
    (TanhNormal has no closed form)."""
    try:
        return dist.entropy()
    except NotImplementedError:
        return -(ratio * log_prob)


def mean_kl(
    old_dist: torch.distributions.Distribution, dist: torch.distributions.Distribution
) -> torch.Tensor:
    """KL(old ‖ new) averaged over the last batch dimension (the samples): a scalar for one learner, (R,) for R."""
    return kl_divergence(old_dist, dist).mean(-1)


def surrogate_terms(
    dist: torch.distributions.Distribution,
    old_dist: torch.distributions.Distribution,
    action: torch.Tensor,
    old_log_prob: torch.Tensor,
    advantage: torch.Tensor,
    entropy_coef: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``TRPOLoss``'s terms, averaged over the last batch dimension (the samples), so that one learner's (N,) batch
    and R replicas' (R, N) batches share the arithmetic: (minus the surrogate, mean KL(old ‖ new), entropy)."""
    log_prob = dist.log_prob(action)
    ratio = (log_prob - old_log_prob).exp()
    entropy = _entropy(dist, log_prob, ratio).mean(-1)
    surrogate = (ratio * advantage.reshape(ratio.shape)).mean(-1) + entropy_coef * entropy
    return -surrogate, mean_kl(old_dist, dist), entropy.detach()


class TRPOLoss(LossModule):
    """TRPO's objective for a stochastic ``actor_network`` (a ``ProbabilisticActor``), against a frozen old policy.

    Reads ``observation``, ``action``, ``advantage``, and what ``snapshot`` writes: ``action_log_prob`` (the old
    policy's log-probability of ``action``) and ``"old_policy"`` (the old distribution's parameters). ``forward``
    returns ``loss_objective`` (minus the surrogate ``mean(ratio · advantage) + entropy_coef · entropy``), ``kl``
    (mean KL(old ‖ new)) and ``entropy``. The update itself is ``trpo_step``.
    """

    def __init__(
        self, actor_network: ProbabilisticActor, *, entropy_coef: float = 0.0, cg_damping: float = 0.1
    ) -> None:
        super().__init__()
        self.actor_network = actor_network
        self.entropy_coef = entropy_coef
        self.cg_damping = cg_damping

    @property
    def policy_parameters(self) -> list[nn.Parameter]:
        """The parameters the trust-region step moves (every trainable parameter of the actor)."""
        return [param for param in self.actor_network.parameters() if param.requires_grad]

    @torch.no_grad()
    def snapshot(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Freeze the current policy as the old one: write its distribution parameters under ``"old_policy"`` and
        its log-probability of ``action`` under ``action_log_prob``, in place; return ``tensordict``."""
        params = self.actor_network.get_dist_params(tensordict.copy()).select(
            *self.actor_network.dist_params_keys
        )
        tensordict.set(OLD_POLICY, params)
        old_dist = self.actor_network.build_dist_from_params(params)
        tensordict.set("action_log_prob", old_dist.log_prob(tensordict.get("action")))
        return tensordict

    def _dist(self, tensordict: TensorDictBase) -> torch.distributions.Distribution:
        # A shallow copy, so the new policy's parameters are not written into the caller's tensordict.
        return self.actor_network.get_dist(tensordict.copy())

    def kl(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Mean KL(old ‖ new) over ``tensordict``'s samples; differentiable in the actor's parameters."""
        old_dist = self.actor_network.build_dist_from_params(tensordict.get(OLD_POLICY))
        return mean_kl(old_dist, self._dist(tensordict))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        dist = self._dist(tensordict)
        old_dist = self.actor_network.build_dist_from_params(tensordict.get(OLD_POLICY))
        loss_objective, kl, entropy = surrogate_terms(
            dist, old_dist, tensordict.get("action"), tensordict.get("action_log_prob"),
            tensordict.get("advantage"), self.entropy_coef,
        )
        return TensorDict(loss_objective=loss_objective, kl=kl, entropy=entropy, batch_size=[])

    def fisher_operator(self, tensordict: TensorDictBase) -> Callable[[torch.Tensor], torch.Tensor]:
        """``v ↦ (F + cg_damping · I) v`` at the current parameters, F the Hessian of ``kl`` on ``tensordict``.

        At new = old that Hessian is the Fisher information of the policy. The KL's gradient graph is built once,
        so each product costs one backward pass.
        """
        params, damping = self.policy_parameters, self.cg_damping
        kl = self.kl(tensordict)
        lead = tuple(kl.shape)  # () for one learner, (R,) for R replicas: each replica's KL is its own
        kl_grad = torch.autograd.grad(kl.sum(), params, create_graph=True, materialize_grads=True)
        kl_grad = flat_vector(kl_grad, lead)

        def product(vector: torch.Tensor) -> torch.Tensor:
            hessian_vector = torch.autograd.grad(
                rowwise_dot(kl_grad, vector).sum(), params, retain_graph=True, materialize_grads=True
            )
            return flat_vector(hessian_vector, lead) + damping * vector

        return product


def trpo_step(
    loss: TRPOLoss,
    tensordict: TensorDictBase,
    *,
    max_kl: float,
    cg_iters: int,
    line_search_steps: int,
    line_search_shrink: float,
    fvp_subsample: int = 1,
) -> dict[str, float | torch.Tensor]:
    """One trust-region update of ``loss.actor_network`` on a flat batch prepared by ``TRPOLoss.snapshot``: (N,)
    samples, or (R, N) for a replicated actor, whose replicas each take their own step.

    The parameters move by the largest step along the natural gradient, shrunk by ``line_search_shrink`` until the
    measured mean KL(old ‖ new) is at most ``max_kl`` and the surrogate improves; if none of ``line_search_steps``
    tries qualifies, they are left exactly as they were. Returns ``kl``, ``surrogate_improvement`` and
    ``expected_improvement`` (of the step taken; 0 when none), ``step_accepted`` (1.0 or 0.0), ``step_fraction``
    (of the full step) and ``entropy`` (of the old policy): floats, or (R,) tensors for R replicas.
    """
    params = loss.policy_parameters
    before = loss(tensordict)
    lead = tuple(before["loss_objective"].shape)
    old_params = flat_vector(params, lead).detach()
    zeros = torch.zeros(lead, dtype=torch.float64, device=old_params.device)
    logs = dict.fromkeys(("kl", "surrogate_improvement", "expected_improvement", "step_accepted", "step_fraction"),
                         zeros)
    logs["entropy"] = before["entropy"]
    gradient = torch.autograd.grad(-before["loss_objective"].sum(), params, materialize_grads=True)
    gradient = flat_vector(gradient, lead)
    movable = torch.isfinite(gradient).all(-1) & gradient.any(-1)
    if movable.any():
        # Natural-gradient direction F⁻¹g, and the step that reaches the KL bound under the quadratic model ½ sᵀFs.
        gradient = torch.where(movable.unsqueeze(-1), gradient, torch.zeros_like(gradient))
        fisher = loss.fisher_operator(tensordict[(slice(None),) * len(lead) + (slice(None, None, fvp_subsample),)])
        direction = conjugate_gradient(fisher, gradient, cg_iters)
        curvature = rowwise_dot(direction, fisher(direction))
        movable = movable & (curvature > 0)
    if movable.any():
        full_step = torch.sqrt(2 * max_kl / curvature.clamp_min(1e-30)).unsqueeze(-1) * direction
        objective_before = -before["loss_objective"].detach().double()
        with torch.no_grad():
            logs.update(_line_search(loss, tensordict, params, old_params, full_step, gradient, objective_before,
                                     movable, max_kl, line_search_steps, line_search_shrink))
    return {key: logged(value, lead) for key, value in logs.items()}


def _line_search(
    loss: TRPOLoss, tensordict: TensorDictBase, params: list[torch.Tensor], old_params: torch.Tensor,
    full_step: torch.Tensor, gradient: torch.Tensor, objective_before: torch.Tensor, movable: torch.Tensor,
    max_kl: float, steps: int, shrink: float,
) -> dict[str, torch.Tensor]:
    """Backtrack along ``full_step`` for every replica that can move (``movable``) until its KL is within
    ``max_kl`` and its surrogate improves; leave the others, and any replica that found no such step, as they were.
    Returns the logs of the steps taken (zeros where none)."""
    lead = tuple(movable.shape)
    accepted = torch.zeros(lead, dtype=torch.bool, device=movable.device)
    fraction_taken = torch.zeros(lead, dtype=torch.float64, device=movable.device)
    logs = {key: torch.zeros(lead, dtype=torch.float64, device=movable.device)
            for key in ("kl", "surrogate_improvement", "expected_improvement")}
    full_expected = rowwise_dot(gradient, full_step).double()
    for attempt in range(steps):
        fraction = shrink**attempt
        taken = torch.where(accepted, fraction_taken, torch.full_like(fraction_taken, fraction))
        assign_flat_(params, old_params + taken.to(old_params.dtype).unsqueeze(-1) * full_step, lead)
        after = loss(tensordict)
        improvement = -after["loss_objective"].double() - objective_before
        kl = after["kl"].double()
        good = torch.isfinite(improvement) & torch.isfinite(kl) & (kl <= max_kl) & (improvement > 0)
        new = good & movable & ~accepted
        expected = fraction * full_expected
        for key, value in (("kl", kl), ("surrogate_improvement", improvement), ("expected_improvement", expected)):
            logs[key] = torch.where(new, value, logs[key])
        fraction_taken = torch.where(new, torch.full_like(fraction_taken, fraction), fraction_taken)
        accepted = accepted | new
        if bool((accepted | ~movable).all()):
            break
    step = old_params + fraction_taken.to(old_params.dtype).unsqueeze(-1) * full_step
    assign_flat_(params, torch.where(accepted.unsqueeze(-1), step, old_params), lead)  # else keep the old policy
    return {**logs, "step_accepted": accepted.double(), "step_fraction": fraction_taken}


class TRPO(StochasticActorPolicies, Algorithm):
    """TRPO for a single-agent env with ``observation`` (a vector or a uint8 image) and ``action`` (``Categorical``
    or ``OneHot`` for discrete actions, ``Bounded`` for continuous ones, sampled from a ``TanhNormal`` in the
    bounds with a state-independent std, as in baselines).

    ``update`` takes one collector batch, (num_envs, T) or (T,) with time last, as ``Collector`` returns it.
    """

    name = "trpo"
    domains = ("discrete", "continuous")
    Config = TRPOConfig
    replicable = True
    config: TRPOConfig

    def _build(self, env: EnvBase) -> None:
        cfg = self.config
        self.actor, self.value, self.obs_norm = on_policy_networks(
            self.observation_spec, self.action_spec, cfg.policy_hidden, cfg.value_hidden, cfg.normalize_observations,
            replicas=self.replicas,
        )
        self.actor, self.value = self.actor.to(self.device), self.value.to(self.device)
        self.loss = TRPOLoss(self.actor, entropy_coef=cfg.entropy_coef, cg_damping=cfg.cg_damping)
        self.advantage = GAE(
            gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=self.value, average_gae=False
        )
        # foreach: one fused update over all parameter tensors; the default per-tensor loop on the CPU made the 80
        # small Adam steps of a value fit cost 2.5× as much (1.9 vs 0.75 ms a step, 2×32 MLP).
        self.value_optimizer = torch.optim.Adam(self.value.parameters(), lr=cfg.lr, foreach=True)
        self._build_policies()

    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        cfg = self.config
        keys = ["observation", "action"] + [
            ("next", key) for key in ("observation", "reward", "done", "terminated")
        ]
        batch = batch.select(*keys).to(self.device)
        self.frames_seen += self.frames_in(batch)
        with torch.no_grad():
            self.advantage(batch)  # GAE runs along the last batch dimension, the collector's time dimension
        flat = batch.reshape(*self.lead, -1)
        if self.obs_norm is not None:
            self.obs_norm.update(flat.get("observation"))
        advantage = flat.get("advantage")
        mean = broadcast_lead(sample_mean(advantage, self.lead), advantage)
        flat.set("advantage", (advantage - mean) / (sample_std(advantage, self.lead) + 1e-8))

        self.loss.snapshot(flat)
        logs = trpo_step(
            self.loss,
            flat,
            max_kl=cfg.max_kl,
            cg_iters=cfg.cg_iters,
            line_search_steps=cfg.line_search_steps,
            line_search_shrink=cfg.line_search_shrink,
            fvp_subsample=cfg.fvp_subsample,
        )
        logs.update(self._fit_value(flat))
        return logs

    def _fit_value(self, flat: TensorDictBase) -> dict[str, float]:
        """Adam regression of V on the GAE returns: ``vf_iters`` epochs of shuffled ``vf_batch_size`` minibatches."""
        cfg = self.config
        lead = self.lead
        observation, target = flat.get("observation"), flat.get("value_target")
        value_before = flat.get("state_value")
        explained_variance = 1.0 - sample_var(target - value_before, lead) / sample_var(target, lead).clamp_min(1e-8)
        epoch_losses = [mse_per_replica(value_before, target, lead).detach()]
        samples = flat.shape[len(lead)]
        for _ in range(cfg.vf_iters):
            epoch_losses = []
            for index in torch.randperm(samples, device=self.device).split(cfg.vf_batch_size):
                take = (slice(None),) * len(lead) + (index,)  # the same minibatch places in every replica's batch
                value_loss = mse_per_replica(self.value.module(observation[take]), target[take], lead)
                self.value_optimizer.zero_grad()
                value_loss.sum().backward()
                if math.isfinite(cfg.max_grad_norm):  # the default, inf, clips nothing: skip the norm's cost
                    clip_grad_norm_(self.value.parameters(), cfg.max_grad_norm, lead)
                self.value_optimizer.step()
                epoch_losses.append(value_loss.detach())
        if lead:
            value_loss = torch.stack(epoch_losses).double().mean(0)
        else:  # a float sum, as the lone learner has always logged it
            value_loss = sum(map(float, epoch_losses)) / len(epoch_losses)
        return {"value_loss": value_loss, "explained_variance": logged(explained_variance, lead)}

    def modules(self) -> dict[str, nn.Module]:
        # The observation statistics live in both networks (one shared RunningNorm), so both state dicts carry them.
        return {"actor": self.actor, "value": self.value}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"value": self.value_optimizer}
