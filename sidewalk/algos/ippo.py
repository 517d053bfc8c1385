"""IPPO (independent PPO, de Witt et al. 2020) from TorchRL parts: every agent's clipped PPO on its own reward, for
both domains, as TorchRL's ``sota-implementations/multiagent/mappo_ippo.py`` builds it.

Each agent's policy and value network read that agent's observation only: ``MultiAgentMLP`` heads
(``centralised=False``) over a per-agent encoder (the paper's conv stack, ``MultiAgentConvNet``, for grid images;
for vectors one ``RunningNorm`` over the per-agent observation, shared by both networks as in our single-agent PPO).
``share_params`` (default) gives every agent the same weights -- each observation is ego-centric, so one network can
play any agent -- or one set per agent. ``ClipPPOLoss`` and ``GAE`` run over the agent-batched keys
``("agents", ...)``: each agent's advantage comes from its own reward and value and its own end (the view's
``("agents", "terminated"|"done")``), and its steps after that end (``("agents", "info", "mask")`` false) are left out of
every loss (``loss_mask_key``), of the advantages' standardisation and of the observation statistics. The rest is
our single-agent PPO (``sidewalk.algos.ppo``): a ``TanhNormal`` with a bounded mean (``mean_bound``) and a
state-independent log-std starting at 0 (continuous) or a ``Categorical`` (grid), an output layer at 1 % of its
default scale, the log-prob reference taken after the statistics moved, minibatches drawn by a generator the
checkpoint keeps.
``sidewalk.algos.mappo`` is this learner with a centralised critic.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.data import Bounded, Categorical, Composite
from torchrl.envs import EnvBase
from torchrl.modules import MultiAgentConvNet, MultiAgentMLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from sidewalk._torchrl import multi_agent_mlp_last_layer
from sidewalk.algos.base import MultiAgentAlgorithm, MultiAgentConfig
from sidewalk.algos.networks import PAPER_CONV, RunningNorm, VectorEncoder, is_image_spec, tanh_normal
from sidewalk.algos.ppo import LOSS_LOGS, ClippedPPOMixin, PPOConfig, clipped_ppo_update
from sidewalk.envs.base import AGENT_GROUP

LOG_PROB_KEY = (AGENT_GROUP, "action_log_prob")
VALUE_KEY = (AGENT_GROUP, "state_value")


@dataclass
class IPPOConfig(PPOConfig, MultiAgentConfig):
    """IPPO settings: our single-agent PPO's (CleanRL's continuous-control preset, ``sidewalk.algos.ppo``) for every
    agent, a minibatch counting world-steps (each holds every agent's transition), and ``share_params``; the run
    length measured on the continuous two-agent sidewalk."""

    name: str = "ippo"
    default_iterations: int = 200
    default_eval_every: int = 10


class Pixels(nn.Module):
    """uint8 grey images → float32 in [0, 1]."""

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return image.to(torch.float32) / 255.0


class OwnValue(nn.Module):
    """Per-agent values from a shared centralised critic's N heads, (..., N, N) → (..., N, 1): agent i reads head
    i. (A shared ``MultiAgentMLP(centralised=True)`` alone gives every agent the same output, right only when the
    agents share one reward; ours each have their own.)"""

    def forward(self, heads: torch.Tensor) -> torch.Tensor:
        return heads.diagonal(dim1=-2, dim2=-1).unsqueeze(-1)


def agent_encoder(observation_spec, share_params: bool, norm: RunningNorm | None) -> tuple[nn.Module, int]:
    """(..., N, *obs) → (..., N, features) for each agent apart: the paper's conv stack (ReLU) for uint8 images,
    one set of weights or one per agent; ``norm`` (or a float cast) for vectors. Returns (module, features)."""
    n_agents, *obs_shape = observation_spec.shape
    if not is_image_spec(observation_spec):
        return (norm if norm is not None else VectorEncoder(torch.Size(obs_shape))), obs_shape[-1]
    conv = MultiAgentConvNet(
        n_agents, centralized=False, share_params=share_params, in_features=obs_shape[-3],
        activation_class=nn.ReLU, **PAPER_CONV,
    )
    encoder = nn.Sequential(Pixels(), conv)
    with torch.no_grad():  # the encoder is built on the CPU and moved with the learner; the spec may live on a GPU
        features = encoder(observation_spec.zero().unsqueeze(0).cpu()).shape[-1]
    return encoder, features


def multi_agent_networks(
    observation_spec, action_spec, cfg: IPPOConfig, centralised_critic: bool
) -> tuple[ProbabilisticActor, ValueOperator, RunningNorm | None]:
    """The agents' policy and value networks from the unbatched specs (agent dimension first): encoder → tanh
    ``MultiAgentMLP``. The policy writes ``("agents", "action")``, sampled from a ``TanhNormal`` within the
    ``Bounded`` spec (state-independent log-std, one per agent without shared parameters) or a ``Categorical``;
    its output layer starts at 1 % of its default scale, so the first policy is centred / near uniform. The value
    network writes ``("agents", "state_value")`` from the agent's own features, or with ``centralised_critic``
    from every agent's. Returns (actor, value, norm)."""
    n_agents = observation_spec.shape[0]
    norm = None
    if cfg.normalize_observations and not is_image_spec(observation_spec):
        norm = RunningNorm(observation_spec.shape[-1])
    if isinstance(action_spec, Bounded):
        n_out, dist_keys, dist = action_spec.shape[-1], ["loc", "scale"], tanh_normal(action_spec, cfg.mean_bound)
    elif isinstance(action_spec, Categorical):
        n_out, dist_keys = action_spec.space.n, ["logits"]
        dist = {"distribution_class": torch.distributions.Categorical}
    else:
        raise TypeError(f"needs a Categorical or Bounded action spec; got {type(action_spec).__name__}")
    dist_keys = [(AGENT_GROUP, key) for key in dist_keys]

    encoder, features = agent_encoder(observation_spec, cfg.share_params, norm)
    head = MultiAgentMLP(
        features, n_out, n_agents, centralized=False, share_params=cfg.share_params, num_cells=list(cfg.hidden),
        activation_class=nn.Tanh,
    )
    out_layer = head.params[multi_agent_mlp_last_layer(head)]
    with torch.no_grad():
        out_layer["weight"].mul_(0.01)
        out_layer["bias"].zero_()
    policy_net = nn.Sequential(encoder, head)
    if isinstance(action_spec, Bounded):
        scale_shape = (n_out,) if cfg.share_params else (n_agents, n_out)
        policy_net.append(AddStateIndependentNormalScale(scale_shape, scale_mapping="exp"))
    module = TensorDictModule(policy_net, in_keys=[MultiAgentAlgorithm.OBSERVATION_KEY], out_keys=dist_keys)
    actor = ProbabilisticActor(
        module,
        in_keys=dist_keys,
        out_keys=[MultiAgentAlgorithm.ACTION_KEY],
        spec=Composite({AGENT_GROUP: Composite(action=action_spec, shape=(n_agents,))}),
        **dist,
    )

    encoder, features = agent_encoder(observation_spec, cfg.share_params, norm)
    shared_heads = centralised_critic and cfg.share_params
    value_head = MultiAgentMLP(
        features, n_agents if shared_heads else 1, n_agents, centralized=centralised_critic,
        share_params=cfg.share_params, num_cells=list(cfg.hidden), activation_class=nn.Tanh,
    )
    value_net = nn.Sequential(encoder, value_head, *([OwnValue()] if shared_heads else []))
    value = ValueOperator(value_net, in_keys=[MultiAgentAlgorithm.OBSERVATION_KEY], out_keys=[VALUE_KEY])
    return actor, value, norm


class IPPO(ClippedPPOMixin, MultiAgentAlgorithm):
    """Clipped PPO for every agent at once, each on its own reward; advantages by GAE over each collected
    (worlds, time) batch. ``centralised_critic``: the value networks see every agent's observation (MAPPO)."""

    name = "ippo"
    domains = ("discrete", "continuous")
    Config = IPPOConfig
    centralised_critic: ClassVar[bool] = False

    def _build(self, env: EnvBase) -> None:
        cfg: IPPOConfig = self.config
        actor, critic, self.obs_norm = multi_agent_networks(
            self.observation_spec, self.action_spec, cfg, self.centralised_critic
        )
        self.actor, self.critic = actor.to(self.device), critic.to(self.device)
        value_keys = {
            "value": VALUE_KEY, "reward": self.REWARD_KEY, "done": self.DONE_KEY, "terminated": self.TERMINATED_KEY,
            "advantage": (AGENT_GROUP, "advantage"), "value_target": (AGENT_GROUP, "value_target"),
        }
        # Advantages are standardised over the masked-in agent-steps by the update, not by GAE over every entry.
        self.advantage = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=self.critic, average_gae=False)
        self.advantage.set_keys(**value_keys)
        self.loss = ClipPPOLoss(
            self.actor, self.critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coef,
            critic_coeff=cfg.critic_coef, normalize_advantage=False,
        )
        self.loss.set_keys(action=self.ACTION_KEY, sample_log_prob=LOG_PROB_KEY, **value_keys)
        self.loss.loss_mask_key = self.MASK_KEY  # an agent's steps after its own end carry no learning signal
        self._build_update()

    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        return clipped_ppo_update(
            self, batch, self.OBSERVATION_KEY, self.ACTION_KEY, LOG_PROB_KEY, (*LOSS_LOGS, "kl_approx", "clip_fraction"),
            mask_key=self.MASK_KEY,
        )
