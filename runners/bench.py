"""Benchmarks of the Sidewalk package, printed as tables: ``python runners/bench.py --help`` lists the sections
(``SECTION_HELP``) and how to call them; docs/guide/benchmarks.md gives the figures they measured.

A section module has ``run(**kwargs) -> list[dict]``; it may add ``parse_options(argv) -> kwargs`` (its own flags,
checked before any section runs) and ``format_rows(rows) -> str`` (its own printout).
"""

from __future__ import annotations

import argparse
import importlib
import platform
import sys
import time

import torch

SECTIONS = {
    "env": "sidewalk.bench.env_speed",
    "planning": "sidewalk.bench.planning",
    "views": "sidewalk.bench.view_speed",
    "training": "sidewalk.bench.training",
    "learners": "sidewalk.bench.learners",
    "geometry": "sidewalk.bench.geometry",
    "budget": "sidewalk.bench.budget",
    "reproduce": "sidewalk.bench.reproduce_wall_clock",
    "scenarios": "sidewalk.bench.scenarios",
    "multiagent": "sidewalk.bench.multiagent",
    "groups": "sidewalk.bench.groups",
    "image_ppo": "sidewalk.bench.image_ppo",
    "benchmarl": "sidewalk.bench.benchmarl_tasks",
}
DEFAULT_SECTIONS = ("env", "planning", "views")
# --help's list: a line per section, the time at its defaults, what it measures and its own flags.
SECTION_HELP = """\
sections (env, planning and views when none is named; times at each section's defaults):
  env         seconds     env-steps/s of both domains, beside VMAS give_way (with the bench extra)
  planning    seconds     µs per plan per world of the scripted planners, beside scipy's Dijkstra;
                          --baseline DIR|REVISION: ms per plan of both trees and their ratio (--repeats, --seconds)
  views       seconds     env-steps/s of the learner views with their opponents
  training    ~1 h        time until our DQN's greedy policy succeeds on 3 evaluations in a row (>= 0.9)
                          against Dijkstra at noise 0.1, beside Stable-Baselines3's DQN
  learners    hours       final ego success of our TRPO and PPO beside sb3-contrib's TRPO and SB3's PPO
                          (--opponent, --frames, --seeds, --setups, --learners, --noise, --eval-episodes)
  geometry    ~6 min      what the continuous geometry allows: untrained success, scripted returns, room to pass
  budget      ~6 min      where an iteration's time goes in the default DQN and the TRPO runs
                          (--baseline REVISION, --seeds, --runs, --trpo-iterations)
  reproduce   ~15 min     runners/reproduce.sh full's wall-clock, estimated from measured iterations
                          (--baseline REVISION, --processes, --probe-iterations, --probe-period, --device)
  scenarios   ~3 min      env-steps/s at N agents, ours beside VMAS navigation (--agents)
  multiagent  ~12 min     IPPO training frames/s at 4096 worlds, ours beside TorchRL's example on VMAS
                          (--ma-steps, --ma-iterations, --ma-warmup, --ma-learners)
  groups      ~25 min     R seeds trained as one process (replicas=R) beside one after another
                          (--setups, --replicas, --iterations, --full)
  image_ppo   ~3 min      s/iteration of grid IPPO and MAPPO, image beside vector settings
  benchmarl   hours       BenchMARL's learners on the sidewalk's tasks, a resumable table (docs/guide/benchmarl.md)
                          (--bm-algorithms, --bm-tasks, --bm-seeds, --bm-frames, --bm-out, --bm-grid-observation,
                          --bm-no-state)

A section's own flags follow the section names. Examples:
  %(prog)s                                   # env, planning and views
  %(prog)s env --num-envs 4096 --threads 1
  %(prog)s planning --baseline ../other-checkout
  %(prog)s learners --opponent prm --seeds 0 1 2
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Benchmarks of the Sidewalk package, printed as tables.",
                                     epilog=SECTION_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "sections", nargs="*", default=list(DEFAULT_SECTIONS), help=f"any of: {', '.join(SECTIONS)}"
    )
    parser.add_argument("--num-envs", type=int, nargs="+", help="override each section's num_envs list")
    parser.add_argument("--threads", type=int, nargs="+", help="override each section's thread counts")
    args, extra = parser.parse_known_args(argv)
    unknown = [s for s in args.sections if s not in SECTIONS]
    if unknown:
        parser.error(f"unknown section(s) {unknown}; valid: {', '.join(SECTIONS)}")
    modules = {section: importlib.import_module(SECTIONS[section]) for section in args.sections}
    # Sections with flags of their own parse (and check) them all before any section runs.
    takes_flags = [section for section, module in modules.items() if hasattr(module, "parse_options")]
    if extra and not takes_flags:
        parser.error(f"unrecognized arguments: {' '.join(extra)} (the sections given take no flags of their own)")
    options = {section: modules[section].parse_options(extra) for section in takes_flags}

    print(f"# torch {torch.__version__}, {platform.processor() or platform.machine()}, {torch.get_num_threads()} threads available")
    from sidewalk.bench.common import format_table

    for section in args.sections:
        module = modules[section]
        kwargs = dict(options.get(section, {}))
        if args.num_envs:
            kwargs["num_envs"] = args.num_envs
        if args.threads:
            kwargs["threads"] = args.threads
        start = time.perf_counter()
        rows = module.run(**kwargs)
        text = module.format_rows(rows) if hasattr(module, "format_rows") else format_table(rows)
        print(f"\n## {section} ({time.perf_counter() - start:.0f} s)\n{text}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
