"""The reporting tools: statistics against hand-computed values, reports on synthetic and real run folders, broken run
folders reported and skipped, renders, and the experiment presets composing into valid sweeps."""

from __future__ import annotations

import functools
import itertools
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.stats
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, OmegaConf

from sidewalk.compose import compose as compose_project
from sidewalk.config import validate
from sidewalk.envs.base import INFO_KEYS
from sidewalk.report.claims import TIE, above_zero, below_zero, check_claims
from sidewalk.report.conditions import condition_config, group_conditions
from sidewalk.report.document import write_report
from sidewalk.report.runs import RunFolderError, find_run_folders, load_run
from sidewalk.report.tables import Settings
from sidewalk.schema import register_schemas
from sidewalk.stats import difference_interval, interval_estimate, iqm, mean_se

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
register_schemas()

PRESETS = (
    "fig5_discrete",
    "fig5_continuous",
    "fig6_discrete",
    "fig6_continuous",
    "fig7_discrete",
    "fig7_continuous",
    "fig8",
)
# The paper's set-ups (§6): what each preset must sweep, on what, for how long.
EXPECTED = {
    "fig5_discrete": ("discrete", "dqn", 5000, {"opponent": "random,dijkstra,centralized"}),
    "fig5_continuous": ("continuous", "trpo", 5000, {"opponent": "random,prm,centralized"}),
    "fig6_discrete": ("discrete", "dqn", 2000, {"noise": "0.0,0.1,0.2"}),
    "fig6_continuous": ("continuous", "trpo", 5000, {"noise": "0.01,0.5,1.5"}),
    "fig7_discrete": ("discrete", "dqn", 5000, {"opponent": "random,dijkstra,centralized"}),
    "fig7_continuous": ("continuous", "trpo", 5000, {"opponent": "random,prm,centralized"}),
    "fig8": ("continuous", "trpo", 5000, {"reward": "explicit,implicit"}),
}
TINY_SWEEP = [
    "-m",
    "seed=0,1",
    "num_envs=4",
    "iterations=4",
    "eval_every=2",
    "eval_episodes=8",
    "algo.frames_per_batch=16",
    "algo.batch_size=16",
    "algo.learning_starts=0",
    "logger=none",
]


# ---- statistics ---------------------------------------------------------------------------------------------------


def test_mean_and_standard_error_match_hand_computed_values():
    mean, se, n = mean_se([0.2, 0.4, 0.6])
    assert (float(mean), int(n)) == (pytest.approx(0.4), 3)
    assert float(se) == pytest.approx(0.2 / math.sqrt(3))  # std(ddof=1) = 0.2
    # Per x across seeds (axis 1), NaN where a seed did not evaluate; one value has no standard error.
    mean, se, n = mean_se([[1.0, 3.0], [2.0, np.nan]], axis=1)
    assert mean.tolist() == [2.0, 2.0] and n.tolist() == [2, 1]
    assert se[0] == pytest.approx(1.0) and np.isnan(se[1])


def test_iqm_is_the_25_percent_trimmed_mean_of_all_scores():
    scores = np.array(
        [[0.0, 10.0], [1.0, 2.0], [3.0, 4.0], [5.0, 100.0]]
    )  # 8 scores; the 2 lowest and 2 highest go
    assert iqm(scores) == pytest.approx(np.mean([2.0, 3.0, 4.0, 5.0]))
    assert iqm([0.2, 0.4, 0.9]) == pytest.approx(0.5)  # fewer than 4 scores: nothing trimmed
    metrics = pytest.importorskip("rliable.metrics")
    assert iqm(scores) == pytest.approx(metrics.aggregate_iqm(scores))


def test_interval_is_the_stratified_percentile_bootstrap_of_scipy():
    rng = np.random.default_rng(1)
    scores = np.stack([rng.normal(0.3, 0.1, 6), rng.normal(0.8, 0.05, 6)], axis=1)  # 6 runs × 2 tasks
    got = interval_estimate(scores, "mean", n_resamples=2000, seed=7)
    # The same resampling done by hand: each task's runs resampled on their own, the mean of everything.
    expected = scipy.stats.bootstrap(
        (scores[:, 0], scores[:, 1]),
        lambda a, b, axis: np.concatenate([a, b], axis=axis).mean(axis=axis),
        n_resamples=2000,
        method="percentile",
        paired=False,
        vectorized=True,
        rng=np.random.default_rng(7),
    ).confidence_interval
    assert (got.low, got.high) == (pytest.approx(expected.low), pytest.approx(expected.high))
    assert got.point == pytest.approx(scores.mean())
    assert interval_estimate(scores, "mean", n_resamples=2000, seed=7) == got  # a seed fixes the interval


def test_interval_covers_the_true_mean_and_shrinks_with_more_runs():
    rng = np.random.default_rng(0)
    widths = []
    for runs in (5, 50, 500):
        interval = interval_estimate(rng.normal(0.5, 0.2, runs), "mean", n_resamples=2000)
        assert interval.low < 0.5 < interval.high
        widths.append(interval.high - interval.low)
    assert widths[0] > widths[1] > widths[2]
    assert widths[1] / widths[2] == pytest.approx(math.sqrt(10), rel=0.35)  # width ∝ 1/√n


def test_one_run_has_no_interval_and_two_runs_a_coarse_one():
    one = interval_estimate([0.7])
    assert one.point == 0.7 and math.isnan(one.low) and math.isnan(one.high) and "1 run" in one.note
    two = interval_estimate([0.2, 0.6], "mean", n_resamples=1000)
    assert 0.2 <= two.low <= two.high <= 0.6 and "coarse" in two.note
    same = interval_estimate([1.0, 1.0, 1.0])
    assert (same.point, same.low, same.high) == (1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="statistic='mode'"):
        interval_estimate([1.0, 2.0], "mode")
    with pytest.raises(ValueError, match="confidence=1.5"):
        interval_estimate([1.0, 2.0], confidence=1.5)


# ---- synthetic run folders ------------------------------------------------------------------------------------------


def write_run(folder: Path, cfg, final: dict[str, float], iterations: int = 10) -> None:
    """A run folder as runners/main.py writes it, with made-up numbers: evaluations at iterations 5 and 10 and the
    training success of every iteration rising linearly to ``final``."""
    folder.mkdir(parents=True)
    OmegaConf.save(cfg, folder / "config.yaml", resolve=True)
    rows = []
    for iteration in range(1, iterations + 1):
        row = {
            "iteration": iteration,
            "frames": iteration * 128,
            "time_s": 0.1 * iteration,
            "frames_per_s": 1280.0,
            "train/loss": 1.0 / iteration,
        }
        # The training success curves rise linearly to the final values, as the evaluations do.
        row.update({f"train/{agent}_success_rate": final[f"{agent}/success_rate"] * iteration / iterations
                    for agent in ("ego", "team") if f"{agent}/success_rate" in final})
        if iteration % 5 == 0:
            row.update({f"eval/{k}": v * iteration / iterations for k, v in final.items()})
        rows.append(row)
    pd.DataFrame(rows).to_csv(folder / "metrics.csv", index=False)
    summary = {
        **final,
        "seed": cfg.seed,
        "iterations": iterations,
        "frames": iterations * 128,
        "wall_clock_s": 1.0,
    }
    (folder / "summary.json").write_text(json.dumps(summary))


def outcomes(cfg, value: float) -> dict[str, float]:
    """Summary metrics of both agents: the learner's success ``value``, the other's ``1 - value``."""
    agents = {"agent0": value, "agent1": 1.0 - value}
    if cfg.opponent.name != "centralized":
        agents.update({"ego": value, "other": 1.0 - value})
    final = {"team/success_rate": value * (1.0 - value)}
    for agent, success in agents.items():
        final.update({f"{agent}/success_rate": success, f"{agent}/collision_rate": 1.0 - success})
    return final


@functools.cache
def job_config(preset: str, key: str, value: str, seed: int) -> DictConfig:
    """The config of one job of a preset's sweep, composed once for the module (the slow part of a synthetic run)."""
    return compose_project([f"+experiment={preset}", f"{key}={value}", f"seed={seed}"])


def write_sweep(root: Path, preset: str, sweep: dict[str, list[str]], seeds: list[int]) -> None:
    """Synthetic runs of a preset's sweep, configs composed from the real preset; the learner's final success is
    0.2 + 0.2 · seed."""
    (root / preset).mkdir(parents=True)
    (root / preset / "multirun.yaml").write_text("# a sweep folder\n")
    key, values = next(iter(sweep.items()))
    for job, (value, seed) in enumerate(itertools.product(values, seeds)):
        cfg = job_config(preset, key, value, seed)
        write_run(root / preset / f"{job}_{key}={value},seed={seed}", cfg, outcomes(cfg, 0.2 + 0.2 * seed))


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synthetic")
    write_sweep(root, "fig5_discrete", {"opponent": ["random", "dijkstra", "centralized"]}, [0, 1, 2])
    write_sweep(root, "fig5_continuous", {"opponent": ["random", "prm", "centralized"]}, [0, 1])
    write_sweep(root, "fig6_discrete", {"noise": ["0.0", "0.1", "0.2"]}, [0, 1])
    write_sweep(root, "fig8", {"reward": ["explicit", "implicit"]}, [0, 1])
    return root


def test_report_on_synthetic_runs_draws_every_figure(synthetic, tmp_path):
    result = write_report([synthetic], tmp_path / "out", Settings(n_resamples=2000))
    names = {path.name for path in result.figures}
    assert {
        "fig5_success_by_opponent.png",
        "fig6_success_under_noise.png",
        "fig7_collisions_by_opponent.png",
        "fig8_explicit_vs_implicit.png",
    } <= names
    assert {f"curves_{p}.png" for p in ("fig5_discrete", "fig5_continuous", "fig6_discrete", "fig8")} <= names
    for path in result.figures:
        assert path.stat().st_size > 10_000
    report = result.report_md.read_text()
    for name in names:
        assert f"](figures/{name})" in report  # embedded by relative path
    assert (
        "Fig. 10" in report and "no run with a loadable policy.pt or checkpoint.pt" in report
    )  # no checkpoints: skipped
    assert result.skipped == []
    # 3 + 3 + 3 + 2 conditions; the grid Dijkstra runs of Fig. 5 (5000 iterations) and Fig. 6 (2000) stay apart.
    assert len(result.conditions) == 11

    numbers = pd.read_csv(result.out / "report.csv")
    fig5 = numbers[
        (numbers.section == "fig5_success_by_opponent")
        & (numbers.agent == "ego")
        & numbers.condition.str.contains("discrete: DQN vs random")
    ]
    by_statistic = dict(zip(fig5.statistic, fig5.value))
    assert by_statistic["mean"] == pytest.approx(0.4)  # seeds 0, 1, 2: 0.2, 0.4, 0.6
    assert by_statistic["se"] == pytest.approx(0.2 / math.sqrt(3))
    assert by_statistic["iqm"] == pytest.approx(0.4)
    assert 0.2 - 1e-9 <= by_statistic["ci_low"] < 0.4 < by_statistic["ci_high"] <= 0.6 + 1e-9
    assert "0.400 ± 0.115" in report
    curves = pd.read_csv(result.out / "curves.csv")
    point = curves[
        (curves.figure == "fig5_success_by_opponent")
        & (curves.agent == "ego")
        & (curves.x == 1280)
        & curves.condition.str.contains("discrete: DQN vs random")
    ]
    assert point["mean"].item() == pytest.approx(0.4) and point["seeds"].item() == 3


def test_every_sidewalk_runs_deadlock_rate_is_reported_where_its_runs_record_it(tmp_path):
    """The greedy pair's standoffs are a first-class result: a self-play condition gets its team's deadlock rate
    beside team success; runs made before the metric existed get no row of NaN."""
    for recorded_it in (True, False):
        root = tmp_path / f"recorded_{recorded_it}"
        for seed in (0, 1):
            cfg = job_config("selfplay_discrete", "algo", "iql", seed)
            final = {"team/success_rate": 0.9 - 0.2 * seed, "agent0/success_rate": 0.9, "agent1/success_rate": 0.9}
            if recorded_it:
                final["deadlock_rate"] = 0.1 + 0.2 * seed
            write_run(root / "selfplay" / f"{seed}_algo=iql,seed={seed}", cfg, final)
        result = write_report([root], tmp_path / f"out_{recorded_it}", Settings(n_resamples=200))
        numbers = pd.read_csv(result.out / "report.csv")
        deadlock = numbers[(numbers.metric == "deadlock_rate") & (numbers.statistic == "mean")]
        if recorded_it:
            assert deadlock.value.tolist() == [pytest.approx(0.2)]  # seeds 0 and 1: 0.1, 0.3
        else:
            assert deadlock.empty


def test_runs_of_two_seeds_get_coarse_intervals_and_centralized_runs_per_agent_rows(synthetic, tmp_path):
    result = write_report([synthetic / "fig5_continuous"], tmp_path / "out", Settings(n_resamples=500))
    report = result.report_md.read_text()
    assert "(coarse)" in report
    assert "agent 0 shaped" in report and "agent 1 unshaped" in report  # reward.shaped_agents=[0]
    assert "TRPO (ego)" in report and "prm (other)" in report


def test_broken_run_folders_are_reported_and_skipped(synthetic, tmp_path):
    sweep = tmp_path / "sweep"
    good = sorted((synthetic / "fig8").glob("*reward=explicit*"))
    for folder in good:
        shutil.copytree(folder, sweep / folder.name)
    template = good[0]

    def broken(name: str, drop: tuple[str, ...] = ()) -> Path:
        folder = sweep / name
        shutil.copytree(template, folder)
        for file in drop:
            (folder / file).unlink()
        return folder

    broken("no_metrics", ("metrics.csv",))
    (broken("empty_metrics") / "metrics.csv").write_text("")
    text = (template / "metrics.csv").read_text()
    (broken("truncated_metrics") / "metrics.csv").write_text(text[: len(text) - 7])
    (broken("header_only") / "metrics.csv").write_text(text.splitlines()[0] + "\n")
    broken("no_summary", ("summary.json",))
    (broken("bad_json") / "summary.json").write_text('{"ego/success_rate": 0.5,')
    (broken("failed_job", ("summary.json",)) / "error.txt").write_text(
        "Traceback...\nRuntimeError: out of memory\n"
    )
    summary = json.loads((template / "summary.json").read_text())
    (broken("mismatch") / "summary.json").write_text(json.dumps({**summary, "iterations": 99}))
    (sweep / "killed_at_start" / ".hydra").mkdir(parents=True)

    reasons = {
        "no_metrics": "no metrics.csv",
        "empty_metrics": "metrics.csv is empty",
        "truncated_metrics": "truncated",
        "header_only": "no rows",
        "no_summary": "no summary.json",
        "bad_json": "summary.json is unreadable",
        "failed_job": "out of memory",
        "mismatch": "iteration 99",
        "killed_at_start": "no config.yaml",
    }
    for name, reason in reasons.items():
        with pytest.raises(RunFolderError, match=reason):
            load_run(sweep / name)
    assert len(find_run_folders([sweep])) == len(good) + len(reasons)

    result = write_report([sweep], tmp_path / "out", Settings(n_resamples=500))
    assert {item.path.name for item in result.skipped} == set(reasons)
    assert len(result.conditions) == 1 and len(result.conditions[0].runs) == len(good)
    report = result.report_md.read_text()
    for name, reason in reasons.items():
        line = next(line for line in report.splitlines() if f"/{name}`" in line)
        assert reason in line


# ---- the paper's claims ----------------------------------------------------------------------------------------------


def claim_runs(root: Path, preset: str, key: str, outcomes_by_value: dict, iterations_by_value=None) -> None:
    """Eight seeds of a preset's runs for each ``key`` value, with that value's summary metrics (equal across seeds)
    and evaluations rising linearly to them over ``iterations_by_value`` (default 10) iterations. Eight: enough that
    the exact tests separate at 95 % after a Holm adjustment over the table's few comparisons (the sign-flip test of
    two agents of the same runs allows p = 2/2^n at best: 0.0625 at 5 seeds)."""
    (root / preset).mkdir(parents=True)
    (root / preset / "multirun.yaml").write_text("# a sweep folder\n")
    for job, (value, seed) in enumerate(itertools.product(outcomes_by_value, range(8))):
        cfg = job_config(preset, key, value, seed)
        iterations = (iterations_by_value or {}).get(value, 10)
        write_run(root / preset / f"{job}_{key}={value},seed={seed}", cfg, outcomes_by_value[value], iterations)


def verdicts(root: Path) -> dict[str, str]:
    conditions = group_conditions([load_run(folder) for folder in find_run_folders([root])])
    return {v.claim: v.verdict for v in check_claims(conditions)}


def agents(**values: float) -> dict[str, float]:
    """Summary metrics from keyword names such as ego_success=0.9 -> {"ego/success_rate": 0.9}."""
    names = {"success": "success_rate", "collision": "collision_rate", "path": "path_efficiency"}
    return {f"{k.split('_')[0]}/{names[k.split('_')[1]]}": v for k, v in values.items()}


GRID_AS_IN_THE_PAPER = {
    "random": agents(ego_success=0.9, ego_collision=0.05, other_success=0.1),
    "dijkstra": agents(ego_success=1.0, ego_path=1.0, other_success=1.0, other_path=0.875),
    "centralized": agents(agent0_success=1.0, agent1_success=1.0, team_success=1.0),
}


def test_claims_of_the_grid_comparison_hold_when_the_runs_show_them(tmp_path):
    # The centralized learner evaluates for 20 iterations: its curve reaches 90 % of its final value later.
    claim_runs(tmp_path, "fig5_discrete", "opponent", GRID_AS_IN_THE_PAPER, {"centralized": 20})
    got = verdicts(tmp_path)
    assert got["DQN learns to avoid the random agent and reach its goal (discrete)"] == "reproduced"
    assert (
        got["against Dijkstra the DQN agent heads straight and the Dijkstra agent yields (discrete)"]
        == "reproduced"
    )
    assert got["centralized learns the most robust policy but needs more training (discrete)"] == "reproduced"
    # Claims of runs that were not made are listed as such, with the command that makes them.
    not_run = [claim for claim, verdict in got.items() if verdict == "not run"]
    assert "centralized learns the most robust policy but needs more training (continuous)" in not_run
    assert "more noise, lower success (discrete)" in not_run and len(not_run) == 5


def test_claims_of_the_grid_comparison_fail_when_the_runs_do_not_show_them(tmp_path):
    claim_runs(
        tmp_path,
        "fig5_discrete",
        "opponent",
        {
            "random": agents(ego_success=0.1, ego_collision=0.9, other_success=0.1),  # first evaluation 0.05
            "dijkstra": agents(
                ego_success=1.0, ego_path=0.8, other_success=1.0, other_path=1.0
            ),  # the ego yields
            "centralized": agents(agent0_success=0.5, agent1_success=1.0, team_success=0.5),
        },
    )
    got = verdicts(tmp_path)
    assert got["DQN learns to avoid the random agent and reach its goal (discrete)"] == "not reproduced"
    # The ego reaches its goal but not straight; the Dijkstra agent succeeds without yielding: neither half holds.
    assert (
        got["against Dijkstra the DQN agent heads straight and the Dijkstra agent yields (discrete)"]
        == "not reproduced"
    )
    assert (
        got["centralized learns the most robust policy but needs more training (discrete)"]
        == "not reproduced"
    )


def noise_reward_and_centralized_verdicts(root: Path, noise, rewards, random, centralized) -> dict[str, str]:
    """Verdicts on grid runs with ego success ``noise`` at n = 0, 0.1, 0.2, continuous runs with ego success
    ``rewards`` (explicit, implicit) and ``random`` against the random agent, and a centralized run's ``centralized``."""
    levels = dict(zip(("0.0", "0.1", "0.2"), noise))
    claim_runs(root, "fig6_discrete", "noise", {n: agents(ego_success=v) for n, v in levels.items()})
    claim_runs(
        root, "fig8", "reward", {r: agents(ego_success=v) for r, v in zip(("explicit", "implicit"), rewards)}
    )
    claim_runs(
        root,
        "fig5_continuous",
        "opponent",
        {"random": agents(ego_success=random), "centralized": centralized},
    )
    return verdicts(root)


def test_claims_of_noise_reward_and_the_unshaped_agent(tmp_path):
    steps_aside = agents(agent0_success=0.9, agent1_success=0.0, agent1_collision=0.0, team_success=0.0)
    got = noise_reward_and_centralized_verdicts(tmp_path / "a", (0.9, 0.7, 0.5), (0.8, 0.4), 0.3, steps_aside)
    assert got["more noise, lower success (discrete)"] == "reproduced"
    assert got["explicit cooperative reward learns better than implicit (continuous)"] == "reproduced"
    unshaped = "centralized with shaping on one agent: the unshaped agent gets out of the way and never reaches its goal"
    assert got[f"{unshaped} (continuous)"] == "reproduced"

    both_crash = agents(agent0_success=0.0, agent1_success=0.0, agent1_collision=1.0, team_success=0.0)
    got = noise_reward_and_centralized_verdicts(tmp_path / "b", (0.5, 0.9, 0.5), (0.4, 0.8), 0.0, both_crash)
    assert got["more noise, lower success (discrete)"] == "not reproduced"
    assert got["explicit cooperative reward learns better than implicit (continuous)"] == "not reproduced"
    # Everyone fails alike: a tie at zero is no robustness; the unshaped agent never arrives, but by crashing, as
    # does the shaped one.
    assert (
        got["centralized learns the most robust policy but needs more training (continuous)"]
        == "not reproduced"
    )
    assert got[f"{unshaped} (continuous)"] == "not reproduced"


def test_learning_speed_is_read_off_the_training_curve_seed_by_seed(tmp_path):
    # Equal final success, but explicit's training curve settles in 10 iterations and implicit's in 20.
    tied = agents(ego_success=0.8)
    claim_runs(tmp_path / "a", "fig8", "reward", {"explicit": tied, "implicit": tied}, {"implicit": 20})
    got = verdicts(tmp_path / "a")
    assert got["explicit cooperative reward learns better than implicit (continuous)"] == "reproduced"
    claim_runs(tmp_path / "b", "fig8", "reward", {"explicit": tied, "implicit": tied})
    assert verdicts(tmp_path / "b")["explicit cooperative reward learns better than implicit (continuous)"] == (
        "not reproduced")  # the same end, reached as soon
    # Faster when the exact test separates the seeds and the difference is below 0: not where the seeds overlap, nor
    # with 3 seeds a side (the smallest p is 0.1), nor with one seed.
    assert below_zero(difference_interval([900.0, 1000.0, 1100.0, 950.0], [1400.0, 1500.0, 1600.0, 1450.0]))
    assert not below_zero(difference_interval([900.0, 1000.0, 1100.0], [1400.0, 1500.0, 1600.0]))
    assert not below_zero(difference_interval([500.0, 1000.0, 1500.0], [1000.0, 1500.0, 2000.0]))
    assert not below_zero(difference_interval([1000.0], [1001.0, 1002.0])) and not below_zero(
        difference_interval([math.nan] * 3, [1.0, 2.0, 3.0])
    )
    # A separated difference smaller than TIE is still a tie.
    assert above_zero(difference_interval([0.81] * 4, [0.8] * 4)) and not above_zero(
        difference_interval([0.81] * 4, [0.8] * 4), TIE
    )


def test_report_holds_the_claims_and_places_the_preamble(tmp_path):
    claim_runs(tmp_path / "runs", "fig5_discrete", "opponent", GRID_AS_IN_THE_PAPER, {"centralized": 20})
    preamble = tmp_path / "notes.md"
    preamble.write_text("Made by `results/reference/run.sh` in 42 minutes.\n")
    result = write_report([tmp_path / "runs"], tmp_path / "out", Settings(n_resamples=200), preamble)
    report = result.report_md.read_text()
    assert (
        report.index("in 42 minutes") < report.index("## Conditions") < report.index("## The paper's claims")
    )
    row = next(
        line for line in report.splitlines() if line.startswith("| DQN learns to avoid the random agent")
    )
    assert "**reproduced**" in row and "ego success 0.90 ± 0.00" in row
    numbers = pd.read_csv(result.out / "report.csv")
    claims = numbers[numbers.section == "claims"]
    assert set(claims.metric) >= {"success_rate", "path_efficiency", "frames_to_learn"}
    # Runs that make no paper figure get one line, not a table of claims that were not run.
    alone = write_report([next((tmp_path / "runs" / "fig5_discrete").iterdir())], tmp_path / "alone")
    assert "None tested" in alone.report_md.read_text() and "**not run**" not in alone.report_md.read_text()
    with pytest.raises(FileNotFoundError, match="nope.md"):
        write_report([tmp_path / "runs"], tmp_path / "out2", preamble=tmp_path / "nope.md")


def test_report_cli_names_bad_paths_and_options(tmp_path, capsys, runner):
    report = runner("report")
    assert report.main([str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert report.main([str(tmp_path)]) == 2
    assert "no run folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        report.main([str(tmp_path), "--confidence", "1.5"])
    assert exit_info.value.code == 2 and "confidence=1.5" in capsys.readouterr().err
    failed = tmp_path / "sweep" / "0_seed=0"
    failed.mkdir(parents=True)
    (failed / "error.txt").write_text("invalid config: iterations=0 is out of range\n")
    assert report.main([str(tmp_path / "sweep")]) == 1  # a report is written, but nothing could be used
    assert "iterations=0 is out of range" in (tmp_path / "sweep" / "report" / "report.md").read_text()


# ---- a real sweep ---------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory, processes) -> Path:
    sweep = tmp_path_factory.mktemp("sweep") / "tiny"
    # A process of its own, forked after the imports (conftest.py), as `python runners/main.py ...` runs it.
    result = processes.run("runners/main.py", *TINY_SWEEP, f"hydra.sweep.dir={sweep}", timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return sweep


def test_report_on_a_real_two_seed_sweep(tiny_sweep, tmp_path, processes):
    result = processes.run("runners/report.py", str(tiny_sweep), "--out", str(tmp_path / "out"), timeout=120)
    assert result.returncode == 0, result.stderr
    assert "report: " in result.stderr and result.stdout == ""  # progress on stderr only
    figures = {p.name for p in (tmp_path / "out" / "figures").iterdir()}
    assert figures == {"curves_tiny.png", "cost_tiny.png", "fig10_trajectories_discrete.png"}
    report = (tmp_path / "out" / "report.md").read_text()
    assert "| C1 | discrete: DQN vs dijkstra | tiny | 0, 1 | 4 | 64 |" in report
    # The checkpoint replayed on the evaluation's worlds gives the evaluation's numbers back.
    assert "replayed success and collision rates match its `summary.json`" in report
    numbers = pd.read_csv(tmp_path / "out" / "report.csv")
    summaries = [json.loads(p.read_text()) for p in sorted(tiny_sweep.glob("*/summary.json"))]
    ego = numbers[
        (numbers.agent == "ego") & (numbers.metric == "success_rate") & (numbers.statistic == "mean")
    ]
    assert ego["value"].iloc[0] == pytest.approx(np.mean([s["ego/success_rate"] for s in summaries]))


def test_a_run_folder_written_before_a_key_existed_still_replays(tiny_sweep, tmp_path):
    from sidewalk.report.checkpoints import load_experiment

    run = tmp_path / "old_run"
    shutil.copytree(next(tiny_sweep.glob("0_*")), run)
    config = OmegaConf.load(run / "config.yaml")
    del config["keep_checkpoint"]  # the key came with the run-folder rules; older folders lack it
    OmegaConf.save(config, run / "config.yaml")
    experiment = load_experiment(run)
    assert experiment.keep_checkpoint == "final" and experiment.iterations == config.iterations


def test_render_a_run_and_scripted_agents(tiny_sweep, tmp_path, capsys, runner):
    render = runner("render")
    run = next(tiny_sweep.glob("0_*"))  # a sweep job folder: its name has '=' in it
    assert render.main([str(run), "--episode", "1", "--out", str(tmp_path / "run.gif")]) == 0
    assert (
        render.main(
            [
                "--env",
                "discrete",
                "--opponent",
                "dijkstra",
                "--ego",
                "random",
                "noise=0.1",
                "--out",
                str(tmp_path / "scripted.gif"),
            ]
        )
        == 0
    )
    from PIL import Image

    for name in ("run.gif", "scripted.gif"):
        with Image.open(tmp_path / name) as gif:
            assert gif.n_frames >= 2 and gif.size[0] > gif.size[1]  # the sidewalk lies along x
    capsys.readouterr()
    for args, message in (
        (["--env", "continuous", "--opponent", "dijkstra"], "does not play env=continuous"),
        (["--env", "discrete", "--opponent", "dijkstra", "--ego", "bogus"], "--ego='bogus' is not valid"),
        (["--env", "discrete", "--opponent", "dijkstra", "noise=2"], "noise=2.0 is out of range"),
        (["--env", "discrete", "--opponent", "centralized"], "render a run folder trained with it"),
        ([str(run), "--episode", "8"], "--episode=8 is out of range"),
    ):
        assert render.main(args) == 2, args
        assert message in capsys.readouterr().err, args
    for args, message in (
        ([str(tmp_path / "nowhere")], "is not a folder"),
        ([str(tmp_path)], "has no config.yaml"),
        ([str(run), "--out", str(tmp_path / "a.avi")], "must end in .gif or .mp4"),
        ([str(run), "--env", "discrete"], "not both"),
        ([], "give a run folder"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            render.main(args)
        assert exit_info.value.code == 2 and message in capsys.readouterr().err, args


# ---- presets -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("scale", ["full", "quick"])
def test_presets_compose_into_valid_sweeps(preset, scale):
    domain, algo, iterations, sweep = EXPECTED[preset]
    ((key, values),) = sweep.items()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=[f"+experiment={preset}", f"scale={scale}"],
            return_hydra_config=True,
        )
        jobs = [
            compose(
                config_name="config",
                overrides=[f"+experiment={preset}", f"scale={scale}", f"{key}={v}", "seed=1"],
            )
            for v in values.split(",")
        ]
    params = dict(cfg.hydra.sweeper.params)
    assert params == sweep  # the seeds are replicas of each job's process, not jobs of the sweep
    assert (cfg.seed, cfg.replicas) == (0, 3 if scale == "full" else 2)
    assert (cfg.env.domain, cfg.algo.name) == (domain, algo)
    assert cfg.iterations == (iterations if scale == "full" else 20)
    assert cfg.hydra.runtime.choices.experiment == preset
    validate(cfg)  # a plain run of the preset (no -m) is valid too
    # Every job of the sweep composes and validates (no opponent of the wrong domain, say).
    for value, job in zip(values.split(","), jobs):
        validate(job)
        if preset.startswith(("fig5_continuous", "fig7_continuous")):
            assert list(job.reward.shaped_agents) == [0]  # the paper's centralized run shaped agent 0 only
        if preset.endswith("continuous") or preset == "fig8":
            assert job.noise == (float(value) if key == "noise" else 0.01)


def test_a_run_from_before_a_learner_key_is_one_condition_with_todays_runs_of_its_setting():
    old = {"env.domain": "discrete", "algo.name": "dqn", "algo.lr": 0.001}
    assert condition_config(old) == condition_config({**old, "algo.advantage_learning": 0.0})
    assert condition_config(old) != condition_config({**old, "algo.advantage_learning": 0.9})
    # A learner without the key gains none.
    assert "algo.advantage_learning" not in condition_config({**old, "algo.name": "ppo"})


# ---- Fig. 10's panels ---------------------------------------------------------------------------------------------


def test_fig10_panel_titles_keep_to_their_panels(monkeypatch, tmp_path):
    """Three continuous panels abreast under the reference's longest titles: no title runs into its neighbour's."""
    from types import SimpleNamespace

    from sidewalk.report import figures

    def panel(label: str, outcomes: list[str]):
        steps, episodes = 20, len(outcomes)
        paths = np.stack(np.broadcast_arrays(np.linspace(0.3, 3.7, steps)[:, None, None], 1.5), -1)  # (T, 1, 1, 2)
        paths = np.repeat(np.repeat(paths, episodes, 1), 2, 2)  # (T, k, 2 agents, 2)
        info = {key: np.array([[outcome == key] * 2 for outcome in outcomes]) for key in INFO_KEYS}
        layout = SimpleNamespace(length_m=4.0, width_m=3.0, boxes=[], goals=[(3.7, 1.5), (0.3, 1.5)])
        replay_ = SimpleNamespace(record=SimpleNamespace(trajectories=paths, info=info, ego=0), layout=layout,
                                  domain="continuous", run=SimpleNamespace(seed=0), matches_summary=True)
        agents = [("ego", "TRPO (ego)"), ("other", "prm (other)")]
        condition = SimpleNamespace(ident="C8", label=label, agents=lambda: agents)
        return condition, replay_

    long_label = "continuous: TRPO vs prm, shaped [0], ε=0.01, explicit reward, iterations=5000"
    outcomes = ["reached_goal", "collided_wall", "collided_agent"]
    drawn = []
    monkeypatch.setattr(figures, "_save", lambda figure, path: drawn.append(figure))
    figures._trajectory_figure("Fig. 10", "continuous", [panel(long_label, outcomes)] * 3, tmp_path, [])
    (figure,) = drawn
    figure.draw_without_rendering()
    boxes = sorted((ax.title.get_window_extent() for ax in figure.axes if ax.get_visible()), key=lambda box: box.x0)
    assert len(boxes) == 3
    for left, right in itertools.pairwise(boxes):
        assert left.x1 <= right.x0, f"a title ends at {left.x1:.0f} px, its right neighbour's starts at {right.x0:.0f}"


def test_the_who_yields_table_reads_each_condition_from_its_seeds(tmp_path):
    # The committed IQL self-play runs with greedy worlds (5 seeds) and their control (1 seed), report on them.
    folders = [ROOT / "results/who-yields/greedy-worlds/iql", ROOT / "results/who-yields/greedy-worlds-control"]
    result = write_report(folders, tmp_path / "out", Settings(n_resamples=200, trajectory_episodes=0))
    section = result.report_md.read_text().split("## Who yields")[1].split("\n## ")[0]
    rows = [line for line in section.splitlines() if line.startswith("| C")]
    assert len(rows) == 2
    greedy = next(row for row in rows if "greedy_worlds=0.25" in row).split(" | ")
    summaries = [json.loads(path.read_text()) for path in sorted(folders[0].glob("seed*/summary.json"))]
    share = np.mean([summary["social/agent1_yields_first"] for summary in summaries])
    team = [summary["team/success_rate"] for summary in summaries]
    assert greedy[2] == str(len(summaries)) and greedy[4].startswith(f"{scipy.stats.trim_mean(team, 0.25):.3f} [")
    assert f"agent 1 first {share:.3f}" in greedy[6]
    salsa = [summary["social/salsa_count"] for summary in summaries]
    assert greedy[7].startswith(f"{np.mean(salsa):.3f} ± {np.std(salsa, ddof=1) / np.sqrt(len(salsa)):.3f}")
    numbers = pd.read_csv(result.out / "report.csv")
    assert set(numbers[numbers.section == "who_yields"].metric) >= {"success_rate", "deadlock_rate", "social/no_yield"}
