"""The suite runs on as many workers as the machine has cores (pytest-xdist, ``-n auto`` in pyproject.toml): each
worker then takes one intra-op thread, or the workers' threads would contend for the same cores."""

from __future__ import annotations

import fcntl
import hashlib
import importlib.util
import json
import os
import select
import shutil
import signal
import subprocess
import sys
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


# A fork server: it runs the code of its second argument (imports) and computes nothing (a process that ran no torch
# kernel forks safely); on each request it forks a child that runs a script as `python <script>` would, from
# `if __name__ == "__main__"` on. Requests on stdin, one JSON line each; replies on the pipe whose file descriptor is
# its first argument.
FORK_SERVER = """
import atexit, json, os, runpy, signal, sys, threading, traceback
exec(sys.argv[2])
replies = os.fdopen(int(sys.argv[1]), "w", buffering=1)

def child(request):
    replies.close()
    os.environ.clear(); os.environ.update(request["env"])
    os.chdir(request["cwd"])
    os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
    for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
        os.dup2(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), fd)
    script = request["script"]
    sys.argv, sys.path[0] = [script, *request["arguments"]], os.path.dirname(os.path.abspath(script))
    code = 0
    try:
        runpy.run_path(script, run_name="__main__")
    except SystemExit as stop:  # as CPython exits on it
        if isinstance(stop.code, int):
            code = stop.code
        elif stop.code is not None:
            print(stop.code, file=sys.stderr); code = 1
    except KeyboardInterrupt:
        traceback.print_exc(); code = -signal.SIGINT
    except BaseException:
        traceback.print_exc(); code = 1
    threading._shutdown(); atexit._run_exitfuncs()  # what CPython's exit runs, in its order (joblib's workers stop)
    sys.stdout.flush(); sys.stderr.flush()
    if code == -signal.SIGINT:  # as CPython ends on an uncaught KeyboardInterrupt: killed by the signal
        signal.signal(signal.SIGINT, signal.SIG_DFL); os.kill(os.getpid(), signal.SIGINT)
    os._exit(code & 0xFF)

def status(waited):
    return -os.WTERMSIG(waited) if os.WIFSIGNALED(waited) else os.WEXITSTATUS(waited)

print(json.dumps({"ready": os.getpid()}), file=replies)
for line in sys.stdin:
    request = json.loads(line)
    if request["op"] == "start":
        sys.stdout.flush(); sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            child(request)
        reply = {"pid": pid}
    else:  # "wait" or "poll"
        pid, waited = os.waitpid(request["pid"], 0 if request["op"] == "wait" else os.WNOHANG)
        reply = {"status": status(waited) if pid else None}
    print(json.dumps(reply), file=replies)
"""


class ForkedProcess:
    """One script forked from the server, with the calls of ``subprocess.Popen`` the tests use: a process of its own
    (its pid, signals and exit status; -n where signal n ended it), its output kept for ``communicate``."""

    def __init__(self, server: ForkServer, pid: int, args: list[str], stdout: Path, stderr: Path) -> None:
        self.server, self.pid, self.args, self.returncode = server, pid, args, None
        self.stdout_file, self.stderr_file = stdout, stderr

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self.server.ask({"op": "poll", "pid": self.pid})["status"]
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            try:
                self.returncode = self.server.ask({"op": "wait", "pid": self.pid}, timeout)["status"]
            except subprocess.TimeoutExpired:
                self.kill()
                self.returncode = self.server.ask(None)["status"]  # the wait asked for, now the child is dead
                raise
        return self.returncode

    def send_signal(self, signum: int) -> None:
        if self.returncode is None:
            os.kill(self.pid, signum)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        self.wait(timeout)
        return self.stdout_file.read_text(), self.stderr_file.read_text()


# What runners/main.py imports, without running its cli(), and what its train() imports.
MAIN_IMPORTS = """
runpy.run_path("runners/main.py", run_name="preloaded")
import sidewalk.experiment, sidewalk.stops, sidewalk.trial_state, sidewalk.report.document
"""


class ForkServer:
    """Starts scripts as processes forked from one that has run ``preload`` (by default: runners/main.py's imports),
    with ``python`` in ``cwd`` (the children's defaults too)."""

    def __init__(self, folder: Path, preload: str = MAIN_IMPORTS, python: Path | str = sys.executable,
                 cwd: Path = ROOT, env: dict | None = None) -> None:
        self.folder, self.started, self.cwd, self.env = folder, 0, cwd, env
        replies, reply_end = os.pipe()
        self.log = folder / "server.log"
        with open(self.log, "w") as log:
            self.server = subprocess.Popen([str(python), "-c", FORK_SERVER, str(reply_end), preload], cwd=cwd,
                                           env=self.env, stdin=subprocess.PIPE, stdout=log, stderr=log, text=True,
                                           pass_fds=(reply_end,))
        os.close(reply_end)
        self.replies = os.fdopen(replies)
        self.ask(None, timeout=300)  # ready: its imports done

    def ask(self, request: dict | None, timeout: float | None = None) -> dict:
        if request is not None:
            self.server.stdin.write(json.dumps(request) + "\n")
            self.server.stdin.flush()
        if not select.select([self.replies], [], [], timeout)[0]:
            raise subprocess.TimeoutExpired(["fork server"], timeout)
        line = self.replies.readline()
        if not line:
            raise RuntimeError(f"the fork server ended:\n{self.log.read_text()[-3000:]}")
        return json.loads(line)

    def start(self, script: str, *arguments: str, cwd: Path | None = None, env: dict | None = None) -> ForkedProcess:
        """``subprocess.Popen([python, script, *arguments], cwd=cwd, env=env)`` (``script`` relative to ``cwd``;
        by default the server's, and the server's environment or else this process's now), its output kept in files."""
        self.started += 1
        stdout, stderr = self.folder / f"{self.started}.out", self.folder / f"{self.started}.err"
        env = env if env is not None else self.env if self.env is not None else os.environ
        reply = self.ask({"op": "start", "script": script, "arguments": list(arguments),
                          "cwd": str(cwd or self.cwd), "env": dict(env), "stdout": str(stdout), "stderr": str(stderr)})
        return ForkedProcess(self, reply["pid"], [script, *arguments], stdout, stderr)

    def run(self, script: str, *arguments: str, timeout: float = 600, **options) -> subprocess.CompletedProcess:
        """``subprocess.run([python, script, *arguments], capture_output=True, text=True, timeout=timeout)``."""
        process = self.start(script, *arguments, **options)
        stdout, stderr = process.communicate(timeout)
        return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)

    def close(self) -> None:
        self.server.stdin.close()
        self.server.wait(timeout=60)
        self.replies.close()


@pytest.fixture(scope="session")
def processes(tmp_path_factory):
    """The scripts of runners/ as processes of their own (real pids to kill, interrupt or hold a lock), each forked
    from a server that has done once the ~5 s of imports every start of runners/main.py pays; one per worker."""
    server = ForkServer(tmp_path_factory.mktemp("processes"))
    yield server
    server.close()


@pytest.fixture(scope="session")
def fork_server() -> type[ForkServer]:
    """``ForkServer`` for a test module's own server (another python, other imports), without importing conftest.py
    (which a test's subprocess importing the module may lack the packages for)."""
    return ForkServer
