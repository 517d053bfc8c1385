"""Env-steps/s of our random-layout cores as the number of agents grows, beside VMAS ``navigation`` at the same N.

    python runners/bench.py scenarios                      # N = 2, 4, 8, 16 at 4096 worlds, 1 thread
    python runners/bench.py scenarios --agents 2 8 --num-envs 1024 --threads 1 2

Three cores of ours run the ``random`` layout (starts and goals drawn per world and per episode) with ``n_agents=N``:
the grid with ``observation="vector"`` and with the default ``"image"``, and the continuous unicycle world. The room
grows with N so that crowding stays about the same:

- grid: 7 × 15 cells (the paper's sidewalk) up to N = 4, then width ``round(7·sqrt(N/4))`` and length
  ``2·width + 1``, so the area grows like N (one agent per ~26 cells: 10 × 21 at N = 8, 14 × 29 at N = 16);
- continuous: a square of side ``sqrt(N·π·(g/2)² / (ρ/2)) + 2·w`` (rounded up to 0.1 m), the size the random
  layout's "too crowded" error suggests (g: gap between goals, w: wall gap, ρ = 0.4 its density limit) for twice
  the agents, so placement never works at the limit: 4.5 m at N = 2, 6.0 m at N = 4, 8.1 m at N = 8, 11.2 m at
  N = 16. The agents' discs then cover 3–4 % of the world from N = 4 on, as the grid agents their cells. (The rule
  ``sqrt(N·2.2) + 1`` m is too small from N ≈ 12 on: 6.9 m at N = 16 raises "crowd ... at least about 8.1 m".)

VMAS ``navigation`` (N agents with lidar, each with its own goal, collisions on) runs with the same N and number of
worlds, in the same process and thread setting; its spawning square grows like ours, ``world_spawning_x = _y =
sqrt(N/4)`` (VMAS's default 1 at N = 4).

Our cores run as a TorchRL collector drives an env: ``step_and_maybe_reset`` with fresh uniform random actions,
finished worlds reset at once (their ``_reset`` draws new layouts for the masked worlds only). VMAS runs its own
batched ``vmas.simulator.environment.Environment`` (``vmas.make_env``), not TorchRL's ``VmasEnv``: one
``step(get_random_actions())``, then ``reset_at(i, return_observations=False)`` for each done world and
``get_from_scenario`` once for the observations of all worlds. VMAS has no batched partial reset (``reset_at``
takes one index, ``reset()`` resets every world), so a Python loop over the done worlds is the least it costs.
``VmasEnv._reset`` runs that same loop but visits all B entries of the ``_reset`` mask in Python, and adds TensorDict
overheads that ours pay: the bare ``Environment`` is VMAS at its fastest, so the ratio is conservative for us.

Under random actions a ``navigation`` episode ends only at its ``max_steps`` timeout (300 steps, as ours), and
every world would time out at the same step. After the first reset the per-world step counters of every core
(``Environment.steps``, our ``_steps``) are therefore spread uniformly over [0, 300), so ~1/300 of the worlds time
out and are reset each step, as deep into training; ours also end episodes sooner by crashes and arrivals, so they
reset more worlds a step (the ``reset %`` columns, counted during the warm-up): conservative for us again.

Each measurement warms up (≥ 3 steps and ``seconds``), then times ``repeats`` runs of at least ``seconds`` each and
keeps the median. Columns: env-steps/s (worlds × steps / s) of ours and of VMAS, their ratio (target ≥ 10 at every
N), the cost per agent-step (µs per world-step per agent) and that cost divided by the one at the smallest N of the
run (target at N = 16 over N = 2: ≤ 2), the share of worlds reset a step, and the CPU share the process got while
timed (100 % at 1 thread on an idle machine; lower means other work shared the cores and the rates are low and
noisy, the ratios less so since each N measures VMAS and ours back to back).

How our cores scale with N: one step is a fixed sequence of tensor operations over (B, N) tensors; the per-agent
work (moves, walls, rewards, goals, resets) is O(N) per world, and the agent-agent collision checks of ``_advance``
(grid: shared cells and swaps; continuous: the swept closest approach of every pair) build (N, N, B) tensors,
O(N²) per world, as does every observation that lists all agents for each agent (the vector and continuous ones,
N × 6N and N × 8N). The grid image is N ego images of the whole room, O(N · cells), and the room grows with N:
O(N²) per world with a large constant. A reset observes only the worlds it resets (with auto-reset, a few a step)
and gives the others the last output's observations; the continuous pair check computes each unordered pair once
(the relation is symmetric bit for bit). At small N the fixed cost of a step (TorchRL and TensorDict bookkeeping,
small kernels, one layout draw for the worlds reset) dominates, so the cost per agent-step falls as N grows until
the O(N²) parts show; VMAS loops over agents and agent pairs in Python, so its cost per agent-step grows with N.
Measured figures: docs/guide/benchmarks.md, "Scenarios at N agents".
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torchrl.envs import EnvBase

from sidewalk.bench.common import format_table, seconds_per_call, torch_threads
from sidewalk.bench.env_speed import _random_actions
from sidewalk.envs import ContinuousParams, ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.layouts import random_plane

AGENTS = (2, 4, 8, 16)
NUM_ENVS = (4096,)
THREADS = (1,)
SECONDS = 1.0  # timed seconds of each repeat
REPEATS = 3
MAX_STEPS = 300  # episode timeout of every core, ours and VMAS's
DOMAINS = ("grid vector", "grid image", "continuous")
VMAS_SCENARIO = "navigation"
RATIO_TARGET = 10.0  # ours ÷ VMAS env-steps/s, at every N
SCALING_TARGET = 2.0  # cost per agent-step at the largest N ÷ at the smallest

StepFn = Callable[[bool], int]  # one env-step of every world, auto-reset included; returns worlds finished if asked
COLUMNS = ("domain", "N", "world", "num_envs", "threads", "ours steps/s", "vmas steps/s", "ours/vmas",
           "ours µs/agent-step", "vmas µs/agent-step", "ours cost ÷ min N", "vmas cost ÷ min N", "ours reset %",
           "vmas reset %", "ours cpu %", "vmas cpu %")


def grid_room(n_agents: int) -> tuple[int, int]:
    """(width_cells, length_cells) of the grid room for ``n_agents``: 7 × 15 up to 4 agents, then the area grows
    like N (width ``round(7·sqrt(N/4))``, length ``2·width + 1``)."""
    width = round(7 * math.sqrt(max(n_agents, 4) / 4))
    return width, 2 * width + 1


def plane_side_m(n_agents: int, params: ContinuousParams | None = None) -> float:
    """Side (m) of the square continuous world for ``n_agents``: the size the random layout's crowding error
    suggests for twice the agents (half its density limit), rounded up to 0.1 m."""
    params = params or ContinuousParams()
    # The gaps the random layout keeps, read from one in a roomy world.
    probe = random_plane(100.0, 100.0, 1, params.agent_radius_m, params.goal_radius_m, params.min_start_goal_m)
    gap = max(probe.start_gap_m, probe.goal_gap_m)
    area = n_agents * math.pi * (gap / 2) ** 2 / (probe.MAX_DENSITY / 2)
    return math.ceil(10 * (math.sqrt(area) + 2 * probe.wall_gap_m)) / 10


def make_ours(domain: str, num_envs: int, n_agents: int, seed: int = 0) -> tuple[EnvBase, str]:
    """Our ``domain`` core (one of ``DOMAINS``) on the random layout sized for ``n_agents``, and its size in words."""
    if domain == "continuous":
        side = plane_side_m(n_agents)
        env = ContinuousSidewalkEnv(num_envs=num_envs, seed=seed, layout="random", n_agents=n_agents,
                                    length_m=side, width_m=side, max_steps=MAX_STEPS)
        return env, f"{side:g}×{side:g} m"
    width, length = grid_room(n_agents)
    observation = domain.removeprefix("grid ")
    env = DiscreteSidewalkEnv(num_envs=num_envs, seed=seed, layout="random", n_agents=n_agents, width_cells=width,
                              length_cells=length, observation=observation, max_steps=MAX_STEPS)
    return env, f"{width}×{length} cells"


def make_vmas(num_envs: int, n_agents: int, seed: int = 0):
    """VMAS ``navigation`` with ``n_agents`` as VMAS's own batched ``Environment`` (300-step timeout, spawning
    square grown like our worlds), or None when VMAS is not installed."""
    if importlib.util.find_spec("vmas") is None:
        return None
    import vmas

    spawn = math.sqrt(n_agents / 4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return vmas.make_env(VMAS_SCENARIO, num_envs=num_envs, device="cpu", continuous_actions=True,
                             max_steps=MAX_STEPS, seed=seed, n_agents=n_agents, world_spawning_x=spawn,
                             world_spawning_y=spawn)


def _staggered_steps(steps: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """Per-world step counters spread uniformly over [0, max_steps), in the dtype of ``steps``: worlds then time
    out one by one, ~1/max_steps of them a step, as deep into a training run, rather than all at the same step."""
    return torch.randint(MAX_STEPS, steps.shape, generator=generator).to(steps)


def ours_step(env: EnvBase, seed: int = 0) -> StepFn:
    """One ``step_and_maybe_reset`` of every world of our ``env`` with fresh random actions, after a reset with
    staggered timeouts; ``step(count)`` returns the worlds it finished when ``count`` (0 otherwise: no sync)."""
    set_action = _random_actions(env)
    loop = {"td": env.reset()}
    env._steps = _staggered_steps(env._steps, torch.Generator().manual_seed(seed))

    def step(count: bool) -> int:
        out, loop["td"] = env.step_and_maybe_reset(set_action(loop["td"]))
        return int(out["next", "done"].sum()) if count else 0

    return step


def vmas_step(env: Any, seed: int = 0) -> StepFn:
    """One step of every world of the VMAS ``Environment`` ``env`` with VMAS's random actions, then
    ``reset_at(i, return_observations=False)`` for each done world and the observations of all worlds again, after
    a reset with staggered timeouts; ``step(count)`` returns the worlds it finished."""
    env.reset()
    env.steps = _staggered_steps(env.steps, torch.Generator().manual_seed(seed))

    def step(count: bool) -> int:
        _, _, done, _ = env.step(env.get_random_actions())
        worlds = done.nonzero().squeeze(-1).tolist()
        for world in worlds:
            env.reset_at(world, return_observations=False)
        if worlds:
            env.get_from_scenario(get_observations=True, get_rewards=False, get_infos=False, get_dones=False)
        return len(worlds)

    return step


def measure(step: StepFn, num_envs: int, seconds: float = SECONDS, repeats: int = REPEATS) -> dict[str, float]:
    """``steps/s``: the median over ``repeats`` of env-steps/s (worlds × steps / s) of ``step``, each repeat at least
    ``seconds``, after a warm-up of at least 3 steps and ``seconds``; ``reset %``: the share of worlds finished (and
    so reset) per step during the warm-up; ``cpu %``: the CPU time the process got over the timed wall-clock (~100
    at 1 thread on an idle machine; lower when other work shares the cores)."""
    finished: list[int] = []
    seconds_per_call(lambda: finished.append(step(True)), min_seconds=seconds, warmup=3)
    cpu_start, wall_start = time.process_time(), time.perf_counter()
    per_step = statistics.median(
        seconds_per_call(lambda: step(False), min_seconds=seconds, warmup=0) for _ in range(repeats)
    )
    cpu_share = 100 * (time.process_time() - cpu_start) / (time.perf_counter() - wall_start)
    return {"steps/s": num_envs / per_step, "reset %": 100 * sum(finished) / (len(finished) * num_envs),
            "cpu %": cpu_share}


def run(
    agents: Sequence[int] = AGENTS,
    num_envs: Sequence[int] = NUM_ENVS,
    threads: Sequence[int] = THREADS,
    seconds: float = SECONDS,
    repeats: int = REPEATS,
    domains: Sequence[str] = DOMAINS,
) -> list[dict]:
    """One row per (domain, threads, num_envs, N) with the ``COLUMNS``; VMAS is measured once per (threads,
    num_envs, N) and shown beside each of our domains (its columns None when VMAS is not installed)."""
    rows = []
    for n_threads in threads:
        with torch_threads(n_threads):
            for batch in num_envs:
                for n_agents in agents:
                    vmas = make_vmas(batch, n_agents)
                    theirs = measure(vmas_step(vmas), batch, seconds, repeats) if vmas is not None else None
                    del vmas
                    for domain in domains:
                        env, world = make_ours(domain, batch, n_agents)
                        ours = measure(ours_step(env), batch, seconds, repeats)
                        del env
                        rows.append({
                            "domain": domain, "N": n_agents, "world": world, "num_envs": batch, "threads": n_threads,
                            "ours steps/s": ours["steps/s"],
                            "vmas steps/s": theirs and theirs["steps/s"],
                            "ours/vmas": theirs and ours["steps/s"] / theirs["steps/s"],
                            "ours µs/agent-step": 1e6 / (ours["steps/s"] * n_agents),
                            "vmas µs/agent-step": theirs and 1e6 / (theirs["steps/s"] * n_agents),
                            "ours reset %": ours["reset %"],
                            "vmas reset %": theirs and theirs["reset %"],
                            "ours cpu %": ours["cpu %"],
                            "vmas cpu %": theirs and theirs["cpu %"],
                        })
    for row in rows:  # each cost per agent-step over the same core's at the smallest N of the run
        first = next(r for r in rows if (r["domain"], r["num_envs"], r["threads"]) ==
                     (row["domain"], row["num_envs"], row["threads"]) and r["N"] == min(agents))
        for side in ("ours", "vmas"):
            cost, reference = row[f"{side} µs/agent-step"], first[f"{side} µs/agent-step"]
            row[f"{side} cost ÷ min N"] = cost and cost / reference
    domain_order = {d: i for i, d in enumerate(domains)}
    rows.sort(key=lambda r: (r["threads"], r["num_envs"], domain_order[r["domain"]], r["N"]))
    return [{column: row[column] for column in COLUMNS} for row in rows]


def format_rows(rows: list[dict]) -> str:
    """The table, then per (domain, threads, num_envs) whether the two targets hold."""
    lines = [format_table(rows, COLUMNS)]
    for key in dict.fromkeys((r["domain"], r["threads"], r["num_envs"]) for r in rows):
        group = [r for r in rows if (r["domain"], r["threads"], r["num_envs"]) == key]
        low, high = group[0], group[-1]
        scaling = high["ours cost ÷ min N"]
        text = (f"{key[0]} ({key[1]} thread(s), {key[2]} worlds): cost per agent-step N={high['N']} ÷ N={low['N']} "
                f"{scaling:.2f} ({'meets' if scaling <= SCALING_TARGET else 'misses'} ≤ {SCALING_TARGET:g})")
        ratios = [r["ours/vmas"] for r in group if r["ours/vmas"] is not None]
        if ratios:
            worst = min(ratios)
            text += (f"; ours/vmas ≥ {min(ratios):.1f} at every N "
                     f"({'meets' if worst >= RATIO_TARGET else 'misses'} ≥ {RATIO_TARGET:g})")
        lines.append(text)
    return "\n".join(lines)


def _positive_ints(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be ≥ 1")
    return value


def parse_options(argv: Sequence[str]) -> dict[str, Any]:
    """``run``'s keyword arguments from the section's own flags (``--agents``, ``--seconds``, ``--repeats``,
    ``--domains``; ``runners/bench.py`` adds ``--num-envs`` and ``--threads``)."""
    parser = argparse.ArgumentParser(prog="runners/bench.py scenarios", description=__doc__.splitlines()[0])
    parser.add_argument("--agents", type=_positive_ints, nargs="+", default=list(AGENTS), help="agent counts N")
    parser.add_argument("--seconds", type=float, default=SECONDS, help="timed seconds of each repeat")
    parser.add_argument("--repeats", type=_positive_ints, default=REPEATS, help="timed repeats; the median is kept")
    parser.add_argument("--domains", nargs="+", default=list(DOMAINS), choices=DOMAINS)
    args = parser.parse_args(list(argv))
    if not args.seconds > 0:
        parser.error(f"--seconds {args.seconds}: must be > 0")
    return {"agents": args.agents, "seconds": args.seconds, "repeats": args.repeats, "domains": args.domains}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=_positive_ints, nargs="+", default=list(NUM_ENVS))
    parser.add_argument("--threads", type=_positive_ints, nargs="+", default=list(THREADS))
    args, rest = parser.parse_known_args(argv)
    print(format_rows(run(num_envs=args.num_envs, threads=args.threads, **parse_options(rest))))


if __name__ == "__main__":
    main()
