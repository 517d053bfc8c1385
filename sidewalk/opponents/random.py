"""The random opponent: uniform random actions, drawn from the env's generator (paper §4.1)."""

from __future__ import annotations

import torch

from sidewalk.envs.grid import ACTIONS
from sidewalk.opponents.base import Opponent, env_domain


class RandomOpponent(Opponent):
    """Uniform random actions: one of the four moves in the grid, a uniform (acceleration, turn) within the
    bounds in the continuous world. It mostly acts as a moving obstacle."""

    name = "random"

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        env, shape = self.env, (state.shape[0], len(self.controlled))
        if env_domain(env) == "discrete":
            return torch.randint(len(ACTIONS), shape, generator=env.generator, device=env.device)
        p = env.params
        high = torch.tensor([p.max_accel_mps2, p.max_turn_rad], device=env.device)
        return (2.0 * torch.rand((*shape, 2), generator=env.generator, device=env.device) - 1.0) * high
