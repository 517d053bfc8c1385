"""Several seeds in one process, priced: the wall-clock of R seeds trained as one group (``replicas=R``) beside the
same R runs one after another, each ``runners/main.py`` end to end, on this machine, one torch thread.

    python runners/bench.py groups                                   # ~25 min: TRPO continuous and DQN grid, 5 seeds
    python runners/bench.py groups --setups trpo --iterations 40     # one setup, a shorter budget
    python runners/bench.py groups --full                            # the default runs' whole budgets (hours)

Each setup is a default run (``env=continuous`` with its TRPO and PRM agent; the grid's DQN against Dijkstra) at
``--iterations`` iterations (the default runs' own budgets with ``--full``), evaluated at the end. Printed per setup:
the group's and the one-after-another wall-clock and their ratio, and each replica's final success beside its lone
run's (a replica is a statistically equivalent run of its seed, not the same run: ``within spread`` says whether each
replica's success lies within the lone runs' range), and the group's mean minus the lone runs' in final success and in
frames to a 0.9 evaluation, with its 95 % bootstrap interval and whether it separates: the exact Mann-Whitney test of
the group's seeds against the lone runs' (``sidewalk.stats.separation_text``), p and seeds a side stated.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from sidewalk.bench.common import REPO_ROOT, format_table
from sidewalk.stats import difference_interval, separation_text

SETUPS = {"trpo": ["env=continuous"], "dqn": []}
SUCCESS = "ego/success_rate"


def _main_py(overrides: list[str], run_dir: Path) -> float:
    """Run ``runners/main.py`` to the end; its wall-clock in seconds."""
    command = [sys.executable, "runners/main.py", *overrides, "logger=none", f"hydra.run.dir={run_dir}"]
    started = time.perf_counter()
    result = subprocess.run(command, cwd=REPO_ROOT, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{result.stderr[-3000:]}")
    return time.perf_counter() - started


def _success(run_dir: Path) -> float:
    return float(json.loads((run_dir / "summary.json").read_text())[SUCCESS])


def _frames_to(run_dir: Path, level: float = 0.9) -> float:
    """The frames of the first evaluation whose ego success reaches ``level``; ``inf`` if none did (censored: the test
    ranks it last, where NaN would drop the seed)."""
    metrics = pd.read_csv(run_dir / "metrics.csv")
    reached = metrics[metrics.get(f"eval/{SUCCESS}", pd.Series(dtype=float)) >= level]
    return float(reached["frames"].iloc[0]) if len(reached) else math.inf


def _compared(group: list[float], lone: list[float]) -> str:
    """The group's mean minus the lone runs', its 95 % interval, and whether it separates by the exact Mann-Whitney
    test of the seeds; where a seed never got there (``inf``), how many did instead of a mean."""
    interval = difference_interval(group, lone)
    if all(map(math.isfinite, [*group, *lone])):
        estimate = f"{interval.point:+.3g} [{interval.low:+.3g}, {interval.high:+.3g}]"
    else:
        estimate = (f"reached by {sum(map(math.isfinite, group))} of {len(group)} in the group, "
                    f"{sum(map(math.isfinite, lone))} of {len(lone)} alone")
    return f"{estimate}, {separation_text(interval, 0.0)}"


def time_setup(name: str, replicas: int, iterations: int | None, tmp: Path) -> dict[str, Any]:
    """One setup: the group of ``replicas`` seeds, then the same seeds one after another."""
    budget = [] if iterations is None else [f"iterations={iterations}", f"eval_every={iterations}"]
    overrides = [*SETUPS[name], *budget]
    print(f"groups: {name}, {replicas} seeds as one group ...", file=sys.stderr, flush=True)
    group_s = _main_py([*overrides, f"replicas={replicas}"], tmp / f"{name}-group")
    lone_s, lone_success = 0.0, []
    for seed in range(replicas):
        print(f"groups: {name}, seed {seed} alone ...", file=sys.stderr, flush=True)
        lone_s += _main_py([*overrides, f"seed={seed}"], tmp / f"{name}-seed{seed}")
        lone_success.append(_success(tmp / f"{name}-seed{seed}"))
    group_dirs = [tmp / f"{name}-group" / f"seed{seed}" for seed in range(replicas)]
    group_success = [_success(folder) for folder in group_dirs]
    group_frames = [_frames_to(folder) for folder in group_dirs]
    lone_frames = [_frames_to(tmp / f"{name}-seed{seed}") for seed in range(replicas)]
    low, high = min(lone_success), max(lone_success)
    return {"setup": name, "seeds": replicas, "iterations": iterations or "default",
            "group s": group_s, "one after another s": lone_s, "group ÷ one after another": group_s / lone_s,
            "group success": " ".join(f"{value:.2f}" for value in group_success),
            "lone success": " ".join(f"{value:.2f}" for value in lone_success),
            "within spread": all(low <= value <= high for value in group_success),
            "success, group − lone": _compared(group_success, lone_success),
            "frames to 0.9, group − lone": _compared(group_frames, lone_frames)}


def run(setups: Sequence[str] = tuple(SETUPS), replicas: int = 5, iterations: int | None = 40,
        full: bool = False) -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory(prefix="sidewalk-groups-") as tmp:
        return [time_setup(name, replicas, None if full else iterations, Path(tmp)) for name in setups]


def format_rows(rows: list[dict[str, Any]]) -> str:
    return format_table(rows)


def parse_options(argv: Sequence[str]) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="runners/bench.py groups", description=__doc__.split("\n\n")[0])
    parser.add_argument("--setups", nargs="+", default=list(SETUPS), choices=list(SETUPS))
    parser.add_argument("--replicas", type=int, default=5, help="seeds in the group (default 5)")
    parser.add_argument("--iterations", type=int, default=40, help="iterations of every run (default 40)")
    parser.add_argument("--full", action="store_true", help="the default runs' own budgets (hours)")
    args = parser.parse_args(list(argv))
    if args.replicas < 2:
        parser.error(f"--replicas={args.replicas} must be ≥ 2")
    if args.iterations < 1:
        parser.error(f"--iterations={args.iterations} must be ≥ 1")
    return {"setups": args.setups, "replicas": args.replicas, "iterations": args.iterations, "full": args.full}
