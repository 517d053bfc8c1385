"""The time budget accounts for the whole loop: its parts sum to Trial.run, and Trial.run to less than the wall-clock."""

from __future__ import annotations

import pytest

from sidewalk.bench import budget


@pytest.fixture(scope="module")
def trpo_budget():
    # 16 evaluation episodes, not 256 (and 160 for the absolute metric, not 2560): the parts sum all the same.
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(budget.RUNS, "trpo", (*budget.RUNS["trpo"], "eval_episodes=16"))
        return budget.run(runs=["trpo"], seeds=[0], trpo_iterations=2)


def test_parts_sum_to_the_run_and_the_run_to_the_wall_clock(trpo_budget):
    (row,) = trpo_budget
    (timed,) = row["timed"]["this checkout"]
    assert timed["iterations"] == 2 and not timed["probes"]["missing"]
    values = budget._budget_rows([timed])
    parts = [label for label, _, probe in budget.LAYOUT if probe is None]
    assert sum(values[label] for label in parts) * 2 / 1000 == pytest.approx(values["Trial.run (s)"], rel=1e-6)
    children = [label for label, part, probe in budget.LAYOUT if part == "update" and probe is not None]
    assert sum(values[label] for label in children) == pytest.approx(values["update"], rel=1e-6)
    assert values["update"] > 0 and values["collection"] > 0 and values["evaluation"] > 0
    assert 0 < values["Trial.run (s)"] < values["end-to-end wall-clock (s)"]


def test_table_names_every_part_and_the_trust_check(trpo_budget):
    text = budget.format_rows(trpo_budget)
    for label in ("collection", "  opponent (scripted agent)", "  policy step (CG, line search)", "evaluation",
                  "Trial.run (s)", "end-to-end wall-clock (s)"):
        assert f"\n{label} " in text, label
    assert "last three evaluations per seed [" in text and "of 1 seeds ≥ 0.9 at all three" in text


def test_bad_options_are_named():
    with pytest.raises(SystemExit):
        budget.parse_options(["--baseline", "no-such-revision"])
    with pytest.raises(SystemExit):
        budget.parse_options(["--trpo-iterations", "0"])
