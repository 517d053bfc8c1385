"""BR-Prox (ZSC-Eval): the ad-hoc score with each held-out partner's score over its best response's, capped at 1."""

import pandas as pd
import pytest
from omegaconf import OmegaConf

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial
from sidewalk.report.crossplay import (
    BEST_RESPONSES_CSV,
    adhoc_table,
    best_responses_from_runs,
    br_prox_scores,
    read_best_responses,
)

TINY = ["num_envs=4", "iterations=2", "eval_every=2", "eval_episodes=8", "logger=none", "plots=false",
        "algo.learning_starts=0", "algo.frames_per_batch=16", "algo.batch_size=16"]


def matrix(scores: dict[str, dict[str, float]]) -> pd.DataFrame:
    """A cross-play frame of held-out cells: run → partner → team success, one condition."""
    rows = [{"row_label": "learner", "row_run": run, "partner": f"heldout:{partner}", "team_success": value,
             "heldout": True, "skipped": "", "distinct_episodes": 256}
            for run, partners in scores.items() for partner, value in partners.items()]
    return pd.DataFrame(rows)


FRAME = matrix({"seed0": {"easy": 0.4, "hard": 0.1, "unmatched": 0.9}, "seed1": {"easy": 1.0, "hard": 0.3,
                                                                                 "unmatched": 0.5}})


def test_each_score_is_over_its_best_response_capped_at_one_and_undefined_partners_are_left_out():
    prox = br_prox_scores(FRAME, {"easy": 0.8, "hard": 0.2, "unmatched": 0.0})["learner"]
    assert list(prox.columns) == ["heldout:easy", "heldout:hard"]  # a best response of 0 leaves its partner out
    assert prox.loc["seed0"].tolist() == pytest.approx([0.5, 0.5])
    assert prox.loc["seed1"].tolist() == pytest.approx([1.0, 1.0])  # 1.25 and 1.5, capped


def test_the_table_gives_br_prox_beside_the_raw_score():
    table = adhoc_table(FRAME, {"easy": 0.8, "hard": 0.2})
    row = table.iloc[0]
    assert row["partners"] == 3 and row["br_prox_partners"] == 2
    assert row["br_prox_low"] <= row["br_prox_iqm"] <= row["br_prox_high"]
    assert row["br_prox_iqm"] > row["iqm"]  # the hard partner weighs as much as the easy one once normalised
    plain = adhoc_table(FRAME).iloc[0]
    assert plain["br_prox_partners"] == 0 and pd.isna(plain["br_prox_iqm"])


def test_the_best_responses_file_reads_back_and_a_bad_one_is_named(tmp_path):
    assert read_best_responses(tmp_path) == {}
    (tmp_path / BEST_RESPONSES_CSV).write_text("member,success\nkeep_left,0.75\n")
    assert read_best_responses(tmp_path) == {"keep_left": 0.75}
    (tmp_path / BEST_RESPONSES_CSV).write_text("partner,rate\nkeep_left,0.75\n")
    with pytest.raises(ValueError, match="lacks the column"):
        read_best_responses(tmp_path)


def train(folder, overrides):
    cfg = compose(TINY + overrides)
    Trial(validate(cfg), folder, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    return folder


def test_runs_against_held_out_members_become_rows_and_others_are_refused(tmp_path):
    train(tmp_path / "brs" / "keep_left", ["opponent=convention", "opponent.params.style=keep_left"])
    table = best_responses_from_runs([tmp_path / "brs"])
    assert table["member"].tolist() == ["keep_left"] and table["runs"].tolist() == [1]
    assert 0 <= table["success"].iloc[0] <= 1
    train(tmp_path / "other" / "wide", ["opponent=convention", "opponent.params.style=keep_left",
                                        "opponent.params.lane_fraction=0.85"])  # a training member, not held out
    with pytest.raises(ValueError, match="match no held-out partner"):
        best_responses_from_runs([tmp_path / "other"])


def test_the_command_refuses_best_responses_without_a_matrix(runner, capsys):
    with pytest.raises(SystemExit) as exit_:
        runner("crossplay").main(["--best-responses", "x", "--out", "y", "somerun"])
    assert exit_.value.code == 2 and "--best-responses goes with --redraw" in capsys.readouterr().err
