"""VDN for the discrete Sidewalk in self-play (``opponent=self``): the team's Q-value is the sum of the agents'
(Sunehag et al. 2018; TorchRL's ``sota-implementations/multiagent/qmix_vdn.py``), learned by TD on the team
reward. IQL's agents, exploration and replay (``sidewalk.algos.iql``) with ``VDNMixer`` and ``QMixerLoss``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torchrl.envs import EnvBase
from torchrl.modules import VDNMixer
from torchrl.objectives import LossModule, QMixerLoss

from sidewalk.algos.iql import CHOSEN_ACTION_VALUE_KEY, IQL, IQLConfig

TEAM_VALUE_KEY = "chosen_action_value"  # the mixer's output, Q_tot (batch, 1)


class InPlayMixer(torch.nn.Module):
    """A mixer of only the agents still in play: the chosen Q-values of agents whose own episode ended (the view's
    ``("agents", "info", "mask")`` false, in the state itself and in the next one for the target) enter as 0, so an agent
    that crashed adds nothing to Q_tot and its meaningless actions take no part in the team's greedy target."""

    def __init__(self, mixer: torch.nn.Module) -> None:
        super().__init__()
        self.mixer = mixer

    def forward(self, chosen: torch.Tensor, mask: torch.Tensor, *state: torch.Tensor) -> torch.Tensor:
        return self.mixer(torch.where(mask, chosen, torch.zeros_like(chosen)), *state)


@dataclass
class VDNConfig(IQLConfig):
    """VDN settings: IQL's (``sidewalk.algos.iql.IQLConfig``). The target is ``QMixerLoss``'s, the target
    network's greedy actions mixed by the target mixer (no double-DQN variant: ``double_dqn`` must be false)."""

    name: str = "vdn"
    double_dqn: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.double_dqn:
            raise ValueError(
                f"algo.double_dqn=true is not available for algo={self.name}: QMixerLoss's target takes the target "
                "network's greedy actions (set algo.double_dqn=false)"
            )


class VDN(IQL):
    """Q_tot = Σ_i Q_i(o_i, a_i) over the agents still in play (``InPlayMixer``), trained on the team reward: the sum
    of the agents' rewards (the centralized learner's team reward, so the two learners estimate the same return),
    with the world's done."""

    name = "vdn"
    domains = ("discrete",)
    Config = VDNConfig
    AGENT_NETWORK: ClassVar[str] = "local_value_network"  # QMixerLoss's name for the agents' Q-network
    # The agents' rewards are summed into the root ("next", "reward") when the buffer is filled (``transitions``).
    TRANSITION_KEYS: ClassVar[tuple[NestedKey, ...]] = (
        IQL.OBSERVATION_KEY, IQL.ACTION_KEY, IQL.MASK_KEY, ("next", *IQL.OBSERVATION_KEY), ("next", *IQL.MASK_KEY),
        ("next", "done"), ("next", "terminated"),
    )

    def _make_mixer(self, env: EnvBase) -> TensorDictModule:
        return TensorDictModule(
            InPlayMixer(VDNMixer(n_agents=self.n_agents, device=self.device)),
            in_keys=[CHOSEN_ACTION_VALUE_KEY, self.MASK_KEY], out_keys=[TEAM_VALUE_KEY],
        )

    def _make_loss(self, env: EnvBase, spec) -> LossModule:
        """TD on Q_tot with the team reward and the world's done (QMixerLoss's default root keys)."""
        self.mixer = self._make_mixer(env)  # shares its weights with the loss's online mixer
        loss = QMixerLoss(
            self.actor, self.mixer, delay_value=True, loss_function=self.config.loss_function,
            action_space="categorical",
        )
        loss.set_keys(local_value=CHOSEN_ACTION_VALUE_KEY, global_value=TEAM_VALUE_KEY, action=self.ACTION_KEY)
        return loss

    def reward_gaps(self, sample: TensorDictBase) -> tuple[NestedKey, torch.Tensor]:
        """The team reward and Q_tot's gap to the best joint action under the target networks: the target mixer at
        every agent's best Q-value less at the taken ones (a monotone mixer's best joint action is every agent's
        best; for VDN's sum it is the in-play agents' gaps summed)."""
        q = self.target_q_values(sample)
        chosen = q.gather(-1, sample[self.ACTION_KEY].unsqueeze(-1))
        mixer = self.loss.mixer_network
        rest = [sample.get(key) for key in mixer.in_keys[1:]]  # the mask, and QMIX's state
        with torch.no_grad(), self.loss.target_mixer_network_params.to_module(mixer):
            gap = mixer.module(q.amax(-1, keepdim=True), *rest) - mixer.module(chosen, *rest)
        return ("next", "reward"), gap

    def transitions(self, batch: TensorDictBase) -> TensorDictBase:
        kept = batch.select(*self.TRANSITION_KEYS)
        kept.set(("next", "reward"), batch.get(("next", *self.REWARD_KEY)).sum(-2))
        return kept.reshape(-1)
