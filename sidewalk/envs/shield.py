"""The safety shields of both domains (``shield=true``): ``grid_shield`` and ``unicycle_shield``, behind the envs'
``shield_action`` (its contract: ``SidewalkEnvBase.shield_action``).

Both follow one rule. Every candidate action of a shielded, still moving agent is stepped once on the env's known
dynamics; it is *wall-safe* when it keeps the agent off the walls, and *agent-safe* when it keeps the agent clear of
everywhere another agent can be after the step (that agent's worst case over all its actions, noise included). An
unsafe proposed action gives way to the best candidate by tiers (``tiered_score``): safe before wall-safe before
neither, and within a tier the candidate nearest the proposed one. Each function reads the state tensors of the env
it is given and changes none of them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from sidewalk.envs.grid import DiscreteSidewalkEnv
    from sidewalk.envs.unicycle import ContinuousSidewalkEnv

UNICYCLE_LEVELS = 5  # the continuous shield's candidate corrections: a 5 × 5 grid of (acceleration, turn)


def tiered_score(tiers: Sequence[tuple[float, torch.Tensor]], within: torch.Tensor | None = None) -> torch.Tensor:
    """A candidate's score: the sum of ``weight × tier`` over ``tiers`` (bools, heaviest first, each weight above
    all lower ones together), plus its preference ``within`` its tier (smaller than the lightest weight)."""
    (weight, tier), *rest = tiers
    score = weight * tier
    for weight, tier in rest:
        score = score + weight * tier
    return score if within is None else score + within


# ---- grid ---------------------------------------------------------------------------------------------------------


def grid_shield(
    env: DiscreteSidewalkEnv, action: torch.Tensor, shielded: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The grid's shield. A move is wall-safe when it stays on the grid and off interior walls, and agent-safe when
    it ends outside every cell another agent can hold after the step: its cell (it may stay parked at its goal, or
    swap with us) and, while it moves, its four neighbours (any of its moves, noise included: four cells are cheap
    to rule out). An unsafe action gives way to a safe one, nearest first: the two perpendicular moves (the one that
    brings the agent closer to its goal first), then the reverse. Where no move is agent-safe, a wall-safe one is
    taken: the shield never steps into a wall while a free cell is next to the agent (a grid cell always has one
    unless walls enclose it). The env's action noise acts after the shield, so with ``noise`` > 0 a replaced action
    can still hit a wall."""
    row, col = env._row.unsqueeze(-1), env._col.unsqueeze(-1)  # (B, N, 1)
    target_row, target_col = row + env._move_row, col + env._move_col  # (B, N, 4)
    wall_safe, target = _grid_wall_safe(env, target_row, target_col)
    safe = wall_safe & _grid_agent_safe(env, row, col, target_row, target_col, target)
    proposed = action.unsqueeze(-1)  # (B, N, 1)
    moves = torch.arange(env._move_row.numel(), device=env.device)
    same = moves == proposed
    # Perpendicular: UP/DOWN (0, 1) against LEFT/RIGHT (2, 3).
    perpendicular = (moves // 2) != (proposed // 2)
    to_goal = (env._goal_row.unsqueeze(-1) - target_row).abs() + (env._goal_col.unsqueeze(-1) - target_col).abs()
    closer = to_goal < ((env._goal_row - env._row).abs() + (env._goal_col - env._col).abs()).unsqueeze(-1)
    score = tiered_score([(64, safe), (32, wall_safe), (8, same), (4, perpendicular), (2, closer)])
    chosen = score.argmax(-1)
    guard = shielded.unsqueeze(0) & env._active
    intervened = guard & (chosen != action)
    return torch.where(intervened, chosen, action), intervened


def _grid_wall_safe(
    env: DiscreteSidewalkEnv, target_row: torch.Tensor, target_col: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Bool (B, N, 4): the move stays on the grid and off interior walls; and each move's target cell, clamped to
    the grid."""
    wall_safe = (target_row >= 0) & (target_row < env.rows) & (target_col >= 0) & (target_col < env.cols)
    target = target_row.clamp(0, env.rows - 1) * env.cols + target_col.clamp(0, env.cols - 1)
    if env._has_blocked:
        wall_safe = wall_safe & ~env._blocked[target]
    return wall_safe, target


def _grid_agent_safe(
    env: DiscreteSidewalkEnv,
    row: torch.Tensor,
    col: torch.Tensor,
    target_row: torch.Tensor,
    target_col: torch.Tensor,
    target: torch.Tensor,
) -> torch.Tensor:
    """Bool (B, N, 4): the move's ``target`` cell is none that another agent in the world may hold after the step."""
    # Cells another agent may hold after the step: (B, N, 5) -- its own, then its four neighbours while active.
    reach_row = torch.cat([row, torch.where(env._active.unsqueeze(-1), target_row, row)], -1)
    reach_col = torch.cat([col, torch.where(env._active.unsqueeze(-1), target_col, col)], -1)
    reach = torch.where(env._present.unsqueeze(-1), reach_row * env.cols + reach_col, -1)
    # (B, i, a, j, c): agent i's move a lands on cell c that agent j may hold.
    hits = target.unsqueeze(-1).unsqueeze(-1) == reach.unsqueeze(1).unsqueeze(1)
    hits = hits & env._not_self.squeeze(-1)[None, :, None, :, None]
    return ~hits.flatten(-2).any(-1)


# ---- unicycle -----------------------------------------------------------------------------------------------------


def unicycle_shield(
    env: ContinuousSidewalkEnv, action: torch.Tensor, shielded: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The continuous shield. Each candidate action -- the proposed one, braking at the proposed turn, then a 5 × 5
    grid of (acceleration, turn) over the bounds -- is stepped on the known dynamics. It is wall-safe when the disc
    after the step, the point where full braking from there would stop it and the midpoint between them stay inside
    the walls and off the boxes: a one-step look-ahead alone lets an agent at full speed reach a place from which it
    cannot stop before the wall (0.4 m of braking from 1 m/s at the SPEC's bounds). It is agent-safe when the agent's
    path in the step keeps two radii from everywhere another agent can be after the step: a disc of radius
    ``(|v| + a_max·dt)·dt`` around it while it moves (its worst case over every action and any action noise, which the
    bounds clip), its own disc when parked. With action noise ±ε a candidate must be safe at the four corners of its
    noise box too (the step is monotone in acceleration and, over turns this small, in the turn), so noise the shield
    can absorb does not defeat it.

    The nearest (in units of the bounds) candidate that is safe under noise replaces an unsafe action; where none
    is, the nearest safe without noise; then the nearest wall-safe one; then braking. A one-step look-ahead cannot
    always leave a way out (an agent cornered by the other's worst case), and noise larger than the room it leaves
    defeats it: tests/test_safety.py measures how often a collision still happens."""
    batch = env.num_envs
    agents = shielded.nonzero().squeeze(-1)
    # Every (world, shielded agent) pair, as flat rows; most proposed actions are safe, so the candidates are
    # looked at only for the pairs whose proposed action is not.
    world = torch.arange(batch, device=env.device).repeat(len(agents))
    agent = agents.repeat_interleave(batch)
    high = env._action_high.view(2, 1, 1)
    proposed = torch.maximum(torch.minimum(action[world, agent].t(), high[:, 0]), -high[:, 0])  # (2, M)
    unsafe = ~_robustly_safe(env, proposed.unsqueeze(1), world, agent)[0] & env._active[world, agent]
    intervened = torch.zeros_like(env._active)
    if not bool(unsafe.any()):
        return action, intervened
    rows = unsafe.nonzero().squeeze(-1)
    world, agent, proposed = world[rows], agent[rows], proposed[:, rows]
    candidates = _unicycle_candidates(env, proposed, world, agent)  # (2, K, m)
    chosen = _unicycle_choice(env, candidates, proposed, world, agent)  # (m,)
    replaced = chosen != 0
    replacement = candidates.gather(1, chosen.view(1, 1, -1).expand(2, 1, -1)).squeeze(1).t()  # (m, 2)
    safe_action = action.clone()
    safe_action[world, agent] = torch.where(replaced.unsqueeze(-1), replacement, action[world, agent])
    intervened[world, agent] = replaced
    return safe_action, intervened


def _unicycle_candidates(
    env: ContinuousSidewalkEnv, proposed: torch.Tensor, world: torch.Tensor, agent: torch.Tensor
) -> torch.Tensor:
    """Float (2, K, m): the candidates of each row, in order: the proposed action (2, m), braking at the proposed
    turn, then the ``UNICYCLE_LEVELS`` × ``UNICYCLE_LEVELS`` grid over the bounds."""
    levels = torch.linspace(-1.0, 1.0, UNICYCLE_LEVELS, device=env.device)
    grid = (torch.cartesian_prod(levels, levels) * env._action_high).t()  # (2, G)
    brake = torch.stack([-torch.sign(env._speed[world, agent]) * env.params.max_accel_mps2, proposed[1]])
    return torch.cat([proposed.unsqueeze(1), brake.unsqueeze(1), grid.unsqueeze(-1).expand(-1, -1, len(world))], 1)


def _unicycle_choice(
    env: ContinuousSidewalkEnv, candidates: torch.Tensor, proposed: torch.Tensor, world: torch.Tensor,
    agent: torch.Tensor,
) -> torch.Tensor:
    """Long (m,): the index of each row's best candidate (``unicycle_shield`` says which is best)."""
    high = env._action_high.view(2, 1, 1)
    wall_safe, clearance = _look_ahead(env, candidates, world, agent)
    safe = wall_safe & (clearance >= 0)
    robust = _robustly_safe(env, candidates, world, agent, nominal=safe)
    # Tiers 4 apart, and within a tier at most 1.75 of preference: the nearest candidate where it is safe, else
    # the one that keeps farthest from the others' reach (the way out of a corner, if the next step has one).
    distance = ((candidates - proposed.unsqueeze(1)) / high).square().sum(0) / 8.0  # within [0, 1]
    within = torch.where(safe, -distance, 1.5 * clearance.clamp(-1.0, 0.0) - 0.25 * distance)
    score = tiered_score([(16.0, robust), (8.0, safe), (4.0, wall_safe)], within)
    score[1] += 1e-6  # among equals (nothing safe), brake
    return score.argmax(0)


def _robustly_safe(
    env: ContinuousSidewalkEnv,
    candidates: torch.Tensor,
    world: torch.Tensor,
    agent: torch.Tensor,
    nominal: torch.Tensor | None = None,
) -> torch.Tensor:
    """Bool (K, M): candidate (2, K, M) of agent ``agent`` in world ``world`` is safe without noise (``nominal``,
    if given, says so already) and at the four corners of its action-noise box."""
    if nominal is None:
        wall_safe, clearance = _look_ahead(env, candidates, world, agent)
        nominal = wall_safe & (clearance >= 0)
    noise = env.params.noise
    if noise == 0.0:
        return nominal
    high = env._action_high.view(2, 1, 1)
    robust = nominal
    for corner in ((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)):
        noisy = candidates + torch.tensor(corner, device=env.device).view(2, 1, 1) * noise
        wall_safe, clearance = _look_ahead(env, torch.maximum(torch.minimum(noisy, high), -high), world, agent)
        robust = robust & wall_safe & (clearance >= 0)
    return robust


def _look_ahead(
    env: ContinuousSidewalkEnv, candidates: torch.Tensor, world: torch.Tensor, agent: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """For candidate actions (2, K, M) -- (acceleration, turn) within the bounds -- of agent ``agent[m]`` in world
    ``world[m]``: bool (K, M), the candidate is wall-safe, and float (K, M), the clearance in metres its path
    keeps from the nearest other agent's reach (agent-safe when ≥ 0; ``unicycle_shield`` says what both mean).
    Rows run last: broadcasting over the long last axis is faster than over trailing axes of 2."""
    p = env.params
    x0, y0 = env._x[world, agent], env._y[world, agent]  # (M,)
    heading = env._heading[world, agent] + candidates[1]
    speed = (env._speed[world, agent] + candidates[0] * p.dt_s).clamp(-p.max_speed_mps, p.max_speed_mps)
    cos, sin = torch.cos(heading), torch.sin(heading)
    dx, dy = speed * cos * p.dt_s, speed * sin * p.dt_s  # (K, M): the step
    x1, y1 = x0 + dx, y0 + dy
    wall_safe = _unicycle_wall_safe(env, x1, y1, speed, cos, sin)
    return wall_safe, _clearance(env, x0, y0, dx, dy, world, agent)


def _unicycle_wall_safe(
    env: ContinuousSidewalkEnv, x1: torch.Tensor, y1: torch.Tensor, speed: torch.Tensor, cos: torch.Tensor,
    sin: torch.Tensor,
) -> torch.Tensor:
    """Bool (K, M): the disc at (x1, y1) after the step, where full braking from there stops it and the midpoint
    between the two stay inside the walls and off the boxes."""
    p = env.params
    # Full braking lowers |v| by a·dt a step: it covers dt·Σ_k max(|v| - k·a·dt, 0) before it stops.
    step_drop = p.max_accel_mps2 * p.dt_s
    k = torch.floor(speed.abs() / step_drop)
    stopping = p.dt_s * (k * speed.abs() - step_drop * k * (k + 1) / 2) * torch.sign(speed)
    xs, ys = x1 + stopping * cos, y1 + stopping * sin
    (x_low, x_high), (y_low, y_high) = env._x_range, env._y_range
    wall_safe = (xs >= x_low) & (xs <= x_high) & (ys >= y_low) & (ys <= y_high)
    wall_safe &= (x1 >= x_low) & (x1 <= x_high) & (y1 >= y_low) & (y1 <= y_high)
    if env._boxes.numel():
        for px, py in ((x1, y1), (xs, ys), ((x1 + xs) / 2, (y1 + ys) / 2)):
            wall_safe &= ~env._touches_box(px, py)
    return wall_safe


def _clearance(
    env: ContinuousSidewalkEnv, x0: torch.Tensor, y0: torch.Tensor, dx: torch.Tensor, dy: torch.Tensor,
    world: torch.Tensor, agent: torch.Tensor,
) -> torch.Tensor:
    """Float (K, M): metres between the agent's path in the step, from (x0, y0) (M,) by (dx, dy) (K, M), and the
    nearest other agent's reach (its worst case in the step, while it moves), less two radii; inf alone."""
    p = env.params
    # (K, N, M): the closest approach of the agent's path in the step to agent j's centre, j over the world's agents.
    to_x = (env._x.index_select(0, world).t() - x0).unsqueeze(0)  # (1, N, M)
    to_y = (env._y.index_select(0, world).t() - y0).unsqueeze(0)
    dx, dy = dx.unsqueeze(1), dy.unsqueeze(1)
    along = ((to_x * dx + to_y * dy) / (dx.square() + dy.square()).clamp_min(1e-12)).clamp(0.0, 1.0)
    gap_sq = (to_x - along * dx).square() + (to_y - along * dy).square()
    # How far agent j can get in the step (its worst case), while it moves.
    step_drop = p.max_accel_mps2 * p.dt_s
    reach = ((env._speed.abs() + step_drop) * p.dt_s * env._active).index_select(0, world).t()  # (N, M)
    keep = 2 * p.agent_radius_m + reach
    others = torch.arange(env.n_agents, device=env.device).unsqueeze(-1) != agent  # (N, M)
    other = others & env._present.index_select(0, world).t()
    return torch.where(other, gap_sq.sqrt() - keep, torch.full_like(gap_sq, math.inf)).amin(1)
