"""How a pass feels: the social measures of two agents meeting on the sidewalk, per episode, for every world at once.

Measured on the two-agent worlds (``sidewalk.evaluate`` adds them to its metrics as ``social/...``; worlds of other
sizes have none), from the agents' states step by step, while both are present and neither is done:

- ``salsa_count``: mirrored dodges, steps in which one agent steps sideways toward a side of the sidewalk and the
  other stepped toward the same side in this step or in the ``SALSA_WINDOW_STEPS`` before it, the two walking toward
  each other and not yet past (grid: a change of row; continuous: at least ``LATERAL_STEP_M`` across in a step), so
  each stays in the other's way; a step counts once however many of its sidesteps match;
- ``min_ttc``: the least time to collision over the episode, the two moving on at their current velocities until
  their bodies touch (continuous: seconds, discs of the agent radius; grid: steps until their centres are half a cell
  apart, velocities from the last step's moves); the median over episodes (a pass that never closes in is inf);
- ``jerk``: the root mean square of the rate of change of acceleration (m/s³) of the learner's agent (the ego; all
  agents in other views), the velocity taken from the state's speed and heading; continuous only (NaN in the grid);
- ``intrusion_steps``: steps with the other agent inside the personal space, ``PERSONAL_SPACE_M`` beyond the
  bodies (CrowdNav's discomfort distance; grid: a neighbouring cell, diagonals included); ``intrusion_rate`` the share
  of episodes with at least one;
- who yields first: the first agent to stray ``DEVIATION_M`` (grid: a row) from the straight line from its start to
  its goal while the two are still to pass; the share of episodes in which agent 0, agent 1 (the ego and the
  partner in an ego view) or both in the same step yielded first, and ``no_yield`` where neither did;
- proxemic zones (Hall 1966, with HuNavSim's radii and distance: Pérez-Higueras et al. 2023,
  ``hunav_evaluator/hunav_metrics.py``): each step both are present and active falls in one zone by the distance
  from one agent's body to the other's centre (centres' distance less the agent radius), intimate below 0.45 m,
  personal below 1.2 m, social below 3.6 m, public beyond; ``zone_<name>`` is the mean over episodes of each
  episode's share of such steps (an episode without one counts in none). The grid has no metres: a cell is taken as
  ``GRID_CELL_M`` (one walker's body fits a cell: Fruin's 0.46 × 0.61 m body ellipse), its radius half a cell;
- who ran into whom: at the first collision of the two, the agent whose step carried it further toward the other
  (its displacement along the line between them before the step) ran into the other, both where neither carried it
  ``RAN_INTO_MARGIN`` further (a swap in the grid, a head-on meeting); ``<agent>_ran_into`` and ``both_ran_into`` are
  shares of episodes (0 without a collision).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

PERSONAL_SPACE_M = 0.2  # beyond the two bodies: CrowdNav's discomfort distance (Chen et al. 2019)
GRID_PERSONAL_SPACE_CELLS = 1.5  # centres within this: the same or a neighbouring cell, diagonals included
LATERAL_STEP_M = 0.05  # a sideways step of a continuous agent (a walking step is 0.1 m at 0.5 m/s)
SALSA_WINDOW_STEPS = 1  # a sidestep answering the other's one step later still mirrors it (0.2 s in the continuous world)
DEVIATION_M = 0.2  # off its line by this much, an agent has yielded (grid: one row)
GRID_COLLIDE_CELLS = 0.5
# Hall's (1966) zones with HuNavSim's radii (m): a step is in the first zone whose bound its distance is below.
ZONES = (("intimate", 0.45), ("personal", 1.2), ("social", 3.6), ("public", math.inf))
GRID_CELL_M = 0.5
RAN_INTO_MARGIN = 0.1  # a share of the larger approach: closer than this, both ran into each other
_SHARE = "share of episodes"
# Every key SocialTally.summary may write, with its unit (ego views name the ego and the partner; others agent 0, 1).
SOCIAL_UNITS = {f"social/{name}": unit for name, unit in (
    ("salsa_count", "steps an episode"), ("min_ttc", "s (grid: steps), median"), ("jerk", "m/s³ (grid: none)"),
    ("intrusion_steps", "steps an episode"), ("intrusion_rate", _SHARE), ("ego_yields_first", _SHARE),
    ("partner_yields_first", _SHARE), ("agent0_yields_first", _SHARE), ("agent1_yields_first", _SHARE),
    ("both_yield_first", _SHARE), ("no_yield", _SHARE),
    *((f"zone_{zone}", "share of steps, mean over episodes") for zone, _ in ZONES),
    ("ego_ran_into", _SHARE), ("partner_ran_into", _SHARE), ("agent0_ran_into", _SHARE),
    ("agent1_ran_into", _SHARE), ("both_ran_into", _SHARE))}
SOCIAL_KEYS = tuple(SOCIAL_UNITS)


@dataclass
class SocialTally:
    """Running social measures of B two-agent worlds (see the module docstring)."""

    grid: bool
    dt_s: float
    collide_at: float
    personal_space: float
    start: torch.Tensor  # (B, 2, 2) positions at the reset
    goal: torch.Tensor  # (B, 2, 2)
    previous: torch.Tensor  # (B, 2, 2)
    velocity: torch.Tensor | None  # (B, 2, 2), the last step's
    acceleration: torch.Tensor | None  # (B, 2, 2), the last step's
    salsa: torch.Tensor  # (B,)
    intrusions: torch.Tensor  # (B,)
    min_ttc: torch.Tensor  # (B,)
    jerk_squares: torch.Tensor  # (B, 2)
    jerk_steps: torch.Tensor  # (B, 2)
    first_yield: torch.Tensor  # (B,) long: -1 none yet, 0 or 1 the agent, 2 both in one step
    last_side: torch.Tensor  # (B, 2) the side of each agent's last sidestep (±1, 0 none yet)
    since_side: torch.Tensor  # (B, 2) steps since that sidestep
    zone_steps: torch.Tensor  # (B, zones) steps both present and active spent in each zone
    zone_bounds: torch.Tensor  # (zones - 1,) the inner zones' outer radii, metres
    body_m: float  # the distance from a centre to the body's edge, in metres
    metres: float  # metres in a unit of position (1, or GRID_CELL_M in the grid)
    ran_into: torch.Tensor  # (B,) long: -1 no collision yet, 0 or 1 the agent that ran into the other, 2 both
    window: int = SALSA_WINDOW_STEPS

    @classmethod
    def begin(cls, state: torch.Tensor, goal: torch.Tensor, grid: bool, dt_s: float, radius_m: float) -> SocialTally:
        """Nothing measured yet, for worlds whose agents start at ``state`` (B, 2, ≥2) with goals ``goal`` (B, 2, 2)."""
        start = state[..., :2].float()
        n_worlds, device = start.shape[0], start.device

        def zeros(*shape: int) -> torch.Tensor:
            return torch.zeros(n_worlds, *shape, device=device)

        return cls(
            grid=grid, dt_s=1.0 if grid else dt_s,
            collide_at=GRID_COLLIDE_CELLS if grid else 2 * radius_m,
            personal_space=GRID_PERSONAL_SPACE_CELLS if grid else 2 * radius_m + PERSONAL_SPACE_M,
            start=start, goal=goal.float(), previous=start, velocity=None, acceleration=None,
            salsa=zeros(), intrusions=zeros(), min_ttc=torch.full((n_worlds,), math.inf, device=device),
            jerk_squares=zeros(2), jerk_steps=zeros(2),
            first_yield=torch.full((n_worlds,), -1, dtype=torch.long, device=device),
            last_side=zeros(2), since_side=zeros(2), zone_steps=zeros(len(ZONES)),
            zone_bounds=torch.tensor([bound for _, bound in ZONES[:-1]], device=device),
            body_m=GRID_CELL_M / 2 if grid else radius_m, metres=GRID_CELL_M if grid else 1.0,
            ran_into=torch.full((n_worlds,), -1, dtype=torch.long, device=device),
        )

    def _axes(self) -> tuple[int, int]:
        return (1, 0) if self.grid else (0, 1)  # (along, across): grid (row, col); continuous (x, y)

    def add_step(self, state: torch.Tensor, active: torch.Tensor, collided: torch.Tensor | None = None) -> None:
        """Add a step that left the agents at ``state`` (B, 2, ≥2); ``active`` (B, 2): present, running, not done
        before it; ``collided`` (B,): the two collided in this step (None: no collision is tallied)."""
        now = state[..., :2].float()
        both = active.all(-1)
        velocity = (now - self.previous) if self.grid else _unicycle_velocity(state)
        along, across = self._axes()
        heading = torch.sign(self.goal[..., along] - self.start[..., along])  # (B, 2)
        to_pass = (heading[:, 0] * heading[:, 1] < 0) & (heading[:, 0] * (now[:, 1, along] - now[:, 0, along]) > 0)
        self.salsa += (self._mirrored(now[..., across] - self.previous[..., across]) & to_pass & both).float()
        gap = (now[:, 1] - now[:, 0]).norm(dim=-1)
        self.intrusions += ((gap < self.personal_space) & both).float()
        # Velocities are cells a step in the grid, m/s in the continuous world: times in steps, in seconds.
        ttc = _time_to_collision(now[:, 1] - now[:, 0], velocity[:, 1] - velocity[:, 0], self.collide_at)
        self.min_ttc = torch.where(both, torch.minimum(self.min_ttc, ttc), self.min_ttc)
        self._add_jerk(velocity, active)
        self._add_yield(now, to_pass & both)
        self._add_zone(gap, both)
        if collided is not None:
            self._add_ran_into(now, collided)
        self.previous = now

    def _add_zone(self, gap: torch.Tensor, both: torch.Tensor) -> None:
        distance = gap * self.metres - self.body_m
        zone = torch.bucketize(distance, self.zone_bounds, right=True)  # (B,) index of the first bound above
        self.zone_steps += torch.nn.functional.one_hot(zone, len(ZONES)).float() * both.unsqueeze(-1)

    def _add_ran_into(self, now: torch.Tensor, collided: torch.Tensor) -> None:
        toward = self.previous.flip(1) - self.previous  # (B, 2, 2): each agent's line to the other, before the step
        toward = toward / toward.norm(dim=-1, keepdim=True).clamp(min=1e-9)
        approach = ((now - self.previous) * toward).sum(-1)  # (B, 2)
        larger = approach.max(-1).values
        both = (approach - larger.unsqueeze(-1)).abs().max(-1).values <= RAN_INTO_MARGIN * larger.abs()
        who = torch.where(both, 2, approach.argmax(-1))
        self.ran_into = torch.where((self.ran_into < 0) & collided, who, self.ran_into)

    def _mirrored(self, sideways: torch.Tensor) -> torch.Tensor:
        """(B,) whether a sidestep of this step matches the other's side now or within the window before."""
        side = torch.sign(sideways) * (sideways.abs() >= (0.5 if self.grid else LATERAL_STEP_M))  # (B, 2) ±1 or 0
        self.since_side += 1
        recent = torch.where(self.since_side <= self.window, self.last_side, torch.zeros_like(side))
        now_or_recent = torch.where(side != 0, side, recent)  # this step's sidestep, else a recent one
        matched = (side != 0) & (side == now_or_recent.flip(-1))  # (B, 2): it matches the other's side
        self.last_side = torch.where(side != 0, side, self.last_side)
        self.since_side = self.since_side.masked_fill(side != 0, 0)
        return matched.any(-1)

    def _add_jerk(self, velocity: torch.Tensor, active: torch.Tensor) -> None:
        if self.grid:
            return
        if self.velocity is not None:
            acceleration = (velocity - self.velocity) / self.dt_s
            if self.acceleration is not None:
                jerk = ((acceleration - self.acceleration) / self.dt_s).square().sum(-1)
                self.jerk_squares += jerk * active
                self.jerk_steps += active.float()
            self.acceleration = acceleration
        self.velocity = velocity

    def _add_yield(self, now: torch.Tensor, meeting: torch.Tensor) -> None:
        line = self.goal - self.start
        offset = now - self.start
        off_line = (line[..., 0] * offset[..., 1] - line[..., 1] * offset[..., 0]).abs() / line.norm(dim=-1).clamp(min=1e-6)
        strayed = (off_line >= (1.0 if self.grid else DEVIATION_M)) & meeting.unsqueeze(-1)
        who = torch.where(strayed.all(-1), 2, torch.where(strayed[:, 0], 0, torch.where(strayed[:, 1], 1, -1)))
        self.first_yield = torch.where(self.first_yield < 0, who, self.first_yield)

    def summary(self, ego: int | None) -> dict[str, float]:
        """The measures as ``social/...`` metrics over the episodes (see the module docstring)."""
        first = self.first_yield.cpu().numpy()
        jerk = (self.jerk_squares / self.jerk_steps.clamp(min=1)).sqrt().cpu().numpy()
        steps = self.jerk_steps.cpu().numpy()
        learner = [ego] if ego is not None else [0, 1]
        learner_jerk = jerk[:, learner][steps[:, learner] > 0]
        names = ("ego", "partner") if ego is not None else ("agent0", "agent1")
        order = (ego, 1 - ego) if ego is not None else (0, 1)
        counted = self.zone_steps.sum(-1, keepdim=True)
        zone_shares = (self.zone_steps / counted.clamp(min=1))[counted.squeeze(-1) > 0].cpu().numpy()
        ran_into = self.ran_into.cpu().numpy()
        return {
            **{f"social/zone_{zone}": float(zone_shares[:, index].mean()) if len(zone_shares) else math.nan
               for index, (zone, _) in enumerate(ZONES)},
            f"social/{names[0]}_ran_into": float((ran_into == order[0]).mean()),
            f"social/{names[1]}_ran_into": float((ran_into == order[1]).mean()),
            "social/both_ran_into": float((ran_into == 2).mean()),
            "social/salsa_count": float(self.salsa.mean()),
            "social/min_ttc": float(np.median(self.min_ttc.cpu().numpy())),
            "social/jerk": float(learner_jerk.mean()) if learner_jerk.size and not self.grid else math.nan,
            "social/intrusion_steps": float(self.intrusions.mean()),
            "social/intrusion_rate": float((self.intrusions > 0).float().mean()),
            f"social/{names[0]}_yields_first": float((first == order[0]).mean()),
            f"social/{names[1]}_yields_first": float((first == order[1]).mean()),
            "social/both_yield_first": float((first == 2).mean()),
            "social/no_yield": float((first < 0).mean()),
        }


def _unicycle_velocity(state: torch.Tensor) -> torch.Tensor:
    """(B, N, 2) m/s from the state's speed and heading (x, y, v, θ)."""
    speed, heading = state[..., 2], state[..., 3]
    return torch.stack([speed * torch.cos(heading), speed * torch.sin(heading)], -1)


def _time_to_collision(relative: torch.Tensor, closing: torch.Tensor, collide_at: float) -> torch.Tensor:
    """(B,) time until |relative + closing·t| = ``collide_at`` going on at constant velocity (0 when already there,
    inf when they never get that close); ``closing`` in units per time unit."""
    a = closing.square().sum(-1)
    b = 2 * (relative * closing).sum(-1)
    c = relative.square().sum(-1) - collide_at**2
    discriminant = b.square() - 4 * a * c
    root = (-b - discriminant.clamp(min=0).sqrt()) / (2 * a).clamp(min=1e-12)
    meets = (discriminant >= 0) & (b < 0) & (a > 0)
    return torch.where(c <= 0, torch.zeros_like(c), torch.where(meets, root, torch.full_like(c, math.inf)))
