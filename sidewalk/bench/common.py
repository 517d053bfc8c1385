"""Timing helpers shared by the benchmark sections."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import contextmanager
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"


@contextmanager
def torch_threads(n: int):
    """Run the block with ``n`` intra-op threads, then restore the previous setting."""
    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def env_steps_per_s(
    env: EnvBase,
    set_action: Callable[[TensorDictBase], TensorDictBase],
    min_seconds: float = 1.0,
    warmup_steps: int = 10,
) -> float:
    """Env-steps per second (worlds × steps / s) of ``step_and_maybe_reset`` in a loop, as a collector runs it.

    ``set_action`` writes the next action into the tensordict (random actions, a policy, ...). The loop runs
    at least ``min_seconds`` after ``warmup_steps`` untimed steps.
    """
    tensordict = env.reset()
    for _ in range(warmup_steps):
        _, tensordict = env.step_and_maybe_reset(set_action(tensordict))
    steps, start = 0, time.perf_counter()
    while True:
        for _ in range(10):
            _, tensordict = env.step_and_maybe_reset(set_action(tensordict))
        steps += 10
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return steps * env.batch_size.numel() / elapsed


def seconds_per_call(fn: Callable[[], object], min_seconds: float = 0.5, warmup: int = 3) -> float:
    """Mean wall-clock seconds of ``fn()`` over repeated calls lasting at least ``min_seconds``."""
    for _ in range(warmup):
        fn()
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return elapsed / calls


def format_table(rows: Sequence[dict], columns: Iterable[str] | None = None) -> str:
    """Rows of dicts as an aligned plain-text table (numbers right-aligned, large ones with separators)."""
    if not rows:
        return "(no rows)"
    columns = list(columns or rows[0].keys())

    def cell(value: object) -> str:
        if isinstance(value, float):
            return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.3g}"
        if isinstance(value, int):
            return f"{value:,}"
        return "" if value is None else str(value)

    table = [[cell(row.get(col)) for col in columns] for row in rows]
    widths = [max(len(col), *(len(r[i]) for r in table)) for i, col in enumerate(columns)]
    lines = ["  ".join(col.rjust(w) for col, w in zip(columns, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(v.rjust(w) for v, w in zip(r, widths)) for r in table]
    return "\n".join(lines)


def compose_experiment(overrides: Sequence[str]):
    """The validated ``Experiment`` that ``runners/main.py`` would run with these overrides (read from ``conf/``)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from sidewalk.config import register_schemas, validate

    register_schemas()
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=list(overrides))
    return validate(cfg)
