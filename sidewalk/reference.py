"""The committed reference results, and whether today's code still makes them.

A reference folder (``results/reference/``, ``results/reference/safe/``) holds ``reference.json``: the commit its runs
were made at, the command, every job it ran (its Hydra overrides), where its runs lie (``runs``: a folder, or one
per group of seeds that ran every job) and any note that explains a probe difference. Its
*probe* (``probe.csv``) is a short deterministic run of every job (seed 0 alone, a few iterations, one evaluation)
made at that commit. ``check`` runs the same probe with today's code and compares it metric by metric (wall clock
aside): equal, the reference is still what today's code makes; different, a change since its commit alters what a
job computes, and the reference must be re-made (or a note in ``reference.json`` must say why it still holds).

    python -m sidewalk.reference check                      # every reference folder; exit 1 on an unexplained change
    python -m sidewalk.reference check --write-status       # ... and rewrite results/reference/freshness.md
    python -m sidewalk.reference probe results/reference --tree ../ref   # record the probe with a worktree of the
                                                            # reference's commit
    python -m sidewalk.reference collect SWEEP_ROOT results/reference/runs   # the runs' small files, for the report
    python -m sidewalk.reference trees ../ref ../ref2      # do two commits compute every job alike, in a group too?
    python -m sidewalk.reference check --root DIR           # the reference folders under DIR, not the clone's

``check`` and ``trees`` read the reference folders under a root: ``--root DIR``, else the clone's ``results/reference``
found in the current folder or the nearest folder above it (an installed package has no reference of its own).

``collect`` copies what ``runners/report.py`` reads of each finished run (``config.yaml``, ``summary.json``,
``history.jsonl``, the metrics as ``metrics.csv.xz`` without the learners' diagnostics) and each sweep's
``multirun.yaml``, so that the report is rebuilt from committed files alone.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shutil
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

REFERENCE_DIR = Path("results") / "reference"  # where a clone keeps its reference folders, from its top
FOLDERS = ("", "safe")  # the reference folders with a probe, under the reference root
META = "reference.json"
PROBE = "probe.csv"
STATUS = "freshness.md"
WALL_CLOCK = ("time_s", "frames_per_s")
# A probe: seed 0 alone, one evaluation of 16 episodes at its end, no checkpoint, nothing logged.
PROBE_OVERRIDES = ("seed=0", "replicas=1", "eval_episodes=16", "checkpoint_every=0", "logger=none")
PROBE_ITERATIONS = 2  # after an off-policy learner's first update (learning_starts)
# Values that differ by less than this (relative) are the same number rounded by another CPU's kernels: two x86 kinds
# of CI machine differ by up to 6.4e-4 (a PPO's explained variance) over a probe's iterations.
ROUNDING = 2e-3
# An evaluation plays long deterministic episodes through thresholds (a collision, the shield, a time limit): another
# CPU's last bit can carry an episode to another outcome (the shielded continuous TRPO: 2 of 16 episodes, training equal
# to 6e-5). Its rates are then compared as rates: at the worst, rounding re-draws every distinct episode's outcome, and
# two samples of n episodes of one policy differ by more than Z standard errors (plus one episode, the continuity
# correction) with probability below 0.003; the moves measured on three kernel sets used at most a quarter of it.
# Training, the counts and an evaluation whose rates did not move are still compared within ROUNDING.
RATE_Z = 3.0
KEPT_TRAIN = ("success", "collision", "return", "cost", "episodes", "shield", "length")


# ---- the probe -----------------------------------------------------------------------------------------------------


def probe_overrides(job_overrides: Sequence[str]) -> list[str]:
    """A job's overrides made into its probe's: the job's config, seed 0 alone, a few iterations (past an off-policy
    learner's ``learning_starts``), one evaluation at the end."""
    from sidewalk.compose import compose

    cfg = compose([*job_overrides, *PROBE_OVERRIDES])
    starts = int(cfg.algo.get("learning_starts", 0) or 0)
    per_iteration = math.ceil(int(cfg.algo.frames_per_batch) / int(cfg.num_envs)) * int(cfg.num_envs)
    iterations = PROBE_ITERATIONS + math.ceil(starts / per_iteration)
    return [*job_overrides, *PROBE_OVERRIDES, f"iterations={iterations}", f"eval_every={iterations}"]


def probe_job(job_overrides: Sequence[str], work_dir: Path) -> pd.DataFrame:
    """The probe of one job: its metrics, one row per iteration, wall clock dropped."""
    from sidewalk.compose import compose_experiment
    from sidewalk.experiment import Trial

    experiment = compose_experiment(probe_overrides(job_overrides))
    Trial(experiment, work_dir).run(progress=False, absolute_metric=False)  # a probe is its metrics.csv
    metrics = pd.read_csv(work_dir / "metrics.csv")
    return metrics.drop(columns=[column for column in WALL_CLOCK if column in metrics.columns])


def probe_job_in(tree: Path, job_overrides: Sequence[str], work_dir: Path, replicas: int = 1) -> pd.DataFrame:
    """The probe of one job made by another checkout's code (``tree``, a worktree of the reference's commit, say):
    its ``runners/main.py`` in a process of its own, on its own package. ``replicas`` > 1: seeds 0..R-1 trained as
    one group, the last replica's metrics (its worlds and networks at the largest offset in the group's tensors)."""
    import os
    import subprocess

    command = [sys.executable, "runners/main.py", *probe_overrides(job_overrides), f"replicas={replicas}",
               f"hydra.run.dir={work_dir}"]
    done = subprocess.run(command, cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)}, capture_output=True,
                          text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"the probe failed in {tree}: {' '.join(command)}\n{done.stderr[-3000:]}")
    from sidewalk.run_folder import METRICS, group_seed_dirs

    metrics = pd.read_csv(group_seed_dirs(work_dir, 0, replicas)[-1] / METRICS)  # the last seed's, seed 0 first
    return metrics.drop(columns=[column for column in WALL_CLOCK if column in metrics.columns])


def probe(jobs: dict[str, Sequence[str]], progress: bool = True, tree: Path | None = None, replicas: int = 1
          ) -> pd.DataFrame:
    """Every job's probe, as one table with a ``job`` column: made by this process's code, or by ``tree``'s (there
    also as a group of ``replicas``)."""
    tables = []
    with tempfile.TemporaryDirectory(prefix="sidewalk-probe-") as tmp:
        for number, (name, overrides) in enumerate(jobs.items()):
            if progress:
                print(f"probe: {name}", file=sys.stderr, flush=True)
            work_dir = Path(tmp) / str(number)
            table = (probe_job(overrides, work_dir) if tree is None
                     else probe_job_in(tree, overrides, work_dir, replicas))
            tables.append(table.assign(job=name))
    table = pd.concat(tables, ignore_index=True)
    return table[["job", *[column for column in table.columns if column != "job"]]]


@dataclass
class Comparison:
    """One job's probe today against the recorded one: ``same`` (bit for bit or within ``ROUNDING``), with what
    differs first where not."""

    job: str
    same: bool
    detail: str


def compare(recorded: pd.DataFrame, today: pd.DataFrame) -> list[Comparison]:
    """Each recorded job's probe against today's."""
    results = []
    for job, old in recorded.groupby("job", sort=False):
        new = today[today["job"] == job]
        results.append(Comparison(job, *_compare_tables(old.drop(columns="job"), new.drop(columns="job"))))
    return results


def _compare_tables(old: pd.DataFrame, new: pd.DataFrame) -> tuple[bool, str]:
    old, new = old.dropna(axis=1, how="all").reset_index(drop=True), new.dropna(axis=1, how="all").reset_index(drop=True)
    gone, added = sorted(set(old.columns) - set(new.columns)), sorted(set(new.columns) - set(old.columns))
    if gone:
        return False, f"its metrics differ: no longer written {gone}, new {added or '-'}"
    new = new[old.columns]  # a metric added since adds to what a job reports, not to what it computes
    if len(old) != len(new):
        return False, f"{len(new)} iterations where the probe recorded {len(old)}"
    differences = list(_differences(old, new))
    if not differences:
        return True, "identical"
    gap, column, iteration, x, y = max(differences, key=lambda difference: difference[0])
    if gap <= ROUNDING:
        return True, f"equal within rounding (largest relative difference {gap:.1e}, {column})"
    beyond = [difference for difference in differences if difference[0] > ROUNDING]
    moved = _outcomes_moved_within_sampling(old, new, beyond)
    if moved:
        return True, f"training equal within rounding; {moved}"
    # Training's (or the episode counts') first difference names what a job computes; else the evaluation's largest.
    training = [difference for difference in beyond if not difference[1].startswith("eval/") or "episodes" in
                difference[1]]
    _, column, iteration, x, y = training[0] if training else max(beyond, key=lambda difference: difference[0])
    return False, f"{column} at iteration {iteration}: recorded {x:.6g}, today {y:.6g}"


def _differences(old: pd.DataFrame, new: pd.DataFrame) -> Iterator[tuple[float, str, int, float, float]]:
    """Every value that differs, in the table's order: (relative gap, column, iteration, recorded, today)."""
    for column in old.columns:
        a, b = old[column].to_numpy(dtype=float), new[column].to_numpy(dtype=float)
        for row, (x, y) in enumerate(zip(a, b)):
            if (math.isnan(x) and math.isnan(y)) or x == y:
                continue
            gap = math.inf if math.isnan(x) or math.isnan(y) else abs(x - y) / max(abs(x), abs(y), 1e-12)
            yield gap, column, row + 1, x, y


def rate_tolerance(rate_a: float, rate_b: float, distinct: float) -> float:
    """How far two evaluations' rates over ``distinct`` episodes may lie apart when rounding alone moved outcomes:
    ``RATE_Z`` standard errors of the difference of two samples at their pooled rate, plus one episode."""
    pooled = min(max((rate_a + rate_b) / 2, 0.0), 1.0)
    return RATE_Z * math.sqrt(2 * pooled * (1 - pooled) / distinct) + 1 / distinct


def _outcomes_moved_within_sampling(old: pd.DataFrame, new: pd.DataFrame, beyond_rounding: list[tuple]) -> str:
    """Why every difference beyond rounding is another CPU's rounding carried through an evaluation's episodes, or
    ``""`` where it is not: each lies in an evaluation (training, the episode counts and the protocol agree within
    rounding), each such evaluation moved a rate (an episode ended otherwise; a mean that moved while every outcome
    stayed is a change of what the evaluation computes), and every rate moved no more than ``rate_tolerance`` at its
    distinct episodes."""
    distinct, counts = "eval/distinct_episodes", ("eval/distinct_episodes", "eval/episodes")
    if distinct not in old.columns or any(not column.startswith("eval/") or column in counts
                                          for _, column, _, _, _ in beyond_rounding):
        return ""
    widest = (0.0, "", 0, 0.0)  # the rate that used most of its tolerance: (share, column, iteration, distinct)
    for iteration in sorted({iteration for _, _, iteration, _, _ in beyond_rounding}):
        n = old[distinct].iloc[iteration - 1]
        rates = [(column, x, y) for _, column, at, x, y in beyond_rounding if at == iteration
                 and column.endswith("_rate")]
        if not rates or math.isnan(n) or n < 1:
            return ""
        for column, x, y in rates:
            share = abs(x - y) / rate_tolerance(x, y, n)
            if share > 1:
                return ""
            widest = max(widest, (share, column, iteration, n))
    share, column, iteration, n = widest
    return (f"the evaluation's outcomes moved within sampling error over {n:.0f} distinct episodes (largest: {column} "
            f"at iteration {iteration}, {share:.0%} of its tolerance)")


# ---- reference folders ---------------------------------------------------------------------------------------------


@dataclass
class Reference:
    """A reference folder and its ``reference.json``."""

    folder: Path
    meta: dict[str, Any]
    root: Path | None = None  # the reference root it lies under: its name starts at the root's results/

    @classmethod
    def load(cls, folder: Path, root: Path | None = None) -> Reference:
        return cls(Path(folder), json.loads((Path(folder) / META).read_text()), root)

    @property
    def name(self) -> str:
        """The folder as the clone names it (``results/reference/safe``) where it lies under its root, else as given."""
        top = None if self.root is None else self.root.parent.parent
        return str(self.folder.relative_to(top)) if top is not None and self.folder.is_relative_to(top) else str(
            self.folder)

    @property
    def jobs(self) -> dict[str, list[str]]:
        return self.meta["jobs"]

    @property
    def runs_folders(self) -> list[Path]:
        """Where the runs lie: ``reference.json``'s ``runs``, one folder or a list of them, one per group of seeds
        that trained every job (``runs/seeds0-4``, ``runs/seeds5-9``)."""
        runs = self.meta.get("runs", "runs")
        return [self.folder / name for name in ([runs] if isinstance(runs, str) else runs)]

    def committed_jobs(self) -> list[str]:
        """The jobs whose finished runs lie in the repository (``collect``), in every runs folder: the report is made
        at this commit only when every job is among them."""
        return [job for job in self.jobs
                if all(_has_runs(runs, job, self.jobs[job]) for runs in self.runs_folders)]

    def recorded_probe(self) -> pd.DataFrame:
        path = self.folder / PROBE
        if not path.exists():
            raise FileNotFoundError(f"{path} does not exist: record it with python -m sidewalk.reference probe "
                                    f"{self.folder} (at commit {self.meta['commit'][:7]})")
        return pd.read_csv(path)

    def check(self, progress: bool = True) -> list[Comparison]:
        """Today's probe of every job against the recorded one; a job whose difference a note explains counts as
        the same, the note appended."""
        results = compare(self.recorded_probe(), probe(self.jobs, progress))
        notes = self.meta.get("explained", {})
        for result in results:
            if not result.same and result.job in notes:
                result.same, result.detail = True, f"differs ({result.detail}), explained: {notes[result.job]}"
        return results


def _has_runs(runs: Path, job: str, overrides: Sequence[str]) -> bool:
    """Whether ``runs`` holds a finished run of ``job``: in the job's own folder (the pool names it so), else, for a
    sweep whose folders Hydra named by their overrides (one per seed), any run under the job's first folder whose
    config is the job's but for the seed and bookkeeping keys."""
    if (runs / job).is_dir():
        return any((runs / job).rglob("summary.json"))
    from omegaconf import OmegaConf

    from sidewalk.compose import compose
    from sidewalk.report.conditions import condition_config
    from sidewalk.run_folder import CONFIG, flatten

    def condition(cfg: Any) -> dict[str, Any]:
        return condition_config(flatten(OmegaConf.to_container(cfg, resolve=True)))

    wanted = condition(compose([*overrides, "replicas=1"]))  # a group's replica writes its config as a lone run's
    domain = runs / Path(job).parts[0]
    return any(condition(OmegaConf.load(summary.parent / CONFIG)) == wanted
               for summary in (domain.rglob("summary.json") if domain.is_dir() else ()))


def find_reference_root(start: Path | None = None) -> Path:
    """The clone's ``results/reference``: in ``start`` (default: the current folder) or the nearest folder above it."""
    start = (Path.cwd() if start is None else Path(start)).resolve()
    for folder in (start, *start.parents):
        if (folder / REFERENCE_DIR).is_dir():
            return folder / REFERENCE_DIR
    raise FileNotFoundError(f"no {REFERENCE_DIR} in {start} or any folder above it: run from a clone of the "
                            f"repository, or give the reference root with --root DIR")


def reference_root(given: Path | None = None) -> Path:
    """``given`` where the user gave a root (it must be a folder), else ``find_reference_root()``."""
    if given is None:
        return find_reference_root()
    if not Path(given).is_dir():
        raise FileNotFoundError(f"--root {given}: not a folder; give the folder that holds the reference folders "
                                f"(a clone's {REFERENCE_DIR})")
    return Path(given).resolve()


def references(root: Path, names: Sequence[str] = FOLDERS) -> list[Reference]:
    """The reference folders ``names`` under ``root`` (``''`` is the root itself)."""
    return [Reference.load(root / name, root) for name in names]


def status_table(checked: list[tuple[Reference, list[Comparison]]]) -> str:
    """The freshness page: per reference folder, its commit and whether today's code gives the same probe."""
    lines = [
        "| reference | made at | jobs | their runs in the repository | today's code gives the same probe |",
        "| --- | --- | ---: | --- | --- |",
    ]
    for reference, results in checked:
        changed = [result for result in results if not result.same]
        verdict = "yes" if not changed else "**no**: " + "; ".join(f"`{r.job}`: {r.detail}" for r in changed)
        committed = len(reference.committed_jobs())
        runs = "all" if committed == len(reference.jobs) else (
            f"**{committed} of {len(reference.jobs)}**: its report still shows the runs of an earlier commit")
        lines.append(f"| `{reference.name}/` | commit `{reference.meta['commit'][:7]}` | {len(results)} | {runs} "
                     f"| {verdict} |")
    return "\n".join(lines) + "\n"


# ---- collecting a sweep's small files -------------------------------------------------------------------------------


def collect(sweep_root: Path, destination: Path, policy_seeds: Sequence[int] = (0,)) -> int:
    """Copy what the report reads of every finished run under ``sweep_root`` into ``destination`` (same relative
    paths), the ``policy.pt`` of the runs of ``policy_seeds`` among it (Fig. 10 replays a condition's first seed;
    a TRPO policy is ~22 kB); returns the number of runs copied."""
    from sidewalk.report.runs import SWEEP_MARKER, find_run_folders
    from sidewalk.run_folder import CONFIG, HISTORY, METRICS, POLICY, SUMMARY, write_compressed_metrics

    sweep_root, destination = Path(sweep_root), Path(destination)
    copied = 0
    for run_dir in find_run_folders([sweep_root]):
        if not (run_dir / SUMMARY).exists():
            continue
        target = destination / run_dir.relative_to(sweep_root)
        target.mkdir(parents=True, exist_ok=True)
        seed = json.loads((run_dir / SUMMARY).read_text()).get("seed")
        for name in (CONFIG, SUMMARY, HISTORY, *([POLICY] if seed in policy_seeds else [])):
            if (run_dir / name).exists():
                shutil.copy2(run_dir / name, target / name)
        metrics = pd.read_csv(run_dir / METRICS)
        kept = [c for c in metrics.columns if not c.startswith("train/") or any(k in c for k in KEPT_TRAIN)]
        write_compressed_metrics(metrics[kept], target)
        copied += 1
    for marker in sweep_root.rglob(SWEEP_MARKER):
        if (destination / marker.relative_to(sweep_root)).parent.exists():  # a sweep with no finished run stays out
            shutil.copy2(marker, destination / marker.relative_to(sweep_root))
    return copied


# ---- the command ----------------------------------------------------------------------------------------------------


def _compare_trees(first: Path, second: Path, root: Path, folders: Sequence[str], replicas: int) -> int:
    """Every job of ``folders`` under ``root`` probed by both checkouts as a group of ``replicas``; exit 1 where they
    differ."""
    differ = 0
    for reference in references(root, folders):
        made = [probe(reference.jobs, tree=tree, replicas=replicas) for tree in (first, second)]
        for result in compare(*made):
            differ += not result.same
            print(f"{reference.name}/ {result.job}: {'same' if result.same else 'DIFFERENT'} ({result.detail})")
    return 1 if differ else 0


def main(argv: Sequence[str] | None = None) -> int:
    # The probes' learners log TorchRL's INFO lines (a replay buffer's size) between the verdicts; the runner's Hydra
    # logging config keeps them at WARNING, as here.
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    parser = argparse.ArgumentParser(prog="python -m sidewalk.reference", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[2:]))
    commands = parser.add_subparsers(dest="command", required=True)
    check = commands.add_parser("check", help="today's probe against every reference folder's recorded one")
    check.add_argument("folders", nargs="*", default=list(FOLDERS), help="under the reference root ('' is itself)")
    check.add_argument("--write-status", action="store_true", help=f"rewrite the reference root's {STATUS}")
    record = commands.add_parser("probe", help="record a reference folder's probe (at the reference's commit)")
    record.add_argument("folder")
    record.add_argument("--tree", help="a checkout of the reference's commit whose code makes the probe (default: "
                                       "this one's)")
    trees = commands.add_parser("trees", help="whether two checkouts compute every reference job alike (a group of "
                                              "--replicas seeds: what a group's arithmetic changes too)")
    trees.add_argument("first")
    trees.add_argument("second")
    trees.add_argument("--folders", nargs="*", default=list(FOLDERS), help="under the reference root")
    trees.add_argument("--replicas", type=int, default=2)
    for command in (check, trees):
        command.add_argument("--root", type=Path, help=f"the reference root (default: {REFERENCE_DIR} in the current "
                                                       "folder or the nearest folder above it)")
    gather = commands.add_parser("collect", help="copy a sweep's small files for the report")
    gather.add_argument("sweep_root")
    gather.add_argument("destination")
    gather.add_argument("--policies-of-seed", type=int, nargs="*", default=[0], metavar="SEED",
                        help="copy these seeds' policy.pt too, for the report's trajectories (default: 0)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command == "probe":
        from sidewalk.run_folder import git_revision

        reference = Reference.load(Path(args.folder))
        tree = None if args.tree is None else Path(args.tree).resolve()
        probe(reference.jobs, tree=tree).to_csv(reference.folder / PROBE, index=False, float_format="%.17g")
        reference.meta["probe_made_at"] = git_revision(tree)  # the code that made it: the reference's commit
        (reference.folder / META).write_text(json.dumps(reference.meta, indent=2) + "\n")
        print(f"wrote {reference.folder / PROBE}, made at {reference.meta['probe_made_at']}", file=sys.stderr)
        return 0
    if args.command == "collect":
        copied = collect(Path(args.sweep_root), Path(args.destination), args.policies_of_seed)
        print(f"collected {copied} run(s) into {args.destination}", file=sys.stderr)
        return 0
    try:
        root = reference_root(args.root)
    except FileNotFoundError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.command == "trees":
        return _compare_trees(Path(args.first).resolve(), Path(args.second).resolve(), root, args.folders,
                              args.replicas)
    checked = [(reference, reference.check()) for reference in references(root, args.folders)]
    for reference, results in checked:
        for result in results:
            print(f"{reference.name}/ {result.job}: {'same' if result.same else 'CHANGED'} ({result.detail})")
    if args.write_status:
        (root / STATUS).write_text(status_table(checked))
    changed = [(reference.name, result.job) for reference, results in checked for result in results if not result.same]
    if changed:
        print(f"error: today's code no longer makes {len(changed)} reference job(s): "
              + ", ".join(f"{folder}/ {job}" for folder, job in changed)
              + " (re-make them, or explain the change in their reference.json)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
