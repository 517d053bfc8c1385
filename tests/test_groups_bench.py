"""The groups section's verdicts on a group against its lone runs rest on the seeds' exact test, and a seed that never
reaches 0.9 counts as not reaching it, not as absent."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from sidewalk.bench import groups


def test_a_comparison_states_the_exact_test_and_its_seeds():
    assert groups._compared([1.0, 1.0, 1.0, 1.0, 1.0], [0.5, 0.6, 0.7, 0.8, 0.9]) == (
        "+0.3 [+0.18, +0.42], separates at 95% (p 0.0079, exact Mann-Whitney, 5 v 5 seeds)")
    assert groups._compared([0.9, 1.0, 0.8], [0.7, 0.8, 0.95]).endswith(
        "cannot separate at 95% (smallest p 0.1: exact Mann-Whitney, 3 v 3 seeds)")


def test_a_seed_that_never_reaches_the_level_ranks_last(tmp_path: Path):
    pd.DataFrame({"frames": [2048, 4096], f"eval/{groups.SUCCESS}": [0.5, 0.8]}).to_csv(tmp_path / "metrics.csv")
    assert groups._frames_to(tmp_path) == math.inf
    never = [math.inf] * 5
    text = groups._compared(never, [2048.0, 4096.0, 4096.0, 6144.0, 8192.0])
    assert text == ("reached by 0 of 5 in the group, 5 of 5 alone, "
                    "separates at 95% (p 0.0079, exact Mann-Whitney, 5 v 5 seeds)")
