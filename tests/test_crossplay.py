"""The cross-play matrix (``runners/crossplay.py``, ``sidewalk.crossplay``, ``sidewalk.report.crossplay``): its
shape, its reproducibility, each cell equal to a plain evaluation of that pairing, its errors before any compute,
its files and figures, and its section in ``runners/report.py``'s report.

The runs are tiny (two iterations, no update: each seed's networks are their initial weights, so seeds differ) on
a 6-cell sidewalk with vector observations; built once for the module."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from sidewalk.config import validate
from sidewalk.crossplay import COLUMNS, run_crossplay
from sidewalk.crossplay.conventions import convention
from sidewalk.crossplay.pairings import evaluation_world
from sidewalk.crossplay.players import CrossplayError, load_player
from sidewalk.envs import DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate
from sidewalk.experiment import EVAL_SEED_OFFSET, Trial
from sidewalk.report.checkpoints import load_experiment, load_policy
from sidewalk.report.crossplay import condition_table, read_crossplay
from sidewalk.report.document import write_report
from sidewalk.report.tables import Settings
from sidewalk.schema import register_schemas
from sidewalk.views import EgoView

ROOT = Path(__file__).resolve().parents[1]
register_schemas()
TINY = ["logger=none", "iterations=2", "eval_every=0", "eval_episodes=8", "checkpoint_every=0", "num_envs=4"]
SMALL_GRID = ["env.length_cells=6", "env.observation=vector", "env.max_steps=30", "algo.frames_per_batch=16"]
RUNS = {
    "dqn_dijkstra_s0": ["algo=dqn", "opponent=dijkstra", "seed=0"],
    "dqn_dijkstra_s1": ["algo=dqn", "opponent=dijkstra", "seed=1"],
    "dqn_centralized_s0": ["algo=dqn", "opponent=centralized", "seed=0"],
    "iql_self_s0": ["algo=iql", "opponent=self", "seed=0"],
}
EPISODES = 8


def train(run_dir: Path, *overrides: str) -> Path:
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, *overrides])
    Trial(validate(cfg), run_dir, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    return run_dir


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("runs")
    built = {name: train(root / name, *overrides, *SMALL_GRID) for name, overrides in RUNS.items()}
    built["ppo_continuous"] = train(
        root / "ppo_continuous", "env=continuous", "opponent=random", "algo=ppo", "iterations=1",
        "algo.frames_per_batch=16", "algo.minibatch_size=8", "algo.epochs=1",
    )
    return built


@pytest.fixture(scope="module")
def matrix(runs):
    rows = [runs[name] for name in RUNS]
    return run_crossplay(rows, episodes=EPISODES, seed=0, show_progress=False)


def test_the_matrix_has_a_cell_for_every_row_and_partner(runs, matrix):
    frame = matrix.frame
    partners = ["dijkstra", "random", *(str(runs[name]) for name in RUNS)]
    assert list(frame.columns) == list(COLUMNS)
    assert len(frame) == len(RUNS) * len(partners)
    assert list(frame["partner"][: len(partners)]) == partners
    assert (frame["skipped"] == "").all()
    assert (frame["episodes"] == EPISODES).all()
    assert frame[["success", "team_success", "collision_rate", "deadlock_rate"]].notna().all().all()
    assert (frame["deadlock_rate"] <= 1 - frame["team_success"] + 1e-9).all()  # a standoff is a failed episode
    by_run = frame.set_index(["row_run", "partner"])
    s0, s1 = str(runs["dqn_dijkstra_s0"]), str(runs["dqn_dijkstra_s1"])
    assert by_run.loc[(s0, s0), "self_pair"] and by_run.loc[(s0, s0), "same_condition"]
    assert not by_run.loc[(s0, s1), "self_pair"] and by_run.loc[(s0, s1), "same_condition"]
    assert not by_run.loc[(s0, str(runs["iql_self_s0"])), "same_condition"]
    labels = dict(zip(frame["row_run"], frame["row_label"]))
    assert labels[s0] == labels[s1] == "dqn vs dijkstra"
    assert labels[str(runs["dqn_centralized_s0"])] == "dqn centralized"
    assert labels[str(runs["iql_self_s0"])] == "iql self-play"
    assert sorted(set(frame["row_seed"])) == [0, 1]
    assert set(frame["row_agent"]) == {0}  # trained as agent 0, or as every agent


def test_a_cell_equals_a_plain_evaluation_of_its_pairing(runs):
    """Row DQN with the scripted partner, and with a learned one (``opponent=policy``), at noise 0.1 so that the
    seeded worlds matter: each cell is what ``evaluate`` gives for that pairing on the same worlds."""
    row, partner = runs["dqn_dijkstra_s0"], runs["dqn_dijkstra_s1"]
    frame = run_crossplay([row], ["dijkstra", "random", str(partner)], episodes=EPISODES, seed=3, noise=0.1,
                          show_progress=False).frame
    experiment = load_experiment(row)
    world = evaluation_world([load_player(row)], 0.1)
    seed = 3 + EVAL_SEED_OFFSET
    for opponent, kwargs, name in (("dijkstra", {}, "dijkstra"), ("random", {}, "random"),
                                   ("policy", {"path": partner}, str(partner))):
        view = EgoView(DiscreteSidewalkEnv(EPISODES, seed=seed, params=world), opponent, ego=0,
                       opponent_kwargs=kwargs)
        metrics = evaluate(view, load_policy(row, experiment, view), seed=seed)
        cell = frame[frame["partner"] == name].iloc[0]
        assert cell["success"] == metrics["ego/success_rate"]
        assert cell["partner_success"] == metrics["other/success_rate"]
        assert cell["collision_rate"] == metrics["ego/collision_rate"]
        assert cell["team_success"] == metrics["team/success_rate"]
        assert cell["return"] == pytest.approx(metrics["ego/return"], abs=1e-6)
        for column, key in (("path_efficiency", "ego/path_efficiency"),
                            ("partner_path_efficiency", "other/path_efficiency")):
            assert cell[column] == pytest.approx(metrics[key], nan_ok=True)


def test_a_run_paired_with_its_training_opponent_reproduces_its_final_evaluation(runs):
    row = runs["dqn_dijkstra_s1"]
    frame = run_crossplay([row], "dijkstra", episodes=8, seed=1, show_progress=False).frame
    summary = json.loads((row / "summary.json").read_text())
    assert frame["success"].iloc[0] == summary["ego/success_rate"]
    assert frame["team_success"].iloc[0] == summary["team/success_rate"]


def test_nominal_plays_a_perturbed_run_on_the_worlds_of_eval_nominal(runs, tmp_path):
    """``nominal``: a run trained under ``eval=perturbed`` (the default) is played from the scenario's own starts and
    goals, the very world a run of ``eval=nominal`` trains and is evaluated in, and a cell then equals that
    evaluation."""
    row = runs["dqn_dijkstra_s1"]
    nominal_run = load_player(train(tmp_path / "nominal", *RUNS["dqn_dijkstra_s1"], *SMALL_GRID, "eval=nominal"))
    perturbed = evaluation_world([load_player(row)], None)
    assert perturbed.start_jitter_rows > 0 and perturbed.goal_jitter_rows > 0
    assert evaluation_world([load_player(row)], None, nominal=True) == nominal_run.partner.world.env_params

    matrix = run_crossplay([row], "dijkstra", episodes=EPISODES, seed=1, nominal=True, show_progress=False)
    assert set(matrix.meta["jitter"].values()) == {0}
    seed = 1 + EVAL_SEED_OFFSET
    view = EgoView(DiscreteSidewalkEnv(EPISODES, seed=seed, params=nominal_run.partner.world.env_params), "dijkstra", ego=0)
    metrics = evaluate(view, load_policy(row, load_experiment(row), view), seed=seed)
    cell = matrix.frame.iloc[0]
    assert (cell["success"], cell["team_success"]) == (metrics["ego/success_rate"], metrics["team/success_rate"])
    assert cell["return"] == pytest.approx(metrics["ego/return"], abs=1e-6)


def test_a_run_of_another_domain_fails_naming_it_before_any_evaluation(runs, monkeypatch):
    from sidewalk import crossplay

    def no_evaluation(*args, **kwargs):
        raise AssertionError("a cell was evaluated before the check")

    monkeypatch.setattr(crossplay.Arena, "evaluate", no_evaluation)
    other = str(runs["ppo_continuous"])
    with pytest.raises(CrossplayError, match=f"{other} cannot be paired.*continuous domain"):
        run_crossplay([runs["dqn_dijkstra_s0"]], f"dijkstra,{other}", episodes=4, show_progress=False)
    with pytest.raises(CrossplayError, match=f"{other} cannot be paired.*continuous domain"):
        run_crossplay([runs["dqn_dijkstra_s0"], other], episodes=4, show_progress=False)


def test_bad_partners_and_run_folders_are_named(runs, tmp_path):
    row = [runs["dqn_dijkstra_s0"]]
    with pytest.raises(CrossplayError, match="unknown partner 'dijkstr'.*dijkstra, random"):
        run_crossplay(row, "dijkstr", show_progress=False)
    with pytest.raises(CrossplayError, match="partner 'prm' does not play the discrete domain"):
        run_crossplay(row, "prm", show_progress=False)
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    (unfinished / "config.yaml").write_text((runs["dqn_dijkstra_s0"] / "config.yaml").read_text())
    with pytest.raises(CrossplayError, match=f"{unfinished} has no policy.pt"):
        run_crossplay([*row, unfinished], show_progress=False)
    with pytest.raises(CrossplayError, match="is not a folder"):
        run_crossplay([tmp_path / "missing"], show_progress=False)


def test_a_scripted_partner_takes_its_settings_and_a_bad_one_is_named_before_any_cell(runs, monkeypatch):
    """``NAME:KEY=VALUE``: the version-1 Dijkstra agent's cell equals a plain evaluation with that setting; an
    unknown key, a bad value and a setting without a value stop the matrix before its first cell."""
    from sidewalk import crossplay

    row = runs["dqn_dijkstra_s0"]
    cell = run_crossplay([row], "dijkstra:tie_break=progress:avoid_cost=5", episodes=EPISODES, seed=3,
                         show_progress=False).frame.iloc[0]
    seed = 3 + EVAL_SEED_OFFSET
    world = evaluation_world([load_player(row)], None)
    view = EgoView(DiscreteSidewalkEnv(EPISODES, seed=seed, params=world), "dijkstra", ego=0,
                   opponent_kwargs={"tie_break": "progress", "avoid_cost": 5})
    metrics = evaluate(view, load_policy(row, load_experiment(row), view), seed=seed)
    assert cell["partner"] == "dijkstra:tie_break=progress:avoid_cost=5"
    assert (cell["success"], cell["partner_success"]) == (metrics["ego/success_rate"], metrics["other/success_rate"])
    assert cell["return"] == pytest.approx(metrics["ego/return"], abs=1e-6)

    monkeypatch.setattr(crossplay, "crossplay", lambda *args, **kwargs: pytest.fail("a cell was played"))
    for spec, message in (("dijkstra:tie_brake=progress", "unknown setting 'tie_brake' \\(did you mean 'tie_break'"),
                          ("dijkstra:tie_break=sideways", "tie_break='sideways' is not valid; valid: 'random'"),
                          ("dijkstra:tie_break", "'tie_break' is not KEY=VALUE")):
        with pytest.raises(CrossplayError, match=message):
            run_crossplay([row], spec, episodes=EPISODES, show_progress=False)


def test_the_runner_writes_the_same_csv_for_the_same_seed_with_figures_and_report(runs, tmp_path, runner):
    crossplay = runner("crossplay")
    rows = [str(runs["dqn_dijkstra_s0"]), str(runs["dqn_dijkstra_s1"])]
    common = ["--partners", "random,rows", "--episodes", "4", "--seed", "5", "--noise", "0.2", "--no-progress"]
    assert crossplay.main([*rows, *common, "--out", str(tmp_path / "a")]) == 0
    assert crossplay.main([*rows, *common, "--out", str(tmp_path / "b")]) == 0
    out = tmp_path / "a"
    assert (out / "crossplay.csv").read_bytes() == (tmp_path / "b" / "crossplay.csv").read_bytes()
    meta = json.loads((out / "crossplay.json").read_text())
    assert meta["world_seed"] == 5 + EVAL_SEED_OFFSET and meta["noise"] == 0.2 and meta["episodes"] == 4
    trained = OmegaConf.load(runs["dqn_dijkstra_s0"] / "config.yaml").env  # eval=perturbed: the rows' worlds moved
    assert meta["jitter"] == {"start_jitter_rows": trained.start_jitter_rows, "goal_jitter_rows": trained.goal_jitter_rows,
                              "start_jitter_cells": 0, "goal_jitter_cells": 0}
    assert meta["jitter"]["start_jitter_rows"] >= 1
    assert meta["command"].startswith("python runners/crossplay.py ") and "--seed 5" in meta["command"]
    figures = sorted(path.name for path in (out / "figures").glob("*.png"))
    assert figures == sorted(
        f"crossplay{part}_{metric}.png" for part in ("", "_by_condition")
        for metric in ("success", "collision_rate", "team_success", "deadlock_rate")
    )
    conventions = pd.read_csv(out / "conventions.csv")
    assert sorted(conventions["row_run"]) == sorted(rows) and conventions["episodes"].eq(4).all()
    assert set(conventions["passing_side"]) <= {"left", "right", "none"}
    report = (out / "report.md").read_text()
    assert "## Cross-play" in report and meta["command"] in report and "Not written yet" in report
    assert f"start_jitter_rows ±{meta['jitter']['start_jitter_rows']}" in report
    assert "### Conventions" in report
    assert "| dqn vs dijkstra | " in report and "(figures/crossplay_by_condition_success.png)" in report
    (out / "notes.md").write_text("Seeds of one condition coordinate with each other.")
    assert crossplay.main(["--redraw", str(out)]) == 0
    assert "Seeds of one condition coordinate" in (out / "report.md").read_text()
    assert crossplay.main([rows[0], "--partners", "nobody", "--out", str(tmp_path / "c"), "--no-progress"]) == 2
    assert not (tmp_path / "c").exists()


def test_condition_means_leave_out_self_pairs():
    cells = []
    for row_seed in (0, 1, 2):
        for partner_seed in (0, 1, 2):
            cells.append({"row_run": f"a{row_seed}", "row_label": "A", "row_seed": row_seed, "partner": f"a{partner_seed}",
                          "partner_label": "A", "partner_kind": "learned", "partner_seed": partner_seed,
                          "self_pair": row_seed == partner_seed, "skipped": "",
                          "success": 1.0 if row_seed == partner_seed else float(row_seed + partner_seed) / 10})
    mean, pairs = condition_table(pd.DataFrame(cells), "success")
    assert pairs.loc["A", "A"] == 6
    assert mean.loc["A", "A"] == pytest.approx((0.1 + 0.2 + 0.1 + 0.3 + 0.2 + 0.3) / 6)


def test_the_report_includes_the_matrix(runs, tmp_path, runner):
    out = tmp_path / "crossplay"
    assert runner("crossplay").main(
        [str(runs["dqn_dijkstra_s0"]), "--partners", "dijkstra,rows", "--episodes", "4", "--no-progress",
         "--out", str(out)]
    ) == 0
    result = write_report([runs["dqn_dijkstra_s0"], out], tmp_path / "report", Settings(trajectory_episodes=0))
    report = result.report_md.read_text()
    assert result.crossplay == [out]
    assert "## Cross-play" in report and "(figures/crossplay_by_condition_team_success.png)" in report
    assert (tmp_path / "report" / "figures" / "crossplay_success.png").exists()
    numbers = pd.read_csv(tmp_path / "report" / "report.csv")
    assert (numbers["section"] == "crossplay").any()
    alone = write_report([out], tmp_path / "alone", Settings(trajectory_episodes=0))  # the matrix alone
    assert alone.crossplay == [out] and "## Cross-play" in alone.report_md.read_text()
    frame, meta = read_crossplay(out)
    assert len(frame) == 2 and meta["partners"] == ["dijkstra", str(runs["dqn_dijkstra_s0"])]



def test_a_partner_that_cannot_play_the_other_role_leaves_its_cell_empty_with_the_reason(tmp_path):
    # The door scenario has no half-turn symmetry: a learner trained as agent 0 cannot play agent 1.
    run = train(tmp_path / "door", "algo=dqn", "opponent=dijkstra", "env.layout=door", "env.observation=vector",
                "env.max_steps=30", "algo.frames_per_batch=16")
    frame = run_crossplay([run], "dijkstra,rows", episodes=4, show_progress=False).frame
    played, empty = frame.iloc[0], frame.iloc[1]
    assert played["skipped"] == "" and played["episodes"] == 4
    assert "cannot play agent 1" in empty["skipped"] and pd.isna(empty["success"]) and pd.isna(empty["episodes"])


def _walk(lateral_0: float, lateral_1: float, steps: int = 15, length: float = 14.0) -> np.ndarray:
    """Positions (T, 1, 2, 2) of agent 0 walking along +along and agent 1 the other way, at fixed lateral places,
    as (lateral, along): the grid's (row, col)."""
    along = np.linspace(0.0, length, steps)
    trajectory = np.zeros((steps, 1, 2, 2))
    trajectory[:, 0, 0] = np.stack([np.full(steps, lateral_0), along], -1)
    trajectory[:, 0, 1] = np.stack([np.full(steps, lateral_1), along[::-1]], -1)
    return trajectory


def test_convention_reads_the_passing_side_and_the_yielder_in_both_domains():
    grid = SimpleNamespace(center_row=3.0)
    # grid: agent 0 (facing +col, its left is row-1) keeps to row 3, agent 1 (facing -col, its left is row+1) steps
    # to row 4: each is on its own left of the other, and agent 1 yields
    assert convention(_walk(3, 4), "discrete", grid) == {
        "passing_side": "left", "passing_fraction": 1.0, "yielder": "agent 1", "episodes": 1}
    assert convention(_walk(4, 3), "discrete", grid)["passing_side"] == "right"
    assert convention(_walk(2, 4), "discrete", grid)["yielder"] == "both"
    # continuous, as (x, y): agent 0 at a larger y than agent 1 is on its own left
    plane = SimpleNamespace(width_m=3.0)
    continuous = _walk(1.9, 1.5, length=3.0)[..., ::-1].copy()
    assert convention(continuous, "continuous", plane) == {
        "passing_side": "left", "passing_fraction": 1.0, "yielder": "agent 0", "episodes": 1}
    # an agent that crashed before they crossed (NaN from then on): no pass, no yielder
    crashed = continuous.copy()
    crashed[5:, 0, 1] = np.nan
    assert convention(crashed, "continuous", plane) == {
        "passing_side": "none", "passing_fraction": 0.0, "yielder": "none", "episodes": 1}
    # two episodes, one each way: the majority is the first in order of a tie, at half the share
    both = np.concatenate([continuous, _walk(1.1, 1.5, length=3.0)[..., ::-1]], axis=1)
    assert convention(both, "continuous", plane)["passing_fraction"] == 0.5


def test_a_held_out_partner_a_row_trained_with_is_flagged_from_its_training_world(runs):
    """A row trained against the held-out Dijkstra agent (the same settings: version 1's tie-break) met it; one
    trained against today's default Dijkstra (random tie-breaks), a self-play row, and a population row did not."""
    import dataclasses

    from sidewalk.crossplay.pairings import met_in_training
    from sidewalk.crossplay.players import heldout_column
    from sidewalk.partners.population import population

    members = population("discrete", "heldout")
    dijkstra, keep_left = (heldout_column("discrete", name, members[name]) for name in ("dijkstra", "keep_left"))
    today, selfplay = load_player(runs["dqn_dijkstra_s0"]), load_player(runs["iql_self_s0"])

    def trained_against(opponent: str, **params) -> object:
        world = today.partner.world.replace(opponent=opponent, opponent_params=params)
        return dataclasses.replace(today, partner=dataclasses.replace(today.partner, world=world))

    version_1 = trained_against("dijkstra", **{**today.partner.world.opponent_params, "tie_break": "progress"})
    assert met_in_training(version_1, dijkstra) and not met_in_training(version_1, keep_left)
    assert not met_in_training(today, dijkstra) and not met_in_training(selfplay, dijkstra)
    assert not met_in_training(trained_against("population"), dijkstra)  # its Dijkstra member plays nearer
    assert met_in_training(trained_against("convention", style="keep_left"), keep_left)


def test_the_ad_hoc_score_leaves_out_partners_a_row_met_and_says_which(tmp_path):
    from sidewalk.report.crossplay import _adhoc_lines, adhoc_table, best_response_table

    cells = [{"row_run": f"{label}/{seed}", "row_label": label, "partner": f"heldout:{partner}",
              "partner_label": partner, "partner_kind": "scripted", "self_pair": False, "skipped": "",
              "heldout": True, "team_success": 1.0, "met_in_training": label == "dqn vs dijkstra" and partner == "dijkstra"}
             for label in ("dqn vs dijkstra", "iql self-play") for seed in (0, 1) for partner in ("dijkstra", "keep_left")]
    frame = pd.DataFrame(cells).reindex(columns=list(COLUMNS))
    table = adhoc_table(frame).set_index("condition")
    assert (table.loc["dqn vs dijkstra", "partners"], table.loc["iql self-play", "partners"]) == (1, 2)
    responses = best_response_table(tmp_path)  # none
    text = " ".join(_adhoc_lines(frame, "###", None, responses))
    assert "left out where a row trained with one (`dijkstra` by dqn vs dijkstra: 2 of 8 cells)" in text
    unmet = frame.assign(met_in_training=False)
    assert "none of which any learner met" in " ".join(_adhoc_lines(unmet, "###", None, responses))


def test_runs_of_one_config_from_two_folders_stay_two_conditions(runs, tmp_path):
    """Two copies of one run in different folders are not seeds of one condition: their labels name the folders."""
    import shutil

    copies = [shutil.copytree(runs["dqn_dijkstra_s0"], tmp_path / folder / "run") for folder in ("first", "second")]
    frame = run_crossplay(copies, "dijkstra", episodes=4, seed=0, show_progress=False).frame
    labels = list(frame["row_label"])
    assert len(set(labels)) == 2 and all("folder=" in label for label in labels)
    assert not frame["same_condition"].any()
