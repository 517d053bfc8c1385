"""The suite runs on as many workers as the machine has cores (pytest-xdist, ``-n auto`` in pyproject.toml): each
worker then takes one intra-op thread, or the workers' threads would contend for the same cores."""

import fcntl
import hashlib
import importlib.util
import json
import os
import shutil
from pathlib import Path
from types import ModuleType

import pytest
import torch
from omegaconf import OmegaConf

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial

ROOT = Path(__file__).resolve().parents[1]
RUNNERS = ROOT / "runners"

if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)
# No test opens a window, display or not: render_mode="human" (Gymnasium's check_env builds it) then warns, draws nothing.
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def finished_run(tmp_path_factory):
    """Trains a config once for the whole suite, as runners/main.py trains it (its Trial, without the plots main.py
    draws after it), in the process of whichever test or worker asks first; every other test asking for the same
    settings (in any order) waits for it and reads the same folder. Read-only: a test that writes into a run
    (resumes, corrupts or refuses in it) copies it first."""
    worker_root = tmp_path_factory.getbasetemp()
    shared = worker_root.parent if os.environ.get("PYTEST_XDIST_WORKER") else worker_root  # xdist: the workers' common folder

    def run(overrides: list[str]) -> Path:
        settings = dict(override.split("=", 1) for override in overrides)  # the last of a key wins, as in Hydra
        key = hashlib.sha256(json.dumps(sorted(settings.items())).encode()).hexdigest()[:16]
        folder, done = shared / f"finished-{key}", shared / f"finished-{key}.done"
        with open(shared / f"finished-{key}.lock", "w") as lock:  # closing it releases the lock
            fcntl.flock(lock, fcntl.LOCK_EX)  # the other workers wait here while one trains
            if not done.exists():
                shutil.rmtree(folder, ignore_errors=True)  # a run that failed before, in another test
                cfg = compose(overrides)
                Trial(validate(cfg), folder, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
                done.touch()
        return folder

    return run


@pytest.fixture(scope="session")
def runner():
    """A script of runners/ imported as a module, so its ``main(argv)`` runs in the test's process (no start-up)."""

    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(f"runner_{name}", RUNNERS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


@pytest.fixture
def one_thread():
    """One torch thread: scripted opponents and small networks run many small operations, where on 2 busy cores a
    second intra-op thread only adds waiting."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
