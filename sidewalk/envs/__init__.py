"""Batched TorchRL environments of the Sidewalk Problem."""

from sidewalk.envs.base import AGENT_GROUP, INFO_KEYS, SidewalkEnvBase
from sidewalk.envs.grid import ACTIONS, DiscreteParams, DiscreteSidewalkEnv
from sidewalk.envs.layouts import GridLayout, PlaneLayout, sidewalk_grid, sidewalk_plane
from sidewalk.envs.rewards import RewardParams
from sidewalk.envs.unicycle import ContinuousParams, ContinuousSidewalkEnv

__all__ = [
    "ACTIONS",
    "AGENT_GROUP",
    "INFO_KEYS",
    "ContinuousParams",
    "ContinuousSidewalkEnv",
    "DiscreteParams",
    "DiscreteSidewalkEnv",
    "GridLayout",
    "PlaneLayout",
    "RewardParams",
    "SidewalkEnvBase",
    "sidewalk_grid",
    "sidewalk_plane",
]
