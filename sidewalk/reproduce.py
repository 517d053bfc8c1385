"""The paper's reproduction: every run of the paper's presets, as one pool of jobs on a few processes.

    python -m sidewalk.reproduce                                   # every preset at the paper's budgets, 2 at a time
    python -m sidewalk.reproduce quick                             # smoke test: every preset at scale=quick
    python -m sidewalk.reproduce full --processes 2 --out DIR replicas=5   # overrides go to every job
    runners/reproduce.sh ...                                       # the same, from the repository root

A *job* is one point of a preset's sweep (``hydra.sweeper.params``): one ``runners/main.py -m`` process, which trains
the preset's seeds together (``replicas``). Jobs of every preset share one pool of ``--processes`` workers, the
largest first (iterations × frames per iteration × replicas), so that no worker idles at the end of a preset while
another preset waits. A job whose config equals an earlier job's is run once (Fig. 8's explicit reward at ε = 0.01 is
Fig. 6's ε = 0.01 condition); the report groups runs by config, so it finds that condition in either family.

Each job lands in ``OUT/<preset>/<n>_<its sweep point>/`` (a sweep folder per preset, as ``runners/main.py -m`` makes
it) and logs to ``<that folder>.log``. SIGTERM or Ctrl-C stops the running jobs at the end of their iteration with a
checkpoint, and the pool prints the command that continues it (``--out OUT``). Run the same command again: without
``--out`` it continues the newest unfinished reproduction of the same arguments (``OUT/reproduce.json`` records them),
so finished jobs are skipped, jobs with a checkpoint resume (``resume=true``), jobs stopped before their first
checkpoint start over in their folder and jobs never started start. A job's line says how it ended as that rerun
will read its folder: ``done`` (its runs finished, even if the stop then reached its process), ``interrupted`` (with
the command that continues it) or ``FAILED`` (with its log). ``OUT/jobs.csv`` records each job's start, end,
wall-clock, exit status and outcome; the report (``OUT/report/report.md``) is written last. Exit status: 0 when every
job and the report succeeded, 1 otherwise, 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sidewalk._hydra import basic_sweeper_points
from sidewalk.compose import compose
from sidewalk.paths import CONFIG_DIR, RUNNERS_DIR
from sidewalk.run_folder import CHECKPOINT, PREVIOUS_CHECKPOINT, SUMMARY, group_seed_dirs, group_state_dir

PRESETS = ("fig5_discrete", "fig5_continuous", "fig6_discrete", "fig6_continuous", "fig8")
SCALES = ("full", "quick")
JOBS_FILE = "jobs.csv"
ARGUMENTS_FILE = "reproduce.json"  # what an output root reproduces (scale, presets, overrides) and when it finished
DEFAULT_PARENT = Path("results/sweeps")  # the default output roots: reproduce_<scale>_<time> in here
# Signals that stop a job rather than fail it: the pool's own SIGTERM, Ctrl-C, a closed terminal, SIGUSR1 (a scheduler's
# notice). SIGKILL is not among them: it is how an out-of-memory killer ends a job, a failure the rerun would repeat.
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGUSR1)


@dataclasses.dataclass(frozen=True)
class Job:
    """One process of the reproduction: ``runners/main.py -m`` with ``overrides`` into ``folder`` (relative to the
    output root); ``size`` orders the pool (largest first) and the rest is what the estimate reads."""

    preset: str
    folder: str
    overrides: tuple[str, ...]
    iterations: int
    eval_every: int
    checkpoint_every: int
    replicas: int
    seed: int
    size: int
    config_key: str = dataclasses.field(compare=False, repr=False)

    @property
    def point(self) -> str:
        """The sweep point, e.g. ``noise=0.5``."""
        return self.folder.split("/", 1)[1].split("_", 1)[1]


def sweep_points(preset: str, overrides: Sequence[str] = (), conf_dir: Path | None = None) -> list[list[str]]:
    """The points of a preset's sweep, each a list of overrides, in the order ``runners/main.py -m`` runs them; a
    key given in ``overrides`` is not swept (the command line wins over the preset's sweep, as in Hydra); the
    points are split as Hydra's basic sweeper splits them."""
    cfg = compose([f"+experiment={preset}", *_composable(overrides)], conf_dir, hydra_config=True)
    given = {override.split("=", 1)[0].lstrip("+~") for override in overrides}
    return basic_sweeper_points({key: value for key, value in cfg.hydra.sweeper.params.items() if key not in given})


def jobs(
    presets: Sequence[str] = PRESETS, scale: str = "full", overrides: Sequence[str] = (), conf_dir: Path | None = None
) -> list[Job]:
    """Every job of ``presets`` at ``scale`` with ``overrides``, each config once, largest first."""
    from omegaconf import OmegaConf

    found: dict[str, Job] = {}
    for preset in presets:
        for number, point in enumerate(sweep_points(preset, [f"scale={scale}", *overrides], conf_dir)):
            job_overrides = (f"+experiment={preset}", *point, f"scale={scale}", *overrides)
            cfg = compose(_composable(job_overrides), conf_dir)
            config = OmegaConf.to_container(cfg, resolve=True)
            key = json.dumps(config, sort_keys=True, default=str)
            if any(job.config_key == key for job in found.values()):
                continue
            frames = int(cfg.algo.frames_per_batch)
            job = Job(preset, f"{preset}/{number}_{','.join(point) or 'preset'}", job_overrides, int(cfg.iterations),
                      int(cfg.eval_every), int(cfg.checkpoint_every), int(cfg.replicas), int(cfg.seed),
                      int(cfg.iterations) * frames * int(cfg.replicas), key)
            found[job.folder] = job
    return sorted(found.values(), key=lambda job: -job.size)  # stable: presets' order among equals


def _composable(overrides: Sequence[str]) -> list[str]:
    """The overrides that shape a run's config (Hydra's own settings, such as its launcher, do not)."""
    return [override for override in overrides if not override.lstrip("+~").startswith("hydra")]


# ---- a job's folder ---------------------------------------------------------------------------------------------------


def job_state(folder: Path, job: Job) -> str:
    """``new`` (nothing there), ``done`` (every seed's summary, no checkpoint left), ``resume`` (a checkpoint), or
    ``stale`` (started, killed before its first checkpoint)."""
    if not folder.exists():
        return "new"
    state_dir = group_state_dir(folder, job.replicas)
    if any((state_dir / name).exists() for name in (CHECKPOINT, PREVIOUS_CHECKPOINT)):
        return "resume"
    if all((replica / SUMMARY).exists() for replica in group_seed_dirs(folder, job.seed, job.replicas)):
        return "done"
    return "stale"


def job_outcome(state: str, code: int) -> str:
    """How a job ended, from its folder's ``job_state`` once its process exited with ``code`` (the state a rerun
    reads), not from the exit code alone: ``done`` (it finished, even if a signal then killed its process on the way
    out), ``interrupted`` (a signal stopped it first: the rerun continues it), or ``failed``."""
    if state == "done":
        return "done"
    if code > 128 or (code < 0 and -code in STOP_SIGNALS):  # 128 + n: main.py stopped by signal n; -n: killed by it
        return "interrupted"
    return "failed"


def describe(outcome: str, state: str, code: int, log: Path, continue_with: str, wall_s: float) -> str:
    """A job's line once its process ended: its outcome, and for one that did not finish, what to do."""
    if outcome == "done":
        return f"done in {wall_s:.0f} s"
    if outcome == "interrupted":
        then = "resumes from its checkpoint" if state == "resume" else "starts again (no checkpoint yet)"
        return f"interrupted after {wall_s:.0f} s ({_exit(code)}); it {then} when you continue with:\n  {continue_with}"
    return f"FAILED ({_exit(code)}; see {log}) after {wall_s:.0f} s"


def _exit(code: int) -> str:
    return f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit {code}"


def continue_command(args: argparse.Namespace, root: Path) -> str:
    """The command that continues the reproduction of ``args`` in ``root``."""
    presets = [] if args.presets == list(PRESETS) else ["--presets", *args.presets]
    return shlex.join(["runners/reproduce.sh", args.scale, *args.overrides, "--processes", str(args.processes),
                       "--out", str(root), *presets])


def _arguments(args: argparse.Namespace) -> dict[str, Any]:
    """What makes two reproductions the same: their scale, presets and overrides (not how many processes run them)."""
    return {"scale": args.scale, "presets": sorted(args.presets), "overrides": list(args.overrides)}


def output_root(args: argparse.Namespace) -> tuple[Path, bool]:
    """Where the reproduction goes, and whether it continues one: ``--out``, else ``$REPRODUCE_DIR``, else the newest
    unfinished reproduction of the same arguments in ``results/sweeps/`` (so that the same command continues it),
    else a new ``results/sweeps/reproduce_<scale>_<time>``."""
    given = args.out or os.environ.get("REPRODUCE_DIR")
    if given:
        return Path(given).resolve(), (Path(given) / ARGUMENTS_FILE).exists()
    for folder in sorted(DEFAULT_PARENT.glob(f"reproduce_{args.scale}_*"), reverse=True):  # the newest first
        recorded = folder / ARGUMENTS_FILE
        if recorded.is_file() and json.loads(recorded.read_text()) == {**_arguments(args), "finished": None}:
            return folder.resolve(), True
    return (DEFAULT_PARENT / f"reproduce_{args.scale}_{time.strftime('%Y-%m-%d_%H-%M-%S')}").resolve(), False


def record_arguments(args: argparse.Namespace, root: Path, finished: bool = False) -> None:
    """Write ``root/reproduce.json``: the reproduction's arguments, and when it finished (every job and the report)."""
    from sidewalk.run_folder import atomic_write

    recorded = {**_arguments(args), "finished": _now() if finished else None}
    atomic_write(root / ARGUMENTS_FILE, lambda tmp: tmp.write_text(json.dumps(recorded, indent=1)))


def command(job: Job, root: Path, resume: bool) -> list[str]:
    preset_dir, subdir = (root / job.folder).parent, (root / job.folder).name
    return [sys.executable, str(RUNNERS_DIR / "main.py"), "-m", *job.overrides, f"hydra.sweep.dir={preset_dir}",
            f"hydra.sweep.subdir='{subdir}'", *(["resume=true"] if resume else [])]


# ---- the pool -----------------------------------------------------------------------------------------------------


class Pool:
    """Runs jobs ``processes`` at a time, largest first; forwards SIGTERM and Ctrl-C to the running jobs (which
    checkpoint and stop) and starts no more."""

    def __init__(self, root: Path, processes: int, continue_with: str) -> None:
        self.root, self.processes, self.continue_with = root, processes, continue_with
        self.lock = threading.Lock()
        self.running: dict[str, subprocess.Popen] = {}
        self.stopping = False
        self.rows: list[dict[str, Any]] = []

    def run(self, queue: list[Job]) -> list[dict[str, Any]]:
        pending = list(queue)
        previous = {sig: signal.signal(sig, self._stop) for sig in (signal.SIGTERM, signal.SIGINT)}
        try:
            workers = [threading.Thread(target=self._worker, args=(pending, len(queue))) for _ in range(self.processes)]
            for worker in workers:
                worker.start()
            for worker in workers:
                while worker.is_alive():
                    worker.join(0.5)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return self.rows

    def _stop(self, signum: int, frame: Any) -> None:
        with self.lock:
            self.stopping = True
            for process in self.running.values():
                process.send_signal(signal.SIGTERM)  # the job checkpoints at the end of its iteration
        self._say(f"{signal.Signals(signum).name}: the running jobs checkpoint and stop; continue with:\n  "
                  f"{self.continue_with}")

    def _worker(self, pending: list[Job], total: int) -> None:
        while True:
            with self.lock:
                if self.stopping or not pending:
                    return
                job = pending.pop(0)
                number = total - len(pending)
            self._run_job(job, f"[{number}/{total}] {job.folder}")

    def _say(self, line: str) -> None:
        sys.stderr.write(f"reproduce: {line}\n")  # one write: lines of two workers never interleave
        sys.stderr.flush()

    def _run_job(self, job: Job, name: str) -> None:
        folder = self.root / job.folder
        state = job_state(folder, job)
        row = {"preset": job.preset, "job": job.folder, "state": state, "started": _now(), "ended": "", "wall_s": 0.0,
               "exit": 0}
        if state == "done":
            self._say(f"{name}: already done")
            self._record({**row, "ended": row["started"], "outcome": "done"})
            return
        folder.parent.mkdir(parents=True, exist_ok=True)
        # resume=true continues a job's folder: from its checkpoint, or (stopped before its first) from the start
        argv = command(job, self.root, resume=state != "new")
        log = folder.with_name(folder.name + ".log")
        what = {"new": "started", "resume": "resumed", "stale": "started again (stopped before its first checkpoint)"}
        self._say(f"{name}: {what[state]} ({job.replicas} seed(s) x {job.iterations} iterations; log {log})")
        started = time.perf_counter()
        with open(log, "a") as out:
            out.write(f"$ {shlex.join(argv)}\n")
            out.flush()
            with self.lock:
                if self.stopping:
                    return
                process = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, cwd=RUNNERS_DIR.parent,
                                           start_new_session=True)  # Ctrl-C reaches it once, through _stop
                self.running[job.folder] = process
            code = process.wait()
            with self.lock:
                del self.running[job.folder]
        wall = time.perf_counter() - started
        after = job_state(folder, job)  # what the rerun will read, whatever the exit code says
        ended = job_outcome(after, code)
        self._say(f"{name}: {describe(ended, after, code, log, self.continue_with, wall)}")
        self._record({**row, "ended": _now(), "wall_s": round(wall, 1), "exit": code, "outcome": ended})

    def _record(self, row: dict[str, Any]) -> None:
        import pandas as pd

        from sidewalk.run_folder import atomic_write

        with self.lock:
            self.rows.append(row)
            path = self.root / JOBS_FILE
            earlier = pd.read_csv(path) if path.exists() and path.stat().st_size else pd.DataFrame()
            table = pd.concat([earlier, pd.DataFrame([row])], ignore_index=True)
            atomic_write(path, lambda tmp: table.to_csv(tmp, index=False))


def _now() -> str:
    return datetime.datetime.now().astimezone().isoformat(timespec="seconds")


def parse_options(argv: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="runners/reproduce.sh", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[2:]))
    parser.add_argument("scale", nargs="?", default="full", help=f"one of {', '.join(SCALES)} (default: full)")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides given to every job (e.g. replicas=5)")
    parser.add_argument("--processes", type=int, default=2, help="jobs at a time (default: 2)")
    parser.add_argument("--out", help="output root (default: $REPRODUCE_DIR, else "
                                      "results/sweeps/reproduce_<scale>_<time>)")
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), metavar="PRESET",
                        help=f"presets to run (default: {' '.join(PRESETS)})")
    parser.add_argument("--list", action="store_true", help="print the jobs in the pool's order and exit")
    args = parser.parse_intermixed_args(argv)  # overrides may follow the options
    if args.scale not in SCALES:
        # An override in the scale's place (replicas=5) means the default scale.
        if "=" in args.scale:
            args.overrides.insert(0, args.scale)
            args.scale = "full"
        else:
            parser.error(f"scale {args.scale!r}: choose one of {', '.join(SCALES)}")
    # --presets takes every word after it: an override given after the presets (a=b) is an override all the same.
    args.overrides += [word for word in args.presets if "=" in word]
    args.presets = [word for word in args.presets if "=" not in word] or list(PRESETS)
    if args.processes < 1:
        parser.error(f"--processes {args.processes}: must be at least 1")
    known = sorted(path.stem for path in (CONFIG_DIR / "experiment").glob("*.yaml"))
    for preset in args.presets:
        if preset not in known:
            parser.error(f"--presets {preset}: not a preset of conf/experiment/ (presets: {', '.join(known)})")
    for override in args.overrides:
        if override.startswith(("hydra.sweep.dir=", "hydra/launcher=")):
            parser.error(f"{override}: the pool places and launches the jobs itself (use --out and --processes)")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_options(sys.argv[1:] if argv is None else argv)
    try:
        queue = jobs(args.presets, args.scale, args.overrides)
    except Exception as error:  # noqa: BLE001 -- a config Hydra cannot compose: one line, before any compute
        print(f"error: {str(error).splitlines()[0]}", file=sys.stderr)
        return 2
    if args.list:
        for job in queue:
            print(f"{job.folder}\t{shlex.join(job.overrides)}")
        return 0
    root, continuing = output_root(args)
    root.mkdir(parents=True, exist_ok=True)
    record_arguments(args, root)
    print(f"reproduce: {len(queue)} jobs, {args.processes} at a time, {'continuing' if continuing else 'into'} {root}",
          file=sys.stderr, flush=True)
    started = time.perf_counter()
    rows = Pool(root, args.processes, continue_command(args, root)).run(queue)
    failed = [row["job"] for row in rows if row["outcome"] == "failed"]
    interrupted = sum(row["outcome"] == "interrupted" for row in rows)
    unfinished = len(queue) - len(rows)
    print(f"reproduce: jobs took {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    if unfinished or interrupted:
        print(f"reproduce: stopped with {interrupted} job(s) interrupted and {unfinished} not started; continue with "
              f"(or run the same command again):\n  {continue_command(args, root)}", file=sys.stderr)
        return 1
    report = subprocess.run([sys.executable, str(RUNNERS_DIR / "report.py"), str(root), "--out", str(root / "report")],
                            check=False)
    if failed or report.returncode:
        print(f"reproduce: failed: {' '.join(failed + (['report'] if report.returncode else []))} (see the jobs' "
              f"logs and {root / 'report' / 'report.md'})", file=sys.stderr)
        return 1
    record_arguments(args, root, finished=True)
    print(f"reproduce: done: {root / 'report' / 'report.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
