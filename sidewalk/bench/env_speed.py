"""Env-steps per second of both Sidewalk domains, and of VMAS ``give_way`` beside them when VMAS is installed.

Each measurement runs ``step_and_maybe_reset`` in a loop with fresh random actions and auto-reset, as a
TorchRL collector drives an env. VMAS runs through TorchRL's own ``VmasEnv`` wrapper, in the same process and
loop, so the ratio compares like with like.
"""

from __future__ import annotations

import argparse
import importlib.util
import warnings
from collections.abc import Sequence

import torch
from tensordict import TensorDictBase

from sidewalk.bench.common import env_steps_per_s, format_table, torch_threads
from sidewalk.envs import AGENT_GROUP, ContinuousSidewalkEnv, DiscreteSidewalkEnv

NUM_ENVS = (1, 64, 1024, 4096, 16384)
THREADS = (1, 2)
VMAS_SCENARIO = "give_way"  # VMAS's closest scenario: two agents must pass each other in a narrow corridor


def _random_actions(env) -> callable:
    """A function writing uniform random actions into a tensordict, drawn with a generator of its own."""
    spec = env.full_action_spec[AGENT_GROUP, "action"]
    generator = torch.Generator(device=env.device).manual_seed(0)
    if isinstance(env, DiscreteSidewalkEnv):
        n = int(spec.space.n)

        def set_action(td: TensorDictBase) -> TensorDictBase:
            td.set((AGENT_GROUP, "action"), torch.randint(n, spec.shape, generator=generator, device=env.device))
            return td

    else:
        low, high = spec.space.low, spec.space.high

        def set_action(td: TensorDictBase) -> TensorDictBase:
            unit = torch.rand(spec.shape, generator=generator, device=env.device)
            td.set((AGENT_GROUP, "action"), low + (high - low) * unit)
            return td

    return set_action


def make_vmas(num_envs: int):
    """VMAS ``give_way`` through TorchRL's wrapper with the same 300-step timeout, or None if VMAS is absent."""
    if importlib.util.find_spec("vmas") is None:
        return None
    from torchrl.envs.libs.vmas import VmasEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return VmasEnv(VMAS_SCENARIO, num_envs=num_envs, continuous_actions=True, max_steps=300, seed=0)


def run(
    num_envs: Sequence[int] = NUM_ENVS, threads: Sequence[int] = THREADS, seconds: float = 1.0
) -> list[dict]:
    """One row per (threads, num_envs): env-steps/s of each domain, of VMAS give_way, and our/VMAS ratios."""
    rows = []
    for n_threads in threads:
        with torch_threads(n_threads):
            for n in num_envs:
                row: dict = {"threads": n_threads, "num_envs": n}
                for name, cls in (("discrete", DiscreteSidewalkEnv), ("continuous", ContinuousSidewalkEnv)):
                    env = cls(num_envs=n, seed=0)
                    row[f"{name} steps/s"] = env_steps_per_s(env, _random_actions(env), min_seconds=seconds)
                vmas = make_vmas(n)
                if vmas is not None:
                    row["vmas give_way steps/s"] = env_steps_per_s(vmas, _random_actions(vmas), min_seconds=seconds)
                    row["discrete/vmas"] = row["discrete steps/s"] / row["vmas give_way steps/s"]
                    row["continuous/vmas"] = row["continuous steps/s"] / row["vmas give_way steps/s"]
                rows.append(row)
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=list(NUM_ENVS))
    parser.add_argument("--threads", type=int, nargs="+", default=list(THREADS))
    parser.add_argument("--seconds", type=float, default=1.0, help="timed seconds per measurement")
    args = parser.parse_args(argv)
    print(format_table(run(args.num_envs, args.threads, args.seconds)))


if __name__ == "__main__":
    main()
