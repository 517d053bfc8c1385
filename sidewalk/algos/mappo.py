"""MAPPO (Yu et al. 2022) from TorchRL parts: IPPO (``sidewalk.algos.ippo``) with a centralised critic.

Every agent's value network reads every agent's observation (``MultiAgentMLP(centralised=True)`` over the per-agent
encoders' features), while each policy still acts on its own observation, so execution stays decentralised. With
``share_params`` one critic gives each agent its own value from one head per agent (the rewards are per agent).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from sidewalk.algos.ippo import IPPO, IPPOConfig


@dataclass
class MAPPOConfig(IPPOConfig):
    """MAPPO settings: IPPO's (the same batch, networks and PPO settings; only the critic's input differs)."""

    name: str = "mappo"


class MAPPO(IPPO):
    """IPPO whose value networks see every agent's observation."""

    name = "mappo"
    domains = ("discrete", "continuous")
    Config = MAPPOConfig
    centralised_critic: ClassVar[bool] = True
