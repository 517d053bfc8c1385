"""The experiment runner end to end: run folders, determinism across processes, kill-and-resume, sweeps."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
WALL_CLOCK = ["time_s", "frames_per_s"]
# A tiny run: a few worlds, small batches; the DQN learns from the first batch on.
RUN = ["num_envs=4", "iterations=12", "eval_every=4", "eval_episodes=8", "checkpoint_every=4", "logger=none"]
TINY_DQN = [
    "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=2000", "algo.learning_starts=0",
    "algo.updates_per_batch=1",
]
TINY = RUN + TINY_DQN


def main_py(*overrides: str, timeout: float = 300, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run(
        [sys.executable, "runners/main.py", *overrides], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )
    if check and result.returncode != 0:
        raise AssertionError(f"main.py failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


def metrics(run_dir: Path) -> pd.DataFrame:
    return pd.read_csv(run_dir / "metrics.csv").drop(columns=WALL_CLOCK)


def test_run_folder_contents(tmp_path):
    run = tmp_path / "run"
    main_py(*TINY, f"hydra.run.dir={run}")
    assert {"config.yaml", "metrics.csv", "summary.json", "checkpoint.pt"} <= {p.name for p in run.iterdir()}
    frame = pd.read_csv(run / "metrics.csv")
    assert list(frame["iteration"]) == list(range(1, 13))
    assert frame["eval/ego/success_rate"].notna().sum() == 3  # iterations 4, 8, 12
    summary = json.loads((run / "summary.json").read_text())
    for key in ("ego/success_rate", "other/success_rate", "agent0/collision_rate", "team/success_rate",
                "min_separation", "path_efficiency", "seed", "wall_clock_s", "versions", "git_revision"):
        assert key in summary
    assert summary["ego/success_rate"] == frame["eval/ego/success_rate"].iloc[-1]
    # A single run ends with its plots: learning curves and trajectories, embedded in report.md.
    report = (run / "report" / "report.md").read_text()
    for figure in (next((run / "report" / "figures").glob("curves_*.png")),
                   run / "report" / "figures" / "fig10_trajectories_discrete.png"):
        assert figure.stat().st_size > 10_000 and f"figures/{figure.name}" in report


def test_same_seed_same_metrics_across_processes(tmp_path):
    main_py(*TINY, "seed=3", f"hydra.run.dir={tmp_path / 'a'}")
    main_py(*TINY, "seed=3", f"hydra.run.dir={tmp_path / 'b'}")
    main_py(*TINY, "seed=4", f"hydra.run.dir={tmp_path / 'c'}")
    pd.testing.assert_frame_equal(metrics(tmp_path / "a"), metrics(tmp_path / "b"))
    assert not metrics(tmp_path / "a").equals(metrics(tmp_path / "c"))


@pytest.mark.parametrize(
    "setup",
    [
        [*TINY_DQN, "noise=0.1"],
        ["env=continuous", "opponent=prm", "algo=trpo", "noise=0.5", "algo.frames_per_batch=32", "algo.vf_batch_size=16"],
    ],
    ids=["dqn-grid", "trpo-continuous"],
)
def test_killed_run_resumes_to_the_same_metrics(tmp_path, setup):
    overrides = [*RUN, "iterations=40", "checkpoint_every=5", "eval_every=10", *setup]
    main_py(*overrides, f"hydra.run.dir={tmp_path / 'whole'}", timeout=600)

    killed = tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, "runners/main.py", *overrides, f"hydra.run.dir={killed}"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 300
    while not (killed / "checkpoint.pt").exists() and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    assert not (killed / "summary.json").exists(), "the run finished before it could be killed"

    main_py(*overrides, f"hydra.run.dir={killed}", "resume=true", timeout=600)
    pd.testing.assert_frame_equal(metrics(killed), metrics(tmp_path / "whole"))


def test_resume_without_checkpoint_is_an_error(tmp_path):
    result = main_py(*TINY, f"hydra.run.dir={tmp_path / 'new'}", "resume=true", check=False)
    assert result.returncode != 0 and "resume=true" in result.stderr


@pytest.mark.parametrize("launcher", ["basic", "joblib"])
def test_a_failing_sweep_job_leaves_the_others_intact(tmp_path, launcher):
    sweep = tmp_path / "sweep"
    extra = ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"] if launcher == "joblib" else []
    # The second job's noise is out of range for the grid: it fails, the first completes.
    result = main_py("-m", *TINY, "noise=0.0,1.5", f"hydra.sweep.dir={sweep}", *extra, check=False)
    assert result.returncode != 0
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert len(jobs) == 2
    good, bad = (jobs[0], jobs[1]) if "0.0" in jobs[0].name else (jobs[1], jobs[0])
    assert json.loads((good / "summary.json").read_text())["seed"] == 0
    assert "noise=1.5" in (bad / "error.txt").read_text()
    assert not (bad / "summary.json").exists()


def test_submitit_local_sweep(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    sweep = tmp_path / "sweep"
    main_py("-m", *TINY, "iterations=4", "seed=0,1", "hydra/launcher=submitit_local", f"hydra.sweep.dir={sweep}",
            timeout=600)
    summaries = sorted(sweep.rglob("summary.json"))
    assert [json.loads(p.read_text())["seed"] for p in summaries] == [0, 1]
