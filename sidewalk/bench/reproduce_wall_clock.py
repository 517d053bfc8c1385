"""The paper's reproduction, priced: the wall-clock of ``runners/reproduce.sh full`` (every preset at the paper's
budgets, continuous 5000 iterations included) estimated from per-iteration costs measured on this machine, with
``--processes`` runs at a time, optionally beside another revision measured the same way in the same call.

    python runners/bench.py reproduce                               # ~8 min: this checkout, 2 processes
    python runners/bench.py reproduce --baseline 681260b            # ~15 min: also the revision issue 31 measured

Every distinct run of the presets that ``runners/reproduce.sh`` sweeps (the preset's sweep parameters, seeds
aside: a seed changes what is learned, not what an iteration costs; a job that trains its seeds as one group,
``replicas=R``, is probed as that group) is probed once: ``runners/main.py`` with the
run's overrides for ``--probe-iterations`` iterations, an evaluation and a checkpoint every ``probe_period``, and
its ``metrics.csv`` times per iteration read apart into

- ``ms/iteration``: the mean of the iterations after the first ``WARMUP`` (DQN learns from its 8th) that neither
  evaluate nor follow a checkpoint (collection, update, metrics; the work that scales with the budget);
- ``eval s`` and ``checkpoint s``: an evaluating iteration's (a checkpoint's next iteration's) excess over that;
- ``fixed s``: the process's wall-clock outside the training loop (imports, config, final policy, plots).

A run of ``iterations`` then costs fixed + iterations × ms/iteration + its evaluations and checkpoints at the
preset's periods. Each revision is priced the way its script runs: one pool of ``--processes`` workers taking every
preset's jobs in the pool's order (``sidewalk.reproduce``), or, for a revision from before the pool, each preset's
runs packed longest first onto the workers (Hydra's joblib launcher) and the presets one after another.
The probes themselves run ``--processes`` at a time (``--probes-at-once``), pairing the two revisions' probes of one
run, so each is measured under the contention of a full machine. Caveats, both making the estimate low or high by little: the
probe's policies are untrained (an untrained continuous policy's evaluation episodes run longer than a trained
one's, so ``eval s`` is high), and its replay buffer is small (a DQN checkpoint writes the buffer, at most 90 MB).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pandas as pd

from sidewalk.bench.common import is_commit, revision_trees
from sidewalk.paths import RUNNERS_DIR

SCRIPT = RUNNERS_DIR / "reproduce.sh"
WARMUP = 10  # iterations left out of ms/iteration: DQN's first updates start after 1000 frames (8 iterations)
PROBE_ITERATIONS = 40
PROBE_PERIOD = 20  # iterations between the probe's evaluations and checkpoints
# What a revision's reproduce.sh runs: "pool" (sidewalk.reproduce: every preset's jobs on one pool of workers, largest
# first, each config once) or, before the pool, "presets" (each preset's multirun in turn, its runs on the workers).
POOL, PRESETS = "pool", "presets"
# Lists a tree's jobs as its sidewalk.reproduce orders them, run with that tree's package.
LIST_JOBS = ("import dataclasses, json; from sidewalk.reproduce import jobs; "
             "print(json.dumps([{k: v for k, v in dataclasses.asdict(job).items() if k != 'config_key'} "
             "for job in jobs()]))")


def presets(script: Path = SCRIPT) -> list[str]:
    """The presets a pre-pool ``runners/reproduce.sh`` sweeps, read from its ``presets=(...)`` line."""
    match = re.search(r"^presets=\(([^)]*)\)", script.read_text(), re.MULTILINE)
    if match is None:
        raise RuntimeError(f"{script} has no presets=(...) line")
    return match.group(1).split()


def sweep(preset: str, conf_dir: Path | None = None) -> dict[str, Any]:
    """The preset's runs (each a list of overrides) and its periods, as ``runners/main.py -m`` would expand it from
    the config folder ``conf_dir`` (default: this checkout's); a revision's presets are its own."""
    from sidewalk.compose import compose
    from sidewalk.reproduce import sweep_points

    cfg = compose([f"+experiment={preset}"], conf_dir)
    return {"preset": preset, "runs": sweep_points(preset, conf_dir=conf_dir), "iterations": int(cfg.iterations),
            "eval_every": int(cfg.eval_every), "checkpoint_every": int(cfg.checkpoint_every),
            "replicas": int(cfg.replicas)}


def revision_jobs(tree: Path) -> tuple[str, list[dict[str, Any]]]:
    """What ``reproduce.sh full`` runs in ``tree``: ``(POOL, its jobs in the pool's order)`` where the tree has the
    pool, else ``(PRESETS, one job per run of each preset, presets in the script's order)``. A job: ``preset``,
    ``overrides``, ``iterations``, ``eval_every``, ``checkpoint_every``, ``replicas``."""
    if (tree / "sidewalk" / "reproduce.py").exists():
        listed = subprocess.run([sys.executable, "-c", LIST_JOBS], cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                                capture_output=True, text=True, check=True)
        return POOL, json.loads(listed.stdout)
    jobs = []
    for preset in presets(tree / "runners" / "reproduce.sh"):
        spec = sweep(preset, tree / "conf")
        jobs += [{"preset": preset, "overrides": [f"+experiment={preset}", *run], **{
            key: spec[key] for key in ("iterations", "eval_every", "checkpoint_every", "replicas")}}
            for run in spec["runs"]]
    return PRESETS, jobs


def _probe_key(job: dict[str, Any]) -> tuple[str, ...]:
    """A job without its seed: a seed changes what is learned, not what an iteration costs."""
    return tuple(override for override in job["overrides"] if not override.startswith("seed="))


def _probe(tree: Path, overrides: list[str], workdir: Path, iterations: int, period: int) -> dict[str, float]:
    """One short ``runners/main.py`` in ``tree``: its per-iteration, evaluation, checkpoint and fixed costs."""
    run_dir = workdir / "run"
    command = [sys.executable, "runners/main.py", *overrides, f"iterations={iterations}", f"eval_every={period}",
               f"checkpoint_every={period}", f"hydra.run.dir={run_dir}"]
    started = time.perf_counter()
    result = subprocess.run(command, cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                            capture_output=True, text=True, check=False)  # a failure is reported below
    wall = time.perf_counter() - started
    if result.returncode != 0:
        raise RuntimeError(f"{shlex.join(command)} failed in {tree}:\n{result.stderr[-3000:]}")
    # A group of replicas (replicas=R) times all of them in each replica's metrics.csv: read the first one's.
    metrics = run_dir / "metrics.csv" if (run_dir / "metrics.csv").exists() else min(run_dir.glob("seed*/metrics.csv"))
    return costs_from_metrics(pd.read_csv(metrics), wall, period)


def costs_from_metrics(rows: pd.DataFrame, wall_s: float, period: int) -> dict[str, float]:
    """A probe's costs from its ``metrics.csv`` (``iteration``, cumulative ``time_s``), its process wall-clock and its
    evaluation and checkpoint period (see the module's docstring)."""
    seconds = rows["time_s"].diff().fillna(rows["time_s"].iloc[0]).to_numpy()
    iteration = rows["iteration"].to_numpy()
    evaluating = iteration % period == 0
    after_checkpoint = (iteration - 1) % period == 0
    steady = [s for s, i, e, c in zip(seconds, iteration, evaluating, after_checkpoint) if i > WARMUP and not (e or c)]
    per_iteration = statistics.fmean(steady)
    evals = [s - per_iteration for s, e in zip(seconds, evaluating) if e]
    checkpoints = [s - per_iteration for s, i, c in zip(seconds, iteration, after_checkpoint) if c and i > 1]
    return {"ms_per_iteration": 1000 * per_iteration, "eval_s": statistics.fmean(evals),
            "checkpoint_s": statistics.fmean(checkpoints) if checkpoints else 0.0,
            "fixed_s": wall_s - float(rows["time_s"].iloc[-1])}


def run_seconds(cost: dict[str, float], iterations: int, eval_every: int, checkpoint_every: int) -> float:
    """Estimated wall-clock of one run of ``iterations`` from its probe's costs."""
    evaluations = math.ceil(iterations / eval_every) if eval_every else 1
    checkpoints = (iterations - 1) // checkpoint_every if checkpoint_every else 0
    return (cost["fixed_s"] + iterations * cost["ms_per_iteration"] / 1000 + evaluations * cost["eval_s"]
            + checkpoints * cost["checkpoint_s"])


def makespan(seconds: Sequence[float], processes: int) -> float:
    """Wall-clock of jobs packed longest first onto ``processes`` workers."""
    return in_order(sorted(seconds, reverse=True), processes)


def in_order(seconds: Sequence[float], processes: int) -> float:
    """Wall-clock of jobs handed out in the given order, each to the first worker free, as the pool does."""
    workers = [0.0] * processes
    for job in seconds:
        workers[workers.index(min(workers))] += job
    return max(workers)


def run(baseline: str | None = None, processes: int = 2, probe_iterations: int = PROBE_ITERATIONS,
        probe_period: int = PROBE_PERIOD, probes_at_once: int | None = None,
        device: str | None = None) -> list[dict[str, Any]]:
    """Rows per distinct job, per preset and in total; ``probes_at_once`` (default: ``processes``) probes run side by
    side, so that each is measured under the load of the estimate's ``processes`` (fewer when other work shares the
    machine); ``device`` (``cuda``, say) is every probe's ``device=``, as ``reproduce.sh full device=cuda`` runs."""
    if probe_period < 2 or probe_iterations < WARMUP + probe_period + 2:
        raise ValueError(f"--probe-iterations {probe_iterations} with --probe-period {probe_period}: the probe needs "
                         f"a period of at least 2 and at least {WARMUP + probe_period + 2} iterations (an evaluation, "
                         f"a checkpoint and steady iterations after {WARMUP} of warm-up)")
    with tempfile.TemporaryDirectory(prefix="sidewalk-reproduce-") as tmp, revision_trees(baseline, tmp) as trees:
        # Each revision's own jobs: its presets (a revision whose presets train their seeds as one group has fewer,
        # larger jobs) and its way of running them (one pool, or one preset after another).
        planned = {name: revision_jobs(tree) for name, tree in trees.items()}
        # The distinct jobs, seeds aside (the probe runs seed 0); the two revisions' probes of one job side by side.
        probes = list(dict.fromkeys((_probe_key(job), name) for name, (_, jobs) in planned.items() for job in jobs))
        probes.sort(key=lambda probe_job: probe_job[0])

        def probe(numbered):
            number, (key, name) = numbered
            print(f"reproduce: probing {' '.join(key)} on {name} ...", file=sys.stderr, flush=True)
            on_device = [f"device={device}"] if device else []
            return _probe(trees[name], [*key, "seed=0", *on_device], Path(tmp) / f"probe-{number}", probe_iterations,
                          probe_period)

        with ThreadPoolExecutor(max_workers=probes_at_once or processes) as pool:
            costs = dict(zip(probes, pool.map(probe, enumerate(probes))))
    rows: list[dict[str, Any]] = []
    for name, (model, jobs) in planned.items():
        rows.extend(_estimate_rows(name, model, jobs, costs, processes))
    return rows


def _estimate_rows(name: str, model: str, jobs: list[dict[str, Any]], costs: dict[tuple, dict[str, float]],
                   processes: int) -> list[dict[str, Any]]:
    """One revision's rows: each distinct job's costs, each preset's job-seconds (the pool) or makespan (one preset
    after another), and the total."""
    rows: list[dict[str, Any]] = []
    seconds = [run_seconds(costs[_probe_key(job), name], job["iterations"], job["eval_every"], job["checkpoint_every"])
               for job in jobs]
    for job, job_seconds in zip(jobs, seconds):
        cost = costs[_probe_key(job), name]
        rows.append({"preset": job["preset"], "run": " ".join(_probe_key(job)[1:]) or "(preset)", "revision": name,
                     "ms/iteration": cost["ms_per_iteration"], "eval s": cost["eval_s"],
                     "checkpoint s": cost["checkpoint_s"], "fixed s": cost["fixed_s"], "run s": job_seconds})
    total = 0.0
    for preset in dict.fromkeys(job["preset"] for job in jobs):
        mine = [(job, s) for job, s in zip(jobs, seconds) if job["preset"] == preset]
        job, replicas = mine[0][0], mine[0][0]["replicas"]
        seeds = f", {replicas} seeds each" if replicas > 1 else ""
        if model == POOL:
            summary = f"{len(mine)} jobs{seeds} x {job['iterations']} iterations in the pool"
            preset_seconds = sum(s for _, s in mine)
        else:
            preset_seconds = makespan([s for _, s in mine], processes)
            total += preset_seconds
            summary = f"sweep: {len(mine)} jobs{seeds} x {job['iterations']} iterations, {processes} at a time"
        rows.append({"preset": preset, "run": summary, "revision": name, "run s": preset_seconds})
    if model == POOL:
        total = in_order(seconds, processes)
    how = f"one pool of {processes}" if model == POOL else f"preset after preset, {processes} at a time"
    rows.append({"preset": "reproduce.sh full", "run": f"total ({total / 3600:.2f} h, {how})", "revision": name,
                 "run s": total})
    return rows


def format_rows(rows: list[dict[str, Any]]) -> str:
    from sidewalk.bench.common import format_table

    table = format_table(rows, ("preset", "run", "revision", "ms/iteration", "eval s", "checkpoint s", "fixed s",
                                "run s"))
    totals = [row for row in rows if row["preset"] == "reproduce.sh full"]
    if len(totals) == 2:
        ratio = totals[1]["run s"] / totals[0]["run s"]
        table += f"\nthis checkout ÷ {totals[0]['revision']}: {ratio:.2f} of the estimated wall-clock"
    return table


def parse_options(argv: Sequence[str]) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="runners/bench.py reproduce", description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="another revision (commit, tag, branch) probed beside this checkout")
    parser.add_argument("--processes", type=int, default=2, help="runs at a time (Hydra joblib n_jobs)")
    parser.add_argument("--probes-at-once", type=int, help="probes run side by side (default: --processes)")
    parser.add_argument("--probe-iterations", type=int, default=PROBE_ITERATIONS)
    parser.add_argument("--probe-period", type=int, default=PROBE_PERIOD,
                        help="iterations between the probe's evaluations and checkpoints")
    parser.add_argument("--device", help="every probe's device= (cuda, cuda:1, ...; default: each run's own)")
    args, _ = parser.parse_known_args(argv)
    for flag in ("processes", "probes_at_once"):
        value = getattr(args, flag)
        if value is not None and value < 1:
            parser.error(f"--{flag.replace('_', '-')} {value}: must be at least 1")
    if args.baseline is not None and not is_commit(args.baseline):
        parser.error(f"--baseline {args.baseline}: not a commit of this repository")
    return vars(args)


def main(argv: Sequence[str] | None = None) -> int:
    options = parse_options(sys.argv[1:] if argv is None else argv)
    print(format_rows(run(**options)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
