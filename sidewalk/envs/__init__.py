"""Batched TorchRL environments of the Sidewalk Problem."""

from sidewalk.envs.base import AGENT_GROUP, INFO_KEYS, OUTCOME_WORDS, SidewalkEnvBase, crashed
from sidewalk.envs.grid import ACTIONS, DiscreteParams, DiscreteSidewalkEnv
from sidewalk.envs.layouts import GridLayout, PlaneLayout, sidewalk_grid, sidewalk_plane
from sidewalk.envs.rewards import RewardParams
from sidewalk.envs.unicycle import ContinuousParams, ContinuousSidewalkEnv

# The one map from a world's domain to its core env class (``sidewalk.world.World.core_class`` reads it).
CORE_ENVS: dict[str, type[SidewalkEnvBase]] = {"discrete": DiscreteSidewalkEnv, "continuous": ContinuousSidewalkEnv}


def core_class(domain: str) -> type[SidewalkEnvBase]:
    """The core env class of ``domain`` (``discrete`` or ``continuous``); ``ValueError`` naming both otherwise."""
    try:
        return CORE_ENVS[domain]
    except (KeyError, TypeError):
        raise ValueError(f"domain={domain!r} is not one of {', '.join(CORE_ENVS)}") from None

__all__ = [
    "ACTIONS",
    "AGENT_GROUP",
    "CORE_ENVS",
    "INFO_KEYS",
    "OUTCOME_WORDS",
    "ContinuousParams",
    "ContinuousSidewalkEnv",
    "DiscreteParams",
    "DiscreteSidewalkEnv",
    "GridLayout",
    "PlaneLayout",
    "RewardParams",
    "SidewalkEnvBase",
    "core_class",
    "crashed",
    "sidewalk_grid",
    "sidewalk_plane",
]
