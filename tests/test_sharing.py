"""Safe to share, safe to interrupt: a received file runs no code, one process writes a run folder, Ctrl-C
checkpoints like SIGTERM, and every refusal is one ``error:`` line."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import torch
from omegaconf import OmegaConf

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial
from sidewalk.run_folder import (
    FolderInUse,
    UnreadableFile,
    UnsafeFile,
    load_checkpoint,
    read_torch_file,
    writer_lock,
)

ROOT = Path(__file__).resolve().parents[1]
WALL_CLOCK = ["time_s", "frames_per_s"]
TINY = [
    "num_envs=4", "eval_every=4", "eval_episodes=8", "checkpoint_every=4", "logger=none", "plots=false",
    "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=2000", "algo.learning_starts=0",
    "algo.updates_per_batch=1",
]


class RunsCommand:
    """Pickled, it makes ``torch.load(weights_only=False)`` run a shell command: here one that writes a marker."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


@pytest.fixture(scope="module")
def shared_run(tmp_path_factory) -> Path:
    """A finished tiny DQN run that kept its checkpoints: the folder a colleague sends (trained in this process, as
    runners/main.py would train it)."""
    run = tmp_path_factory.mktemp("shared") / "run"
    cfg = compose([*TINY, "iterations=8", "keep_checkpoint=all"])
    Trial(validate(cfg), run, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    return run


def poisoned_copy(shared_run: Path, tmp_path: Path, name: str) -> tuple[Path, Path]:
    """A copy of the shared run whose ``name`` keeps its real content beside a pickled command."""
    run, marker = tmp_path / "received", tmp_path / "marker"
    shutil.copytree(shared_run, run)
    state = torch.load(run / name, weights_only=False)  # our own file, trusted
    state["extra"] = RunsCommand(marker)
    torch.save(state, run / name)
    return run, marker


def one_error_line(result: subprocess.CompletedProcess, *expected: str) -> None:
    assert result.returncode != 0, result.stdout
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
    for text in expected:
        assert text in errors[0], errors[0]


@pytest.mark.parametrize("face", ["report", "render", "crossplay"])
def test_a_policy_file_that_carries_code_is_refused_by_every_reader_and_nothing_runs(shared_run, tmp_path, face,
                                                                                     runner, capsys, one_thread):
    run, marker = poisoned_copy(shared_run, tmp_path, "policy.pt")
    arguments = {
        "report": [str(run), "--out", str(tmp_path / "report"), "--resamples", "100"],
        "render": [str(run), "--out", str(tmp_path / "episode.gif")],
        "crossplay": [str(run), "--out", str(tmp_path / "crossplay"), "--episodes", "4"],
    }
    try:
        code = runner(face).main(arguments[face])  # in this process: the refusal is the runner's, not its start-up's
    except SystemExit as exit_info:
        code = exit_info.code
    one_error_line(subprocess.CompletedProcess(face, code, "", capsys.readouterr().err),
                   str(run / "policy.pt"), "posix.system")
    assert not marker.exists()


def test_a_partner_policy_file_that_carries_code_is_refused_and_nothing_runs(shared_run, tmp_path, processes):
    run, marker = poisoned_copy(shared_run, tmp_path, "policy.pt")
    result = processes.run("runners/main.py", *TINY, "iterations=2", "opponent=policy", f"opponent.path={run}",
                    f"hydra.run.dir={tmp_path / 'partnered'}")
    one_error_line(result, str(run / "policy.pt"), "posix.system")
    assert not marker.exists()


def test_a_checkpoint_that_carries_code_is_refused_on_resume_and_nothing_runs(shared_run, tmp_path, processes):
    run, marker = poisoned_copy(shared_run, tmp_path, "checkpoint.pt")
    result = processes.run("runners/main.py", *TINY, "iterations=12", "keep_checkpoint=all", "resume=true",
                    f"hydra.run.dir={run}")
    one_error_line(result, str(run / "checkpoint.pt"), "posix.system")
    assert not marker.exists()
    # Not a torn write: the previous generation is not tried in its place (it would quietly lose iterations).
    with pytest.raises(UnsafeFile, match="checkpoint.pt holds posix.system"):
        load_checkpoint(run)


def test_every_file_a_run_writes_reads_back_without_unpickling_objects(shared_run, tmp_path):
    for name in ("policy.pt", "checkpoint.pt", "checkpoint.prev.pt"):
        state = read_torch_file(shared_run / name)
        assert isinstance(state, dict) and state
    torn = tmp_path / "torn.pt"
    torn.write_bytes((shared_run / "policy.pt").read_bytes()[:1000])
    with pytest.raises(UnreadableFile, match="torn.pt is unreadable"):
        read_torch_file(torn)


def test_a_missing_or_corrupt_partner_is_one_error_line(shared_run, tmp_path, processes):
    missing = processes.run("runners/main.py", *TINY, "iterations=2", "opponent=policy",
                     f"opponent.path={tmp_path / 'nowhere'}", f"hydra.run.dir={tmp_path / 'a'}")
    one_error_line(missing, str(tmp_path / "nowhere"))
    run = tmp_path / "corrupt"
    shutil.copytree(shared_run, run)
    (run / "policy.pt").write_bytes(b"not a torch file")
    corrupt = processes.run("runners/main.py", *TINY, "iterations=2", "opponent=policy", f"opponent.path={run}",
                            f"hydra.run.dir={tmp_path / 'b'}")
    one_error_line(corrupt, str(run / "policy.pt"), "unreadable")
    assert missing.returncode == corrupt.returncode == 2


def test_a_second_writer_is_refused_naming_the_holder_and_a_killed_one_leaves_no_lock(tmp_path, processes):
    run = tmp_path / "run"
    overrides = [*TINY, "iterations=40", f"hydra.run.dir={run}"]
    first = processes.start("runners/main.py", *overrides)  # a process of its own: forked, not started (conftest.py)
    try:
        deadline = time.time() + 300
        while not (run / "checkpoint.pt").exists() and first.poll() is None and time.time() < deadline:
            time.sleep(0.02)
        first.send_signal(signal.SIGSTOP)  # paused, still holding the folder, however long the second takes
        assert first.poll() is None, "the first run ended before the second could ask for its folder"
        second = processes.run("runners/main.py", *overrides, "resume=true")
        one_error_line(second, f"pid {first.pid}", "in use")
        assert second.returncode == 2
        with pytest.raises(FolderInUse, match=f"pid {first.pid}"), writer_lock(run):  # the library's callers too
            pass
    finally:
        first.kill()  # SIGKILL: no handler runs, the kernel drops the lock
        first.wait()
    resumed = processes.run("runners/main.py", *overrides, "resume=true", timeout=600)  # at once: no stale lock
    assert resumed.returncode == 0, resumed.stderr
    assert events(run)[0] == "started" and events(run)[-2:] == ["resumed", "finished"]


def events(folder: Path) -> list[str]:
    return [json.loads(line)["event"] for line in (folder / "history.jsonl").read_text().splitlines()]


def ctrl_c_once(processes, arguments: list[str], written: Path, pattern: str) -> tuple[int, str]:
    """Start ``runners/main.py`` with ``arguments``, send Ctrl-C once ``written`` holds a file matching ``pattern``;
    its exit status and stderr."""
    process = processes.start("runners/main.py", *arguments)
    deadline = time.time() + 300
    while not list(written.glob(pattern)) and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    return process.returncode, stderr


def run_printed(processes, command: list[str]) -> subprocess.CompletedProcess:
    """The printed command run as typed: ``python runners/main.py ...`` (its process forked, as the others here)."""
    assert command[:2] == [sys.executable, "runners/main.py"], command
    return processes.run(*command[1:], timeout=600)


def printed_command(stderr: str) -> list[str]:
    """The command an interruption printed (the line after "continue with:"), run by this interpreter."""
    lines = stderr.splitlines()
    words = shlex.split(lines[lines.index(next(line for line in lines if line.endswith("continue with:"))) + 1])
    return [sys.executable, *words[1:]] if words[0] == "python" else words


def test_ctrl_c_checkpoints_exits_130_and_prints_the_command_that_resumes_to_the_uninterrupted_metrics(
    tmp_path, finished_run, processes
):
    overrides = [*TINY, "iterations=40", "checkpoint_every=5", "eval_every=10", "noise=0.1"]
    whole = finished_run(overrides)
    # A folder named by the time it starts, as the default one is: the same command again would start another.
    returncode, stderr = ctrl_c_once(processes,
                                     [*overrides, f"hydra.run.dir={tmp_path}/runs/${{now:%Y-%m-%d_%H-%M-%S-%f}}"],
                                     tmp_path, "runs/*/checkpoint.pt")
    assert returncode == 130, stderr
    assert "SIGINT received: checkpointed at iteration" in stderr and "Traceback" not in stderr
    (stopped,) = tmp_path.glob("runs/*")
    at = read_torch_file(stopped / "checkpoint.pt")["iteration"]
    assert len(pd.read_csv(stopped / "metrics.csv")) == at < 40
    command = printed_command(stderr)
    assert f"hydra.run.dir={stopped}" in command and command[-1] == "resume=true"
    resumed = run_printed(processes, command)
    assert resumed.returncode == 0, resumed.stderr
    assert [path.name for path in tmp_path.glob("runs/*")] == [stopped.name]  # no second folder
    assert "plots and report" not in resumed.stdout and not (stopped / "report").exists()  # plots=false
    pd.testing.assert_frame_equal(pd.read_csv(stopped / "metrics.csv").drop(columns=WALL_CLOCK),
                                  pd.read_csv(whole / "metrics.csv").drop(columns=WALL_CLOCK))


def test_an_interrupted_sweep_of_groups_continues_with_the_one_command_it_prints(tmp_path, processes):
    # Ctrl-C in the second of three jobs (each a group of two seeds): the first has finished, the second checkpoints,
    # the third never starts. The printed command skips the first, resumes the second and starts the third.
    overrides = [*TINY, "iterations=12", "checkpoint_every=2", "replicas=2", "noise=0,0.05,0.1"]
    returncode, stderr = ctrl_c_once(processes,
                                     ["-m", *overrides, f"hydra.sweep.dir={tmp_path}/${{now:%Y-%m-%d_%H-%M-%S-%f}}"],
                                     tmp_path, "*/1_*/.group/checkpoint.pt")  # a folder named as the default's
    assert returncode == 130, stderr
    (sweep,) = tmp_path.iterdir()
    assert [job.name[0] for job in sorted(sweep.glob("[0-9]_*"))] == ["0", "1"]
    command = printed_command(stderr)
    assert "-m" in command and f"hydra.sweep.dir={sweep}" in command and command[-1] == "resume=true"
    continued = run_printed(processes, command)
    assert continued.returncode == 0, continued.stderr
    first, second, third = sorted(sweep.glob("[0-9]_*"))
    assert events(first / ".group") == ["started", "finished"]  # skipped, not trained again
    assert events(second / ".group") == ["started", "interrupted", "resumed", "finished"]
    assert events(third / ".group") == ["started", "finished"]
    summaries = [job / f"seed{seed}" / "summary.json" for job in (first, second, third) for seed in (0, 1)]
    assert [json.loads(summary.read_text())["iterations"] for summary in summaries] == [12] * 6
    assert not list(sweep.rglob("*error.txt"))


def test_a_second_ctrl_c_stops_at_once_and_prints_the_command_that_continues():
    # The first Ctrl-C is recorded (the loop checkpoints at the end of its iteration); the second kills the process
    # by SIGINT where it stands, which the atomic writes (tests/test_experiment.py's kill -9) make safe.
    script = """
import os, signal, time
from sidewalk.stops import StopSignals
with StopSignals("python runners/main.py hydra.run.dir=results/runs/mine resume=true") as signals:
    os.kill(os.getpid(), signal.SIGINT); time.sleep(0.2)
    print("recorded", signals.received, flush=True)
    os.kill(os.getpid(), signal.SIGINT); time.sleep(2)
    print("still running", flush=True)
"""
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120,
                            check=False)
    assert result.stdout.split("\n")[0] == f"recorded {int(signal.SIGINT)}"
    assert "still running" not in result.stdout and result.returncode == -signal.SIGINT
    assert "Ctrl-C again: stopped at once" in result.stderr
    assert printed_command(result.stderr)[1:] == ["runners/main.py", "hydra.run.dir=results/runs/mine", "resume=true"]


@pytest.mark.parametrize(
    "override, expected, traceback",
    [
        ("algo=foo", "Could not find 'algo/foo'; valid: dqn, ippo, iql, mappo, ppo, ppo_lagrangian, qmix, trpo, vdn",
         False),
        ("iterations=abc", "iterations=abc: Value 'abc' of type 'str' could not be converted to Integer", True),
    ],
)
def test_a_config_hydra_cannot_compose_is_one_error_line_and_a_traceback_only_when_asked(tmp_path, processes, override,
                                                                                         expected, traceback):
    result = processes.run("runners/main.py", override, f"hydra.run.dir={tmp_path / 'run'}")
    one_error_line(result, expected)
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()  # nothing was written
    if traceback:  # one branch of main.py's cli() for every kind of error: asked once
        asked = processes.run("runners/main.py", override, f"hydra.run.dir={tmp_path / 'run'}", timeout=300,
                              env={**os.environ, "HYDRA_FULL_ERROR": "1"})
        assert "Traceback" in asked.stderr and asked.returncode != 0
