"""The training loop's time budget: where an iteration's milliseconds go in the default run (discrete, DQN against
Dijkstra) and in the continuous TRPO run, measured on ``runners/main.py`` end to end, optionally beside another
revision of this repository on the same machine in the same call.

    python runners/bench.py budget                              # this checkout: default DQN run (seed 0), TRPO 50 its
    python runners/bench.py budget --baseline f082f2a --seeds 0 1 2
    python -m sidewalk.bench.budget --runs trpo --trpo-iterations 20

Each run is ``python runners/main.py`` (its defaults, a run folder in a temporary directory) under the probes of
``sidewalk/bench/probes.py``: every part of the loop (collection, environment step, opponent, update and its
replay-buffer, loss, backward, optimiser and target-network parts, evaluation, checkpoints, metrics) is timed
exclusively, so the rows of a part sum to it and the parts sum to ``Trial.run``. ``start-up and report`` is the
rest of the end-to-end wall-clock: imports, config, and the plots ``main.py`` writes at the end. The baseline is a
``git worktree`` of ``--baseline`` (removed afterwards), timed with the same probes; runs alternate between the two
revisions seed by seed, so a machine that slows down mid-benchmark slows both.

``trusted``: the default run's last three evaluations all have ego success ≥ 0.9 (the issue's "a curve a user can
trust"); the table gives each seed's last three values.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from sidewalk.bench.common import REPO_ROOT as ROOT
from sidewalk.bench.common import is_commit, revision_trees
from sidewalk.bench.probes import OUTSIDE

PROBES_SCRIPT = Path(__file__).with_name("probes.py")
RUNS: dict[str, tuple[str, ...]] = {
    "dqn": (),  # the default run: python runners/main.py
    "trpo": ("env=continuous",),  # the paper's continuous learner, at its defaults
}
TRUST = 0.9
PART_COLUMN = "part (ms per iteration; median over seeds)"

# Rows: (label, part, probe label); probe None marks a part's total. Order as the loop runs.
LAYOUT: tuple[tuple[str, str | None, str | None], ...] = (
    ("collection", "collection", None),
    ("  environment step", "collection", "env step"),
    ("  opponent (scripted agent)", "collection", "opponent"),
    ("  policy forward + collector", "collection", "collection"),
    ("update", "update", None),
    ("  replay-buffer write", "update", "replay write"),
    ("  replay-buffer sample", "update", "replay sample"),
    ("  advantage (GAE)", "update", "advantage (GAE)"),
    ("  loss forward", "update", "loss forward"),
    ("  backward", "update", "backward"),
    ("  gradient clip", "update", "gradient clip"),
    ("  optimizer step", "update", "optimizer step"),
    ("  target-network update", "update", "target update"),
    ("  policy step (CG, line search)", "update", "policy step (CG, line search)"),
    ("  value fit", "update", "value fit"),
    ("  rest of the update", "update", "update"),
    ("divergence check", "divergence check", None),
    ("evaluation", "evaluation", None),
    ("checkpoint writes", "checkpoint writes", None),
    ("metrics.csv + logger", "metrics.csv + logger", None),
    ("loop rest (build, train metrics, bar)", "trial", None),
)

LISTED_PARTS = {part for _, part, _ in LAYOUT if part != "trial"} | {OUTSIDE}


def parse_options(argv: Sequence[str]) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="runners/bench.py budget", description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", help="a git revision to time beside this checkout (e.g. f082f2a)")
    parser.add_argument("--runs", nargs="+", default=list(RUNS), choices=list(RUNS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="seeds of each run (default: 0)")
    parser.add_argument("--trpo-iterations", type=int, default=50, help="iterations of the TRPO run (default 50)")
    args = parser.parse_args(list(argv))
    if args.trpo_iterations < 1:
        parser.error(f"--trpo-iterations={args.trpo_iterations} must be ≥ 1")
    if any(seed < 0 for seed in args.seeds):
        parser.error(f"--seeds {args.seeds}: seeds must be ≥ 0")
    if args.baseline is not None and not is_commit(args.baseline):
        parser.error(f"--baseline={args.baseline!r} is not a commit of {ROOT}")
    return {"baseline": args.baseline, "runs": args.runs, "seeds": args.seeds,
            "trpo_iterations": args.trpo_iterations}


def _time_run(tree: Path, overrides: list[str], workdir: Path) -> dict[str, Any]:
    """One ``runners/main.py`` in ``tree`` under the probes: its probe times, wall-clock and metrics."""
    run_dir = workdir / "run"
    out = workdir / "probes.json"
    env = {**os.environ, "PYTHONPATH": str(tree)}
    started = time.perf_counter()
    result = subprocess.run(
        [sys.executable, str(PROBES_SCRIPT), str(out), "--", *overrides, f"hydra.run.dir={run_dir}"],
        cwd=tree, env=env, capture_output=True, text=True, check=False,  # a failure is reported below
    )
    wall = time.perf_counter() - started
    if result.returncode != 0 or not out.exists():
        raise RuntimeError(f"runners/main.py {' '.join(overrides)} failed in {tree}:\n{result.stderr[-3000:]}")
    probes = json.loads(out.read_text())
    metrics = pd.read_csv(run_dir / "metrics.csv")
    column = "eval/ego/success_rate" if "eval/ego/success_rate" in metrics else "eval/team/success_rate"
    evaluations = metrics[column].dropna().tolist()
    return {"wall_s": wall, "probes": probes, "iterations": int(metrics["iteration"].iloc[-1]),
            "last_three": evaluations[-3:]}


def _budget_rows(runs: list[dict[str, Any]]) -> dict[str, float]:
    """Median over seeds of each row's ms per iteration, and the end-to-end figures in seconds."""
    def per_iteration(run: dict[str, Any], part: str, label: str | None) -> float:
        exclusive = run["probes"]["exclusive"]
        if part == "trial":  # everything in Trial.run outside the loop parts above it
            seconds = sum(v for k, v in exclusive.items() if k.split("/", 1)[0] not in LISTED_PARTS)
        elif label is None:
            seconds = sum(v for k, v in exclusive.items() if k.split("/", 1)[0] == part)
        else:
            seconds = exclusive.get(f"{part}/{label}", 0.0)
        return 1000.0 * seconds / run["iterations"]

    values: dict[str, float] = {}
    for label, part, probe in LAYOUT:
        values[label] = statistics.median(per_iteration(run, part, probe) for run in runs)
    trial = [sum(v for k, v in run["probes"]["exclusive"].items() if not k.startswith(OUTSIDE)) for run in runs]
    values["Trial.run (s)"] = statistics.median(trial)
    values["start-up and report (s)"] = statistics.median(run["wall_s"] - t for run, t in zip(runs, trial))
    values["end-to-end wall-clock (s)"] = statistics.median(run["wall_s"] for run in runs)
    return values


def run(baseline: str | None = None, runs: Sequence[str] = tuple(RUNS), seeds: Sequence[int] = (0,),
        trpo_iterations: int = 50) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="sidewalk-budget-") as tmp, revision_trees(baseline, tmp) as trees:
        for run_name in runs:
            overrides = list(RUNS[run_name])
            if run_name == "trpo":
                overrides.append(f"iterations={trpo_iterations}")
            timed: dict[str, list[dict[str, Any]]] = {name: [] for name in trees}
            for seed in seeds:
                for name, tree in trees.items():
                    workdir = Path(tmp) / f"{run_name}-{seed}-{len(timed[name])}-{name.split()[0]}"
                    print(f"budget: {run_name} seed {seed} on {name} ...", file=sys.stderr, flush=True)
                    timed[name].append(_time_run(tree, [*overrides, f"seed={seed}"], workdir))
            rows.append({"run": run_name, "overrides": " ".join(overrides) or "(defaults)", "timed": timed})
    return rows


def format_rows(rows: list[dict[str, Any]]) -> str:
    from sidewalk.bench.common import format_table

    blocks = []
    for row in rows:
        timed = row["timed"]
        names = list(timed)
        budgets = {name: _budget_rows(runs) for name, runs in timed.items()}
        # format_table right-aligns; labels padded to one width read as a left-aligned, indented tree.
        width = max(len(PART_COLUMN), *map(len, budgets[names[0]]))
        table = []
        for label in budgets[names[0]]:
            line: dict[str, Any] = {PART_COLUMN: label.ljust(width)}
            for name in names:
                line[name] = budgets[name][label]
            if len(names) == 2 and budgets[names[0]][label] > 0:
                line["this ÷ baseline"] = f"{budgets[names[1]][label] / budgets[names[0]][label]:.2f}"
            if any(budgets[name][label] > 0 for name in names):
                table.append(line)
        iterations = {name: timed[name][0]["iterations"] for name in names}
        trust = []
        for name in names:
            lasts = [" ".join(f"{v:.2f}" for v in run["last_three"]) for run in timed[name]]
            trusted = sum(all(v >= TRUST for v in run["last_three"]) for run in timed[name])
            trust.append(f"{name}: last three evaluations per seed [{'; '.join(lasts)}], "
                         f"{trusted} of {len(lasts)} seeds ≥ {TRUST} at all three")
        blocks.append(f"### {row['run']}: runners/main.py {row['overrides']} "
                      f"({', '.join(f'{n}: {i} iterations' for n, i in iterations.items())})\n"
                      + format_table(table).replace(PART_COLUMN.rjust(width), PART_COLUMN.ljust(width), 1)
                      + "\n" + "\n".join(trust))
    return "\n\n".join(blocks)


def main(argv: Sequence[str] | None = None) -> int:
    options = parse_options(sys.argv[1:] if argv is None else argv)
    print(format_rows(run(**options)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
