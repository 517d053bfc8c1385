"""Seconds per iteration of grid IPPO and MAPPO on images at their image settings (CleanRL's Atari PPO: 4 epochs of
minibatches of 512 world-steps, entropy 0.01, the grid's defaults) beside the vector settings (CleanRL's MuJoCo PPO:
10 epochs of 64, the continuous defaults), interleaved in one process so that both meet the same load.

    python runners/bench.py image_ppo                       # ~3 min: ippo and mappo, 3 timed iterations each
    python -m sidewalk.bench.image_ppo

An iteration is one collection of ``frames_per_batch`` world-steps (16 steps of 128 worlds, ``opponent=self``, noise 0,
``SelfPlayView`` with ``RewardSum``) and one ``update``, both as ``runners/main.py`` builds them; the first of each
setting is warm-up, the figure the minimum of the rest. Weights are shared or not as each setting's defaults say.
"""

from __future__ import annotations

import time
from typing import Any

import torch

SETTINGS = {
    "vectors' (10 epochs of 64)": ["algo.epochs=10", "algo.minibatch_size=64", "algo.entropy_coef=0.0",
                                   "algo.share_params=true"],
    "images' (4 epochs of 512)": [],
}


def run(algos: tuple[str, ...] = ("ippo", "mappo"), repeats: int = 4, threads: list[int] | None = None,
        num_envs: list[int] | None = None) -> list[dict[str, Any]]:
    from torchrl.envs import RewardSum, TransformedEnv

    from sidewalk.compose import compose_experiment
    from sidewalk.registry import LEARNERS

    torch.set_num_threads((threads or [1])[0])
    rows = []
    for algo_name in algos:
        built = {}
        for name, overrides in SETTINGS.items():
            experiment = compose_experiment(["env=discrete", "opponent=self", f"algo={algo_name}", "noise=0", *overrides])
            env = TransformedEnv(experiment.world.make(experiment.num_envs, 0, experiment.device), RewardSum())
            algo = LEARNERS[algo_name](experiment.algo, env)
            built[name] = (env, algo, experiment.algo.frames_per_batch // experiment.num_envs)
        seconds: dict[str, list[float]] = {name: [] for name in SETTINGS}
        for repeat in range(repeats):
            for name, (env, algo, steps) in built.items():
                start = time.perf_counter()
                with torch.no_grad():
                    batch = env.rollout(steps, algo.collection_policy(), break_when_any_done=False, auto_reset=True)
                algo.update(batch)
                if repeat:
                    seconds[name].append(time.perf_counter() - start)
        vector, image = (min(seconds[name]) for name in SETTINGS)
        for name in SETTINGS:
            rows.append({"learner": algo_name, "settings": name, "s / iteration": round(min(seconds[name]), 2),
                         "vector ÷ image": round(vector / image, 2)})
    return rows


if __name__ == "__main__":
    from sidewalk.bench.common import format_table

    print(format_table(run()))
