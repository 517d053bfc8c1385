"""Benchmarks of the Sidewalk package, printed as tables.

    python runners/bench.py                    # the env, planning and views sections
    python runners/bench.py env --num-envs 4096 --threads 1
    python runners/bench.py planning views
    python runners/bench.py training           # minutes: time to 0.9 ego success, ours vs Stable-Baselines3 DQN

Sections: ``env`` (env-steps/s of both domains beside VMAS give_way), ``planning`` (µs per plan per world of the
scripted planners beside scipy), ``views`` (env-steps/s of the learner views with their opponents), ``training``
(wall clock to 0.9 ego success against Dijkstra and frames/s, our DQN beside SB3's; not run by default).
"""

from __future__ import annotations

import argparse
import importlib
import platform
import sys
import time

import torch

SECTIONS = {
    "env": "sidewalk.bench.envs",
    "planning": "sidewalk.bench.planning",
    "views": "sidewalk.bench.views",
    "training": "sidewalk.bench.training",
}
DEFAULT_SECTIONS = ("env", "planning", "views")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Sidewalk benchmarks", epilog=__doc__)
    parser.add_argument(
        "sections", nargs="*", default=list(DEFAULT_SECTIONS), help=f"any of: {', '.join(SECTIONS)}"
    )
    parser.add_argument("--num-envs", type=int, nargs="+", help="override each section's num_envs list")
    parser.add_argument("--threads", type=int, nargs="+", help="override each section's thread counts")
    args = parser.parse_args(argv)
    unknown = [s for s in args.sections if s not in SECTIONS]
    if unknown:
        parser.error(f"unknown section(s) {unknown}; valid: {', '.join(SECTIONS)}")

    print(f"# torch {torch.__version__}, {platform.processor() or platform.machine()}, {torch.get_num_threads()} threads available")
    from sidewalk.bench.common import format_table

    for section in args.sections:
        module = importlib.import_module(SECTIONS[section])
        kwargs = {}
        if args.num_envs:
            kwargs["num_envs"] = args.num_envs
        if args.threads:
            kwargs["threads"] = args.threads
        start = time.perf_counter()
        rows = module.run(**kwargs)
        print(f"\n## {section} ({time.perf_counter() - start:.0f} s)\n{format_table(rows)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
