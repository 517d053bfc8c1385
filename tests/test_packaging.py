"""The wheel is a whole product: it carries the Hydra configs and the commands, and runs from any folder."""

from __future__ import annotations

import os
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ("sidewalk-train", "sidewalk-report", "sidewalk-render", "sidewalk-crossplay", "sidewalk-baselines",
            "sidewalk-bench")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q", "-w", str(out)],
        check=True, capture_output=True, text=True, timeout=300,
    )
    (built,) = out.glob("sidewalk-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """A fresh virtual environment with the wheel; its dependencies come from the running environment."""
    env_dir = tmp_path_factory.mktemp("venv")
    venv.create(env_dir, system_site_packages=True, with_pip=False)
    python = env_dir / "bin" / "python"
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300)
    return env_dir / "bin"


def test_the_wheel_carries_every_config_and_runner(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    configs = {f"sidewalk/conf/{path.relative_to(ROOT / 'conf')}" for path in (ROOT / "conf").rglob("*.yaml")}
    runners = {f"sidewalk/runners/{path.name}" for path in (ROOT / "runners").glob("*.py")}
    packages = {f"{path.parent.relative_to(ROOT)}/__init__.py" for path in (ROOT / "sidewalk").rglob("__init__.py")}
    assert configs and configs <= names, sorted(configs - names)
    assert runners <= names, sorted(runners - names)
    assert packages <= names, f"a subpackage is missing from [tool.setuptools] packages: {sorted(packages - names)}"


def test_the_installed_train_command_runs_outside_the_clone(installed, tmp_path):
    folder = tmp_path / "elsewhere"
    folder.mkdir()
    environment = {**os.environ, "PYTHONPATH": ""}
    where = subprocess.run([str(installed / "python"), "-c", "import sidewalk; print(sidewalk.__file__)"],
                           cwd=folder, capture_output=True, text=True, check=True, env=environment)
    assert str(installed.parent) in where.stdout, where.stdout  # the wheel's copy, not the clone
    done = subprocess.run(
        [str(installed / "sidewalk-train"), "iterations=2", "num_envs=4", "eval_every=0", "eval_episodes=4",
         "logger=none"],
        cwd=folder, capture_output=True, text=True, timeout=600, env=environment,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = (folder / "results" / "runs").iterdir()
    for name in ("config.yaml", "metrics.csv", "summary.json", "policy.pt"):
        assert (run / name).is_file(), name
    assert not (ROOT / "results" / "runs" / run.name).exists()


@pytest.mark.parametrize("command", COMMANDS)
def test_every_installed_command_answers_help(installed, tmp_path, command):
    done = subprocess.run([str(installed / command), "--help"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "PYTHONPATH": ""})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip()
