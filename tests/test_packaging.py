"""The wheel is a whole product: it carries the Hydra configs and the commands, and runs from any folder, under a
distribution name of its own that every install line of the repository uses."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ("sidewalk-train", "sidewalk-report", "sidewalk-render", "sidewalk-crossplay", "sidewalk-baselines",
            "sidewalk-bench", "sidewalk-partners")
PURELIB = "import sysconfig; print(sysconfig.get_paths()['purelib'])"  # a venv's own site-packages
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
# Names on PyPI that are other projects: `pip install sidewalk` installs "The Simple Activity Aggregator" (2013).
TAKEN_ON_PYPI = ("sidewalk",)
# Where install lines and dependencies on this package are written: the pages, the code's messages, the CI script.
INSTALL_TEXTS = ("README.md", "CITATION.cff", ".ci/run", "docs/**/*.md", "docs/**/*.py", "sidewalk/**/*.py",
                 "runners/*.py", "runners/*.sh", "conf/**/*.yaml")
# `pip install 'NAME[extras]'` or `pip install -e '.[extras]'`, and a dependency `"NAME..."` in a TOML list.
PIP_INSTALL = re.compile(r"pip install (?:-e )?['\"]?(?P<name>sidewalk[\w.-]*|\.)(?:\[(?P<extras>[^\]]*)\])?")
DEPENDENCY = re.compile(r"dependencies = \[[^\]]*?\"(?P<name>sidewalk[\w.-]*)")
# The libraries every command stands on, imported once by the server the commands' processes fork from.
LIBRARIES = "import hydra, matplotlib, numpy, omegaconf, pandas, tensordict, torch, torchrl"


def canonical(name: str) -> str:
    """A distribution name as the package index compares names (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q", "-w", str(out)],
        check=True, capture_output=True, text=True, timeout=300,
    )
    (built,) = out.glob("sidewalk_problem-*.whl")
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
    # No PYTHONPATH: a clone on it shows pip the egg-info the wheel's build left there, as this package installed.
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": ""})
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


def test_the_distribution_name_is_free_of_other_projects_and_every_install_line_uses_it():
    name, extras = canonical(PROJECT["name"]), set(PROJECT["optional-dependencies"])
    assert name not in TAKEN_ON_PYPI, f"{PROJECT['name']!r} is another project on PyPI"
    seen = []
    for path in sorted({path for pattern in INSTALL_TEXTS for path in ROOT.glob(pattern) if path.is_file()}):
        text = path.read_text()
        for match in [*PIP_INSTALL.finditer(text), *DEPENDENCY.finditer(text)]:
            where = f"{path.relative_to(ROOT)}: {match.group(0)!r}"
            seen.append(where)
            if match["name"] != ".":
                assert canonical(match["name"]) == name, f"{where} names another distribution than {name!r}"
            wanted = {extra.strip() for extra in (match.groupdict().get("extras") or "").split(",") if extra.strip()}
            assert wanted <= extras, f"{where}: no such extra {sorted(wanted - extras)}; valid: {sorted(extras)}"
    assert len(seen) >= 5, seen  # the README's, the guides', the PettingZoo face's message, the plug-in example's


def test_the_wheel_carries_every_config_and_runner(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    configs = {f"sidewalk/conf/{path.relative_to(ROOT / 'conf')}" for path in (ROOT / "conf").rglob("*.yaml")}
    configs |= {str(path.relative_to(ROOT)) for path in (ROOT / "sidewalk").rglob("*.yaml")}  # BenchMARL's tasks, ...
    runners = {f"sidewalk/runners/{path.name}" for path in (ROOT / "runners").glob("*.py")}
    packages = {f"{path.parent.relative_to(ROOT)}/__init__.py" for path in (ROOT / "sidewalk").rglob("__init__.py")}
    assert configs and configs <= names, sorted(configs - names)
    assert runners <= names, sorted(runners - names)
    assert packages <= names, f"a subpackage is missing from [tool.setuptools] packages: {sorted(packages - names)}"
    page = {f"sidewalk/play/static/{path.name}" for path in (ROOT / "sidewalk" / "play" / "static").iterdir()}
    assert page <= names, f"sidewalk-play's page is missing from the wheel: {sorted(page - names)}"


def test_the_installed_train_command_runs_outside_the_clone(installed, tmp_path):
    folder = tmp_path / "elsewhere"
    folder.mkdir()
    environment = {**os.environ, "PYTHONPATH": ""}
    probe = ("import importlib.metadata, sidewalk; print(sidewalk.__file__); print(sidewalk.__version__); "
             f"print(importlib.metadata.version({PROJECT['name']!r}))")
    where = subprocess.run([str(installed / "python"), "-c", probe],
                           cwd=folder, capture_output=True, text=True, check=True, env=environment)
    file, version, distribution_version = where.stdout.split()
    assert str(installed.parent) in file, where.stdout  # the wheel's copy, not the clone
    assert version == distribution_version, where.stdout  # sidewalk.__version__ is the installed distribution's
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


@pytest.fixture(scope="module")
def installed_processes(installed, fork_server, tmp_path_factory):
    """Processes of the installed environment's python forked after the imports of the libraries the commands stand
    on (torch, Hydra, ...; not this package: each command imports it as its own start does); outside the clone."""
    folder = tmp_path_factory.mktemp("installed-processes")
    server = fork_server(folder, preload=LIBRARIES, python=installed / "python", cwd=folder,
                        env={**os.environ, "PYTHONPATH": ""})
    yield server
    server.close()


@pytest.mark.parametrize("command", COMMANDS)
def test_every_installed_command_answers_help(installed, installed_processes, tmp_path, command):
    # An executable whose first line runs the environment's python on it (as the train command's run above does) ...
    script = installed / command
    assert os.access(script, os.X_OK) and script.read_text().splitlines()[0] == f"#!{installed / 'python'}"
    # ... and that script, run by that python as its own process, answers --help.
    done = installed_processes.run(str(script), "--help", cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip()


def test_the_bench_help_gives_each_section_a_line_of_its_own_and_no_internal_revisions(capsys):
    spec = importlib.util.spec_from_file_location("runner_bench", ROOT / "runners" / "bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    with pytest.raises(SystemExit) as done:
        bench.main(["--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    starts = [line.split()[0] for line in text.splitlines() if line.startswith("  ") and line.split()]
    assert [section for section in bench.SECTIONS if section not in starts] == [], text
    commits = re.findall(r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b", text)
    assert commits == [], f"--help names this repository's revisions, which a user's clone may lack: {commits}"
