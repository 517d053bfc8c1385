"""Learners: one file each (dqn, trpo, ppo), each with its dataclass config."""
