"""Per-agent reward of the Sidewalk Problem (SPEC §1 "Rewards", paper §3.2 and eq. 2)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from sidewalk._checks import check_int, check_range


@dataclass(frozen=True)
class RewardParams:
    """The reward constants, with the paper's values as defaults.

    ``alpha`` is the cooperation weight of eq. 2 applied to the other agents' goal reward: 1.0 is the paper's
    *explicit* cooperative reward (+1 each when both arrive), 0.0 the *implicit* one. ``c_center`` shapes the grid
    (per cell of distance from the central axis), ``c_potential`` the continuous world (per m² of squared
    distance to the agent's own goal); ``c_progress`` (ours, 0 by default) pays for the step's progress toward the
    agent's own goal -- in the grid per cell the shortest path around the walls shrank (for the scenarios whose
    walls make random exploration lethal), in the continuous world per metre the shortest path around interior
    walls shrank (the straight line where nothing stands between; ``sidewalk.envs.geodesic``; a dense signal like
    VMAS give_way's) -- a potential-based term (Ng et al. 1999: it leaves the optimal policies of the undiscounted
    game as they are). ``shaped_agents`` lists the agents that receive shaping; ``None`` means all of them (the
    paper's centralized continuous run shaped agent 0 only: ``(0,)``).
    """

    c_step: float = -0.01
    c_goal: float = 0.5
    c_collision: float = -0.5
    alpha: float = 1.0
    c_center: float = -0.01
    c_potential: float = -0.0001
    c_progress: float = 0.0  # per cell (grid) / metre (continuous) of progress toward the own goal (0: the paper's)
    shaped_agents: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        for name in ("c_step", "c_goal", "c_collision", "c_center", "c_potential", "c_progress"):
            check_range(name, getattr(self, name))
        check_range("alpha", self.alpha, -1.0, 1.0)
        if self.shaped_agents is not None:
            object.__setattr__(self, "shaped_agents", tuple(self.shaped_agents))
            for agent in self.shaped_agents:
                check_int("shaped_agents[]", agent, 0)

    def shaping_mask(self, n_agents: int, device: torch.device) -> torch.Tensor:
        """A float (n_agents,) mask of the agents that receive shaping."""
        if self.shaped_agents is None:
            return torch.ones(n_agents, device=device)
        bad = [a for a in self.shaped_agents if a >= n_agents]
        if bad:
            raise ValueError(f"shaped_agents={self.shaped_agents} names agent(s) {bad}; valid: 0..{n_agents - 1}")
        mask = torch.zeros(n_agents, device=device)
        mask[list(self.shaped_agents)] = 1.0
        return mask


def compose_reward(
    params: RewardParams,
    shaping_mask: torch.Tensor,
    active: torch.Tensor,
    reached_now: torch.Tensor,
    collided_now: torch.Tensor,
    crashed: torch.Tensor,
    shaping_term: torch.Tensor,
    shaping_weight: float,
) -> torch.Tensor:
    """Reward of each agent for one step, shape (B, N).

    ``active`` marks agents that were not done when the step began: only they pay the step cost, collect their
    own goal or collision reward and receive shaping (``shaping_weight * shaping_term``). The cooperative term
    ``alpha * c_goal`` for every *other* agent reaching its goal this step is paid to every agent that has not
    ``crashed`` (this episode, this step included), done or not: with alpha = 1 both agents end with +1 of goal
    reward when both arrive, whichever arrives first, but an agent that crashed out of the other's way is not paid
    for the other's arrival (SPEC §1: that payment taught learners to crash on purpose).
    """
    own = (
        params.c_step
        + params.c_goal * reached_now
        + params.c_collision * collided_now
        + shaping_weight * shaping_mask * shaping_term
    ) * active
    if params.alpha == 0.0:
        return own
    arrivals = reached_now.to(own.dtype)
    others_arrived = arrivals.sum(-1, keepdim=True) - arrivals
    return own + params.alpha * params.c_goal * others_arrived * ~crashed
