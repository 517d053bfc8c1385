"""QMIX for the discrete Sidewalk in self-play (``opponent=self``): the team's Q-value is a monotone mix of the
agents', with mixing weights made by hypernetworks from the global state (Rashid et al. 2018; TorchRL's
``sota-implementations/multiagent/qmix_vdn.py``). VDN's learner (``sidewalk.algos.vdn``) with ``QMixer``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torchrl.envs import EnvBase
from torchrl.modules import QMixer

from sidewalk._checks import check_int
from sidewalk.algos.iql import CHOSEN_ACTION_VALUE_KEY
from sidewalk.algos.vdn import TEAM_VALUE_KEY, VDN, InPlayMixer, VDNConfig

STATE_KEY = "state"  # the self-play view's global state (batch, 5·N), stored beside each transition


@dataclass
class QMIXConfig(VDNConfig):
    """QMIX settings: VDN's plus the mixer's embedding width (32: PyMARL's and TorchRL's example's)."""

    name: str = "qmix"
    mixing_embed_dim: int = 32

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int("algo.mixing_embed_dim", self.mixing_embed_dim, 1)


class QMIX(VDN):
    """Q_tot = mixer(Q_1(o_1, a_1), ..., Q_N(o_N, a_N); s), monotone in every Q_i, trained on VDN's team reward.

    The global state ``s`` is the self-play view's root ``"state"`` (``SidewalkEnvBase.global_state``), the true
    world, which no agent observes whole: every agent's cell and goal, scaled to [0, 1] by the grid's extent, and its
    presence flag (5·N numbers, in agent order). It is smaller and exact where the agents' images are large and
    ego-centric.
    """

    name = "qmix"
    domains = ("discrete",)
    Config = QMIXConfig
    TRANSITION_KEYS: ClassVar[tuple[NestedKey, ...]] = (*VDN.TRANSITION_KEYS, STATE_KEY, ("next", STATE_KEY))

    def _make_mixer(self, env: EnvBase) -> TensorDictModule:
        cfg: QMIXConfig = self.config
        mixer = QMixer(
            state_shape=env.full_observation_spec_unbatched[STATE_KEY].shape, mixing_embed_dim=cfg.mixing_embed_dim,
            n_agents=self.n_agents, device=self.device,
        )
        return TensorDictModule(
            InPlayMixer(mixer), in_keys=[CHOSEN_ACTION_VALUE_KEY, self.MASK_KEY, STATE_KEY], out_keys=[TEAM_VALUE_KEY]
        )
