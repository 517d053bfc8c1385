"""Benchmarks of the Sidewalk package, printed as tables.

    python runners/bench.py                    # the env, planning and views sections
    python runners/bench.py env --num-envs 4096 --threads 1
    python runners/bench.py planning views
    python runners/bench.py planning --num-envs 128 1024 --baseline ../other-checkout   # ms per plan, this ÷ that
    python runners/bench.py training           # ~1 h: time to 3 evaluations >= 0.9, ours vs Stable-Baselines3 DQN
    python runners/bench.py learners --opponent prm    # hours: our TRPO/PPO vs sb3-contrib TRPO / SB3 PPO
    python runners/bench.py geometry           # ~6 min: what the continuous geometry allows (untrained success, ...)
    python runners/bench.py budget --baseline f082f2a   # ~6 min: per-iteration time budget, beside a revision
    python runners/bench.py reproduce --baseline 4549d80  # ~15 min: runners/reproduce.sh full's wall-clock, estimated
    python runners/bench.py scenarios --agents 2 4 8 16   # ~3 min: env-steps/s at N agents, ours vs VMAS navigation
    python runners/bench.py multiagent         # ~12 min: IPPO training frames/s, ours vs TorchRL's VMAS example
    python runners/bench.py groups             # ~25 min: 5 seeds as one process (replicas=5) vs one after another
    python runners/bench.py image_ppo          # ~3 min: s/iteration of grid IPPO/MAPPO, image vs vector settings
    python runners/bench.py benchmarl --bm-tasks sidewalk_continuous   # hours: BenchMARL's learners on our tasks

Sections: ``env`` (env-steps/s of both domains beside VMAS give_way), ``planning`` (µs per plan per world of the
scripted planners beside scipy; with ``--baseline``, a checkout directory or revision, CPU ms per plan of both
trees' planners and their ratio: ``--repeats``, ``--seconds``), ``views`` (env-steps/s of the learner views with
their opponents), ``training`` (training time to three evaluations in a row with ego success ≥ 0.9 against
Dijkstra at noise 0.1, frames/s and cost per gradient step, our DQN beside SB3's; not run by default),
``learners`` (final ego success of our TRPO and PPO beside sb3-contrib's TRPO and SB3's PPO on the continuous
sidewalk at equal seeds and frames; not run by default), ``geometry`` (untrained-policy success, scripted returns
and the PRM agent passing an ego, at the continuous defaults; not run by default), ``budget`` (where an
iteration's time goes in the default DQN run and the TRPO run, ``runners/main.py`` end to end, optionally beside
another revision: ``--baseline``, ``--seeds``, ``--runs``, ``--trpo-iterations``; not run by default),
``reproduce`` (the wall-clock of ``runners/reproduce.sh full`` estimated from measured per-iteration costs,
optionally beside another revision: ``--baseline``, ``--processes``, ``--probe-iterations``, ``--probe-period``;
not run by default), ``multiagent`` (training frames/s of our IPPO self-play on the continuous sidewalk at 4096
worlds and 1 and 2 threads beside TorchRL's MAPPO/IPPO example on VMAS ``navigation``, two agents, the same networks,
batch, epochs and minibatches: ``--ma-steps``, ``--ma-iterations``, ``--ma-warmup``, ``--ma-learners``; not run by
default), ``groups`` (the wall-clock of 5 seeds trained as one process, ``replicas=5``, beside the same runs one
after another, TRPO continuous and DQN grid: ``--setups``, ``--replicas``, ``--iterations``, ``--full``; not run by
default), ``image_ppo`` (seconds per iteration of grid IPPO and MAPPO at their image settings beside the vector
settings, interleaved in one process; not run by default), ``benchmarl`` (BenchMARL's algorithms at their defaults on
the sidewalk's BenchMARL tasks, final team success on 256 fresh worlds, a resumable table: ``--bm-algorithms``,
``--bm-tasks``, ``--bm-seeds``, ``--bm-frames``, ``--bm-out``, ``--bm-grid-observation``, ``--bm-no-state``;
docs/guide/benchmarl.md; not run by default). Flags after the sections that are not the ones below go
to the sections that take flags of their own (``learners``: ``--opponent``, ``--frames``, ``--seeds``,
``--setups``, ``--learners``, ``--noise``, ``--eval-episodes``; see ``python -m sidewalk.bench.learners -h``).
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Sidewalk benchmarks", epilog=__doc__)
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
