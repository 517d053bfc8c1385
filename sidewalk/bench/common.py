"""Helpers shared by the benchmark sections: timing, tables, git worktrees of other revisions, and the
Stable-Baselines3 adapter of the gymnasium face."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

REPO_ROOT = Path(__file__).resolve().parents[2]  # a clone: the benchmarks time git worktrees of it


@contextmanager
def torch_threads(n: int):
    """Run the block with ``n`` intra-op threads, then restore the previous setting."""
    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def is_commit(revision: str) -> bool:
    """Whether ``revision`` names a commit of this repository."""
    found = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{revision}^{{commit}}"], cwd=REPO_ROOT,
                           capture_output=True, text=True, check=False)
    return found.returncode == 0


@contextmanager
def revision_trees(baseline: str | None, tmp: str | Path) -> Iterator[dict[str, Path]]:
    """``{"baseline REV": a git worktree of REV under tmp, "this checkout": REPO_ROOT}`` (only this checkout without
    a baseline), the worktree removed afterwards: the benchmarks that time two revisions side by side."""
    if baseline is None:
        yield {"this checkout": REPO_ROOT}
        return
    worktree = Path(tmp) / "baseline"
    subprocess.run(["git", "worktree", "add", "--detach", "--quiet", str(worktree), baseline], cwd=REPO_ROOT,
                   check=True)
    try:
        yield {f"baseline {baseline}": worktree, "this checkout": REPO_ROOT}
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(worktree)], cwd=REPO_ROOT, check=False)


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


def sb3_vec_env(env_id: str, num_envs: int, seed: int, **kwargs: Any):
    """``gymnasium.make_vec(env_id, num_envs=num_envs, **kwargs)`` (one batched core) as a Stable-Baselines3 ``VecEnv``.

    SB3 resets a finished world inside the same step and hands its last observation in
    ``info["terminal_observation"]``; the gymnasium face resets it on the next step instead, so the adapter resets
    the finished worlds at once through the face's ``reset(options={"reset_mask": ...})``. A ``Box`` action space
    (continuous world, physical units) is rescaled to [-1, 1] by gymnasium's ``RescaleAction``, the range SB3's
    policies assume; ``reset`` seeds the core with ``seed`` the first time.
    """
    import gymnasium
    from gymnasium.wrappers.vector import RescaleAction
    from stable_baselines3.common.vec_env import VecEnv

    import sidewalk.interop.gymnasium  # noqa: F401  (registers the ids)

    class SidewalkSB3VecEnv(VecEnv):
        def __init__(self) -> None:
            self.envs = gymnasium.make_vec(env_id, num_envs=num_envs, **kwargs)
            box = self.envs.single_action_space
            if isinstance(box, gymnasium.spaces.Box):
                one = np.ones(box.shape, dtype=box.dtype)
                self.envs = RescaleAction(self.envs, -one, one)
            self.render_mode = None
            self._seed = seed
            super().__init__(num_envs, self.envs.single_observation_space, self.envs.single_action_space)

        def reset(self):
            observation, _ = self.envs.reset(seed=self._seed)
            self._seed = None
            return observation

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self):
            observation, reward, terminated, truncated, info = self.envs.step(self._actions)
            done = terminated | truncated
            infos: list[dict] = [{} for _ in range(self.num_envs)]
            if done.any():
                for i in np.flatnonzero(done):
                    infos[i] = {
                        "terminal_observation": observation[i],
                        "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                        "is_success": bool(info["is_success"][i]),
                    }
                observation, _ = self.envs.reset(options={"reset_mask": done})
            return observation, reward.astype(np.float32), done, infos

        def close(self) -> None:
            self.envs.close()

        def get_attr(self, attr_name, indices=None):
            return [getattr(self, attr_name)] * len(self._get_indices(indices))

        def set_attr(self, attr_name, value, indices=None):
            setattr(self, attr_name, value)

        def env_method(self, method_name, *args, indices=None, **kwargs):
            raise NotImplementedError("one batched core: no per-world methods")

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False] * len(self._get_indices(indices))

    return SidewalkSB3VecEnv()
