"""Re-evaluate grid self-play policies greedily and epsilon-greedily (``eval.epsilon``) on the perturbed protocol's
worlds: the table of docs/guide/evaluation.md, "Acting epsilon-greedily in evaluation".

    python results/who-yields/epsilon-eval/evaluate_policies.py results/who-yields/epsilon-eval/policies/*

Each folder holds one run's ``policy.pt`` and ``config.yaml`` (its ``role_frame`` says which frame it played in).
Every policy plays 256 worlds (starts and goals within ±1 row) for each evaluation seed and each epsilon, the same worlds
for every epsilon; it prints a CSV row per (policy, seed, epsilon).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from omegaconf import OmegaConf

from sidewalk.envs import DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate
from sidewalk.partners.policy import partner_policy, read_partner
from sidewalk.views.selfplay import SelfPlayView

EPSILONS = (0.0, 0.01, 0.03)
SEEDS = (1000003, 2000003)  # seed 0's evaluation stream (sidewalk.experiment.EVAL_SEED_OFFSET) and another


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args(argv)
    print("run,role_frame,eval_seed,epsilon,team_success,deadlock_rate,collision_rate,distinct_episodes")
    for run in args.runs:
        partner = read_partner(run)
        policy, _ = partner_policy(partner)
        role_frame = bool(OmegaConf.load(run / "config.yaml").get("role_frame", False))
        params = dataclasses.replace(partner.world.env_params, start_jitter_rows=1, goal_jitter_rows=1)
        for seed in SEEDS:
            for epsilon in EPSILONS:
                view = SelfPlayView(DiscreteSidewalkEnv(256, seed=seed, params=params), role_frame=role_frame)
                m = evaluate(view, policy, seed=seed, epsilon=epsilon)
                print(f"{run.name},{role_frame},{seed},{epsilon},{m['team/success_rate']:.4f},{m['deadlock_rate']:.4f},"
                      f"{m['collision_rate']:.4f},{int(m['distinct_episodes'])}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
