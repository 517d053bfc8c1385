"""A first look: random agents in both domains, 1024 worlds each, with the outcome rates of their episodes.

    python runners/demo.py [--num-envs 1024] [--steps 600] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import torch
from tqdm import tqdm

from sidewalk.envs import AGENT_GROUP, INFO_KEYS, ContinuousSidewalkEnv, DiscreteSidewalkEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    for env in (DiscreteSidewalkEnv(args.num_envs, seed=args.seed), ContinuousSidewalkEnv(args.num_envs, seed=args.seed)):
        start, td = time.perf_counter(), env.reset()
        outcomes = {key: torch.zeros(env.n_agents) for key in INFO_KEYS}
        episodes = 0
        for _ in tqdm(range(args.steps), desc=type(env).__name__, leave=False):
            out, td = env.step_and_maybe_reset(env.rand_action(td))
            ended = out["next", "done"].squeeze(-1)
            episodes += int(ended.sum())
            for key in outcomes:
                outcomes[key] += out["next", AGENT_GROUP, "info", key][ended].squeeze(-1).float().sum(0)
        seconds = time.perf_counter() - start
        print(f"{type(env).__name__}: {episodes} random episodes, {args.num_envs * args.steps / seconds:,.0f} env-steps/s")
        for key, total in outcomes.items():
            rates = ", ".join(f"agent{i} {rate:.3f}" for i, rate in enumerate((total / max(episodes, 1)).tolist()))
            print(f"  {key + ' rate':22s} {rates}")


if __name__ == "__main__":
    main()
