"""The report's safety accounting: the learner's cumulative training cost drawn per condition, Safety Gym's triple
(final return, final cost, training cost rate) and the shield's rate against hand-computed means, shielded runs a
condition of their own, and run folders written before the accounting reported as before."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from sidewalk.report.document import write_report
from sidewalk.report.tables import Settings
from sidewalk.schema import register_schemas

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
FRAMES_PER_BATCH = 128
SETTINGS = Settings(n_resamples=200, trajectory_episodes=0)
register_schemas()

# Two seeds of the grid's DQN against Dijkstra, unshielded and shielded: each iteration's training cost, the final
# evaluation's ego return and cost, and the shield's per-iteration rate (None: a run without the shield).
RUNS = {
    ("unshielded", 0): ([10, 6, 3, 1], 0.6, 0.5, None),
    ("unshielded", 1): ([12, 8, 4, 0], 0.8, 0.25, None),
    ("shielded", 0): ([2, 1, 1, 0], 0.5, 0.0, [0.2, 0.1, 0.1, 0.0]),
    ("shielded", 1): ([0, 2, 0, 0], 0.7, 0.125, [0.3, 0.1, 0.1, 0.1]),
}


def base_config(seed: int, opponent: str = "dijkstra"):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"seed={seed}", f"opponent={opponent}"])
    OmegaConf.set_struct(cfg, False)
    cfg.pop("shield", None)  # as a run written before the shield existed: the key missing means unshielded
    return cfg


def final_values(cfg, learner_return: float, learner_cost: float, safety: bool) -> dict[str, float]:
    """The last evaluation's keys: ``ego/``, ``other/`` and overall against a scripted opponent, ``agent{i}/`` and
    overall (the mean over agents, all of them the learner's) for a centralized learner."""
    if cfg.opponent.name == "centralized":
        agents = {"agent0": (learner_return, learner_cost), "agent1": (learner_return, learner_cost)}
        overall = (learner_return, learner_cost)
    else:
        agents = {"ego": (learner_return, learner_cost), "other": (0.2, 0.0)}
        overall = ((learner_return + 0.2) / 2, learner_cost / 2)
    final = {"team/success_rate": 0.9, "success_rate": 0.9, "return": overall[0]}
    for agent, (ret, _) in agents.items():
        final.update({f"{agent}/success_rate": 0.9, f"{agent}/collision_rate": 0.1, f"{agent}/return": ret})
    if safety:
        final.update({f"{agent}/cost": cost for agent, (_, cost) in agents.items()} | {"cost": overall[1]})
    return final


def write_run(
    folder: Path, cfg, costs, learner_return, learner_cost, shield_rates, safety: bool = True
) -> None:
    """A run folder as runners/main.py writes it, with ``costs`` the learner's cost in each iteration's batch;
    ``safety=False``: as written before the safety accounting (no cost columns or keys)."""
    folder.mkdir(parents=True)
    OmegaConf.save(cfg, folder / "config.yaml", resolve=True)
    iterations = len(costs)
    final = final_values(cfg, learner_return, learner_cost, safety)
    rows, total = [], 0.0
    for iteration, cost in enumerate(costs, 1):
        total += cost
        row = {"iteration": iteration, "frames": iteration * FRAMES_PER_BATCH, "time_s": 0.1 * iteration}
        if safety:
            row.update({"train/cost": float(cost), "train/cumulative_cost": total})
        if shield_rates is not None:
            row["train/shield_rate"] = shield_rates[iteration - 1]
        if iteration == iterations:
            row.update({f"eval/{key}": value for key, value in final.items()})
        rows.append(row)
    pd.DataFrame(rows).to_csv(folder / "metrics.csv", index=False)
    frames = iterations * FRAMES_PER_BATCH
    summary = {**final, "seed": int(cfg.seed), "iterations": iterations, "frames": frames}
    if safety:
        summary.update({"train_cost": total, "cost_rate": total / frames})
    (folder / "summary.json").write_text(json.dumps(summary))


def sweep(root: Path) -> Path:
    root.mkdir(parents=True)
    (root / "multirun.yaml").write_text("# a sweep folder\n")
    return root


@pytest.fixture(scope="module")
def safety_sweep(tmp_path_factory) -> Path:
    root = sweep(tmp_path_factory.mktemp("runs") / "safety")
    for (shield, seed), (costs, ret, cost, rates) in RUNS.items():
        cfg = base_config(seed)
        if shield == "shielded":
            cfg.shield = True
        elif seed == 1:
            cfg.shield = False  # beside seed 0's config without the key: one condition all the same
        write_run(root / f"{shield}_seed={seed}", cfg, costs, ret, cost, rates)
    return root


def mean_and_se(a: float, b: float) -> tuple[float, float]:
    return (a + b) / 2, abs(a - b) / 2  # two seeds: std(ddof=1) / √2 is half their distance


def table_rows(report: str, header_start: str) -> dict[str, dict[str, str]]:
    """The Markdown table whose header starts with ``header_start``, as {condition: {column: cell}}."""
    lines = report.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    header = [cell.strip() for cell in lines[start].strip("|").split("|")]
    rows = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = dict(zip(header, (cell.strip() for cell in line.strip("|").split("|"))))
        rows[cells["condition"]] = cells
    return rows


def test_safety_triple_and_shield_rate_are_the_means_over_seeds(safety_sweep, tmp_path):
    result = write_report([safety_sweep], tmp_path / "out", SETTINGS)
    assert [len(c.runs) for c in result.conditions] == [2, 2]
    labels = sorted(c.label for c in result.conditions)
    assert labels == ["discrete: DQN vs dijkstra, shielded", "discrete: DQN vs dijkstra, unshielded"]

    numbers = pd.read_csv(result.out / "report.csv")
    safety = numbers[numbers.section == "safety:safety"]
    for shield in ("unshielded", "shielded"):
        runs = [RUNS[(shield, seed)] for seed in (0, 1)]
        expected = {
            "cost_rate": mean_and_se(*(sum(costs) / (4 * FRAMES_PER_BATCH) for costs, *_ in runs)),
            "return": mean_and_se(*(ret for _, ret, _, _ in runs)),
            "cost": mean_and_se(*(cost for _, _, cost, _ in runs)),
        }
        if shield == "shielded":
            expected["shield_rate"] = mean_and_se(*(sum(rates) / 4 for *_, rates in runs))
        rows = safety[safety.condition == f"discrete: DQN vs dijkstra, {shield}"]
        assert set(rows.metric) == set(expected) | {"success_rate"}
        assert set(rows.agent) == {"ego"}
        for metric, (mean, se) in expected.items():
            values = dict(zip(rows[rows.metric == metric].statistic, rows[rows.metric == metric].value))
            assert values["mean"] == pytest.approx(mean), (shield, metric)
            assert values["se"] == pytest.approx(se), (shield, metric)

    report = result.report_md.read_text()
    assert "Ray, Achiam & Amodei 2019" in report
    table = table_rows(report, "| id | condition | learner |")
    unshielded, shielded = (table[f"discrete: DQN vs dijkstra, {s}"] for s in ("unshielded", "shielded"))
    # (20 + 24) / 2 / 512 frames, three significant digits so that a small rate never reads as 0.000.
    assert unshielded["training cost rate"] == "0.043 ± 0.00391"
    assert unshielded["final cost"] == "0.375 ± 0.125" and unshielded["final return"] == "0.700 ± 0.100"
    assert shielded["training cost rate"] == "0.00586 ± 0.00195"
    assert shielded["shield rate"] == "0.125 ± 0.025"
    assert unshielded["shield rate"] == "—"  # not recorded, not zero
    assert shielded["learner"] == "DQN (ego)" and shielded["seeds"] == "2"


def test_cumulative_training_cost_is_drawn_per_condition(safety_sweep, tmp_path):
    result = write_report([safety_sweep], tmp_path / "out", SETTINGS)
    figure = result.out / "figures" / "cost_safety.png"
    assert figure in result.figures and figure.stat().st_size > 10_000
    assert "](figures/cost_safety.png)" in result.report_md.read_text()
    curves = pd.read_csv(result.out / "curves.csv")
    cost = curves[curves.figure == "cost_safety"]
    assert set(cost.metric) == {"cumulative_cost"} and cost.condition.nunique() == 2
    first = cost[cost.condition.str.endswith(", unshielded") & (cost.x == FRAMES_PER_BATCH)]
    assert first["mean"].item() == pytest.approx(11.0) and first["se"].item() == pytest.approx(1.0)
    last = cost[cost.condition.str.endswith(", shielded") & (cost.x == 4 * FRAMES_PER_BATCH)]
    assert last["mean"].item() == pytest.approx(3.0) and last["seeds"].item() == 2


def test_runs_written_before_the_safety_accounting_report_as_before(tmp_path):
    old = sweep(tmp_path / "old")
    for seed in (0, 1):
        write_run(old / f"seed={seed}", base_config(seed), [3, 2, 1, 0], 0.6, 0.5, None, safety=False)
    result = write_report([old], tmp_path / "out", SETTINGS)
    report = result.report_md.read_text()
    assert {p.name for p in result.figures} == {"curves_old.png"}
    assert "Ray, Achiam & Amodei 2019" not in report and "cost" not in report
    numbers = pd.read_csv(result.out / "report.csv")
    assert not numbers.section.str.startswith("safety:").any()
    assert not numbers.metric.isin(["cost", "cost_rate", "return"]).any()
    assert "| C1 | discrete: DQN vs dijkstra | DQN (ego) | success_rate | 2 | 0.900 ± 0.000 |" in report


def test_an_old_condition_beside_a_new_one_shows_dashes_not_zeros(tmp_path):
    mixed = sweep(tmp_path / "mixed")
    for seed in (0, 1):
        write_run(
            mixed / f"old_seed={seed}", base_config(seed, "random"), [3, 2], 0.6, 0.5, None, safety=False
        )
        write_run(mixed / f"new_seed={seed}", base_config(seed), [3, 2], 0.6, 0.5, None)
    result = write_report([mixed], tmp_path / "out", SETTINGS)
    table = table_rows(result.report_md.read_text(), "| id | condition | learner |")
    old, new = table["discrete: DQN vs random"], table["discrete: DQN vs dijkstra"]
    assert old["final cost"] == old["training cost rate"] == "—"
    assert old["final return"] == "0.600 ± 0.000"  # summaries had the return before the cost
    assert new["training cost rate"] == "0.0195 ± 0.000"  # 5 / 256 frames, both seeds
    assert "shield rate" not in old
    cost = pd.read_csv(result.out / "curves.csv").query("figure == 'cost_mixed'")
    assert set(cost.condition) == {"discrete: DQN vs dijkstra"}  # the old runs have no cost curve to draw


def test_a_centralized_learner_is_measured_over_all_its_agents(tmp_path):
    runs = sweep(tmp_path / "centralized")
    for seed, (ret, cost) in enumerate(((0.4, 1.0), (0.6, 0.5))):
        write_run(runs / f"seed={seed}", base_config(seed, "centralized"), [4, 4], ret, cost, None)
    result = write_report([runs], tmp_path / "out", SETTINGS)
    row = table_rows(result.report_md.read_text(), "| id | condition | learner |")[
        "discrete: DQN centralized"
    ]
    assert row["learner"] == "all agents"
    assert (row["final return"], row["final cost"]) == ("0.500 ± 0.100", "0.750 ± 0.250")
    assert row["training cost rate"] == "0.0312 ± 0.000"  # 8 / 256 frames
    cost = pd.read_csv(result.out / "curves.csv").query("figure == 'cost_centralized'")
    assert set(cost.agent) == {"all"} and list(cost["mean"]) == [4.0, 8.0]
