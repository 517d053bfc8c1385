"""The experiment runner end to end: run folders, determinism across processes, kill-and-resume, sweeps."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest
from omegaconf import OmegaConf

from sidewalk.compose import compose as compose_config
from sidewalk.config import validate
from sidewalk.experiment import Trial
from sidewalk.run_folder import read_torch_file

ROOT = Path(__file__).resolve().parents[1]
WALL_CLOCK = ["time_s", "frames_per_s"]
# A tiny run: a few worlds, small batches; the DQN learns from the first batch on.
# plots=false: the report costs a process ~5 s; the main run below writes it and its test reads it.
RUN = [
    "num_envs=4", "iterations=12", "eval_every=4", "eval_episodes=8", "checkpoint_every=4", "logger=none", "plots=false"
]
TINY_DQN = [
    "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=2000", "algo.learning_starts=0",
    "algo.updates_per_batch=1",
]
TINY = RUN + TINY_DQN


def main_py(processes, *overrides: str, timeout: float = 300, check: bool = True) -> subprocess.CompletedProcess:
    """``python runners/main.py *overrides`` in a process of its own (forked after the imports: conftest.py)."""
    result = processes.run("runners/main.py", *overrides, timeout=timeout)
    if check and result.returncode != 0:
        raise AssertionError(f"main.py failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


def metrics(run_dir: Path) -> pd.DataFrame:
    return pd.read_csv(run_dir / "metrics.csv").drop(columns=WALL_CLOCK)


def history(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "history.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def main_run(tmp_path_factory, processes) -> tuple[Path, subprocess.CompletedProcess]:
    """The tiny run made by runners/main.py in a process of its own, plots and all, and what it printed."""
    run = tmp_path_factory.mktemp("main") / "run"
    return run, main_py(processes, *TINY, "plots=true", f"hydra.run.dir={run}")


def test_run_folder_contents(main_run):
    run, result = main_run
    # What trains and where, first; TorchRL's INFO line on the replay buffer's storage not inside the progress bar.
    assert result.stdout.startswith("training env=discrete env.layout=sidewalk algo=dqn opponent=dijkstra noise=0 "
                                    f"seed=0 iterations=12; run folder: {run}\n"), result.stdout
    assert "Storage" not in result.stdout + result.stderr
    files = {p.name for p in run.iterdir()}
    assert {"config.yaml", "history.jsonl", "metrics.csv", "summary.json", "policy.pt"} <= files
    assert not {"checkpoint.pt", "checkpoint.prev.pt"} & files  # keep_checkpoint=final: the state is dropped
    assert [event["event"] for event in history(run)] == ["started", "finished"]
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


def test_same_seed_same_metrics_across_processes(tmp_path, main_run, finished_run):
    # Seed 0 by main.py in a process of its own, and by a Trial in a test's process that may have run other tests.
    pd.testing.assert_frame_equal(metrics(main_run[0]), metrics(finished_run(TINY)))
    cfg = compose_config([*TINY, "seed=4"])
    Trial(validate(cfg), tmp_path / "seed4", OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    assert not metrics(main_run[0]).equals(metrics(tmp_path / "seed4"))


GRID_SETUP = [*TINY_DQN, "noise=0.1"]
CONTINUOUS_SETUP = [
    "env=continuous", "opponent=prm", "algo=trpo", "noise=0.5", "algo.frames_per_batch=32", "algo.vf_batch_size=16"
]


@pytest.mark.parametrize(
    "setup, stop",
    [(GRID_SETUP, signal.SIGKILL), (CONTINUOUS_SETUP, signal.SIGKILL), (GRID_SETUP, signal.SIGTERM)],
    ids=["dqn-grid-killed", "trpo-continuous-killed", "dqn-grid-preempted"],
)
def test_stopped_run_resumes_to_the_same_metrics(tmp_path, finished_run, processes, setup, stop):
    # SIGKILL: the run resumes from its last periodic checkpoint. SIGTERM (a scheduler's pre-emption): the run
    # writes a checkpoint at the end of the iteration it is in and exits with 128 + 15.
    overrides = [*RUN, "iterations=40", "checkpoint_every=5", "eval_every=10", *setup]
    whole = finished_run(overrides)

    stopped = tmp_path / "stopped"
    process = processes.start("runners/main.py", *overrides, f"hydra.run.dir={stopped}")
    deadline = time.time() + 300
    while not (stopped / "checkpoint.pt").exists() and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    os.kill(process.pid, stop)
    returncode = process.wait()
    assert not (stopped / "summary.json").exists(), "the run finished before it could be stopped"
    if stop == signal.SIGTERM:
        assert returncode == 128 + signal.SIGTERM
        assert history(stopped)[-1]["event"] == "interrupted"
        at = read_torch_file(stopped / "checkpoint.pt")["iteration"]
        assert len(pd.read_csv(stopped / "metrics.csv")) == at  # the metrics end where the checkpoint does

    main_py(processes, *overrides, f"hydra.run.dir={stopped}", "resume=true", timeout=600)
    pd.testing.assert_frame_equal(metrics(stopped), metrics(whole))
    # The best evaluation's policy is in the checkpoint: the absolute metric is the uninterrupted run's.
    absolute = [json.loads((run / "summary.json").read_text())["absolute"] for run in (stopped, whole)]
    assert absolute[0] == absolute[1]


def test_resume_refuses_another_config_naming_each_key(tmp_path, finished_run, processes):
    run = tmp_path / "run"
    shutil.copytree(finished_run([*TINY, "keep_checkpoint=all"]), run)
    config = (run / "config.yaml").read_text()
    result = main_py(processes, *TINY, "noise=0.2", "iterations=8", "resume=true", f"hydra.run.dir={run}",
                     check=False)
    assert result.returncode == 2
    assert "noise: 0.0 -> 0.2" in result.stderr and "iterations: 12 -> 8" in result.stderr
    assert (run / "config.yaml").read_text() == config and len(history(run)) == 2  # nothing was touched
    # A new run into the folder is refused too: two runs never mix in one folder.
    result = main_py(processes, *TINY, f"hydra.run.dir={run}", check=False)
    assert result.returncode == 2 and "already holds a run" in result.stderr


def test_a_finished_run_extends_to_the_run_of_the_larger_budget(tmp_path, finished_run, processes):
    extended = tmp_path / "extended"
    shutil.copytree(finished_run([*TINY, "keep_checkpoint=all"]), extended)
    main_py(processes, *TINY, "iterations=16", "resume=true", f"hydra.run.dir={extended}")
    pd.testing.assert_frame_equal(metrics(extended), metrics(finished_run([*TINY, "iterations=16"])))
    assert history(extended)[2] | {"time": None, "git_revision": None} == {
        "event": "resumed", "iterations": {"from": 12, "to": 16}, "time": None, "git_revision": None
    }
    assert "iterations: 16" in (extended / "config.yaml").read_text()


def test_a_corrupt_checkpoint_falls_back_to_the_previous_one(tmp_path, finished_run, processes):
    finished = finished_run([*TINY, "keep_checkpoint=all"])  # checkpoints at 12, prev at 8
    run, both = tmp_path / "run", tmp_path / "both"
    shutil.copytree(finished, run)
    shutil.copytree(finished, both)
    data = (run / "checkpoint.pt").read_bytes()
    (run / "checkpoint.pt").write_bytes(data[: len(data) // 2])  # torn: the disk filled, the node died
    result = main_py(processes, *TINY, "iterations=16", "resume=true", f"hydra.run.dir={run}")
    assert "checkpoint.pt is unreadable" in result.stderr
    pd.testing.assert_frame_equal(metrics(run), metrics(finished_run([*TINY, "iterations=16"])))  # from 8, exactly

    for name in ("checkpoint.pt", "checkpoint.prev.pt"):
        (both / name).write_bytes(b"not a checkpoint")
    result = main_py(processes, *TINY, "iterations=16", "resume=true", f"hydra.run.dir={both}", check=False)
    assert result.returncode == 2 and "no readable checkpoint" in result.stderr  # refused before any compute
    assert "checkpoint.pt and checkpoint.prev.pt are unreadable" in result.stderr


def test_a_finished_default_run_folder_is_small(tmp_path, processes):
    # The default DQN's replay buffer alone is ~90 MB; a finished folder keeps the policy, metrics and plots.
    run = tmp_path / "run"
    main_py(processes, "iterations=3", "eval_every=0", "eval_episodes=16", f"hydra.run.dir={run}")
    size = sum(path.stat().st_size for path in run.rglob("*") if path.is_file())
    assert size < 5_000_000, size
    assert (run / "policy.pt").exists() and not (run / "checkpoint.pt").exists()


def test_a_diverged_learner_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch):
    import torch
    from hydra import compose, initialize_config_dir

    from sidewalk.algos.dqn import DQN
    from sidewalk.schema import register_schemas
    from sidewalk.stops import LearnerDiverged

    register_schemas()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, "checkpoint_every=1"])
    update, calls = DQN.update, []

    def update_that_diverges(self, batch, replay_buffer=None):
        logs = update(self, batch, replay_buffer)
        calls.append(1)
        if len(calls) == 3:
            with torch.no_grad():
                next(self.loss.parameters()).fill_(float("nan"))
        return logs

    monkeypatch.setattr(DQN, "update", update_that_diverges)
    with pytest.raises(LearnerDiverged, match="diverged at iteration 3: non-finite parameters of 'loss'"):
        Trial(validate(cfg), tmp_path, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    assert read_torch_file(tmp_path / "checkpoint.pt")["iteration"] == 2
    assert len(pd.read_csv(tmp_path / "metrics.csv")) == 2
    assert history(tmp_path)[-1]["event"] == "diverged"


def test_resume_without_checkpoint_is_an_error(tmp_path, finished_run, processes):
    result = main_py(processes, *TINY, f"hydra.run.dir={tmp_path / 'new'}", "resume=true", check=False)
    assert result.returncode == 2 and "resume=true" in result.stderr
    finished = tmp_path / "finished"
    shutil.copytree(finished_run(TINY), finished)  # keep_checkpoint=final: the state is gone after the run
    result = main_py(processes, *TINY, "iterations=16", "resume=true", f"hydra.run.dir={finished}", check=False)
    assert result.returncode == 2 and "keep_checkpoint=all" in result.stderr


def test_what_resume_does_with_the_folder_it_finds(tmp_path):
    from dataclasses import replace

    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from sidewalk.config import validate
    from sidewalk.run_folder import RunFolderError
    from sidewalk.schema import register_schemas
    from sidewalk.trial_state import check_folders

    register_schemas()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, "replicas=2", "resume=true"])
    experiment, config, job = validate(cfg), OmegaConf.to_container(cfg, resolve=True), tmp_path / "job"
    # A sweep's job that the interrupted sweep never reached starts; a lone run refuses (a mistyped folder, likely).
    assert check_folders(job, experiment, config, in_sweep=True) == "start"
    with pytest.raises(RunFolderError, match="is not a run folder"):
        check_folders(job, experiment, config)
    # Stopped before its first checkpoint: it trains again from the start, in its folder.
    for folder, seed in ((job / ".group", 0), (job / "seed0", 0), (job / "seed1", 1)):
        folder.mkdir(parents=True)
        OmegaConf.save(OmegaConf.create({**config, "seed": seed}), folder / "config.yaml")
    assert check_folders(job, experiment, config, in_sweep=True) == check_folders(job, experiment, config) == "resume"
    # Finished at this budget: nothing to do, in a sweep or alone.
    for seed in (0, 1):
        (job / f"seed{seed}" / "summary.json").write_text("{}")
    assert check_folders(job, experiment, config, in_sweep=True) == check_folders(job, experiment, config) == "finished"
    # A larger budget needs a checkpoint to extend.
    with pytest.raises(RunFolderError, match="no checkpoint to extend"):
        check_folders(job, replace(experiment, iterations=24), {**config, "iterations": 24})


@pytest.mark.parametrize("launcher", ["basic", "joblib"])
def test_a_failing_sweep_job_leaves_the_others_intact(tmp_path, processes, launcher):
    sweep = tmp_path / "sweep"
    extra = ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"] if launcher == "joblib" else []
    # The second job's learner diverges at its first update (a valid config: only running it finds out): it fails,
    # the first completes. A config the checks refuse stops the sweep before any job (test_config.py).
    result = main_py(processes, "-m", *TINY, "reward.c_step=-0.01,-1e38", f"hydra.sweep.dir={sweep}", *extra,
                     check=False)
    assert result.returncode != 0
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert len(jobs) == 2
    good, bad = (jobs[0], jobs[1]) if jobs[0].name.startswith("0_") else (jobs[1], jobs[0])
    assert json.loads((good / "summary.json").read_text())["seed"] == 0
    assert "LearnerDiverged: the learner diverged at iteration 1" in (bad / "error.txt").read_text()
    assert not (bad / "summary.json").exists()


def test_submitit_local_sweep(tmp_path, processes):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    sweep = tmp_path / "sweep"
    main_py(processes, "-m", *TINY, "iterations=4", "seed=0,1", "hydra/launcher=submitit_local",
            f"hydra.sweep.dir={sweep}", timeout=600)
    summaries = sorted(sweep.rglob("summary.json"))
    assert [json.loads(p.read_text())["seed"] for p in summaries] == [0, 1]


def test_resume_reads_keys_added_since_the_folder_was_written_at_their_defaults(tmp_path):
    from hydra import compose, initialize_config_dir

    from sidewalk import run_folder
    from sidewalk.schema import register_schemas

    register_schemas()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        config = OmegaConf.to_container(compose(config_name="config", overrides=["resume=true"]), resolve=True)
    # A folder written before these keys existed: the behaviour it ran with is their default.
    old = {**config, "algo": dict(config["algo"])}
    for key in ("dueling", "default_iterations", "default_eval_every"):
        del old["algo"][key]
    del old["keep_checkpoint"]
    OmegaConf.save(OmegaConf.create(old), tmp_path / run_folder.CONFIG)
    (tmp_path / run_folder.CHECKPOINT).write_bytes(b"")
    assert run_folder.check(tmp_path, config, resume=True) is None
    # Asking for other than the default of a key the folder lacks is another experiment.
    plain = {**config, "algo": {**config["algo"], "dueling": False}}
    with pytest.raises(run_folder.RunFolderError, match=r"algo.dueling: True -> False"):
        run_folder.check(tmp_path, plain, resume=True)


def test_a_dqn_folder_from_before_advantage_learning_reads_as_the_plain_dqn_it_ran(tmp_path):
    from hydra import compose, initialize_config_dir

    from sidewalk import run_folder
    from sidewalk.schema import register_schemas

    register_schemas()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        config = OmegaConf.to_container(compose(config_name="config", overrides=["resume=true"]), resolve=True)
    assert config["algo"]["advantage_learning"] == 0.9  # today's default learner
    old = {**config, "algo": {k: v for k, v in config["algo"].items() if k != "advantage_learning"}}
    OmegaConf.save(OmegaConf.create(old), tmp_path / run_folder.CONFIG)
    (tmp_path / run_folder.CHECKPOINT).write_bytes(b"")
    assert run_folder.read_saved_config(tmp_path).algo.advantage_learning == 0.0
    with pytest.raises(run_folder.RunFolderError, match=r"algo.advantage_learning: 0.0 -> 0.9"):
        run_folder.check(tmp_path, config, resume=True)
    plain = {**config, "algo": {**config["algo"], "advantage_learning": 0.0}}
    assert run_folder.check(tmp_path, plain, resume=True) is None
