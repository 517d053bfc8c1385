"""The Sidewalk Problem: a benchmark for cooperative stochastic games and interactive decision making."""

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv, RewardParams

__version__ = "0.1.0"
__all__ = ["ContinuousSidewalkEnv", "DiscreteSidewalkEnv", "RewardParams", "__version__"]
