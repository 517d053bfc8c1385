"""BR-Prox (ZSC-Eval): the ad-hoc score with each held-out partner's score over its best response's, capped at 1."""

from pathlib import Path

import pandas as pd
import pytest
from omegaconf import OmegaConf

from sidewalk.best_responses import (
    BEST_RESPONSE_COLUMNS,
    best_responses_from_runs,
    member_overrides,
    read_cache,
    train_best_responses,
    write_cache,
)
from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial
from sidewalk.partners.population import population
from sidewalk.report.crossplay import (
    BEST_RESPONSES_CSV,
    adhoc_table,
    best_response_table,
    br_prox_scores,
    read_best_responses,
)

TINY = ["num_envs=4", "iterations=2", "eval_every=2", "eval_episodes=8", "logger=none", "plots=false",
        "algo.learning_starts=0", "algo.frames_per_batch=16", "algo.batch_size=16"]


def matrix(scores: dict[str, dict[str, float]]) -> pd.DataFrame:
    """A cross-play frame of held-out cells: run → partner → team success, one condition."""
    rows = [{"row_label": "learner", "row_run": run, "partner": f"heldout:{partner}", "partner_label": partner,
             "team_success": value,
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
    rows = best_responses_from_runs([tmp_path / "brs"], episodes=8)
    assert [row["member"] for row in rows] == ["keep_left"] and rows[0]["seeds"] == 1
    assert 0 <= rows[0]["success"] <= 1 and rows[0]["budget"] == 2
    train(tmp_path / "other" / "wide", ["opponent=convention", "opponent.params.style=keep_left",
                                        "opponent.params.lane_fraction=0.85"])  # a training member, not held out
    with pytest.raises(ValueError, match="match no held-out partner"):
        best_responses_from_runs([tmp_path / "other"])


def test_a_member_is_named_by_its_opponent_and_settings():
    members = population("discrete", "heldout")
    assert member_overrides("discrete", members["keep_left"]) == ["opponent=convention", "opponent.params.style=keep_left"]
    assert member_overrides("discrete", members["dijkstra"]) == ["opponent=dijkstra", "opponent.params.tie_break=progress"]
    shipped = member_overrides("discrete", members["vdn_seed0"])
    assert shipped[0] == "opponent=policy" and Path(shipped[1].split("=", 1)[1]).name == "vdn_seed0"


def test_the_cache_reads_back_and_a_new_row_replaces_the_members_old_one(tmp_path):
    assert read_cache(tmp_path).empty
    row = {"member": "keep_left", "command": "python runners/main.py x", "budget": 300, "seeds": 1, "success": 0.5,
           "low": float("nan"), "high": float("nan"), "note": "1 run", "episodes": 256, "distinct_low": 9,
           "distinct_high": 9, "run_folders": "a"}
    write_cache(tmp_path, [row, {**row, "member": "salsa", "success": 0.25}])
    write_cache(tmp_path, [{**row, "success": 0.75}])
    table = read_cache(tmp_path)
    assert list(table.columns) == list(BEST_RESPONSE_COLUMNS)
    assert table.set_index("member")["success"].to_dict() == {"salsa": 0.25, "keep_left": 0.75}
    assert read_best_responses(tmp_path) == {"salsa": 0.25, "keep_left": 0.75}  # what the report reads


def test_a_tiny_best_response_is_trained_evaluated_cached_and_not_trained_again(tmp_path, caplog):
    tiny = ["num_envs=4", "eval_every=2", "eval_episodes=8", "logger=none", "algo.learning_starts=0",
            "algo.frames_per_batch=16", "algo.batch_size=16", "env.observation=vector"]
    path = train_best_responses("discrete", tmp_path / "matrix", tmp_path / "runs", ["keep_left"], iterations=2,
                                episodes=8, show_progress=False, extra=tiny)
    row = read_cache(tmp_path / "matrix").iloc[0]
    assert path.name == BEST_RESPONSES_CSV and row["member"] == "keep_left" and row["budget"] == 2
    assert row["reference_budget"] == 300  # DQN's own budget, conf/algo/dqn.yaml
    assert "`keep_left` (2 iterations, reference 300;" in caplog.text  # said as it is trained, not only in the CSV
    assert 0 <= row["success"] <= 1 and row["episodes"] == 8 and 1 <= row["distinct_low"] <= 8
    assert "opponent.params.style=keep_left" in row["command"] and "algo=dqn" in row["command"]
    assert (tmp_path / "runs" / "discrete" / "keep_left" / "policy.pt").exists()
    write_cache(tmp_path / "matrix", [{**row.to_dict(), "success": 0.123}])  # a cached member is skipped, not redone
    train_best_responses("discrete", tmp_path / "matrix", tmp_path / "runs", ["keep_left"], iterations=2,
                         episodes=8, show_progress=False, extra=tiny)
    assert read_best_responses(tmp_path / "matrix") == {"keep_left": 0.123}
    policy = tmp_path / "runs" / "discrete" / "keep_left" / "policy.pt"
    trained_at = policy.stat().st_mtime_ns
    (tmp_path / "matrix" / BEST_RESPONSES_CSV).unlink()  # a finished run is evaluated again, not trained again
    train_best_responses("discrete", tmp_path / "matrix", tmp_path / "runs", ["keep_left"], iterations=2,
                         episodes=8, show_progress=False, extra=tiny)
    assert read_best_responses(tmp_path / "matrix") == {"keep_left": row["success"]}
    assert policy.stat().st_mtime_ns == trained_at


def test_the_command_refuses_an_unknown_member_before_training(runner, tmp_path, capsys):
    code = runner("crossplay").main(["--train-best-responses", "discrete", "--members", "keep_left,moonwalk",
                                     "--out", str(tmp_path / "m"), "--runs-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("error:") == 1 and "'moonwalk'" in err and "keep_left" in err
    assert not (tmp_path / "runs").exists() and not (tmp_path / "m").exists()
    assert runner("crossplay").main(["--train-best-responses", "mars", "--out", str(tmp_path / "m")]) == 2
    assert "'mars'" in capsys.readouterr().err


def test_the_command_refuses_best_responses_without_a_matrix(runner, capsys):
    with pytest.raises(SystemExit) as exit_:
        runner("crossplay").main(["--best-responses", "x", "--out", "y", "somerun"])
    assert exit_.value.code == 2 and "--best-responses goes with --redraw" in capsys.readouterr().err


def test_the_report_names_partners_without_a_best_response_and_those_whose_best_response_never_succeeds():
    from sidewalk.report.crossplay import _adhoc_lines

    responses = pd.DataFrame({"member": ["easy", "hard"], "success": [0.8, 0.0]})
    text = "\n".join(_adhoc_lines(FRAME, "###", None, responses))
    assert "No best response cached for `unmatched`" in text
    assert "best response to `hard` never succeeds" in text
    assert "(1 partners)" in text  # only `easy` is left to BR-Prox
    assert "`easy` 0.80, `hard` 0.00" in text  # the denominators, as cached


def test_a_stopped_best_response_job_says_how_to_continue_in_one_line(runner, tmp_path, capsys, monkeypatch):
    import signal

    import sidewalk.best_responses
    from sidewalk.stops import RunInterrupted

    def preempted(*args, **kwargs):
        raise RunInterrupted(signal.SIGTERM, 7, tmp_path / "runs" / "discrete" / "keep_left")

    monkeypatch.setattr(sidewalk.best_responses, "train_best_responses", preempted)
    code = runner("crossplay").main(["--train-best-responses", "discrete", "--out", str(tmp_path / "m")])
    err = capsys.readouterr().err.strip()
    assert code == 128 + signal.SIGTERM and "\n" not in err and "Traceback" not in err
    assert "SIGTERM received: checkpointed at iteration 7" in err and "run the same command again" in err


def response(member: str, success: float, budget: int = 300, **more) -> dict:
    """A best_responses.csv row trained against ``member`` for ``budget`` of DQN's 300 reference iterations."""
    return {"member": member, "command": "", "budget": budget, "reference_budget": 300, "seeds": 1, "success": success,
            "low": float("nan"), "high": float("nan"), "note": "1 run", "episodes": 64, "distinct_low": 9,
            "distinct_high": 9, "run_folders": "", **more}


def test_br_prox_over_under_trained_or_weak_best_responses_is_flagged_beside_the_figure(tmp_path, caplog):
    from sidewalk.report.crossplay import _adhoc_lines

    # The case seen: best responses at 20 of 300 iterations, 0.31 team success, made every condition's BR-Prox 1.
    scores = {"keep_left": 0.5, "salsa": 0.9, "prm": 0.7, "hesitates": 0.2}
    frame = matrix({"seed0": scores, "seed1": {name: value / 2 for name, value in scores.items()}})
    write_cache(tmp_path, [response("keep_left", 0.31, budget=20), response("salsa", 0.97, budget=20),
                           response("prm", 0.45), response("hesitates", 0.0, budget=20),
                           response("dijkstra", 0.1, budget=20)])
    lines = _adhoc_lines(frame, "###", None, best_response_table(tmp_path))
    warning = next(line for line in lines if "Warning" in line)
    assert "`keep_left` (20 iterations, reference 300; team success 0.31)" in warning
    assert "`salsa` (20 iterations, reference 300; team success 0.97)" in warning  # short of its budget
    assert "`prm` (300 iterations, reference 300; team success 0.45)" in warning  # weak with its partner
    assert "hesitates" not in warning  # never succeeds: left out of BR-Prox (and named so)
    assert "dijkstra" not in warning  # not a partner of this matrix
    assert lines.index(warning) < lines.index(next(line for line in lines if line.startswith("| learner")))
    assert "(3 partners) **over weak best responses: see the warning**" in "\n".join(lines)  # beside the figure
    assert warning.strip("*") in caplog.text  # and printed

    write_cache(tmp_path, [response(name, 0.97) for name in ("keep_left", "salsa", "prm", "hesitates")])
    caplog.clear()
    assert not any("Warning" in line for line in _adhoc_lines(frame, "###", None, best_response_table(tmp_path)))
    assert "Warning" not in caplog.text
    (tmp_path / BEST_RESPONSES_CSV).write_text("member,success\nkeep_left,0.31\n")  # a file of before the budgets
    assert "`keep_left` (budget unknown; team success 0.31)" in "\n".join(
        _adhoc_lines(frame, "###", None, best_response_table(tmp_path)))
