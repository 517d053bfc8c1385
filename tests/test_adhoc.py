"""The ad-hoc score: cross-play with the held-out partner population (``--partners heldout``), aggregated per
condition as an IQM over seeds × partners with a 95 % interval, in ``adhoc.csv`` and the cross-play report."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.stats
import torch

from sidewalk.crossplay import run_crossplay
from sidewalk.crossplay.players import CrossplayError
from sidewalk.partners.population import PARTNERS_DIR, population
from sidewalk.report.crossplay import ADHOC_CSV, adhoc_table

ROOT = Path(__file__).resolve().parents[1]
ROWS = [PARTNERS_DIR / "continuous" / f"ippo_seed{seed}" for seed in (0, 1)]  # training partners as rows


@pytest.fixture(scope="module")
def matrix():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return run_crossplay(ROWS, "heldout", episodes=4, show_progress=False)
    finally:
        torch.set_num_threads(previous)


def test_heldout_partners_are_the_held_out_population(matrix):
    frame = matrix.frame
    members = list(population("continuous", "heldout"))
    assert list(dict.fromkeys(frame["partner"])) == [f"heldout:{name}" for name in members]
    assert frame["heldout"].all() and (frame["skipped"] == "").all()
    assert set(frame.loc[frame["partner_kind"] == "learned", "partner_label"]) == {
        f"mappo_seed{s}" for s in range(3)
    }


def test_the_adhoc_score_is_the_iqm_over_seeds_and_partners(matrix):
    table = adhoc_table(matrix.frame)
    assert len(table) == 1 and table.loc[0, "runs"] == 2 and table.loc[0, "partners"] == len(population("continuous", "heldout"))
    scores = matrix.frame.pivot_table(index="row_run", columns="partner", values="team_success").to_numpy()
    assert table.loc[0, "iqm"] == pytest.approx(scipy.stats.trim_mean(scores, 0.25, axis=None))
    assert table.loc[0, "mean"] == pytest.approx(scores.mean())
    assert table.loc[0, "low"] <= table.loc[0, "iqm"] <= table.loc[0, "high"]
    assert adhoc_table(matrix.frame.drop(columns="heldout")) is None, "a matrix from before: no score"


def test_the_runner_writes_the_score_and_the_report_shows_it(tmp_path, matrix, monkeypatch):
    import sidewalk.crossplay

    monkeypatch.setattr(sidewalk.crossplay, "run_crossplay", lambda *args, **kwargs: matrix)
    spec = importlib.util.spec_from_file_location("runner_crossplay", ROOT / "runners" / "crossplay.py")
    runner = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(runner)
    assert runner.main([str(ROWS[0]), "--partners", "heldout", "--out", str(tmp_path), "--no-progress"]) == 0
    written = pd.read_csv(tmp_path / ADHOC_CSV)
    assert np.isclose(written.loc[0, "iqm"], adhoc_table(matrix.frame).loc[0, "iqm"])
    assert "Ad-hoc score: partners never met" in (tmp_path / "report.md").read_text()


def test_a_misspelt_shorthand_names_heldout_among_the_valid_partners():
    with pytest.raises(CrossplayError, match="unknown partner 'held_out'.*'heldout'"):
        run_crossplay(ROWS[:1], "held_out", episodes=2, show_progress=False)
