"""The Sidewalk Problem: a benchmark for cooperative stochastic games and interactive decision making."""

from importlib.util import find_spec as _find_spec

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv, RewardParams
from sidewalk.version import __version__

if _find_spec("gymnasium") is not None:  # registers sidewalk/Discrete-v0, sidewalk/Continuous-v0 and their Safety-
    from sidewalk.interop import gymnasium as _gymnasium_registration  # noqa: F401  # Gymnasium twins (6-tuple step)
    from sidewalk.interop import safety_gymnasium as _safety_registration  # noqa: F401

__all__ = ["ContinuousSidewalkEnv", "DiscreteSidewalkEnv", "RewardParams", "__version__"]
