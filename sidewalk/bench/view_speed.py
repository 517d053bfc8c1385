"""Env-steps per second of the learner's views: each ego view with its opponents, the centralized view, and the
gymnasium vector face of the ego view against the random opponent.

TorchRL views run ``step_and_maybe_reset`` in a loop with fresh random actions and auto-reset, as a collector
drives an env; the gymnasium rows run ``step`` of ``gymnasium.make_vec`` (one batched core, next-step autoreset)
with numpy actions. An opponent whose module is not installed gets a row with a note instead of a number.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence

import gymnasium
import torch
from tensordict import TensorDictBase

from sidewalk.bench.common import env_steps_per_s, format_table, torch_threads
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.interop.gymnasium import ENV_IDS
from sidewalk.views import make_view

NUM_ENVS = 4096
# (domain, core class, opponents of the ego view): the SPEC's opponents of each domain.
CASES = (
    ("discrete", DiscreteSidewalkEnv, ("random", "dijkstra")),
    ("continuous", ContinuousSidewalkEnv, ("random", "prm")),
)
COLUMNS = ("threads", "num_envs", "face", "view", "domain", "opponent", "env_steps_per_s", "note")


def _random_actions(view) -> Callable[[TensorDictBase], TensorDictBase]:
    """A function writing uniform random view actions into a tensordict, from a generator of its own."""
    spec = view.full_action_spec["action"]
    generator = torch.Generator(device=view.device).manual_seed(0)
    if spec.domain == "discrete":
        n = int(spec.space.n)

        def set_action(td: TensorDictBase) -> TensorDictBase:
            td.set("action", torch.randint(n, spec.shape, generator=generator, device=view.device))
            return td

    else:
        low, high = spec.space.low, spec.space.high

        def set_action(td: TensorDictBase) -> TensorDictBase:
            td.set(
                "action", low + (high - low) * torch.rand(spec.shape, generator=generator, device=view.device)
            )
            return td

    return set_action


def gymnasium_steps_per_s(
    envs: gymnasium.vector.VectorEnv, min_seconds: float = 1.0, warmup_steps: int = 10
) -> float:
    """Env-steps per second of a gymnasium vector env's ``step`` with pre-drawn random actions."""
    envs.action_space.seed(0)
    actions = [envs.action_space.sample() for _ in range(16)]
    envs.reset(seed=0)
    for step in range(warmup_steps):
        envs.step(actions[step % len(actions)])
    steps, start = 0, time.perf_counter()
    while True:
        for _ in range(10):
            envs.step(actions[steps % len(actions)])
            steps += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return steps * envs.num_envs / elapsed


def _as_list(value: int | Sequence[int]) -> list[int]:
    return [value] if isinstance(value, int) else list(value)


def run(
    num_envs: int | Sequence[int] = NUM_ENVS, threads: int | Sequence[int] = 1, seconds: float = 1.0
) -> list[dict]:
    """One row per (threads, num_envs, face, view, domain, opponent): env-steps/s of that view.

    ``num_envs`` and ``threads`` take one value or several (``runners/bench.py`` passes lists).
    """
    rows = []
    for n_threads in _as_list(threads):
        with torch_threads(n_threads):
            for n in _as_list(num_envs):
                rows += _measure(n, n_threads, seconds)
    return [{column: row.get(column) for column in COLUMNS} for row in rows]


def _measure(num_envs: int, threads: int, seconds: float) -> list[dict]:
    rows = []
    for domain, cls, opponents in CASES:
        base = {"threads": threads, "num_envs": num_envs, "domain": domain}
        for opponent in opponents:
            row = {**base, "face": "torchrl", "view": "ego", "opponent": opponent}
            view = make_view("ego", cls(num_envs=num_envs, seed=0), opponent=opponent)
            row["env_steps_per_s"] = env_steps_per_s(view, _random_actions(view), min_seconds=seconds)
            rows.append(row)
        view = make_view("centralized", cls(num_envs=num_envs, seed=0))
        rate = env_steps_per_s(view, _random_actions(view), min_seconds=seconds)
        rows.append(
            {**base, "face": "torchrl", "view": "centralized", "opponent": "-", "env_steps_per_s": rate}
        )
        envs = gymnasium.make_vec(ENV_IDS[domain], num_envs=num_envs, opponent="random", seed=0)
        rate = gymnasium_steps_per_s(envs, min_seconds=seconds)
        rows.append(
            {**base, "face": "gymnasium", "view": "ego", "opponent": "random", "env_steps_per_s": rate}
        )
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[NUM_ENVS])
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--seconds", type=float, default=1.0, help="timed seconds per measurement")
    args = parser.parse_args(argv)
    print(format_table(run(args.num_envs, args.threads, args.seconds)))


if __name__ == "__main__":
    main()
