"""The random opponent: uniform random actions, drawn from the env's generator(s) (paper §4.1)."""

from __future__ import annotations

import torch

from sidewalk.envs.grid import ACTIONS
from sidewalk.opponents.base import Opponent, env_domain


class RandomOpponent(Opponent):
    """Uniform random actions: one of the four moves in the grid, a uniform (acceleration, turn) within the
    bounds in the continuous world. It mostly acts as a moving obstacle."""

    name = "random"
    per_replica = False  # draws through env.randint/env.rand, which draw each replica's worlds from its generator
    batch_invariant = True

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        env, shape = self.env, (state.shape[0], len(self.controlled))
        if env_domain(env) == "discrete":
            return env.randint(len(ACTIONS), shape)
        p = env.params
        high = torch.tensor([p.max_accel_mps2, p.max_turn_rad], device=env.device)
        return (2.0 * env.rand((*shape, 2)) - 1.0) * high
