"""One global random stream per replica, for several seeds trained in one process (``sidewalk.replica_learners``).

Network initialisation, action sampling, ε-greedy exploration, replay sampling and minibatch permutations draw from
torch's (and NumPy's and Python's) global generators. A replica's draws must not depend on which other replicas
share its process, so each replica owns a saved copy of the global state, and work done for replica ``r`` runs
inside ``streams.use(r)``: the process's generators hold replica ``r``'s state for the duration, and what was drawn
is saved back to replica ``r`` on the way out. A group of one replica therefore draws exactly what a lone run does.
"""

from __future__ import annotations

import contextlib
import os
import random
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch


def seed_globals(seed: int, device: str | torch.device = "cpu") -> None:
    """Seed torch's, NumPy's and Python's global generators; on a GPU also ask for deterministic kernels, PyTorch's
    recipe for the same numbers from the same seed twice on one device (a kernel without one warns)."""
    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)
    if torch.device(device).type == "cuda":
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # read when cuBLAS starts, before its first call
        torch.use_deterministic_algorithms(True, warn_only=True)


def seeded_state(seed: int) -> dict[str, Any]:
    """The global generators' state right after ``torch.manual_seed(seed)``, ``np.random.seed(seed)`` and
    ``random.seed(seed)``, as a lone trial seeds them; the process's own state is left as it was."""
    outer = capture_global()
    seed_globals(seed)
    state = capture_global()
    restore_global(outer)
    return state


def capture_global() -> dict[str, Any]:
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_global(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


class ReplicaStreams:
    """The global generators' state of each replica; ``use(r)`` runs a block on replica ``r``'s stream."""

    def __init__(self, seeds: Sequence[int]) -> None:
        self.states = [seeded_state(int(seed)) for seed in seeds]

    def __len__(self) -> int:
        return len(self.states)

    @contextlib.contextmanager
    def use(self, replica: int) -> Iterator[None]:
        outer = capture_global()
        restore_global(self.states[replica])
        try:
            yield
        finally:
            self.states[replica] = capture_global()
            restore_global(outer)

    def state_dict(self) -> list[dict[str, Any]]:
        return list(self.states)

    def load_state_dict(self, states: Sequence[dict[str, Any]]) -> None:
        if len(states) != len(self.states):
            raise ValueError(f"{len(states)} saved streams for {len(self.states)} replicas")
        self.states = list(states)
