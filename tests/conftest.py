"""The suite runs on as many workers as the machine has cores (pytest-xdist, ``-n auto`` in pyproject.toml): each
worker then takes one intra-op thread, or the workers' threads would contend for the same cores."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)
# No test opens a window, display or not: render_mode="human" (Gymnasium's check_env builds it) then warns, draws nothing.
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="module")
def uninterrupted_run(tmp_path_factory):
    """Trains runners/main.py on a config once for every test of a module that stops and resumes it."""
    finished: dict[tuple[str, ...], Path] = {}

    def run(overrides: list[str]) -> Path:
        key = tuple(overrides)
        if key not in finished:
            folder = tmp_path_factory.mktemp("uninterrupted")
            result = subprocess.run([sys.executable, "runners/main.py", *overrides, f"hydra.run.dir={folder}"],
                                    cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=600,
                                    check=False)
            assert result.returncode == 0, result.stderr
            finished[key] = folder
        return finished[key]

    return run


@pytest.fixture
def one_thread():
    """One torch thread: scripted opponents and small networks run many small operations, where on 2 busy cores a
    second intra-op thread only adds waiting."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
