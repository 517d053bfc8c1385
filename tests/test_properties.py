"""Property tests (hypothesis): every scenario of both domains, built with random legal parameters and driven by
random and goal-seeking actions (continuous ones far outside the bounds too), with auto-reset or explicit partial
resets, keeps SPEC §1's rules at the end of every step:

- the world: agents inside the grid / a radius inside the walls, never on a blocked cell or in an interior box, and
  no centre crossing a box within a step; the limits of the moves (one cell a step; |v| ≤ max speed,
  θ in [-π, π), |Δθ| ≤ max turn, |Δv| ≤ max accel · dt while moving);
- no two present agents in one cell / overlapping (with ``remove_crashed=False``: only two done agents, one of which
  crashed into the other, may share space);
- the step's outcome flags as the rules say (wall, agent collision incl. swaps and swept contact, arrival), read off
  the states before and after the step;
- the reward of SPEC §1 for those flags: step cost, goal, collision, eq. 2's alpha paid to agents not crashed, and
  the shaping (c_center / c_potential and c_progress, from the states, only for ``shaped_agents``);
- the cost: 1 exactly on a step with a wall or agent collision (default ``env.cost``);
- the life cycle: done agents stay done and still until their world resets; per-agent and world done / terminated /
  truncated, ``timed_out`` and ``present`` consistent with the flags and the step count; resets start clean.

The env bugs these properties found have properties of their own at the end, with their minimal examples pinned:
steps long enough to tunnel through a box, and door and circle rooms too small to start their agents apart.

Runtime budget: 12 properties × ``EXAMPLES`` examples of ≤ 60 steps in ≤ 8 worlds: about 30 s for the whole file on
2 CPU cores shared with training jobs (keep it under a minute). Examples are derandomized and no example database is
kept, so CI runs the same examples every time; ``--hypothesis-show-statistics`` lists what the runs exercised.
"""

from __future__ import annotations

import functools
import math
from collections import deque

import pytest
import torch
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st
from torchrl.envs.utils import step_mdp

from sidewalk.envs import (
    AGENT_GROUP,
    INFO_KEYS,
    ContinuousParams,
    ContinuousSidewalkEnv,
    DiscreteParams,
    DiscreteSidewalkEnv,
)
from sidewalk.envs.grid import MOVES
from sidewalk.envs.layouts import scenario_names

SCENARIOS = scenario_names()  # the built-in scenarios, in the paper's order

ACTION = (AGENT_GROUP, "action")
MAX_AGENTS = 6  # keeps the grid's grey levels distinct and a step cheap
EXAMPLES = 30  # per (domain, scenario) case; see the runtime budget above
TOL = 1e-5  # float32 rounding of positions
MARGIN = 1e-4  # oracle checks of contact / bounds skip cases this close to the boundary
PROPERTY = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)


# ---- legal parameters ------------------------------------------------------------------------------------------

WEIGHTS = st.one_of(st.sampled_from([0.0, -0.01, 0.5, -0.5, 1.0]), st.floats(-1.0, 1.0, width=32))


@st.composite
def reward_params(draw, n_agents: int, shaping_name: str) -> dict:
    rewards = {name: draw(WEIGHTS) for name in ("c_step", "c_goal", "c_collision", shaping_name)}
    rewards["alpha"] = draw(st.one_of(st.sampled_from([0.0, 1.0]), st.floats(-1.0, 1.0, width=32)))
    rewards["c_progress"] = draw(st.one_of(st.just(0.0), WEIGHTS))
    rewards["shaped_agents"] = draw(
        st.one_of(st.none(), st.lists(st.integers(0, n_agents - 1), unique=True, max_size=n_agents).map(tuple))
    )
    return rewards


def legal_counts(layout_for, params_type, **geometry) -> list[int]:
    """The agent counts up to MAX_AGENTS that the scenario accepts in this geometry."""
    counts = []
    for n in range(1, MAX_AGENTS + 1):
        try:
            layout_for(params_type(n_agents=n, **geometry))
        except ValueError:
            continue
        counts.append(n)
    return counts


@st.composite
def grid_params(draw, scenario: str) -> dict:
    geometry = {"layout": scenario, "width_cells": draw(st.integers(2, 9)), "length_cells": draw(st.integers(6, 15))}
    if scenario == "random":
        geometry["min_start_goal_cells"] = draw(st.integers(1, 6))
    counts = legal_counts(DiscreteSidewalkEnv.layout_for, DiscreteParams, **geometry)
    assume(counts)
    n_agents = draw(st.sampled_from(counts))
    return {
        **geometry,
        "n_agents": n_agents,
        "noise": draw(st.sampled_from([0.0, 0.1, 0.2, 1.0])),
        "observation": draw(st.sampled_from(["image", "vector"])),
        "remove_crashed": draw(st.booleans()),
        "max_steps": draw(st.one_of(st.just(300), st.integers(1, 12))),
        "rewards": draw(reward_params(n_agents, "c_center")),
    }


DTS_S, SPEEDS_MPS = (0.2, 0.1, 0.5, 1.0), (1.0, 0.5, 2.0)

@st.composite
def plane_params(draw, scenario: str, long_steps: bool = False) -> dict:
    """Legal parameters of the continuous ``scenario``; with ``long_steps``, where the layout has interior boxes,
    only steps at least a disc's diameter long (``max_speed · dt ≥ 2 r``: long enough to tunnel through a box)."""
    geometry = {
        "layout": scenario,
        "length_m": draw(st.floats(3.0, 8.0)),
        "width_m": draw(st.floats(1.5, 5.0)),
        "agent_radius_m": draw(st.sampled_from([0.3, 0.2, 0.4])),
        "goal_radius_m": draw(st.sampled_from([0.3, 0.2, 0.5])),
    }
    if scenario == "random":
        geometry["min_start_goal_m"] = draw(st.floats(0.0, 2.5))
    counts = legal_counts(ContinuousSidewalkEnv.layout_for, ContinuousParams, **geometry)
    assume(counts)
    n_agents = draw(st.sampled_from(counts))
    boxed = bool(plane_layout_of(n_agents, geometry).boxes)
    diameter = 2 * geometry["agent_radius_m"]
    steps = [
        (dt, speed) for dt in DTS_S for speed in SPEEDS_MPS
        if not (boxed and long_steps) or speed * dt >= diameter
    ]
    dt_s, max_speed_mps = draw(st.sampled_from(steps))
    return {
        **geometry,
        "n_agents": n_agents,
        "dt_s": dt_s,
        "max_speed_mps": max_speed_mps,
        "max_accel_mps2": draw(st.sampled_from([1.0, 0.5, 3.0])),
        "max_turn_rad": draw(st.sampled_from([math.pi / 8, math.pi / 4, math.pi])),
        "noise": draw(st.sampled_from([0.0, 0.01, 0.5, 1.5])),
        "remove_crashed": draw(st.booleans()),
        "max_steps": draw(st.one_of(st.just(300), st.integers(1, 12))),
        "rewards": draw(reward_params(n_agents, "c_potential")),
    }


def plane_layout_of(n_agents: int, geometry: dict):
    return ContinuousSidewalkEnv.layout_for(ContinuousParams(n_agents=n_agents, **geometry))


def starts_apart(layout, radius: float) -> bool:
    """No two of a fixed plane layout's start discs overlap."""
    starts = torch.tensor(layout.starts, dtype=torch.float64)
    gaps = torch.cdist(starts, starts) + torch.eye(len(starts)) * 1e9
    return bool(gaps.min() >= 2 * radius - TOL)


RUNS = st.fixed_dictionaries(
    {
        "num_envs": st.integers(1, 8),
        "seed": st.integers(0, 2**31 - 1),
        "steps": st.integers(10, 60),
        "random_share": st.sampled_from([0.0, 0.1, 0.3, 1.0]),  # share of random actions; the rest walk to the goal
        "action_scale": st.sampled_from([1.0, 0.5, 3.0, 1e3]),  # continuous: multiples of the bounds
        "resets": st.sampled_from(["auto", "explicit"]),
        "reset_chance": st.sampled_from([0.0, 0.1]),  # explicit: a world not done is reset anyway
    }
)


# ---- reading a tensordict ---------------------------------------------------------------------------------------


def snapshot(td) -> dict[str, torch.Tensor]:
    """The per-agent entries of one output (B, N[, ...]), flags squeezed, cloned (later steps may reuse memory)."""
    group = td[AGENT_GROUP]
    out = {key: group[key].clone() for key in ("state", "goal")}
    for key in ("terminated", "truncated", "done", "present", "cost"):
        out[key] = group[key].squeeze(-1).clone()
    for key in INFO_KEYS:
        out[key] = group["info", key].squeeze(-1).clone()
    if "reward" in group:
        out["reward"] = group["reward"].squeeze(-1).clone()
    for key in ("terminated", "truncated", "done"):
        out[f"world_{key}"] = td[key].squeeze(-1).clone()
    out["observation"] = group["observation"]
    return out


class BoxCrossed(AssertionError):
    """A disc's centre passed through an interior box within one step (the walls are checked at its end only)."""


class StartsOverlap(AssertionError):
    """Two agents start in one cell / with overlapping discs."""


def holds(ok: torch.Tensor, what: str, error: type[AssertionError] = AssertionError, **shown: torch.Tensor) -> None:
    """Assert ``ok`` everywhere; otherwise name the first (world, agent) where it fails and show the tensors there."""
    if bool(ok.all()):
        return
    where = tuple((~ok).nonzero()[0].tolist())
    # Each tensor shown at the failing entry, or its whole world where it is laid out otherwise.
    details = ", ".join(
        f"{name}={(value[where] if value.shape == ok.shape else value[where[0]]).tolist()}"
        for name, value in shown.items()
    )
    raise error(f"{what} fails at (world, agent) {where}: {details}")


def outcomes(before: dict, after: dict) -> dict[str, torch.Tensor]:
    """The outcome flags of the step (B, N): the sticky episode flags it set."""
    for key in INFO_KEYS:
        holds(after[key] | ~before[key], f"{key} is sticky")
    now = {key: after[key] & ~before[key] for key in INFO_KEYS}
    now["collided"] = now["collided_wall"] | now["collided_agent"]
    return now


def shaping_mask(env) -> torch.Tensor:
    shaped = env.params.rewards.shaped_agents
    mask = torch.ones(env.n_agents, dtype=torch.float64)
    if shaped is not None:
        mask.zero_()[list(shaped)] = 1.0
    return mask


# ---- the rules both domains share ---------------------------------------------------------------------------------


def life_cycle_holds(env, before: dict, after: dict, now: dict, steps: torch.Tensor) -> None:
    """Done agents stay done; done / terminated / truncated, timed_out, present and cost follow the step's flags."""
    active = ~before["terminated"]
    for key in ("reached_goal", "collided_wall", "collided_agent"):
        holds(~now[key] | active, f"only an agent not yet done can have {key} set by a step")
    holds(~(now["reached_goal"] & now["collided"]) & ~(now["collided_wall"] & now["collided_agent"]),
          "one outcome per step", **now)
    outcome_count = after["reached_goal"].int() + after["collided_wall"].int() + after["collided_agent"].int()
    holds(outcome_count <= 1, "one outcome per episode")
    terminated = before["terminated"] | now["reached_goal"] | now["collided"]
    holds(after["terminated"] == terminated, "an agent is terminated once it arrived or crashed, and stays so")
    holds(after["terminated"] == (outcome_count == 1), "terminated is exactly the episode's outcome flags")
    timeout = (steps >= env.params.max_steps).unsqueeze(-1).expand_as(terminated)
    holds(after["truncated"] == (~terminated & timeout), "an agent is truncated at the timeout while not terminated",
          steps=steps, truncated=after["truncated"])
    holds(after["done"] == (terminated | after["truncated"]), "done = terminated | truncated")
    holds(after["timed_out"] == (before["timed_out"] | after["truncated"]), "timed_out records the truncation")
    all_terminated = terminated.all(-1)
    holds(after["world_terminated"] == all_terminated, "the world is terminated when all its agents are")
    holds(after["world_truncated"] == (timeout[:, 0] & ~all_terminated), "the world is truncated at the timeout")
    holds(after["world_done"] == (after["world_terminated"] | after["world_truncated"]), "world done")
    crashed = after["collided_wall"] | after["collided_agent"]
    present = ~crashed if env.params.remove_crashed else torch.ones_like(crashed)
    holds(after["present"] == present, "present: every agent but the crashed ones (remove_crashed)")
    holds(after["cost"] == now["collided"].float(), "cost is 1 exactly on a step with a collision",
          cost=after["cost"])


def reward_holds(env, before: dict, after: dict, now: dict, shaping: torch.Tensor, slack: torch.Tensor) -> None:
    """SPEC §1: (c_step + c_goal·arrived + c_collision·collided + shaping) for agents not done before the step,
    plus alpha · c_goal for every other agent's arrival, paid to the agents that have not crashed. ``shaping``
    (B, N) is the domain's shaping term, known to within ``slack``."""
    r = env.params.rewards
    active = (~before["terminated"]).double()
    arrived, collided = now["reached_goal"].double(), now["collided"].double()
    mask = shaping_mask(env)
    own = (r.c_step + r.c_goal * arrived + r.c_collision * collided + mask * shaping) * active
    others_arrived = arrived.sum(-1, keepdim=True) - arrived
    crashed = after["collided_wall"] | after["collided_agent"]
    expected = own + r.alpha * r.c_goal * others_arrived * (~crashed).double()
    got = after["reward"].double()
    bound = 1e-4 + 1e-5 * expected.abs() + slack * mask * active
    holds((got - expected).abs() <= bound, "reward of SPEC §1", got=got, expected=expected, **now)


def drive(env, run: dict, policy, step_holds, world_holds, start_holds) -> None:
    """Step ``env`` for ``run["steps"]`` steps with ``policy``, checking every step and every reset."""
    generator = torch.Generator().manual_seed(run["seed"])
    td = env.reset()
    world = snapshot(td)
    everywhere = torch.ones(env.num_envs, dtype=torch.bool)
    reset_holds(env, world, world, everywhere, start_holds, world_holds)
    steps = torch.zeros(env.num_envs, dtype=torch.long)
    seen = dict.fromkeys((*INFO_KEYS, "reset"), False)  # what the run exercised (--hypothesis-show-statistics)
    for _ in range(run["steps"]):
        action = policy(env, world, generator, run)
        td.set(ACTION, action)
        if run["resets"] == "auto":
            out, td = env.step_and_maybe_reset(td)
        else:
            out = env.step(td)
            td = step_mdp(out, reward_keys=env.reward_keys, done_keys=env.done_keys, action_keys=env.action_keys)
        after = snapshot(out["next"])
        steps = steps + 1
        holds(torch.isfinite(after["observation"].float()).all().expand(1), "finite observations")
        world_holds(env, after)
        step_holds(env, world, action, after, steps)
        reset = after["world_done"]
        if run["resets"] == "explicit":
            reset = reset | (torch.rand(env.num_envs, generator=generator) < run["reset_chance"])
            if bool(reset.any()):
                td = env.reset(td.set("_reset", reset.unsqueeze(-1)))
        world = snapshot(td)
        reset_holds(env, after, world, reset, start_holds, world_holds)
        steps = steps.masked_fill(reset, 0)
        seen = {key: seen[key] or bool(after.get(key, reset).any()) for key in seen}
    for key, happened in seen.items():
        event(f"{key}: {'yes' if happened else 'no'}")


def reset_holds(env, after: dict, fresh: dict, reset: torch.Tensor, start_holds, world_holds) -> None:
    """The worlds ``reset`` start clean (nobody done, flagged or absent, zero cost, apart, in the world); the others
    go on unchanged."""
    rows = reset.unsqueeze(-1).expand(-1, env.n_agents)
    for key in ("terminated", "truncated", "done", *INFO_KEYS):
        holds(~fresh[key] | ~rows, f"{key} is False after a reset")
    for key in ("terminated", "truncated", "done", "present", *INFO_KEYS):
        holds((fresh[key] == after[key]) | rows, f"{key} of a world not reset goes on")
    holds(fresh["present"] | ~rows, "every agent is present after a reset")
    holds((fresh["cost"] == 0) | ~rows, "no cost on a reset")
    same_state = (fresh["state"] == after["state"]).all(-1) & (fresh["goal"] == after["goal"]).all(-1)
    holds(same_state | rows, "the state of a world not reset goes on")
    if bool(reset.any()):
        start_holds(env, fresh, reset)
        world_holds(env, fresh)


# ---- grid ----------------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def blocked_cells(layout) -> torch.Tensor:
    """Bool (rows, cols): the layout's interior walls."""
    return layout.blocked_mask(torch.device("cpu"))


@functools.lru_cache(maxsize=64)
def grid_paths(layout) -> torch.Tensor:
    """Float (cells, cells): moves on the shortest 4-connected path between free cells (breadth-first search);
    rows·cols where no path joins them."""
    rows, cols = layout.rows, layout.cols
    cells = rows * cols
    free = (~blocked_cells(layout)).view(-1).tolist()
    table = []
    for source in range(cells):
        distance = [cells] * cells
        if free[source]:
            distance[source] = 0
            queue = deque([source])
            while queue:
                cell = queue.popleft()
                row, col = divmod(cell, cols)
                for d_row, d_col in MOVES:
                    r, c = row + d_row, col + d_col
                    nxt = r * cols + c
                    if 0 <= r < rows and 0 <= c < cols and free[nxt] and distance[nxt] == cells:
                        distance[nxt] = distance[cell] + 1
                        queue.append(nxt)
        table.append(distance)
    return torch.tensor(table, dtype=torch.float64)


def grid_policy(env, world: dict, generator: torch.Generator, run: dict) -> torch.Tensor:
    """Random moves, or a shortest-path move toward the goal (random among the best)."""
    row, col = world["state"].unbind(-1)
    goal = world["goal"][..., 0] * env.cols + world["goal"][..., 1]
    move = torch.tensor(MOVES)
    target_row, target_col = row.unsqueeze(-1) + move[:, 0], col.unsqueeze(-1) + move[:, 1]
    inside = (target_row >= 0) & (target_row < env.rows) & (target_col >= 0) & (target_col < env.cols)
    target = target_row.clamp(0, env.rows - 1) * env.cols + target_col.clamp(0, env.cols - 1)
    distance = grid_paths(env.layout)[target, goal.unsqueeze(-1)].masked_fill(~inside, math.inf)
    tie_break = torch.rand(distance.shape, generator=generator, dtype=torch.float64)
    greedy = (distance + 0.5 * tie_break).argmin(-1)
    random_move = torch.randint(4, greedy.shape, generator=generator)
    pick_random = torch.rand(greedy.shape, generator=generator) < run["random_share"]
    return torch.where(pick_random, random_move, greedy)


def grid_world_holds(env, world: dict) -> None:
    """Every agent on a free cell of the grid; no two present agents in one cell (but see ``pairs_allowed``)."""
    row, col = world["state"].unbind(-1)
    inside = (row >= 0) & (row < env.rows) & (col >= 0) & (col < env.cols)
    holds(inside, "agents stay on the grid", row=row, col=col)
    holds(~blocked_cells(env.layout)[row, col], "agents never stand on a blocked cell", row=row, col=col)
    cell = row * env.cols + col
    pairs_allowed(env, world, cell.unsqueeze(-1) == cell.unsqueeze(-2))
    holds((world["state"] == world["goal"]).all(-1) | ~world["reached_goal"], "an arrived agent stands on its goal")


def pairs_allowed(env, world: dict, overlap: torch.Tensor) -> None:
    """No two present agents overlap; with remove_crashed=False a crashed agent stays where it crashed, so two done
    agents may, when one of them crashed into the other."""
    others = ~torch.eye(env.n_agents, dtype=torch.bool)
    present = world["present"]
    overlap = overlap & others & present.unsqueeze(-1) & present.unsqueeze(-2)
    done, crashed = world["terminated"], world["collided_agent"]
    allowed = done.unsqueeze(-1) & done.unsqueeze(-2) & (crashed.unsqueeze(-1) | crashed.unsqueeze(-2))
    if env.params.remove_crashed:
        allowed = torch.zeros_like(allowed)
    holds((~overlap | allowed).flatten(1), "no two present agents overlap (pairs flattened i·N + j)",
          state=world["state"], present=present, terminated=done, collided_agent=crashed)


def grid_start_holds(env, fresh: dict, reset: torch.Tensor) -> None:
    if env.layout.fixed:
        starts, goals = env.layout.sample(int(reset.sum()), torch.Generator())
        holds((fresh["state"][reset] == starts).all(-1), "a fixed layout starts at its starts")
        holds((fresh["goal"][reset] == goals).all(-1), "a fixed layout keeps its goals")
    goal_row, goal_col = fresh["goal"].unbind(-1)
    holds(~blocked_cells(env.layout)[goal_row, goal_col], "goals lie on free cells")
    holds((fresh["state"] != fresh["goal"]).any(-1) | ~reset.unsqueeze(-1), "no agent starts on its goal")
    cell = fresh["state"][reset][..., 0] * env.cols + fresh["state"][reset][..., 1]
    apart = (cell.unsqueeze(-1) != cell.unsqueeze(-2)) | torch.eye(env.n_agents, dtype=torch.bool)
    holds(apart.flatten(1), "agents start in different cells", StartsOverlap)


def grid_step_holds(env, before: dict, action: torch.Tensor, after: dict, steps: torch.Tensor) -> None:
    p = env.params
    active = ~before["terminated"]
    now = outcomes(before, after)
    cols, paths, blocked = env.cols, grid_paths(env.layout), blocked_cells(env.layout)
    cell_before = before["state"][..., 0] * cols + before["state"][..., 1]
    cell_after = after["state"][..., 0] * cols + after["state"][..., 1]
    moved = cell_after != cell_before
    holds((after["state"] - before["state"]).abs().sum(-1) <= 1, "one cell a step at most")
    holds(~moved | active, "a done agent does not move")
    # An agent not done always moves a cell: one that did not hit a wall.
    holds(now["collided_wall"] == (active & ~moved), "hit_wall exactly where an agent not done stays put")
    if p.noise == 0.0:
        move = torch.tensor(MOVES)[action]
        target = before["state"] + move
        inside = ((target >= 0) & (target < torch.tensor([env.rows, env.cols]))).all(-1)
        clamped = torch.minimum(target.clamp_min(0), torch.tensor([env.rows - 1, env.cols - 1]))
        off = ~inside | blocked[clamped[..., 0], clamped[..., 1]]
        holds(
            now["collided_wall"] == (active & off),
            "without noise, a wall hit is a move off the grid or onto a wall",
        )
        holds((after["state"] == target).all(-1) | ~moved, "without noise, an agent moves as its action says")
    # Agent collisions: ending in the cell of a present agent (one removed by its wall hit is gone), or swapping.
    mover = active & moved
    present = before["present"] & ~(now["collided_wall"] & p.remove_crashed)
    others = ~torch.eye(env.n_agents, dtype=torch.bool)
    shared = (cell_after.unsqueeze(-1) == cell_after.unsqueeze(-2)) & present.unsqueeze(-2)
    swapped = (
        (cell_after.unsqueeze(-1) == cell_before.unsqueeze(-2))
        & (cell_before.unsqueeze(-1) == cell_after.unsqueeze(-2))
        & mover.unsqueeze(-2)
    )
    hit_agent = mover & ((shared | swapped) & others).any(-1)
    holds(now["collided_agent"] == hit_agent, "agent collision: same cell or swap", state=after["state"])
    at_goal = (after["state"] == after["goal"]).all(-1)
    holds(now["reached_goal"] == (mover & ~hit_agent & at_goal), "arrival: a move onto the goal without collision")
    life_cycle_holds(env, before, after, now, steps)
    goal_cell = after["goal"][..., 0] * cols + after["goal"][..., 1]
    shaping = p.rewards.c_center * (after["state"][..., 0].double() - env.layout.center_row).abs()
    shaping = shaping + p.rewards.c_progress * (paths[cell_before, goal_cell] - paths[cell_after, goal_cell])
    reward_holds(env, before, after, now, shaping, torch.zeros_like(shaping))


# ---- continuous -------------------------------------------------------------------------------------------------


def wrap(angle: torch.Tensor) -> torch.Tensor:
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


def box_gap(env, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Distance (B, N) from each centre to the nearest interior box (inf without boxes)."""
    gap = torch.full_like(x, math.inf)
    for x0, y0, x1, y1 in env.layout.boxes:
        gap = torch.minimum(gap, torch.hypot(x - x.clamp(x0, x1), y - y.clamp(y0, y1)))
    return gap


def wall_gap(env, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Signed clearance (B, N) of each disc from the border walls and the boxes: ≥ 0 where it touches none."""
    r, length, width = env.params.agent_radius_m, env.layout.length_m, env.layout.width_m
    border = torch.stack([x - r, length - r - x, y - r, width - r - y]).amin(0)
    return torch.minimum(border, box_gap(env, x, y) - r)


def segment_meets_box(env, x0: torch.Tensor, y0: torch.Tensor, x1: torch.Tensor, y1: torch.Tensor, grow: float):
    """Bool (B, N): the segment from (x0, y0) to (x1, y1) meets an interior box grown by ``grow`` (slab test)."""
    meets = torch.zeros_like(x0, dtype=torch.bool)
    for box_x0, box_y0, box_x1, box_y1 in env.layout.boxes:
        enter, leave = torch.zeros_like(x0), torch.ones_like(x0)
        for start, end, low, high in ((x0, x1, box_x0 - grow, box_x1 + grow), (y0, y1, box_y0 - grow, box_y1 + grow)):
            delta = end - start
            moving = delta != 0
            safe = torch.where(moving, delta, torch.ones_like(delta))
            t_low, t_high = (low - start) / safe, (high - start) / safe
            inside = (start >= low) & (start <= high)
            t_in = torch.where(moving, torch.minimum(t_low, t_high), torch.where(inside, -math.inf, math.inf))
            t_out = torch.where(moving, torch.maximum(t_low, t_high), torch.where(inside, math.inf, -math.inf))
            enter, leave = torch.maximum(enter, t_in), torch.minimum(leave, t_out)
        meets |= enter <= leave
    return meets


def plane_policy(env, world: dict, generator: torch.Generator, run: dict) -> torch.Tensor:
    """Random actions up to ``action_scale`` times the bounds (half of them at the corners), or steering toward the
    goal with the turn and the braking unclipped (the env clamps them)."""
    p = env.params
    x, y, v, theta = world["state"].unbind(-1)
    to_goal = wrap(torch.atan2(world["goal"][..., 1] - y, world["goal"][..., 0] - x) - theta)
    accel = torch.where(to_goal.abs() < math.pi / 4, torch.full_like(v, p.max_accel_mps2), -v / p.dt_s)
    greedy = torch.stack([accel, to_goal], -1)
    high = torch.tensor([p.max_accel_mps2, p.max_turn_rad]) * run["action_scale"]
    raw = torch.rand(greedy.shape, generator=generator) * 2 - 1
    corner = torch.rand(greedy.shape, generator=generator) < 0.5
    random_action = torch.where(corner, raw.sign(), raw) * high
    pick_random = torch.rand(greedy.shape[:-1], generator=generator) < run["random_share"]
    return torch.where(pick_random.unsqueeze(-1), random_action, greedy)


def plane_world_holds(env, world: dict) -> None:
    """Every disc inside the walls and off the boxes, within the speed limit, heading in [-π, π); no overlaps."""
    p = env.params
    x, y, v, _ = world["state"].double().unbind(-1)
    holds(wall_gap(env, x, y) >= -TOL, "discs keep a radius from the walls and the boxes", x=x, y=y)
    holds(v.abs() <= p.max_speed_mps + TOL, "|v| ≤ max_speed", v=v)
    theta32 = world["state"][..., 3]
    holds((theta32 >= -math.pi) & (theta32 < math.pi), "heading in [-π, π)", theta=theta32)
    distance = torch.hypot(x.unsqueeze(-1) - x.unsqueeze(-2), y.unsqueeze(-1) - y.unsqueeze(-2))
    pairs_allowed(env, world, distance < 2 * p.agent_radius_m - TOL)
    to_goal = torch.hypot(x - world["goal"][..., 0], y - world["goal"][..., 1])
    holds((to_goal <= p.goal_radius_m + TOL) | ~world["reached_goal"], "an arrived agent is within its goal radius")
    holds((v == 0) | ~world["terminated"], "a done agent stands still", v=v)


def plane_start_holds(env, fresh: dict, reset: torch.Tensor) -> None:
    x, y, v, theta = fresh["state"][reset].unbind(-1)
    holds(v == 0, "agents start at rest")
    if env.layout.fixed:
        starts, headings, goals = env.layout.sample(int(reset.sum()), torch.Generator())
        torch.testing.assert_close(torch.stack([x, y], -1), starts)
        torch.testing.assert_close(torch.cos(theta), torch.cos(headings), atol=1e-5, rtol=0)
        torch.testing.assert_close(torch.sin(theta), torch.sin(headings), atol=1e-5, rtol=0)
        torch.testing.assert_close(fresh["goal"][reset], goals)
    holds(wall_gap(env, x.double(), y.double()) >= -TOL, "starts keep a radius from the walls", x=x, y=y)
    distance = torch.hypot(x.unsqueeze(-1) - x.unsqueeze(-2), y.unsqueeze(-1) - y.unsqueeze(-2))
    apart = (distance >= 2 * env.params.agent_radius_m - TOL) | torch.eye(env.n_agents, dtype=torch.bool)
    holds(apart.flatten(1), "agents start apart (pairs flattened i·N + j)", StartsOverlap, x=x, y=y)


def swept_gap(before: torch.Tensor, after: torch.Tensor) -> torch.Tensor:
    """(B, N, N): the least distance between agents i and j while both move in a straight line through the step."""
    start = before.unsqueeze(-2) - before.unsqueeze(-3)  # (B, N, N, 2)
    delta = (after.unsqueeze(-2) - after.unsqueeze(-3)) - start
    t = (-(start * delta).sum(-1) / delta.square().sum(-1).clamp_min(1e-18)).clamp(0.0, 1.0)
    return (start + t.unsqueeze(-1) * delta).norm(dim=-1)


def plane_step_holds(env, before: dict, action: torch.Tensor, after: dict, steps: torch.Tensor) -> None:
    p = env.params
    active = ~before["terminated"]
    now = outcomes(before, after)
    x0, y0, v0, theta0 = before["state"].double().unbind(-1)
    x1, y1, v1, theta1 = after["state"].double().unbind(-1)
    holds((after["state"][..., :3] == before["state"][..., :3]).all(-1) | ~before["terminated"],
          "a done agent does not move")
    turn = wrap(theta1 - theta0)
    max_turn = torch.where(before["terminated"], 1e-5, p.max_turn_rad + 1e-5)
    holds(turn.abs() <= max_turn, "|Δθ| ≤ max_turn (0 when done)", turn=turn)
    moving = active & ~after["terminated"]
    holds(~moving | ((v1 - v0).abs() <= p.max_accel_mps2 * p.dt_s + TOL), "|Δv| ≤ max_accel·dt while moving",
          v0=v0, v1=v1)
    holds(~moving | ((x1 - x0 - v1 * torch.cos(theta1) * p.dt_s).abs() <= TOL)
          & ((y1 - y0 - v1 * torch.sin(theta1) * p.dt_s).abs() <= TOL), "(x, y) += v·(cos θ, sin θ)·dt")
    holds(~now["collided_wall"] | ((x1 == x0) & (y1 == y0)), "an agent that hits a wall stays where it was")
    crossed = segment_meets_box(env, x0, y0, x1, y1, -MARGIN)
    holds(~crossed, "no centre crosses a box within a step", BoxCrossed, before=before["state"], after=after["state"])
    if p.noise == 0.0:
        accel = action[..., 0].double().clamp(-p.max_accel_mps2, p.max_accel_mps2)
        turn_action = action[..., 1].double().clamp(-p.max_turn_rad, p.max_turn_rad)
        holds(~active | (wrap(theta1 - theta0 - turn_action).abs() <= TOL), "θ += clamp(turn)")
        speed = (v0 + accel * p.dt_s).clamp(-p.max_speed_mps, p.max_speed_mps)
        holds(~moving | ((v1 - speed).abs() <= TOL), "v = clip(v + clamp(a)·dt)")
        x_end, y_end = x0 + speed * torch.cos(theta1) * p.dt_s, y0 + speed * torch.sin(theta1) * p.dt_s
        gap = wall_gap(env, x_end, y_end)
        # A wall hit: the disc ends in a wall, or its centre crosses a box on the way (a long step).
        crosses, may_cross = (segment_meets_box(env, x0, y0, x_end, y_end, margin) for margin in (-MARGIN, MARGIN))
        sure = active & (gap.abs() > MARGIN) & (crosses == may_cross)
        holds(~sure | (now["collided_wall"] == ((gap < 0) | crosses)),
              "without noise, a wall hit is a step into a wall or across a box", gap=gap)
    # Swept contact with any present agent (one removed by its wall hit this step is gone).
    mover = active & ~now["collided_wall"]
    present = before["present"] & ~(now["collided_wall"] & p.remove_crashed)
    gap = swept_gap(before["state"][..., :2].double(), after["state"][..., :2].double())
    others = ~torch.eye(env.n_agents, dtype=torch.bool) & present.unsqueeze(-2)
    contact = ((gap < 2 * p.agent_radius_m) & others).any(-1)
    sure = ~((gap - 2 * p.agent_radius_m).abs() <= MARGIN).any(-1)
    holds(~sure | (now["collided_agent"] == (mover & contact)), "agent collision: swept contact with a present agent")
    to_goal = torch.hypot(x1 - after["goal"][..., 0], y1 - after["goal"][..., 1])
    sure = sure & ((to_goal - p.goal_radius_m).abs() > MARGIN)
    arrives = mover & ~now["collided_agent"] & (to_goal <= p.goal_radius_m)
    holds(~sure | (now["reached_goal"] == arrives), "arrival: within the goal radius without collision")
    life_cycle_holds(env, before, after, now, steps)
    # Shaping: c_potential · d², plus c_progress times the shrinking of the path to the goal; where a box may stand
    # between an agent and its goal the path bends, and the progress term is only bounded by the distance walked (and
    # the path's jump where a line of sight grazes a corner) --
    # unless the step itself came within a radius of a box: a disc may graze a box's corner within a step (only its
    # centre's path and its end are checked), a shortcut no path around the box takes (then the term is not bounded).
    goal_x, goal_y = after["goal"].double().unbind(-1)
    d0, d1 = torch.hypot(goal_x - x0, goal_y - y0), to_goal
    # The line to the goal keeps a radius (and a little) from every box: the shortest path is that line.
    grow = p.agent_radius_m + 1e-3
    straight = ~segment_meets_box(env, x0, y0, goal_x, goal_y, grow)
    straight &= ~segment_meets_box(env, x1, y1, goal_x, goal_y, grow)
    c_progress = p.rewards.c_progress
    shaping = p.rewards.c_potential * to_goal.square() + c_progress * (d0 - d1) * straight
    walked = torch.hypot(x1 - x0, y1 - y0)
    clipped = segment_meets_box(env, x0, y0, x1, y1, p.agent_radius_m - MARGIN)
    # Where a line of sight grazes a box's corner the path may jump by up to 2r(√2 - 1) (sidewalk.envs.geodesic).
    jump = 2 * p.agent_radius_m * (2**0.5 - 1)
    slack = torch.where(clipped, 1e9, abs(c_progress) * (walked + jump + 1e-3)) * ~straight
    reward_holds(env, before, after, now, shaping, slack)


def drive_grid(params: dict, run: dict) -> None:
    env = DiscreteSidewalkEnv(run["num_envs"], seed=run["seed"], **params)
    drive(env, run, grid_policy, grid_step_holds, grid_world_holds, grid_start_holds)


def drive_plane(params: dict, run: dict) -> None:
    env = ContinuousSidewalkEnv(run["num_envs"], seed=run["seed"], **params)
    drive(env, run, plane_policy, plane_step_holds, plane_world_holds, plane_start_holds)


# ---- the properties -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario", SCENARIOS)
@PROPERTY
@given(data=st.data())
def test_grid_keeps_the_rules_in_every_scenario(scenario, data):
    params, run = data.draw(grid_params(scenario), "params"), data.draw(RUNS, "run")
    drive_grid(params, run)


@pytest.mark.parametrize("scenario", SCENARIOS)
@PROPERTY
@given(data=st.data())
def test_continuous_world_keeps_the_rules_in_every_scenario(scenario, data):
    params, run = data.draw(plane_params(scenario), "params"), data.draw(RUNS, "run")
    drive_plane(params, run)


# The door of ContinuousSidewalkEnv(layout="door", n_agents=2, dt_s=1.0): both agents walk straight at their goals;
# a 1 m step carries each across the 0.2 m wall (x 1.9..2.1), from x 1.5 to 2.5, and both arrive.
DOOR_TUNNEL = {
    "layout": "door", "length_m": 4.0, "width_m": 3.0, "agent_radius_m": 0.3, "goal_radius_m": 0.3, "n_agents": 2,
    "dt_s": 1.0, "max_speed_mps": 1.0, "max_accel_mps2": 1.0, "max_turn_rad": math.pi / 8, "noise": 0.0,
    "remove_crashed": True, "max_steps": 300, "rewards": {},
}
WALK_STRAIGHT = {
    "num_envs": 1, "seed": 0, "steps": 3, "random_share": 0.0, "action_scale": 1.0, "resets": "auto",
    "reset_chance": 0.0,
}


# What hypothesis found in the zipper: in world 1, agent 1 cuts the box's corner in one 2 m step, from (1.95, 0.24)
# to (3.50, 1.50), across the box [2.67, 4] × [0, 1].
ZIPPER_CORNER = {
    **DOOR_TUNNEL, "layout": "zipper", "width_m": 2.0, "agent_radius_m": 0.2, "max_speed_mps": 2.0,
    "max_accel_mps2": 3.0, "max_turn_rad": math.pi / 4, "remove_crashed": False,
}
ZIPPER_CORNER_RUN = {
    "num_envs": 2, "seed": 899177, "steps": 10, "random_share": 0.1, "action_scale": 1e3, "resets": "explicit",
    "reset_chance": 0.0,
}
LONG_STEPS = st.one_of(plane_params("door", long_steps=True), plane_params("zipper", long_steps=True))


@settings(PROPERTY)
@example(params=DOOR_TUNNEL, run=WALK_STRAIGHT)
@example(params=ZIPPER_CORNER, run=ZIPPER_CORNER_RUN)
@given(params=LONG_STEPS, run=RUNS)
def test_boxes_stop_steps_of_a_diameter_or_more(params, run):
    """The scenarios with interior boxes, with steps at least a disc's diameter long (max_speed · dt ≥ 2 r): a centre
    that would cross a box is a wall collision (the pinned examples tunnelled through before the swept check)."""
    drive_plane(params, run)


# ContinuousSidewalkEnv(layout="door", n_agents=2, width_m=1.5) started its agents 0.3 m apart (discs of radius 0.3
# overlapping) and circle at width 1.2 m 0.4 m apart: both layouts took more agents than they could start apart.
DOOR_CROWDED = {**DOOR_TUNNEL, "width_m": 1.5, "dt_s": 0.2}
CIRCLE_CROWDED = {**DOOR_CROWDED, "layout": "circle", "width_m": 1.2}


@pytest.mark.parametrize("crowded", [DOOR_CROWDED, CIRCLE_CROWDED, {**DOOR_CROWDED, "width_m": 3.0,
                                                                     "n_agents": 3, "agent_radius_m": 0.4}])
def test_a_room_too_small_to_start_its_agents_apart_is_refused(crowded):
    settings_ = {k: v for k, v in crowded.items() if k != "rewards"}
    with pytest.raises(ValueError, match=f"layout '{crowded['layout']}' takes .* agents in the"):
        ContinuousSidewalkEnv(**settings_)
    # Every count the layout takes in its rooms starts apart (the main properties drive them all).
    geometry = {k: crowded[k] for k in ("layout", "length_m", "width_m", "agent_radius_m", "goal_radius_m")}
    for n_agents in legal_counts(ContinuousSidewalkEnv.layout_for, ContinuousParams, **geometry):
        assert starts_apart(plane_layout_of(n_agents, geometry), geometry["agent_radius_m"])
