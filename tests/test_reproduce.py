"""The reproduction pool (python -m sidewalk.reproduce, runners/reproduce.sh): its options, its jobs (each config once,
largest first) and how it reads a job's folder to skip, resume or restart it."""

from __future__ import annotations

import dataclasses
import itertools
import sys
import time
import types

import pytest

from sidewalk import reproduce
from sidewalk.reproduce import PRESETS, Pool, job_state, jobs, main, parse_options
from sidewalk.run_folder import CHECKPOINT, GROUP_DIR, SUMMARY


def test_overrides_may_come_before_after_or_among_the_options():
    before = parse_options(["full", "seed=0", "replicas=5", "--presets", "fig8", "step_cost_centralized"])
    after = parse_options(["--presets", "fig8", "step_cost_centralized", "seed=0", "replicas=5"])
    for args in (before, after):
        assert (args.scale, args.presets, args.overrides) == ("full", ["fig8", "step_cost_centralized"],
                                                              ["seed=0", "replicas=5"])
    assert parse_options(["replicas=5"]).presets == list(PRESETS)


@pytest.mark.parametrize("argv, named", [
    (["--presets", "fig9"], "--presets fig9: not a preset"),
    (["--processes", "0"], "--processes 0"),
    (["huge"], "scale 'huge'"),
    (["hydra.sweep.dir=/tmp/x"], "the pool places and launches the jobs itself"),
])
def test_bad_options_are_one_error_naming_the_value(capsys, argv, named):
    with pytest.raises(SystemExit) as stopped:
        parse_options(argv)
    assert stopped.value.code == 2 and named in capsys.readouterr().err


def test_each_config_runs_once_largest_first(capsys):
    queue = jobs(["fig6_continuous", "fig8"])
    folders = [job.folder for job in queue]
    assert "fig8/0_reward=explicit" not in folders  # Fig. 6's noise 0.01 is the very config
    assert folders.count("fig8/1_reward=implicit") == 1 and len(folders) == 4
    assert [job.size for job in queue] == sorted((job.size for job in queue), reverse=True)
    assert main(["--list", "--presets", "fig6_continuous", "fig8"]) == 0
    listed = [line.split("\t")[0] for line in capsys.readouterr().out.splitlines()]
    assert listed == folders


def test_a_jobs_folder_says_whether_to_skip_resume_or_restart_it(tmp_path):
    (job,) = [job for job in jobs(["fig8"]) if job.folder == "fig8/1_reward=implicit"]
    group = dataclasses.replace(job, replicas=2, seed=0)
    folder = tmp_path / "job"
    assert job_state(folder, group) == "new"
    (folder / "seed0").mkdir(parents=True)
    assert job_state(folder, group) == "stale"  # killed before its first checkpoint: started again
    (folder / GROUP_DIR).mkdir()
    (folder / GROUP_DIR / CHECKPOINT).write_bytes(b"")
    assert job_state(folder, group) == "resume"
    (folder / GROUP_DIR / CHECKPOINT).unlink()
    for seed in (0, 1):
        (folder / f"seed{seed}").mkdir(exist_ok=True)
        (folder / f"seed{seed}" / SUMMARY).write_text("{}")
    assert job_state(folder, group) == "done"
    lone, alone = dataclasses.replace(job, replicas=1), tmp_path / "lone"  # a lone run is its own folder
    alone.mkdir()
    (alone / CHECKPOINT).write_bytes(b"")
    assert job_state(alone, lone) == "resume"
    (alone / CHECKPOINT).unlink()
    (alone / SUMMARY).write_text("{}")
    assert job_state(alone, lone) == "done"


def test_the_same_command_continues_an_unfinished_reproduction_and_a_stopped_pool_prints_it(tmp_path, monkeypatch,
                                                                                          capsys):
    # The pool stands in for the jobs: each command is stopped (Ctrl-C) in its first job.
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("REPRODUCE_DIR", raising=False)
    seconds = itertools.count()  # the pool's clock: each folder name a second later, however fast the calls come
    clock = types.SimpleNamespace(strftime=lambda pattern: f"2026-11-28_00-00-{next(seconds):02d}",
                                  perf_counter=time.perf_counter)
    monkeypatch.setattr(reproduce, "time", clock)
    roots = []

    def stopped_in_the_first_job(self, queue):
        roots.append(self.root)
        return [{"job": queue[0].folder, "exit": 130, "outcome": "interrupted"}]

    monkeypatch.setattr(Pool, "run", stopped_in_the_first_job)
    argv = ["quick", "--presets", "fig8", "eval_episodes=8", "--processes", "1"]
    assert main(argv) == 1
    assert f"--out {roots[0]}" in capsys.readouterr().err
    assert main(argv) == 1
    assert roots[1] == roots[0]  # the same command went on where the stopped one was, not into a new folder
    assert main([*argv, "eval_every=2"]) == 1 and roots[2] != roots[0]  # other arguments: another reproduction


# What a job's process does, in place of runners/main.py: its folder's files, then how it ends.
FINISHED_THEN_KILLED = "(folder / 'summary.json').write_text('{}'); print('sweep done'); os.kill(os.getpid(), 15)"
STOPPED_AT_A_CHECKPOINT = "(folder / 'checkpoint.pt').write_bytes(b''); sys.exit(128 + 15)"
KILLED_BEFORE_ITS_FIRST_CHECKPOINT = "os.kill(os.getpid(), 15)"
BROKEN = "sys.exit(1)"


@pytest.mark.parametrize("ends, outcome, said", [
    (FINISHED_THEN_KILLED, "done", "done in"),  # the stop reached it on its way out: its runs are finished all the same
    (STOPPED_AT_A_CHECKPOINT, "interrupted", "(exit 143); it resumes from its checkpoint when you continue with:"),
    (KILLED_BEFORE_ITS_FIRST_CHECKPOINT, "interrupted", "(killed by SIGTERM); it starts again (no checkpoint yet)"),
    (BROKEN, "failed", "FAILED (exit 1; see "),
], ids=["finished then killed", "stopped at a checkpoint", "killed before its first checkpoint", "failed"])
def test_a_jobs_line_says_how_it_ended_as_its_folder_says_not_its_exit_code_alone(tmp_path, monkeypatch, capsys,
                                                                                  ends, outcome, said):
    (job,) = [job for job in jobs(["fig8"]) if job.folder == "fig8/1_reward=implicit"]
    job = dataclasses.replace(job, replicas=1)
    folder = tmp_path / job.folder
    script = f"import os, sys, pathlib; folder = pathlib.Path({str(folder)!r}); folder.mkdir(); {ends}"
    monkeypatch.setattr(reproduce, "command", lambda job, root, resume: [sys.executable, "-c", script])
    continue_with = f"runners/reproduce.sh quick --out {tmp_path}"
    pool = Pool(tmp_path, 1, continue_with)
    pool._run_job(job, "[1/1] fig8")
    (line,) = [line for line in capsys.readouterr().err.split("reproduce: ") if line.startswith("[1/1] fig8: ") and
               "started" not in line]
    assert said in line and (continue_with in line) == (outcome == "interrupted")
    assert pool.rows[-1]["outcome"] == outcome
    # The rerun reads the same folder: it skips what was reported done, and continues what was not.
    assert (job_state(folder, job) == "done") == (outcome == "done")
    if outcome == "done":
        pool._run_job(job, "[1/1] fig8")
        assert "[1/1] fig8: already done" in capsys.readouterr().err
