"""The report's aggregates over a paper figure's panels (rliable's way): the learner's final values of the conditions
at one rank of every panel pooled into one row, against hand-computed means, IQMs and optimality gaps; the probability
of improvement of every ordered pair of settings against hand counts; conditions at a rank that not every panel has
left out and named; the numbers in report.csv; Fig. 5's performance profile drawn, embedded and its points in
curves.csv; and a figure of one panel aggregated over its one task."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from sidewalk.report.conditions import PAPER_FIGURES, compared_settings, figure_panels, group_conditions
from sidewalk.report.document import write_report
from sidewalk.report.runs import find_run_folders, load_run
from sidewalk.report.tables import Settings
from sidewalk.schema import register_schemas
from sidewalk.stats import holm_adjusted, interval_estimate, probability_of_improvement, separation_text

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
SETTINGS = Settings(n_resamples=500, trajectory_episodes=0)
FIG5 = "fig5_success_by_opponent"
register_schemas()

# The learner's final success of each seed, by preset and opponent (4 seeds in the grid, 5 in the plane): pooled, the
# random rows' 9 runs have mean 4/9 and IQM 0.4 (the 2 lowest and 2 highest trimmed), not the mean of the panels'
# IQMs (0.25 and 0.5); the planners' 9 runs, mean 6.8/9 and IQM 0.76.
LEARNER_SUCCESS = {
    ("fig5_discrete", "random"): [0.1, 0.2, 0.3, 0.9],
    ("fig5_discrete", "dijkstra"): [0.7, 0.7, 0.7, 0.7],
    ("fig5_discrete", "centralized"): [1.0, 1.0, 1.0, 1.0],
    ("fig5_continuous", "random"): [0.0, 0.4, 0.5, 0.6, 1.0],
    ("fig5_continuous", "prm"): [0.8, 0.8, 0.8, 0.8, 0.8],
    ("fig5_continuous", "centralized"): [0.5, 0.5, 0.5, 0.5, 0.5],
}
RANDOM_RUNS = [0.1, 0.2, 0.3, 0.9, 0.0, 0.4, 0.5, 0.6, 1.0]
# The plane's PRM runs with every agent shaped (Fig. 6's setting): a second planner condition in the plane's panel,
# at no rank of the grid's; with naive rank matching it would pool with the grid's centralized learner.
ALL_SHAPED_PRM = [0.0, 0.0, 0.0, 0.0, 0.0]


def outcomes(opponent: str, learner: float) -> dict[str, float]:
    """summary.json's keys: the learner (``ego``, or ``agent0`` when centralized) at ``learner``, the other agent
    always failing, so that a row reading the wrong agent shows."""
    agents = {"agent0": learner, "agent1": 0.0}
    if opponent != "centralized":
        agents.update({"ego": learner, "other": 0.0})
    final = {"team/success_rate": 0.0}
    for agent, success in agents.items():
        final.update({f"{agent}/success_rate": success, f"{agent}/collision_rate": 1.0 - success})
    return final


def write_run(folder: Path, cfg, final: dict[str, float], iterations: int = 4) -> None:
    """A run folder as runners/main.py writes it: evaluations at iterations 2 and 4 rising to ``final``."""
    folder.mkdir(parents=True)
    OmegaConf.save(cfg, folder / "config.yaml", resolve=True)
    rows = [
        {"iteration": i, "frames": i * 128, "time_s": 0.1 * i}
        | ({f"eval/{k}": v * i / iterations for k, v in final.items()} if i % 2 == 0 else {})
        for i in range(1, iterations + 1)
    ]
    pd.DataFrame(rows).to_csv(folder / "metrics.csv", index=False)
    summary = {
        **final,
        "seed": cfg.seed,
        "iterations": iterations,
        "frames": iterations * 128,
        "wall_clock_s": 1.0,
    }
    (folder / "summary.json").write_text(json.dumps(summary))


def write_preset(
    root: Path, preset: str, opponent: str, values: list[float], extra: tuple[str, ...] = ()
) -> None:
    (root / preset).mkdir(parents=True, exist_ok=True)
    (root / preset / "multirun.yaml").write_text("# a sweep folder\n")
    composed = compose(config_name="config", overrides=[f"+experiment={preset}", f"opponent={opponent}", *extra])
    for seed, value in enumerate(values):
        cfg = composed.copy()
        cfg.seed = seed  # what the override seed=N sets: one composition serves every seed
        name = f"{opponent}{'_'.join(('',) + extra)},seed={seed}".replace("=", "-")
        write_run(root / preset / name, cfg, outcomes(opponent, value))


@pytest.fixture(scope="module")
def fig5_runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("aggregates")
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        for (preset, opponent), values in LEARNER_SUCCESS.items():
            write_preset(root, preset, opponent, values)
        write_preset(root, "fig5_continuous", "prm", ALL_SHAPED_PRM, ("reward.shaped_agents=null",))
    return root


@pytest.fixture(scope="module")
def fig5_report(fig5_runs, tmp_path_factory):
    return write_report([fig5_runs], tmp_path_factory.mktemp("report"), SETTINGS)


def fig5_section(report: str) -> str:
    return report.split("### Fig. 5")[1].split("### Fig. 6")[0]


def table_rows(section: str, header: str) -> list[list[str]]:
    """The cells of each row of the table of ``section`` whose header line starts with ``header``."""
    lines = section.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


def aggregate_rows(report: str) -> dict[str, list[str]]:
    """The aggregate table's rows under Fig. 5, cells by the setting's label."""
    return {cells[0]: cells for cells in table_rows(fig5_section(report), "| setting |")}


def stratified(grid: list[float], plane: list[float]) -> np.ndarray:
    """A setting's (runs, tasks) scores: the grid's runs and the plane's, the shorter column padded with NaN."""
    scores = np.full((max(len(grid), len(plane)), 2), np.nan)
    scores[: len(grid), 0], scores[: len(plane), 1] = grid, plane
    return scores


# Fig. 5's settings as the aggregate pools them: random, the planners (without the all-shaped PRM), centralized.
FIG5_SETTINGS = {
    "random": stratified(RANDOM_RUNS[:4], RANDOM_RUNS[4:]),
    "dijkstra / prm, shaped [0]": stratified([0.7] * 4, [0.8] * 5),
    "centralized": stratified([1.0] * 4, [0.5] * 5),
}


def test_the_aggregate_pools_the_runs_at_one_rank_of_every_panel(fig5_report):
    ids = {c.label: c.ident for c in fig5_report.conditions}
    table = aggregate_rows(fig5_report.report_md.read_text())
    assert list(table) == ["random", "dijkstra / prm, shaped [0]", "centralized"]
    random_row = table["random"]
    assert random_row[1] == f"{ids['discrete: DQN vs random']}, {ids['continuous: TRPO vs random']}"
    assert random_row[2:6] == ["ego", "success_rate", "2", "9"]
    assert random_row[6].startswith("0.444 ± ") and random_row[7].startswith("0.400 [")
    planner = table["dijkstra / prm, shaped [0]"]
    assert planner[6].startswith("0.756 ± ") and planner[7].startswith(
        "0.760 ["
    )  # the all-shaped PRM runs are not in it
    centralized = table["centralized"]
    assert centralized[2] == "agent0" and centralized[5] == "9"
    assert centralized[6].startswith(
        "0.722 ± "
    )  # (4 × 1.0 + 5 × 0.5) / 9: the centralized learners, not the PRM's


def test_a_condition_at_a_rank_not_every_panel_has_is_left_out_and_named(fig5_report):
    left_out = next(c for c in fig5_report.conditions if "all shaped" in c.label and c.opponent == "prm")
    section = fig5_section(fig5_report.report_md.read_text())
    line = next(line for line in section.splitlines() if line.startswith("Not at their rank in every panel"))
    assert f"{left_out.ident} ({left_out.label})" in line
    assert "all shaped" not in "".join(aggregate_rows(fig5_report.report_md.read_text()))


def test_report_csv_carries_the_aggregate_numbers(fig5_report):
    numbers = pd.read_csv(fig5_report.out / "report.csv")
    rows = numbers[(numbers.section == f"{FIG5}/aggregate") & (numbers.condition == "random")]
    by_statistic = dict(zip(rows.statistic, rows.value))
    gap_statistics = {"optimality_gap", "optimality_gap_ci_low", "optimality_gap_ci_high"}
    assert set(by_statistic) == {"tasks", "mean", "se", "iqm", "ci_low", "ci_high", *gap_statistics}
    assert (by_statistic["tasks"], by_statistic["mean"], by_statistic["iqm"]) == (
        2,
        pytest.approx(4 / 9),
        0.4,
    )
    assert by_statistic["se"] == pytest.approx(np.std(RANDOM_RUNS, ddof=1) / 3)
    # The CI is the stratified bootstrap of the two panels' runs (4 and 5), at the report's settings.
    scores = FIG5_SETTINGS["random"]
    interval = interval_estimate(scores, "iqm", n_resamples=SETTINGS.n_resamples, seed=SETTINGS.seed)
    assert (by_statistic["ci_low"], by_statistic["ci_high"]) == (
        pytest.approx(interval.low),
        pytest.approx(interval.high),
    )
    # The optimality gap: every run's shortfall below 1, 0.9 + 0.8 + 0.7 + 0.1 + 1.0 + 0.6 + 0.5 + 0.4 + 0.0 over 9.
    gap = interval_estimate(scores, "optimality_gap", n_resamples=SETTINGS.n_resamples, seed=SETTINGS.seed)
    assert by_statistic["optimality_gap"] == pytest.approx(5.0 / 9)
    assert (by_statistic["optimality_gap_ci_low"], by_statistic["optimality_gap_ci_high"]) == (
        pytest.approx(gap.low),
        pytest.approx(gap.high),
    )
    assert (
        set(rows.seeds) == {9}
        and set(rows.agent) == {"ego"}
        and rows.condition_id.str.contains(r"^C\d+\+C\d+$").all()
    )
    collisions = numbers[
        (numbers.section == "fig7_collisions_by_opponent/aggregate") & (numbers.statistic == "mean")
    ]
    assert dict(zip(collisions.condition, collisions.value))["random"] == pytest.approx(
        1 - 4 / 9
    )  # Fig. 7 too


def test_fig5_s_performance_profile_is_drawn_embedded_and_its_points_recorded(fig5_report):
    assert "fig5_performance_profile.png" in {path.name for path in fig5_report.figures}
    assert (fig5_report.out / "figures" / "fig5_performance_profile.png").stat().st_size > 10_000
    assert "](figures/fig5_performance_profile.png)" in fig5_section(fig5_report.report_md.read_text())
    curves = pd.read_csv(fig5_report.out / "curves.csv")
    profile = curves[curves.figure == "fig5_performance_profile"]
    assert len(profile) == 3 * 101 and set(profile.x_axis) == {"tau"}
    assert not curves.figure.str.contains("fig7_performance").any()  # only the figure that compares learners
    random_row = profile[profile.condition == "random"].set_index("x")
    # Strictly above: at τ = 0 the run scoring 0.0 does not count, at τ = 0.5 only 0.6, 0.9 and 1.0 do.
    assert random_row.loc[0.0, "mean"] == pytest.approx(8 / 9) and random_row.loc[
        0.5, "mean"
    ] == pytest.approx(3 / 9)
    assert random_row.loc[1.0, "mean"] == 0.0 and (random_row.seeds == 9).all()
    assert (random_row.ci_low <= random_row["mean"] + 1e-12).all() and (
        random_row["mean"] <= random_row.ci_high + 1e-12
    ).all()
    assert random_row.loc[0.5, "ci_low"] < random_row.loc[0.5, "ci_high"]
    planner = profile[profile.condition.str.startswith("dijkstra")].set_index("x")
    assert planner.loc[0.75, "mean"] == pytest.approx(5 / 9)  # the 5 PRM runs at 0.8, not the grid's 0.7
    assert curves[curves.figure == FIG5].ci_low.isna().all()  # mean ± SE curves have no bootstrap band


def test_a_figure_of_one_panel_is_aggregated_over_its_one_task(fig5_runs, tmp_path):
    result = write_report([fig5_runs / "fig5_discrete"], tmp_path / "out", SETTINGS)
    table = aggregate_rows(result.report_md.read_text())
    assert list(table) == ["random", "dijkstra", "centralized"]
    assert table["random"][4:6] == ["1", "4"]
    assert "Not at their rank" not in fig5_section(result.report_md.read_text())
    numbers = pd.read_csv(result.out / "report.csv")
    own = numbers[
        (numbers.section == FIG5) & (numbers.agent == "ego") & numbers.condition.str.contains("random")
    ]
    pooled = numbers[(numbers.section == f"{FIG5}/aggregate") & (numbers.condition == "random")]
    # One task: the aggregate is the condition's own final value, to the last bit (the same bootstrap and seed).
    by_statistic = dict(zip(pooled.statistic, pooled.value))
    gap = {name: by_statistic.pop(name) for name in list(by_statistic) if name.startswith("optimality_gap")}
    assert by_statistic == {"tasks": 1, **dict(zip(own.statistic, own.value))}
    assert gap["optimality_gap"] == pytest.approx(1 - 0.375)  # the grid's random runs: 0.1, 0.2, 0.3, 0.9
    assert dict(zip(own.statistic, own.value))["iqm"] == pytest.approx(0.25)  # 0.1 and 0.9 trimmed
    assert (result.out / "figures" / "fig5_performance_profile.png").exists()


def test_the_aggregate_table_shows_each_setting_s_optimality_gap(fig5_report):
    section = fig5_section(fig5_report.report_md.read_text())
    assert next(line for line in section.splitlines() if line.startswith("| setting |")).endswith(
        "| IQM [95% CI] | optimality gap [95% CI] |"
    )
    table = aggregate_rows(fig5_report.report_md.read_text())
    # Shortfalls below 1: random 5/9; the planners (4 × 0.3 + 5 × 0.2) / 9; centralized (4 × 0 + 5 × 0.5) / 9.
    for label, gap in (("random", 5 / 9), ("dijkstra / prm, shaped [0]", 2.2 / 9), ("centralized", 2.5 / 9)):
        interval = interval_estimate(
            FIG5_SETTINGS[label], "optimality_gap", n_resamples=SETTINGS.n_resamples, seed=SETTINGS.seed
        )
        assert table[label][8] == f"{gap:.3f} [{interval.low:.3f}, {interval.high:.3f}]"
    assert "mean shortfall of final success_rate below 1" in section
    # Fig. 7's collision rate is better low: no gap to 1 to show.
    fig7 = fig5_report.report_md.read_text().split("### Fig. 7")[1].split("### Fig. 8")[0]
    assert "optimality gap" not in fig7 and "| setting |" in fig7


def test_every_pair_of_settings_gets_its_probability_of_improvement_once(fig5_report):
    section = fig5_section(fig5_report.report_md.read_text())
    rows = table_rows(section, "| A | B | P(A > B) [95% CI] |")
    planner = "dijkstra / prm, shaped [0]"
    # Pairs won over pairs per panel, averaged over the two panels: random's 0.9 beats the grid's four 0.7s (4 of
    # 16) and its 1.0 the plane's five 0.8s (5 of 25); against centralized, nothing beats 1.0 in the grid, and in the
    # plane 0.6 and 1.0 beat five 0.5s and 0.5 ties them (12.5 of 25); the planners lose the grid, win the plane.
    expected = {
        ("random", planner): (0.25 + 0.2) / 2,
        ("random", "centralized"): (0.0 + 0.5) / 2,
        (planner, "centralized"): (0.0 + 1.0) / 2,
    }
    assert [(row[0], row[1]) for row in rows] == list(expected)  # each pair once (P(B > A) = 1 − P(A > B))
    numbers = pd.read_csv(fig5_report.out / "report.csv")
    logged = numbers[numbers.section == f"{FIG5}/probability_of_improvement"]
    tested = holm_adjusted([
        probability_of_improvement(FIG5_SETTINGS[a], FIG5_SETTINGS[b], n_resamples=SETTINGS.n_resamples,
                                   seed=SETTINGS.seed)
        for a, b in expected
    ])
    for (a, b, cell, words), interval in zip(rows, tested):
        assert cell == f"{expected[a, b]:.3f} [{interval.low:.3f}, {interval.high:.3f}]"
        assert words == separation_text(interval, 0.5) and words.endswith("; Holm over 3)")
        row = logged[logged.condition == f"{a} > {b}"]
        values = dict(zip(row.statistic, row.value))
        assert values["probability_of_improvement"] == pytest.approx(expected[a, b])
        assert (
            values["probability_of_improvement_ci_low"],
            values["probability_of_improvement_ci_high"],
        ) == (
            pytest.approx(interval.low),
            pytest.approx(interval.high),
        )
        assert set(row.note) == {f"{words}; {interval.note}"} and set(row.seeds) == {18}  # few runs: said
    # 4 and 5 runs a panel: random's interval against centralized excludes 0.5, but the stratified test of the runs
    # does not separate them (p ≈ 0.06 alone, 0.12 in the family of three); the planners and centralized split the
    # panels, P = 0.5 in every resample.
    verdicts = {(row[0], row[1]): row[3] for row in rows}
    assert tested[1].high < 0.5 and verdicts["random", "centralized"].startswith("does not separate at 95% (p 0.12")
    assert all(words.startswith("does not separate at 95%") for words in verdicts.values())


def test_panels_of_different_numbers_of_noise_levels_match_only_their_lowest_and_highest():
    # The reference's Fig. 6: the grid and the 5000-iteration plane compare three noise levels, the 500-iteration
    # plane panels two. Matched by rank, the plane's ε = 1.5 at 500 iterations would pool with the grid's n = 0.1;
    # only each panel's lowest and highest are matched, and the middle levels are left out, named.
    conditions = group_conditions(
        [load_run(folder) for folder in find_run_folders([ROOT / "results/reference/runs/seeds0-4"])]
    )
    spec = next(figure for figure in PAPER_FIGURES if figure.name == "fig6_success_under_noise")
    compared, left_out = compared_settings(spec, figure_panels(spec, conditions))
    noise = [sorted({str(c.flat.get("noise")) for c in setting.conditions}) for setting in compared]
    assert noise == [["0.0", "0.01", "0.5"], ["0.2", "1.5"]]
    assert sorted(str(c.flat.get("noise")) for c in left_out) == ["0.1", "0.5"]  # the grid's and the 5000 plane's middles
