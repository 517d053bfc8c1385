"""IQL for the discrete Sidewalk in self-play (``opponent=self``): every agent learns its own Q-values with DQN
(Tan 1993; TorchRL's ``sota-implementations/multiagent/iql.py``), all TorchRL parts.

Each agent's Q-network is DQN's (the paper's conv stack, a dueling head) on the agent's ego-centric observation, one
set of weights for every agent (``share_params``) or one per agent; ε-greedy explores each agent independently;
a replay buffer of joint transitions, double-DQN targets on each agent's own reward and a Polyak target network.
This file also holds the machinery VDN and QMIX share (``sidewalk.algos.vdn``, ``sidewalk.algos.qmix``): they
replace the per-agent loss by ``QMixerLoss`` on a mixer of the agents' chosen Q-values.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Composite
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import MLP, EGreedyModule, MultiAgentNetBase, QValueModule
from torchrl.objectives import DQNLoss, HardUpdate, LossModule, SoftUpdate, ValueEstimators

from sidewalk._checks import check_range
from sidewalk.algos.base import MultiAgentAlgorithm, MultiAgentConfig
from sidewalk.algos.dqn import DQNConfig, action_gap, decay_epsilon, loss_module_step, replay_updates
from sidewalk.algos.networks import DuelingHead, is_image_spec, make_encoder
from sidewalk.envs.base import AGENT_GROUP

ACTION_VALUE_KEY = (AGENT_GROUP, "action_value")
CHOSEN_ACTION_VALUE_KEY = (AGENT_GROUP, "chosen_action_value")


@dataclass
class IQLConfig(DQNConfig, MultiAgentConfig):
    """IQL settings: DQN's (``sidewalk.algos.dqn.DQNConfig``, every field and check) for every agent, plus
    ``share_params``. Each frame is one step of every agent of one world, so a batch of ``batch_size`` transitions
    trains on ``batch_size × N`` agent-steps; the ε schedule counts frames, as DQN's does.

    The defaults are DQN's against Dijkstra (the network, γ, lr, the batch of 4 steps of 128 worlds) with what the
    reference self-play runs used (results/reference/crossplay/): 16 gradient steps an iteration at Polyak 0.0125
    (the same target-network speed per frame as DQN's 4 at 0.05), ε floored at 0.15 (at 0.05 both greedy agents
    settled into a head-on standoff), 1000 iterations (512,000 frames: under the perturbed evaluation protocol the
    grid's IQL and VDN were still settling at 600, IQL's last five evaluations 0.87-1.00, VDN's 0.77-1.00;
    docs/guide/evaluation.md). ``eps_ladder``
    (Ape-X's per-world ε) and ``lr_end`` (a linear step-size decay) are off by default: neither was measured at scale.
    """

    name: str = "iql"
    frames_per_batch: int = 512
    default_num_envs: int = 128
    default_iterations: int = 1000
    default_eval_every: int = 20
    gamma: float = 0.95
    lr: float = 5e-4
    batch_size: int = 128
    updates_per_batch: int = 16
    learning_starts: int = 1_000
    eps_start: float = 1.0
    eps_end: float = 0.15
    eps_decay_frames: int = 20_000
    tau: float = 0.0125
    double_dqn: bool = True
    loss_function: str = "smooth_l1"
    eps_ladder: float = 0.0
    # The share of a batch's worlds in which every agent acts greedily while training (ε 0 for the whole episode):
    # the greedy pair the evaluation plays, met in training, so that the values price the standoffs two greedy copies
    # of one policy walk into and ε-greedy partners always break (docs/guide/multiagent.md, "The greedy pair").
    greedy_worlds: float = 0.0
    lr_end: float = 5e-4  # = lr: no decay
    lr_decay_frames: int = 153_600
    advantage_learning: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_range("algo.eps_ladder", self.eps_ladder, 0.0)
        check_range("algo.greedy_worlds", self.greedy_worlds, 0.0, 1.0)


class AgentQNetwork(MultiAgentNetBase):
    """Per-agent Q-values (..., N, n_actions) from per-agent observations (..., N, *obs): DQN's network (the paper's
    conv stack for images, the raw vector otherwise; a dueling head or one hidden layer) for every agent, with one
    set of weights (``share_params``) or one per agent (run together through ``torch.vmap``)."""

    def __init__(
        self,
        n_agents: int,
        observation_shape: torch.Size,
        is_image: bool,
        n_actions: int,
        hidden: int,
        dueling: bool,
        share_params: bool,
        device: torch.device | str = "cpu",
    ) -> None:
        self.observation_shape = torch.Size(observation_shape)
        self.is_image = is_image
        self.n_actions = n_actions
        self.hidden = hidden
        self.dueling = dueling
        super().__init__(
            n_agents=n_agents, centralized=False, share_params=share_params,
            agent_dim=-(len(self.observation_shape) + 1), device=device,
        )

    def _build_single_net(self, *, device: torch.device | str) -> nn.Module:
        with torch.device(device):  # also "meta": MultiAgentNetBase builds a parameter-free copy to run
            encoder = make_encoder(self.observation_shape, self.is_image, channels_last=True)
            if self.dueling:
                head: nn.Module = DuelingHead(encoder.out_features, self.n_actions, self.hidden)
            else:
                head = MLP(in_features=encoder.out_features, out_features=self.n_actions, num_cells=[self.hidden],
                           activation_class=nn.ReLU)
            return nn.Sequential(encoder, head)

    def _pre_forward_check(self, inputs: torch.Tensor) -> torch.Tensor:
        agents = inputs.shape[self.agent_dim] if inputs.dim() >= -self.agent_dim else None
        if agents != self.n_agents:
            raise ValueError(
                f"expected observations (..., {self.n_agents}, {', '.join(map(str, self.observation_shape))}); "
                f"got {tuple(inputs.shape)}"
            )
        return inputs


class LadderEGreedy(EGreedyModule):
    """TorchRL's ε-greedy over every agent of every world, each with its own ε on a fixed ladder (Ape-X, Horgan
    et al. 2018: ε_k = ε^(1 + ladder·k/(K-1)) over the K agent slots of a batch), where ε is ``EGreedyModule``'s
    annealed value. ``ladder=0`` is plain ε-greedy. Agent a of world w takes rung (w + a·⌈B/N⌉) mod B, so every
    world pairs agents at rungs far apart and every agent plays on every rung in some world.

    The first ``greedy_worlds`` share of the worlds (a world keeps its slot for its whole episode) explore not at all:
    every agent there acts greedily, as an evaluation's agents do."""

    def __init__(
        self, spec, eps_init: float, eps_end: float, annealing_num_steps: int, ladder: float,
        greedy_worlds: float = 0.0, **kwargs,
    ) -> None:
        super().__init__(spec, eps_init=eps_init, eps_end=eps_end, annealing_num_steps=annealing_num_steps, **kwargs)
        self.ladder = float(ladder)
        self.greedy_worlds = float(greedy_worlds)

    def rungs(self, shape: torch.Size, device: torch.device) -> torch.Tensor:
        """Each agent slot's place on the ladder, in [0, 1], for actions of ``shape`` (..., N)."""
        n_agents = shape[-1]
        worlds = int(torch.Size(shape[:-1]).numel())
        agent_shift = -(-worlds // n_agents)
        rung = (torch.arange(worlds, device=device)[:, None] + agent_shift * torch.arange(n_agents, device=device)) % worlds
        return (rung / max(worlds - 1, 1)).reshape(shape)

    def greedy(self, shape: torch.Size, device: torch.device) -> torch.Tensor:
        """Whether each agent slot of actions of ``shape`` (..., N) is in a greedy world: the first
        ``round(greedy_worlds × worlds)`` worlds, every agent of them."""
        worlds = int(torch.Size(shape[:-1]).numel())
        greedy = torch.arange(worlds, device=device) < round(self.greedy_worlds * worlds)
        return greedy[:, None].expand(worlds, shape[-1]).reshape(shape)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if exploration_type() not in (ExplorationType.RANDOM, None):
            return tensordict
        action = tensordict.get(self.action_key)
        eps = self.eps ** (1.0 + self.ladder * self.rungs(action.shape, action.device))
        explore = (torch.rand(action.shape, device=action.device) < eps) & ~self.greedy(action.shape, action.device)
        spec = self.spec[self.action_key] if isinstance(self.spec, Composite) else self.spec
        random_action = torch.randint(0, spec.space.n, action.shape, device=action.device)
        tensordict.set(self.action_key, torch.where(explore, random_action, action))
        return tensordict


class IQL(MultiAgentAlgorithm):
    """Independent double DQN for every agent, over the agents' Q-network (``AgentQNetwork``)."""

    name = "iql"
    domains = ("discrete",)
    Config = IQLConfig
    uses_replay_buffer = True
    AGENT_NETWORK: ClassVar[str] = "value_network"  # the agents' Q-network, as the loss module names it
    # What the replay buffer keeps of a transition: the agents' own rewards, ends and masks.
    TRANSITION_KEYS: ClassVar[tuple[NestedKey, ...]] = (
        MultiAgentAlgorithm.OBSERVATION_KEY, MultiAgentAlgorithm.ACTION_KEY, MultiAgentAlgorithm.MASK_KEY,
        ("next", *MultiAgentAlgorithm.OBSERVATION_KEY), ("next", *MultiAgentAlgorithm.REWARD_KEY),
        ("next", *MultiAgentAlgorithm.DONE_KEY), ("next", *MultiAgentAlgorithm.TERMINATED_KEY),
    )

    def _build(self, env: EnvBase) -> None:
        cfg: IQLConfig = self.config
        if not self.discrete_actions:
            raise ValueError(f"algo={cfg.name} needs a discrete action space (env=discrete); use algo=ippo or algo=mappo")
        per_agent = self.observation_spec.shape[1:]
        self.q_network = AgentQNetwork(
            self.n_agents, per_agent, is_image_spec(self.observation_spec), int(self.action_spec.space.n),
            cfg.hidden, cfg.dueling, cfg.share_params, device=self.device,
        )
        # The action spec with its "agents" level (shape (N,)), as QValueModule and EGreedyModule read nested keys.
        spec = env.full_action_spec_unbatched.clone().to(self.device)
        self.actor = TensorDictSequential(
            TensorDictModule(self.q_network, in_keys=[self.OBSERVATION_KEY], out_keys=[ACTION_VALUE_KEY]),
            QValueModule(
                action_value_key=ACTION_VALUE_KEY, out_keys=[self.ACTION_KEY, ACTION_VALUE_KEY, CHOSEN_ACTION_VALUE_KEY],
                spec=spec, action_space="categorical",
            ),
        )
        self.greedy = LadderEGreedy(
            spec, eps_init=float(cfg.eps_start), eps_end=float(cfg.eps_end), annealing_num_steps=cfg.eps_decay_frames,
            ladder=cfg.eps_ladder, greedy_worlds=cfg.greedy_worlds, action_key=self.ACTION_KEY, device=self.device,
        )
        self.explorer = TensorDictSequential(self.actor, self.greedy)
        self.loss = self._make_loss(env, spec)
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma)
        if cfg.target_update == "soft":
            self.target_updater = SoftUpdate(self.loss, tau=cfg.tau)
        else:
            self.target_updater = HardUpdate(self.loss, value_network_update_interval=cfg.target_period)
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.lr)
        self.updates = 0

    def _make_loss(self, env: EnvBase, spec) -> LossModule:
        """DQN's loss on every agent's own reward and end: a (batch, N) TD error, averaged over the agent-steps that
        carry learning signal (``("agents", "info", "mask")``): an agent's own end stops its target, and its later steps,
        whose actions move nothing, are left out."""
        cfg: IQLConfig = self.config
        loss = DQNLoss(
            self.actor, delay_value=True, double_dqn=cfg.double_dqn, action_space="categorical",
            loss_function=cfg.loss_function,
        )
        loss.set_keys(
            action_value=ACTION_VALUE_KEY, action=self.ACTION_KEY, value=CHOSEN_ACTION_VALUE_KEY,
            reward=self.REWARD_KEY, done=self.DONE_KEY, terminated=self.TERMINATED_KEY,
        )
        loss.loss_mask_key = self.MASK_KEY
        return loss

    def transitions(self, batch: TensorDictBase) -> TensorDictBase:
        """What the replay buffer keeps of a collected batch, flattened to transitions."""
        return batch.select(*self.TRANSITION_KEYS).reshape(-1)

    def collection_policy(self) -> TensorDictModuleBase:
        return self.explorer

    def evaluation_policy(self) -> TensorDictModuleBase:
        return self.actor

    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        cfg: IQLConfig = self.config
        self.frames_seen += batch.numel()
        replay_buffer.extend(self.transitions(batch))
        decay_epsilon(self.greedy, self.frames_seen, cfg.eps_decay_frames)
        # Adam's step size decays linearly to lr_end: the greedy policy settles instead of flipping between near-ties.
        progress = min(1.0, self.frames_seen / cfg.lr_decay_frames) if cfg.lr_decay_frames else 0.0
        for group in self.optimizer.param_groups:
            group["lr"] = cfg.lr + (cfg.lr_end - cfg.lr) * progress
        logs: dict[str, float] = {"epsilon": float(self.greedy.eps), "lr": self.optimizer.param_groups[0]["lr"]}
        step = self._advantage_learning_step if cfg.advantage_learning else None
        return {**logs, **replay_updates(self, replay_buffer, step)}

    def target_q_values(self, sample: TensorDictBase) -> torch.Tensor:
        """(batch, N, actions): every agent's Q-values under the target network, without gradient."""
        network = getattr(self.loss, self.AGENT_NETWORK)
        with torch.no_grad(), getattr(self.loss, f"target_{self.AGENT_NETWORK}_params").to_module(network):
            return self.q_network(sample[self.OBSERVATION_KEY])

    def action_gaps(self, sample: TensorDictBase) -> torch.Tensor:
        """(batch, N): each agent's taken action's gap to its best one under the target network."""
        return action_gap(self.target_q_values(sample), sample[self.ACTION_KEY])

    def reward_gaps(self, sample: TensorDictBase) -> tuple[NestedKey, torch.Tensor]:
        """The reward the loss trains on and the action gaps in its shape: each agent's own."""
        return ("next", *self.REWARD_KEY), self.action_gaps(sample).unsqueeze(-1)

    def _advantage_learning_step(self, sample: TensorDictBase) -> torch.Tensor:
        """DQN's advantage learning (``DQNConfig.advantage_learning``): the loss's step on the reward less α times
        the action gap."""
        reward_key, gaps = self.reward_gaps(sample)
        sample.set(reward_key, sample.get(reward_key) - self.config.advantage_learning * gaps)
        return loss_module_step(self, sample)

    def modules(self) -> dict[str, torch.nn.Module]:
        return {"loss": self.loss, "greedy": self.greedy}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"adam": self.optimizer}

    def state_dict(self) -> dict[str, Any]:
        # The target networks' weights live in the loss module; a hard updater also counts steps to its next copy.
        counter = getattr(self.target_updater, "counter", 0)
        return {**super().state_dict(), "updates": self.updates, "target_counter": counter}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.updates = state["updates"]
        if hasattr(self.target_updater, "counter"):
            self.target_updater.counter = state["target_counter"]
