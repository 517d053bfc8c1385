"""DQN for the discrete Sidewalk (paper §6.1): the paper's conv stack, a dueling head, double DQN, a replay
buffer, ε-greedy exploration and a target network, from TorchRL parts; the gradient step is ours
(``DQN._gradient_step``: TorchRL's ``DQNLoss`` arithmetic without its per-call parameter swaps)."""

from __future__ import annotations

from copy import deepcopy
from dataclasses import dataclass
from functools import partial
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.data import Categorical
from torchrl.envs import EnvBase
from torchrl.modules import MLP, EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate, ValueEstimators
from torchrl.objectives.utils import distance_loss
from torchrl.objectives.value.functional import td0_return_estimate

from sidewalk._checks import check_choice, check_int, check_range
from sidewalk._torchrl import foreach_lerp_
from sidewalk.algos.base import AlgoConfig, Algorithm
from sidewalk.algos.networks import DuelingHead, is_image_spec, make_encoder
from sidewalk.algos.replicas import clip_grad_norm_, logged, replicate_, sample_mean

# What the replay buffer keeps of a transition (the "world" group and info are for metrics, not learning).
TRANSITION_KEYS = (
    "observation", "action",
    ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "terminated"), ("next", "truncated"),
)


@dataclass
class DQNConfig(AlgoConfig):
    """DQN settings. The network is the paper's; the rest are tuned for the batched env (a batch of worlds feeds
    one replay buffer), so that the default run reaches ego success ≥ 0.8 against Dijkstra in minutes on 2 cores.
    """

    name: str = "dqn"
    # One iteration: 4 steps of 128 worlds, then 4 gradient steps, Polyak 0.05 a step. Against 4 steps of 32 worlds
    # and Polyak 0.01 (the reference runs' settings, which the grid presets keep), the default run learns in as
    # many frames with a quarter of the gradient steps. Under the perturbed evaluation protocol (starts and goals
    # moved by a row, trained alike) ego success is ≥ 0.95 at each of the last three evaluations on 19 of seeds 0-19
    # at 400 iterations (204,800 frames), 17 of 20 at 300, 10 of seeds 0-9 at 300; at 200 it was still rising
    # (docs/guide/evaluation.md, results/who-yields/main-job-400).
    frames_per_batch: int = 512
    default_num_envs: int = 128
    default_iterations: int = 400
    default_eval_every: int = 25
    # With the explicit reward, at 0.99 "let the other agent pass first" is worth nearly as much as walking and
    # DQN wavered between the two (eval success flipping 0/1 over 64k frames); at 0.95 it settles by ~40k frames.
    gamma: float = 0.95
    lr: float = 5e-4  # OpenAI baselines' DQN default
    max_grad_norm: float = 10.0
    hidden: int = 256  # the paper's dense layer
    dueling: bool = True  # the paper's head; False: Linear(hidden) → ReLU → Linear(actions), SB3's DQN network
    buffer_size: int = 100_000
    batch_size: int = 128
    updates_per_batch: int = 4  # gradient steps per iteration
    learning_starts: int = 1_000  # frames collected before the first update
    eps_start: float = 1.0
    eps_end: float = 0.05
    eps_decay_frames: int = 20_000
    target_update: str = "soft"  # "soft" (Polyak, tau per update) or "hard" (copy every target_period updates)
    tau: float = 0.05
    target_period: int = 500
    double_dqn: bool = True
    loss_function: str = "smooth_l1"
    # Advantage learning (Bellemare et al. 2016, "Increasing the Action Gap"): the target loses this share of the
    # taken action's gap to the best one under the target network, so approximation noise flips no greedy action
    # (docs/guide/known-properties.md, "Evaluations that hold"). 0 is the paper's DQN, which its presets pin.
    advantage_learning: float = 0.9

    def __post_init__(self) -> None:
        super().__post_init__()
        check_range("algo.advantage_learning", self.advantage_learning, 0.0, 1.0)
        check_int("algo.hidden", self.hidden, 1)
        check_int("algo.buffer_size", self.buffer_size, 1)
        check_int("algo.batch_size", self.batch_size, 1, self.buffer_size)
        check_int("algo.updates_per_batch", self.updates_per_batch, 0)
        check_int("algo.learning_starts", self.learning_starts, 0)
        check_range("algo.eps_start", self.eps_start, 0.0, 1.0)
        check_range("algo.eps_end", self.eps_end, 0.0, self.eps_start)
        check_int("algo.eps_decay_frames", self.eps_decay_frames, 1)
        check_choice("algo.target_update", self.target_update, ("soft", "hard"))
        check_range("algo.tau", self.tau, 0.0, 1.0, low_open=True)
        check_int("algo.target_period", self.target_period, 1)
        check_choice("algo.loss_function", self.loss_function, ("l2", "l1", "smooth_l1"))


def decay_epsilon(greedy: EGreedyModule, frames_seen: int, decay_frames: int) -> None:
    """Set ``greedy``'s ε to its linear schedule at ``frames_seen``: ``EGreedyModule.step`` loops once per frame,
    and one call with the decayed value is the same schedule."""
    greedy.eps.copy_(
        torch.clamp(
            greedy.eps_init - (greedy.eps_init - greedy.eps_end) * frames_seen / decay_frames, min=greedy.eps_end
        )
    )


def replay_updates(algo: Algorithm, replay_buffer: Any, gradient_step=None) -> dict[str, float]:
    """``updates_per_batch`` gradient steps on replayed minibatches, once the buffer holds ``learning_starts``
    transitions; ``{"loss": mean}``, or nothing before that. ``gradient_step(sample) -> loss`` takes one step and its
    target update (default: ``loss_module_step``, through ``algo.loss``). DQN and the multi-agent IQL/VDN/QMIX share
    it."""
    cfg = algo.config
    if len(replay_buffer) < max(cfg.learning_starts, cfg.batch_size):
        return {}
    step = gradient_step or partial(loss_module_step, algo)
    losses = []
    for _ in range(cfg.updates_per_batch):
        sample = replay_buffer.sample(cfg.batch_size).to(algo.device)
        losses.append(step(sample.transpose(0, 1) if algo.lead else sample))  # replicas: (batch, R) → (R, batch)
        algo.updates += 1
    if not losses:
        return {"loss": float("nan")}
    return {"loss": logged(torch.stack(losses).mean(0), algo.lead)}


def replay_rows(transitions: TensorDictBase, lead: tuple[int, ...]) -> TensorDictBase:
    """A collected (worlds, time) batch as replay-buffer rows: one transition a row, or with R replicas one row of R
    transitions (the replicas' batches (R, worlds, time) laid out (worlds·time, R)), so a sampled row is every
    replica's transition at one place of its own stream."""
    rows = transitions.reshape(*lead, -1)
    return rows.transpose(0, 1).contiguous() if lead else rows


def action_gap(q_values: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """How far below the best action's value the taken ``action``'s lies: ``q_values`` (..., actions), ``action`` (...)."""
    return q_values.amax(-1) - q_values.gather(-1, action.unsqueeze(-1)).squeeze(-1)


def loss_module_step(algo: Algorithm, sample: TensorDictBase) -> torch.Tensor:
    """One gradient step of ``algo.loss`` (a TorchRL loss module) on ``sample``: backward, gradient-norm clip, the
    optimiser, then ``algo.target_updater``; returns the detached loss."""
    loss = algo.loss(sample)["loss"]
    algo.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(algo.loss.parameters(), algo.config.max_grad_norm)
    algo.optimizer.step()
    algo.target_updater.step()
    return loss.detach()


def bound_copy(network: nn.Module, weights: dict[str, torch.Tensor]) -> nn.Module:
    """A copy of ``network`` whose parameters are replaced by the given tensors themselves (name → tensor, as
    ``named_parameters`` names them), held as non-persistent buffers: it computes with whatever those tensors hold
    now, without a swap per call."""
    copy = deepcopy(network)
    for name, tensor in weights.items():
        owner_name, _, leaf = name.rpartition(".")
        owner = copy.get_submodule(owner_name)
        delattr(owner, leaf)  # nn.Module drops the parameter, so the buffer can take its name
        owner.register_buffer(leaf, tensor, persistent=False)
    return copy


class DQN(Algorithm):
    """Double DQN with a dueling head (or a plain one) over the paper's conv stack (or over the raw vector
    observation).

    TorchRL's parts hold the state and explore: ``QValueActor`` + ``EGreedyModule`` collect, ``DQNLoss`` owns the
    online and target parameters (its ``state_dict`` is the checkpoint's), ``SoftUpdate``/``HardUpdate`` the target
    schedule, the replay buffer is the experiment's. The gradient step is ours (``_gradient_step``), because
    ``DQNLoss.forward`` was a cost: it swaps the online or target parameters into the network around each of its
    passes and copies the sample's tensordict, 0.7 ms a step beyond the passes themselves at SB3's network, 1.3 ms at
    the defaults' three passes (5.3 vs 4.6 and 8.1 vs 6.8 ms here). Ours runs the Q-network, and a copy bound to the
    loss's target tensors, directly; with fused Adam and one foreach Polyak step, a step went from 1.37× to 1.04×
    the same update in plain PyTorch (1.29× to 1.02× at the defaults; ``python -m sidewalk.bench.training --setups``).
    """

    name = "dqn"
    domains = ("discrete",)
    Config = DQNConfig
    uses_replay_buffer = True
    replicable = True

    def _build(self, env: EnvBase) -> None:
        cfg: DQNConfig = self.config
        if not self.discrete_actions or not isinstance(self.action_spec, Categorical):
            raise ValueError("algo=dqn needs a discrete action space (env=discrete); use algo=trpo or algo=ppo")
        n_actions = int(self.action_spec.space.n)
        encoder = make_encoder(self.observation_spec.shape, is_image_spec(self.observation_spec), channels_last=True)
        if cfg.dueling:
            head: nn.Module = DuelingHead(encoder.out_features, n_actions, cfg.hidden)
        else:
            head = MLP(in_features=encoder.out_features, out_features=n_actions, num_cells=[cfg.hidden],
                       activation_class=nn.ReLU)
        self.q_network = nn.Sequential(encoder, head).to(self.device)
        if self.replicas:
            replicate_(self.q_network, self.replicas)
        spec = self.action_spec.clone().to(self.device)
        self.actor = QValueActor(self.q_network, in_keys=["observation"], spec=spec)
        self.greedy = EGreedyModule(
            spec, eps_init=float(cfg.eps_start), eps_end=float(cfg.eps_end),
            annealing_num_steps=cfg.eps_decay_frames, device=self.device,
        )
        self.explorer = TensorDictSequential(self.actor, self.greedy)
        self.loss = DQNLoss(
            self.actor, delay_value=True, double_dqn=cfg.double_dqn, action_space=spec,
            loss_function=cfg.loss_function,
        )
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma)
        if cfg.target_update == "soft":
            self.target_updater = SoftUpdate(self.loss, tau=cfg.tau)
        else:
            self.target_updater = HardUpdate(self.loss, value_network_update_interval=cfg.target_period)
        # The loss's online parameters are the Q-network's own; its target parameters become the weights of a copy
        # (the same tensors: Polyak steps and checkpoint loads write them in place, and the copy sees them).
        online = self.loss.value_network_params.flatten_keys(".")
        target = self.loss.target_value_network_params.flatten_keys(".")
        key_of = {id(tensor): key for key, tensor in online.items()}
        self.target_q_network = bound_copy(
            self.q_network, {name: target[key_of[id(p)]] for name, p in self.q_network.named_parameters()}
        )
        keys = list(online.keys())  # a TensorDict iterates over its batch dimension, not its keys
        self._online, self._target = [online[key] for key in keys], [target[key] for key in keys]
        # Fused Adam (CPU and CUDA kernels): the per-tensor loop's update up to float rounding (1e-7 after 40 steps),
        # 0.23-0.27 ms a step instead of 0.42-0.61 here.
        fused = self.device.type in ("cpu", "cuda")
        self._adam_flags = {"fused": True if fused else None, "foreach": None if fused else True}
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.lr, **self._adam_flags)
        self.updates = 0

    def collection_policy(self) -> TensorDictModuleBase:
        return self.explorer

    def evaluation_policy(self) -> TensorDictModuleBase:
        return self.actor

    def update(self, batch: TensorDictBase, replay_buffer: Any = None) -> dict[str, float]:
        cfg: DQNConfig = self.config
        self.frames_seen += self.frames_in(batch)
        replay_buffer.extend(replay_rows(batch.select(*TRANSITION_KEYS), self.lead))
        decay_epsilon(self.greedy, self.frames_seen, cfg.eps_decay_frames)
        logs: dict[str, float] = {"epsilon": float(self.greedy.eps)}
        return {**logs, **replay_updates(self, replay_buffer, self._gradient_step)}

    def _gradient_step(self, sample: TensorDictBase) -> torch.Tensor:
        """One step on a replayed minibatch with ``DQNLoss``'s arithmetic (``tests/test_dqn.py`` holds the two equal):
        Q of the taken actions (with gradient), the TD(0) target from the next observations (the online network
        picks the next action under double DQN, the target network values it), the loss function averaged, the
        gradient norm clipped, Adam, the target update; returns the detached loss. The next observations' online pass
        runs apart from the observations' one: a single pass over both would back-propagate through both halves
        (a step 17 vs 10 ms at SB3's network, 17 vs 13 ms at the defaults, measured here)."""
        cfg: DQNConfig = self.config
        action, next_observation = sample["action"], sample["next", "observation"]
        q_taken = self.q_network(sample["observation"]).gather(-1, action.unsqueeze(-1)).squeeze(-1)
        with torch.no_grad():
            next_q = self.target_q_network(next_observation)
            next_choice = self.q_network(next_observation) if cfg.double_dqn else next_q
            next_value = next_q.gather(-1, next_choice.argmax(-1, keepdim=True))
            target = td0_return_estimate(
                self.loss.value_estimator.gamma, next_value, sample["next", "reward"], sample["next", "terminated"]
            ).squeeze(-1)
            if cfg.advantage_learning:
                target = target - cfg.advantage_learning * action_gap(self.target_q_network(sample["observation"]), action)
        loss = sample_mean(distance_loss(q_taken, target, cfg.loss_function), self.lead)
        self.optimizer.zero_grad(set_to_none=True)
        loss.sum().backward()  # replicas: each replica's gradient is its own loss's
        clip_grad_norm_(self._online, cfg.max_grad_norm, self.lead)
        self.optimizer.step()
        if isinstance(self.target_updater, SoftUpdate):
            # SoftUpdate's arithmetic (its weight, 1 - eps) in one foreach call instead of a lerp_ per tensor through
            # tensordict lookups; tests/test_dqn.py holds the two equal.
            with torch.no_grad():
                foreach_lerp_(self._target, self._online, 1 - self.target_updater.eps)
        else:
            self.target_updater.step()
        return loss.detach()

    def modules(self) -> dict[str, torch.nn.Module]:
        return {"loss": self.loss, "greedy": self.greedy}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"adam": self.optimizer}

    def state_dict(self) -> dict[str, Any]:
        # The target network's weights live in the loss module; a hard updater also counts steps to its next copy.
        counter = getattr(self.target_updater, "counter", 0)
        return {**super().state_dict(), "updates": self.updates, "target_counter": counter}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        # A loaded optimiser state brings its implementation flags: a checkpoint of the per-tensor Adam runs fused on.
        for group in self.optimizer.param_groups:
            group.update(self._adam_flags)
        self.updates = state["updates"]
        if hasattr(self.target_updater, "counter"):
            self.target_updater.counter = state["target_counter"]
