"""A resume whose checkpoints are torn (the disk filled, the node died mid-write): a torn ``checkpoint.pt`` falls back
to ``checkpoint.prev.pt`` with one warning; with both torn, the command is refused before any compute with one
``error:`` line that says what to do, and doing it works."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from omegaconf import OmegaConf

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial
from sidewalk.run_folder import (
    CHECKPOINT,
    POLICY,
    PREVIOUS_CHECKPOINT,
    SUMMARY,
    RunFolderError,
    load_checkpoint,
)
from sidewalk.trial_state import check_folders

ROOT = Path(__file__).resolve().parents[1]
# Two iterations, a checkpoint after each, both kept: checkpoint.pt at 2, checkpoint.prev.pt at 1.
TINY = [
    "num_envs=4", "iterations=2", "eval_every=0", "eval_episodes=4", "checkpoint_every=1", "keep_checkpoint=all",
    "logger=none", "plots=false", "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=200",
    "algo.learning_starts=0",
]
MINIZ = "internal miniz error"  # the second sentence of torch's message for a torn zip


def torn(finished: Path, into: Path, *names: str) -> Path:
    """A copy of ``finished`` as a run stopped mid-way (no summary or policy yet), with ``names`` cut to their first
    1000 bytes (``truncate -s 1000``)."""
    shutil.copytree(finished, into)
    for name in (SUMMARY, POLICY):
        (into / name).unlink()
    for name in names:
        os.truncate(into / name, 1000)
    return into


def test_a_torn_checkpoint_falls_back_with_one_warning_that_names_what_it_tries(tmp_path, finished_run, capsys):
    run = torn(finished_run(TINY), tmp_path / "run", CHECKPOINT)
    assert load_checkpoint(run)["iteration"] == 1
    (warning,) = capsys.readouterr().err.strip().splitlines()
    assert warning.startswith(f"warning: {run / CHECKPOINT} is unreadable (RuntimeError: PytorchStreamReader")
    assert warning.endswith(f"trying the previous checkpoint, {PREVIOUS_CHECKPOINT}") and MINIZ not in warning


@pytest.mark.parametrize("names", [(CHECKPOINT, PREVIOUS_CHECKPOINT), (PREVIOUS_CHECKPOINT,)])
def test_no_readable_checkpoint_is_one_line_with_no_previous_to_try(tmp_path, finished_run, capsys, names):
    run = torn(finished_run(TINY), tmp_path / "run", *names)
    if names == (PREVIOUS_CHECKPOINT,):
        (run / CHECKPOINT).unlink()  # killed between save_checkpoint's renames, and the one left torn
    with pytest.raises(RunFolderError) as refused:
        load_checkpoint(run)
    message = str(refused.value)
    assert "\n" not in message and MINIZ not in message and message.count("PytorchStreamReader") == 1
    assert f"rm {run / names[0]}" in message and "hydra.run.dir=<a new folder>" in message
    warnings = capsys.readouterr().err.strip().splitlines()
    assert len(warnings) == len(names) - 1  # a warning where the previous one was there to try, and none for it
    assert all("trying the previous checkpoint" in line for line in warnings)


def test_resume_with_both_checkpoints_torn_is_refused_with_one_error_line(tmp_path, finished_run):
    run = torn(finished_run(TINY), tmp_path / "run", CHECKPOINT, PREVIOUS_CHECKPOINT)
    result = subprocess.run([sys.executable, "runners/main.py", *TINY, f"hydra.run.dir={run}", "resume=true"],
                            cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 2, result.stderr  # a run folder that cannot continue (runners/main.py's docstring)
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"error: resume=true but {run} has no readable checkpoint: ")
    assert f"{CHECKPOINT} and {PREVIOUS_CHECKPOINT} are unreadable (RuntimeError: PytorchStreamReader" in line
    assert MINIZ not in line and line.count("PytorchStreamReader") == 1
    assert f"rm {run / CHECKPOINT} {run / PREVIOUS_CHECKPOINT}" in line


def test_deleting_the_torn_checkpoints_as_advised_trains_the_run_again_from_the_start(tmp_path, finished_run):
    finished = finished_run(TINY)
    run = torn(finished, tmp_path / "run", CHECKPOINT, PREVIOUS_CHECKPOINT)
    for name in (CHECKPOINT, PREVIOUS_CHECKPOINT):
        (run / name).unlink()
    cfg = compose([*TINY, "resume=true"])
    experiment, config = validate(cfg), OmegaConf.to_container(cfg, resolve=True)
    assert check_folders(run, experiment, config) == "resume"  # the same command again passes its checks ...
    Trial(experiment, run, config).run(progress=False)  # ... and trains from the start: the same run again
    columns = ["time_s", "frames_per_s"]
    pd.testing.assert_frame_equal(pd.read_csv(run / "metrics.csv").drop(columns=columns),
                                  pd.read_csv(finished / "metrics.csv").drop(columns=columns))


def test_a_finished_run_without_checkpoints_says_how_to_keep_them(tmp_path):
    from sidewalk.run_folder import POLICY, SUMMARY, RunFolderError, load_checkpoint

    (tmp_path / SUMMARY).write_text("{}")
    (tmp_path / POLICY).write_bytes(b"")
    with pytest.raises(RunFolderError, match=r"holds no checkpoint\. The run finished with keep_checkpoint=final.*"
                                             r"train it with keep_checkpoint=all"):
        load_checkpoint(tmp_path)
