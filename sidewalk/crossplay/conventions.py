"""The convention two agents followed on the two-agent sidewalk: the side they passed on and who yielded."""

from __future__ import annotations

from typing import Any

import numpy as np

CONVENTION_COLUMNS = ("row_run", "row_label", "row_seed", "passing_side", "passing_fraction", "yielder", "episodes")


def convention(trajectories: np.ndarray, domain: str, layout: Any) -> dict[str, Any]:
    """The convention two agents followed on the two-agent sidewalk, from positions (T, k, 2, 2) of k episodes (NaN
    once an agent finished; grid (row, col), continuous (x, y)); agent 0 walks along +col / +x, agent 1 the other way.

    - ``passing_side``: at the first step where the agents' along-the-sidewalk coordinates cross, "left" if agent 0
      is on its own left of agent 1 (grid: a smaller row; continuous: a larger y) -- by the half turn agent 1 is then
      on its own left too: both keep left -- "right" the other way; the majority over the episodes that crossed with
      a lateral gap ("none" if none did, crashes and standoffs among them), ``passing_fraction`` its share of all k;
    - ``yielder``: in the episodes that crossed, the agent whose largest distance from the centre line was larger by
      a clear margin (a cell; 0.1 m), in most of them: "agent 0", "agent 1", or "both" (they swerved alike).
    """
    along, lateral, left = (1, 0, -1.0) if domain == "discrete" else (0, 1, 1.0)
    centre, margin = (layout.center_row, 1.0) if domain == "discrete" else (layout.width_m / 2, 0.1)
    episodes = trajectories.shape[1]
    with np.errstate(invalid="ignore"):
        crossed = trajectories[:, :, 0, along] >= trajectories[:, :, 1, along]  # NaN (finished) compares False
        first = crossed.argmax(0)
        gap = left * (trajectories[first, np.arange(episodes), 0, lateral] - trajectories[first, np.arange(episodes), 1, lateral])
        deviation = np.nanmax(np.abs(trajectories[..., lateral] - centre), axis=0)  # (k, 2)
    passed = crossed.any(0) & (gap != 0)
    sides = np.where(gap > 0, "left", "right")[passed]
    if not passed.any():
        return {"passing_side": "none", "passing_fraction": 0.0, "yielder": "none", "episodes": episodes}
    side = max(("left", "right"), key=lambda s: int((sides == s).sum()))
    swerve = deviation[passed, 0] - deviation[passed, 1]
    yielders = np.where(swerve >= margin, "agent 0", np.where(swerve <= -margin, "agent 1", "both"))
    names, counts = np.unique(yielders, return_counts=True)
    return {
        "passing_side": side,
        "passing_fraction": float((sides == side).sum() / episodes),
        "yielder": str(names[counts.argmax()]),
        "episodes": episodes,
    }
