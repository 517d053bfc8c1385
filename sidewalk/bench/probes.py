"""Timing probes around the training loop's parts, and a worker that runs ``runners/main.py`` under them.

Run as a script (``python sidewalk/bench/probes.py OUT.json -- <main.py overrides>``) in a checkout's root, it wraps
the functions in ``PROBES`` with timers, runs that checkout's ``runners/main.py`` exactly as a user would, and writes
where the time went to ``OUT.json``. It imports nothing from ``sidewalk.bench``, so it also times an older revision
(a git worktree on ``PYTHONPATH``): ``sidewalk.bench.budget`` compares two revisions with the same probes.

Accounting is exclusive: a probe's time excludes the probes called inside it, and each time is filed under the
outermost loop part it ran in (``collection``, ``update``, ``evaluation``, ...), so the parts of one loop part sum to
its total and the loop parts sum to ``Trial.run``. What ``Trial.run`` spends outside every probe (building the env
and learner, train metrics, the progress bar) is its own row; probes that ran outside ``Trial.run`` (main.py's
report replaying the final evaluation) are filed under ``OUTSIDE``.
"""

from __future__ import annotations

import functools
import importlib
import json
import runpy
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

# (label, "module:attribute.path"). A target missing in a revision is skipped (and listed in the output).
PROBES: tuple[tuple[str, str], ...] = (
    ("trial", "sidewalk.experiment:Trial.run"),
    ("collection", "torchrl.collectors._single:Collector.rollout"),
    ("env step", "sidewalk.views.base:_SidewalkView._step"),
    ("opponent", "sidewalk.opponents.base:Opponent.forward"),
    ("update", "sidewalk.algos.dqn:DQN.update"),
    ("update", "sidewalk.algos.trpo:TRPO.update"),
    ("update", "sidewalk.algos.ppo:PPO.update"),
    ("replay write", "torchrl.data.replay_buffers.replay_buffers:TensorDictReplayBuffer.extend"),
    ("replay sample", "torchrl.data.replay_buffers.replay_buffers:TensorDictReplayBuffer.sample"),
    ("loss forward", "torchrl.objectives.dqn:DQNLoss.forward"),
    # Our DQN's own step since issue 25: its forward passes, TD target and loss, and its Polyak step (one foreach lerp).
    ("loss forward", "sidewalk.algos.dqn:DQN._gradient_step"),
    ("loss forward", "torchrl.objectives.ppo:ClipPPOLoss.forward"),
    ("advantage (GAE)", "torchrl.objectives.value.advantages:GAE.forward"),
    ("policy step (CG, line search)", "sidewalk.algos.trpo:trpo_step"),
    ("value fit", "sidewalk.algos.trpo:TRPO._fit_value"),
    ("backward", "torch.autograd:backward"),
    ("gradient clip", "torch.nn.utils:clip_grad_norm_"),
    ("optimizer step", "torch.optim:Adam.step"),
    ("target update", "torchrl.objectives.utils:TargetNetUpdater.step"),
    ("divergence check", "sidewalk.replica_learners:divergence"),
    ("evaluation", "sidewalk.experiment:evaluate"),
    ("checkpoint writes", "torch:save"),
    ("metrics.csv + logger", "sidewalk.trial_state:SeedRun.write_metrics"),
    ("metrics.csv + logger", "torchrl.record.loggers.csv:CSVLogger.log_scalar"),
)
OUTER = "trial"
OUTSIDE = "outside Trial.run"

_stack: list[list[Any]] = []  # [label, start, seconds spent in probes called inside]
exclusive: dict[str, float] = defaultdict(float)  # "part/label" -> seconds


def _probe(label: str, fn: Callable) -> Callable:
    @functools.wraps(fn)
    def probed(*args: Any, **kwargs: Any) -> Any:
        if _stack and _stack[-1][0] == label:  # a probed method calling its probed parent (super()): count once
            return fn(*args, **kwargs)
        frame = [label, time.perf_counter(), 0.0]
        _stack.append(frame)
        try:
            return fn(*args, **kwargs)
        finally:
            _stack.pop()
            elapsed = time.perf_counter() - frame[1]
            # The loop part: the outermost probe below Trial.run (or the label itself at that level).
            parts = [entry[0] for entry in _stack if entry[0] != OUTER]
            part = parts[0] if parts else label
            if label != OUTER and not any(entry[0] == OUTER for entry in _stack):
                part = OUTSIDE  # e.g. main.py's report replaying the final evaluation
            exclusive[f"{part}/{label}"] += elapsed - frame[2]
            if _stack:
                _stack[-1][2] += elapsed

    return probed


def install() -> list[str]:
    """Wrap every target that exists; return the targets that do not."""
    missing = []
    for label, target in PROBES:
        module_name, path = target.split(":")
        *owners, name = path.split(".")
        try:
            owner: Any = importlib.import_module(module_name)
            for attribute in owners:
                owner = getattr(owner, attribute)
            setattr(owner, name, _probe(label, getattr(owner, name)))
        except (ImportError, AttributeError):
            missing.append(target)
    return missing


def main(argv: list[str]) -> int:
    out, overrides = argv[0], argv[2:] if len(argv) > 1 and argv[1] == "--" else argv[1:]
    started = time.perf_counter()
    missing = install()
    sys.argv = ["runners/main.py", *overrides]
    code: Any = 0
    try:
        runpy.run_path("runners/main.py", run_name="__main__")
    except SystemExit as stop:
        code = stop.code
    result = {
        "seconds": time.perf_counter() - started,
        "exclusive": dict(exclusive),
        "missing": missing,
        "exit_code": code,
    }
    with open(out, "w") as handle:
        json.dump(result, handle)
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
