"""The sidewalk salsa: a partner that picks a side to pass on with a cultural bias and re-decides, after a
reaction time, when the oncoming agent mirrors it (``opponent=salsa``), in both domains.

After "A Model of the Sidewalk Salsa" (O. Siebinga, arXiv:2412.04023, 2024; IEEE SMC 2025): two pedestrians who
meet head on each plan a path that keeps their perceived risk of meeting the other below a threshold; a cultural
bias in the belief about which side the other passes on makes them agree more often, and when both deviate to the
same side each replans, which can repeat, back and forth. The paper's pedestrians optimise a 7 s plan against a
probabilistic belief; ours keep three of its mechanisms as rules, computed for every world at once:

- it walks the centre line until another present agent is ahead of it, coming, within ``notice_fraction`` of the
  sidewalk's length; then it steps onto a lane ``lane_fraction`` of the free half-width to its right (probability
  ``right_prob``, drawn per world at each reset from the env's generator) or its left;
- while that agent is ahead and on the same side of the centre line as its lane (the mirrored position), it counts
  the steps; after ``reaction_steps`` of them it switches to the other side with probability ``switch_prob``, and
  counts again. ``switches`` (B, C) counts each world's switches since its reset: the salsa's steps.

Where the numbers come from. The 7 s plan is in the paper's text; the 1.2 : 0.8 weights and the 0.25 s plan step are
our reading of the simulations published with its code (sidewalk 2.5 m × 15 m, 1.3 m/s, step 50 ms), not re-checked:

| parameter | default | source |
| --- | --- | --- |
| ``right_prob`` | 0.6 | the paper's code as we read it: its biased belief weighs the two passing sides 1.2 : 0.8, a 60 : 40 split; it biases a belief, we take the split as the share of worlds in which it first picks its right |
| ``notice_fraction`` | 1.0 | the paper: its pedestrians plan 7 s ahead, more than the 5.8 s two of them need to close a 15 m sidewalk at 1.3 m/s each, so each sees the other from the start: here the whole sidewalk (4 m, 14 cells) |
| ``reaction_steps`` | 1 | the paper's code as we read it: it replans whenever its risk passes the threshold, on plans of 0.25 s steps (4 Hz); 0.25 s is 1 step of our continuous world's 0.2 s (the grid: 1 step). Its perception lag (a first-order filter of the other's speed and heading, rate 0.25 /s) has no counterpart here |
| ``switch_prob`` | 0.5 | ours: the paper has no such number (its switches come from the risk); a re-decision with no side preferred |
| ``lane_fraction`` | 0.6 | ours (the conventions' lane: 0.72 m off the centre line; 2 of 3 grid cells): the paper keeps a 0.3 m comfortable range around bodies 0.25 m apart at contact, ours touch at 0.6 m |
| ``lookahead_m`` | 0.4 m | ours: it steers for a point this far ahead on its lane, a sharper step aside than the conventions' 0.8 m, so it clears a walker on the centre line of our 4 m sidewalk |

It walks, merges onto its goal and waits as the conventions do (``sidewalk.opponents.convention``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from sidewalk._checks import check_int, check_range
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.opponents.convention import LANE_FRACTION, ConventionOpponent

# The share of worlds in which it first picks its right: the paper's code's 1.2 : 0.8 bias, as we read it.
RIGHT_PROB = 0.6
NOTICE_FRACTION = 1.0  # it picks its side once the oncoming agent is within this share of the sidewalk's length
# Steps of mirrored position before it re-decides: its code's 0.25 s plan step, as we read it (1 step of 0.2 s).
REACTION_STEPS = 1
SWITCH_PROB = 0.5  # the chance that a re-decision switches sides (ours)


class SalsaOpponent(ConventionOpponent):
    """A side-biased walker that mirrors back when mirrored (see the module docstring); ``right_prob``,
    ``notice_fraction``, ``reaction_steps``, ``switch_prob`` and ``lane_fraction`` as described there."""

    name = "salsa"
    lookahead_m = 0.4  # continuous: a sharper step aside than the conventions' (see the module docstring)

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled: Sequence[int] = (1,),
        ego: int | None = 0,
        *,
        right_prob: float = RIGHT_PROB,
        notice_fraction: float = NOTICE_FRACTION,
        reaction_steps: int = REACTION_STEPS,
        switch_prob: float = SWITCH_PROB,
        lane_fraction: float = LANE_FRACTION,
    ) -> None:
        super().__init__(env, controlled, ego, style="never_yields", lane_fraction=lane_fraction)
        check_range("right_prob", right_prob, 0.0, 1.0)
        check_range("notice_fraction", notice_fraction, 0.0, 1.0, low_open=True)
        check_int("reaction_steps", reaction_steps, 1)
        check_range("switch_prob", switch_prob, 0.0, 1.0)
        self.right_prob, self.notice_fraction = float(right_prob), float(notice_fraction)
        self.reaction_steps, self.switch_prob = reaction_steps, float(switch_prob)
        length = env.layout.cols if self._grid else env.layout.length_m
        self._notice = self.notice_fraction * length
        self.chosen: torch.Tensor | None = None  # (B, C) ±1: the side it passes on (+1 its left)
        self.committed: torch.Tensor | None = None  # (B, C) bool: it has noticed the oncoming agent
        self.mirrored_steps: torch.Tensor | None = None  # (B, C) steps in the mirrored position since its last decision
        self.switches: torch.Tensor | None = None  # (B, C) side switches since the world's reset

    def reset(self, rows: torch.Tensor | None = None) -> None:
        super().reset(rows)
        if self.chosen is None:
            return
        fresh = self._draw_sides(self.chosen.shape, rows)
        every = torch.ones(self.chosen.shape[0], dtype=torch.bool, device=self.chosen.device) if rows is None else rows
        mask = every.unsqueeze(-1)
        self.chosen = torch.where(mask, fresh, self.chosen)
        for counts in (self.committed, self.mirrored_steps, self.switches):
            counts.masked_fill_(mask, 0)

    def _draw_sides(self, shape: tuple[int, ...], rows: torch.Tensor | None = None) -> torch.Tensor:
        right = self.env.rand(tuple(shape), rows) < self.right_prob
        return torch.where(right, -1, 1)

    def act(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None = None
    ) -> torch.Tensor:
        shape = (state.shape[0], len(self.controlled))
        if self.chosen is None or self.chosen.shape != shape:
            self.chosen = self._draw_sides(shape).to(state.device)
            self.committed = torch.zeros(shape, dtype=torch.bool, device=state.device)
            self.mirrored_steps = torch.zeros(shape, dtype=torch.long, device=state.device)
            self.switches = torch.zeros(shape, dtype=torch.long, device=state.device)
        self._decide(state, goal, done, present)
        return super().act(state, goal, done, present)

    def _decide(
        self, state: torch.Tensor, goal: torch.Tensor, done: torch.Tensor, present: torch.Tensor | None
    ) -> None:
        """Commit to a side once the oncoming agent is near; re-decide after ``reaction_steps`` mirrored steps."""
        along_axis, across_axis = (1, 0) if self._grid else (0, 1)
        index = self._controlled_index
        along, across = state[..., along_axis].float(), state[..., across_axis].float()
        heading = torch.where(goal[:, index, along_axis].float() >= along[:, index], 1.0, -1.0)  # (B, C)
        ahead, coming = self._oncoming(along, heading, state, done, present, self._notice)  # (B, C, N)
        nearest = torch.where(coming, ahead, torch.inf).argmin(-1)  # (B, C): the oncoming agent nearest ahead
        noticed = coming.any(-1)
        self.committed |= noticed
        centre = self.env.layout.center_row if self._grid else self.env.layout.width_m / 2
        # Its lane's side of the centre line in world coordinates (+: larger across), and the other's.
        toward_left = -1.0 if self._grid else 1.0  # the grid's rows grow to the right of a walker heading +col
        lane_offset = toward_left * heading * self.chosen
        other_offset = across.gather(1, nearest) - centre
        mirrored = noticed & (other_offset * lane_offset > 0) & (other_offset.abs() >= self._lateral_slack())
        self.mirrored_steps = torch.where(mirrored, self.mirrored_steps + 1, torch.zeros_like(self.mirrored_steps))
        deciding = self.mirrored_steps >= self.reaction_steps
        switch = deciding & (self.env.rand(tuple(deciding.shape)) < self.switch_prob)
        self.chosen = torch.where(switch, -self.chosen, self.chosen)
        self.switches += switch.long()
        self.mirrored_steps = self.mirrored_steps.masked_fill(deciding, 0)

    def _lateral_slack(self) -> float:
        """How far from the centre line the other must be to stand on a side: half a cell, or a tenth of a metre."""
        return 0.5 if self._grid else 0.1

    def _lane_side(self) -> torch.Tensor:
        side = torch.where(self.committed, self.chosen, torch.zeros_like(self.chosen))
        return side if self._grid else side.float()
