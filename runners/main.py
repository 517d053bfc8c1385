"""One trial of the Sidewalk Problem, configured by Hydra (``conf/``). See ``--help`` for the groups.

    python runners/main.py                                        # discrete, Dijkstra opponent, DQN
    python runners/main.py env=continuous opponent=prm algo=trpo noise=0.5
    python runners/main.py -m seed=0,1,2 noise=0,0.1,0.2 hydra/launcher=joblib
    python runners/main.py hydra.run.dir=results/runs/mine resume=true   # continue a killed run
    python runners/main.py hydra.run.dir=results/runs/mine resume=true iterations=1000 keep_checkpoint=all
                                                   # extend a run that finished with keep_checkpoint=all
    python runners/main.py -m seed=0,1,2 hydra.sweep.dir=results/sweeps/mine resume=true
                                         # continue a sweep: finished jobs skipped, the others resumed or started

A stopped run or sweep prints the command that continues it.

Exit status: 0 done; 2 a bad config or run folder, or a folder another process is writing (nothing computed); 1 an
error, or a learner that diverged; 128 + n when signal n (SIGTERM, SIGUSR1, Ctrl-C's SIGINT) stopped the run after
writing its checkpoint (a second Ctrl-C stops at once, from the last checkpoint on).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import traceback
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from hydra.types import RunMode
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException

from sidewalk import hydra_callbacks, run_folder
from sidewalk.compose import one_line
from sidewalk.continue_command import continue_command
from sidewalk.hydra_callbacks import ERROR_FILE, planned
from sidewalk.paths import CONFIG_DIR
from sidewalk.schema import register_schemas

register_schemas()

# The learner's own figures first (the ego's, or the team's where it plays every agent), then the partner's, then
# the means over every agent, labelled so: a bare success_rate beside the ego's read as the learner's.
HEADLINE = {"ego/success_rate": "", "ego/collision_rate": "", "ego/return": "", "team/success_rate": "",
            "other/success_rate": "", "success_rate": " (mean over agents)", "collision_rate": " (mean over agents)",
            "return": " (mean over agents)", "episode_length": ""}


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="config")
def main(cfg: DictConfig) -> float | None:
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    in_sweep = hydra_cfg.mode == RunMode.MULTIRUN
    refused_file = run_dir.with_name(f"{run_dir.name}.{ERROR_FILE}")  # a refused job's error: not in its folder
    with contextlib.ExitStack() as held:
        try:
            # Every check before any compute (a single run's passed them in CheckFirst), then the folder's plan.
            experiment, config, plan = planned(cfg, run_dir, held, in_sweep)
        except run_folder.FolderInUse as error:
            refuse(error, in_sweep, refused_file)
            return None
        except hydra_callbacks.REFUSED as error:
            refuse(error, in_sweep, run_dir / ERROR_FILE)
            return None
        for stale in (run_dir / ERROR_FILE, refused_file):  # an earlier attempt's failure, which this one retries
            stale.unlink(missing_ok=True)
        if plan == "finished":
            from sidewalk.trial_state import read_summaries

            print(f"resume=true: {run_dir} finished at this budget already; nothing to do", file=sys.stderr)
            return report(read_summaries(run_dir, experiment), run_dir, plots=False)
        try:
            return train(experiment, run_dir, config, in_sweep, cfg.plots, continue_command(hydra_cfg))
        except KeyboardInterrupt:  # Ctrl-C before the training loop took over SIGINT (start-up, the final report)
            from sidewalk.trial_state import state_dir

            holds_run = (state_dir(run_dir, experiment) / run_folder.CONFIG).exists()  # else: start it, no resume
            print(f"\ninterrupted; {run_dir} keeps what it had written; continue with:\n  "
                  f"{continue_command(hydra_cfg, resume=holds_run)}", file=sys.stderr)
            sys.exit(128 + signal.SIGINT)


def refuse(error: Exception, in_sweep: bool, error_file: Path) -> None:
    """A bad config or run folder, before any compute: one ``error:`` line and exit 2 (a sweep's job records it in
    ``error_file`` and lets the others run)."""
    if in_sweep:
        error_file.parent.mkdir(parents=True, exist_ok=True)
        error_file.write_text(f"invalid config or run folder: {error}\n")
        return
    hydra_callbacks.refuse(error)


def train(experiment, run_dir: Path, config: dict, in_sweep: bool, plots: bool, continue_with: str) -> float | None:
    """Run the trial and print its headline figures (and write its plots if ``plots``, outside a sweep);
    ``continue_with``: the command that continues it, printed if it is stopped."""
    from sidewalk.experiment import Trial
    from sidewalk.stops import LearnerDiverged, RunInterrupted

    print(f"training {experiment.describe()}; run folder: {run_dir}", flush=True)  # before the progress bar
    try:
        summaries = Trial(experiment, run_dir, config, continue_with).run()
    except RunInterrupted as stopped:
        print(f"\n{stopped}", file=sys.stderr)
        sys.exit(128 + stopped.signum)
    except (LearnerDiverged, run_folder.RunFolderError) as error:
        if in_sweep:
            (run_dir / ERROR_FILE).write_text(f"{type(error).__name__}: {error}\n")
            return None
        print(f"\nerror: {error}", file=sys.stderr)
        sys.exit(1)
    except Exception:
        if not in_sweep:
            raise
        # A failing job keeps its error in its own folder and lets the other jobs run; SweepStatus exits 1 at the end.
        (run_dir / ERROR_FILE).write_text(traceback.format_exc())
        return None
    return report(summaries, run_dir, plots=plots and not in_sweep)  # a sweep's runs are reported together: runners/report.py <sweep folder>


def report(summaries: list[dict], run_dir: Path, plots: bool) -> float | None:
    """Print the seeds' headline figures (and write the run's plots); return their mean success."""
    print(f"\nrun folder: {run_dir}" + (f" ({len(summaries)} seeds)" if len(summaries) > 1 else ""))
    for summary in summaries:
        if len(summaries) > 1:
            print(f"  seed {summary['seed']}:")
        print(f"  {evaluated_on(summary)}")
        for key, label in HEADLINE.items():
            if key in summary:
                print(f"  {key + label:40s} {summary[key]:.3f}")
        print(f"  {'wall_clock_s':40s} {summary['wall_clock_s']:.1f}")
    if plots:
        write_plots(run_dir)
    successes = [summary.get("ego/success_rate", summary.get("team/success_rate")) for summary in summaries]
    return sum(successes) / len(successes) if None not in successes else None


def evaluated_on(summary: dict) -> str:
    """What the figures rest on: "eval: perturbed, 256 episodes (246 distinct)"."""
    protocol = (summary.get("eval_protocol") or {}).get("name", "nominal")
    episodes, distinct = summary.get("episodes"), summary.get("distinct_episodes")
    counted = "" if episodes is None else f", {int(episodes):,} episodes" + (
        "" if distinct is None else f" ({int(distinct):,} distinct)")
    return f"eval: {protocol}{counted}"


def write_plots(run_dir: Path) -> None:
    """The run's learning curves, final values and trajectories in ``run_dir/report/`` (``sidewalk.report``)."""
    from sidewalk.report.document import write_report
    from sidewalk.report.tables import Settings

    try:
        result = write_report([run_dir], run_dir / "report", Settings(n_resamples=2000))
    except Exception as error:  # noqa: BLE001 (the run's results are written; a plot must not turn it into a failure)
        print(f"warning: no plots: {type(error).__name__}: {error}", file=sys.stderr)
        return
    print(f"  {'plots and report':40s} {result.report_md} ({len(result.figures)} figures)")


def scale_added(arguments: list[str]) -> list[str]:
    """The command line with ``scale=NAME`` read as ``+scale=NAME`` where no preset is chosen. The presets list the
    ``scale`` group after their own budgets, so that ``scale=quick`` overrides them; a default in the root config could
    not (a preset added with ``+experiment=`` composes after every root default), so a plain run has no ``scale`` for
    Hydra to override."""
    if any(argument.lstrip("+").startswith("experiment=") for argument in arguments):
        return arguments
    return [f"+{argument}" if argument.startswith("scale=") else argument for argument in arguments]


def cli() -> None:
    """``main`` with every error as one ``error:`` line (exit 2 for a config Hydra cannot compose, 1 otherwise);
    the traceback only with ``HYDRA_FULL_ERROR=1``."""
    asked_for_traceback = os.environ.get("HYDRA_FULL_ERROR") == "1"
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises instead of printing its multi-line report
    sys.argv[1:] = scale_added(sys.argv[1:])
    try:
        main()
    except Exception as error:
        if asked_for_traceback:
            raise
        config_error = isinstance(error, (HydraException, OmegaConfBaseException))
        detail = one_line(error) if config_error else f"{type(error).__name__}: {one_line(error)}"
        print(f"error: {detail} (HYDRA_FULL_ERROR=1 shows the traceback)", file=sys.stderr)
        sys.exit(2 if config_error else 1)


if __name__ == "__main__":
    cli()
