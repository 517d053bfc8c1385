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
PURELIB = "import sysconfig; print(sysconfig.get_paths()['purelib'])"  # a venv's own site-packages


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q", "-w", str(out)],
        check=True, capture_output=True, text=True, timeout=300,
    )
    (built,) = out.glob("sidewalk-*.whl")
    return built


def running_site_packages() -> list[str]:
    """The folders the running interpreter imports installed packages from: a venv's, a conda env's or the base
    interpreter's, whichever runs the tests."""
    return [path for path in sys.path if path and Path(path).name in ("site-packages", "dist-packages")
            and Path(path).is_dir()]


def fresh_venv(env_dir: Path) -> Path:
    """A new virtual environment whose imports fall back on the *running* environment's packages (a ``.pth`` file
    naming them, after its own), so that what it installs shadows them. ``system_site_packages=True`` would hand it
    the base interpreter's packages instead, which lack torch when the tests run in a venv. Returns its python."""
    venv.create(env_dir, system_site_packages=False, with_pip=False)
    python = env_dir / "bin" / "python"
    own = subprocess.run([str(python), "-c", PURELIB], capture_output=True, text=True, check=True).stdout.strip()
    # Plain path lines: the running environment's own .pth files (an editable install of the clone) are not run.
    (Path(own) / "running-environment.pth").write_text("".join(f"{path}\n" for path in running_site_packages()))
    return python


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """A fresh virtual environment with the wheel; its dependencies come from the running environment."""
    python = fresh_venv(tmp_path_factory.mktemp("venv"))
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300)
    return python.parent


def test_a_fresh_venv_sees_the_running_environment_not_the_base_interpreter(tmp_path):
    """Run from a venv of its own (as a user runs the suite), ``fresh_venv`` still hands its venv that venv's packages:
    the check that the venv bug cannot come back where the suite runs in the base interpreter (as CI does)."""
    outer = tmp_path / "user-venv"
    venv.create(outer, system_site_packages=False, with_pip=False)
    outer_python = outer / "bin" / "python"
    # The user's venv holds the running environment's packages, and a marker module the base interpreter lacks.
    outer_site = Path(subprocess.run([str(outer_python), "-c", PURELIB], capture_output=True, text=True,
                                     check=True).stdout.strip())
    (outer_site / "running.pth").write_text("".join(f"{path}\n" for path in running_site_packages()))
    (outer_site / "only_in_the_users_venv.py").write_text("")
    inner = tmp_path / "inner"
    script = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); from pathlib import Path; "
              f"from test_packaging import fresh_venv; print(fresh_venv(Path({str(inner)!r})))")
    made = subprocess.run([str(outer_python), "-c", script], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": ""}, check=False)
    assert made.returncode == 0, made.stderr[-3000:]
    probe = "import only_in_the_users_venv, torch; print('ok')"
    seen = subprocess.run([made.stdout.strip(), "-c", probe], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": ""}, check=False)
    assert seen.stdout.strip() == "ok", seen.stderr[-3000:]
    assert "include-system-site-packages = false" in (inner / "pyvenv.cfg").read_text()


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
        cwd=folder, capture_output=True, text=True, timeout=600, env=environment, check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = (folder / "results" / "runs").iterdir()
    for name in ("config.yaml", "metrics.csv", "summary.json", "policy.pt"):
        assert (run / name).is_file(), name
    assert not (ROOT / "results" / "runs" / run.name).exists()


@pytest.mark.parametrize("command", COMMANDS)
def test_every_installed_command_answers_help(installed, tmp_path, command):
    done = subprocess.run([str(installed / command), "--help"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "PYTHONPATH": ""}, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip()
