"""The runnable examples under docs/examples/ still run (a smoke run each; what they reach is in docs/)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"
# A deprecation warning whose caller is the example's own code (ours warn at the caller's line) is an error: a shipped
# example must not teach what is on its way out.
DEPRECATIONS_AS_ERRORS = [f"-Werror::{category}:__main__"
                          for category in ("DeprecationWarning", "PendingDeprecationWarning", "FutureWarning")]


def test_the_torchrl_self_play_example_trains_and_evaluates():
    done = subprocess.run(
        [sys.executable, *DEPRECATIONS_AS_ERRORS, str(EXAMPLES / "torchrl_selfplay_ppo.py"), "--iterations", "1"],
        capture_output=True, text=True, timeout=600, check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "iteration    1  frames     2048  team success" in done.stdout
