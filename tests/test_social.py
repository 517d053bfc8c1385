"""The social measures of a pass (sidewalk.social) on hand-built steps with known answers, and in real evaluations."""

import json
import math

import pytest
import torch
from test_report_safety import SETTINGS, base_config, sweep, write_run

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate
from sidewalk.report.document import write_report
from sidewalk.social import GRID_CELL_M, SocialTally
from sidewalk.views import view_for_opponent

RADIUS_M = 0.2
BOTH = torch.ones(1, 2, dtype=torch.bool)


def grid_tally(rows_cols, goals):
    return SocialTally.begin(torch.tensor([rows_cols]), torch.tensor([goals]), grid=True, dt_s=1.0, radius_m=0.5)


def unicycle(*agents):
    """One world's continuous state (1, 2, 4) from (x, y, speed, heading) per agent."""
    return torch.tensor([agents], dtype=torch.float32)


def continuous_tally(state, goals):
    return SocialTally.begin(state, torch.tensor([goals], dtype=torch.float32), grid=False, dt_s=0.2, radius_m=RADIUS_M)


def test_a_mirrored_dodge_is_one_salsa_step_and_opposite_dodges_are_none():
    # Agent 0 walks to +col, agent 1 to -col, both on row 2, not yet past each other.
    start, goals = [[2, 3], [2, 8]], [[2, 12], [2, 0]]
    mirrored = grid_tally(start, goals)
    mirrored.add_step(torch.tensor([[[1, 3], [1, 8]]]), BOTH)  # both step UP: each into the other's new row
    assert mirrored.summary(ego=0)["social/salsa_count"] == 1.0
    passing = grid_tally(start, goals)
    passing.add_step(torch.tensor([[[1, 3], [3, 8]]]), BOTH)  # UP and DOWN: out of each other's way
    assert passing.summary(ego=0)["social/salsa_count"] == 0.0


@pytest.mark.parametrize("lag, counted", [(1, 1.0), (2, 0.0)])
def test_a_sidestep_answered_within_the_window_is_a_mirrored_dodge(lag, counted):
    # Agent 0 steps UP, then agent 1 steps UP ``lag`` steps later (the window is one step): mirrored only within it.
    tally = grid_tally([[2, 2], [2, 12]], [[2, 14], [2, 0]])
    rows = [[1, 2]] * lag + [[1, 1]]
    for step, (row0, row1) in enumerate(rows, start=1):
        tally.add_step(torch.tensor([[[row0, 2 + step], [row1, 12 - step]]]), BOTH)
    assert tally.summary(ego=0)["social/salsa_count"] == counted


def test_a_head_on_approach_has_the_time_its_gap_takes_to_close():
    start = unicycle((1.0, 1.0, 0.5, 0.0), (3.0, 1.0, 0.5, math.pi))
    tally = continuous_tally(start, [[4.0, 1.0], [0.0, 1.0]])
    tally.add_step(start, BOTH)
    # A 2 m gap closing at 1 m/s until the discs (0.4 m together) touch.
    assert tally.summary(ego=0)["social/min_ttc"] == pytest.approx(1.6, abs=1e-5)
    parallel = continuous_tally(unicycle((1.0, 0.5, 0.5, 0.0), (1.0, 1.5, 0.5, 0.0)), [[4.0, 0.5], [4.0, 1.5]])
    parallel.add_step(unicycle((1.1, 0.5, 0.5, 0.0), (1.1, 1.5, 0.5, 0.0)), BOTH)
    assert parallel.summary(ego=0)["social/min_ttc"] == math.inf


def test_constant_acceleration_has_no_jerk_and_a_change_of_it_has():
    def run(speeds):
        tally = continuous_tally(unicycle((0.5, 0.5, 0.0, 0.0), (3.5, 1.5, 0.0, math.pi)), [[4.0, 0.5], [0.0, 1.5]])
        for speed in speeds:
            tally.add_step(unicycle((0.5, 0.5, speed, 0.0), (3.5, 1.5, 0.0, math.pi)), BOTH)
        return tally.summary(ego=0)["social/jerk"]

    assert run([0.1, 0.2, 0.3, 0.4]) == pytest.approx(0.0, abs=1e-4)
    # Accelerations 0.5, 0.5, -0.5 m/s² at 0.2 s a step: one jerk of -5 m/s³ over two measured steps.
    assert run([0.1, 0.2, 0.3, 0.2]) == pytest.approx(math.sqrt(25 / 2), rel=1e-4)


def test_an_agent_inside_the_personal_space_is_an_intrusion():
    tally = continuous_tally(unicycle((1.0, 1.0, 0.0, 0.0), (3.0, 1.0, 0.0, math.pi)), [[4.0, 1.0], [0.0, 1.0]])
    tally.add_step(unicycle((1.0, 1.0, 0.0, 0.0), (1.5, 1.0, 0.0, math.pi)), BOTH)  # 0.5 m < 0.4 + 0.2 m
    tally.add_step(unicycle((1.0, 1.0, 0.0, 0.0), (1.7, 1.0, 0.0, math.pi)), BOTH)  # 0.7 m: outside
    summary = tally.summary(ego=0)
    assert summary["social/intrusion_steps"] == 1.0 and summary["social/intrusion_rate"] == 1.0


def test_the_first_agent_off_its_line_yields_first():
    tally = grid_tally([[2, 3], [2, 9]], [[2, 12], [2, 0]])
    tally.add_step(torch.tensor([[[2, 4], [2, 8]]]), BOTH)  # both walk on
    tally.add_step(torch.tensor([[[2, 5], [1, 8]]]), BOTH)  # the partner steps aside
    tally.add_step(torch.tensor([[[3, 5], [1, 7]]]), BOTH)  # then the ego: too late to be first
    summary = tally.summary(ego=0)
    assert summary["social/partner_yields_first"] == 1.0 and summary["social/ego_yields_first"] == 0.0
    assert summary["social/no_yield"] == 0.0


def test_each_step_falls_in_one_proxemic_zone_by_the_distance_from_a_body_to_the_other_centre():
    # Continuous, radius 0.2 m: centres 0.6 m apart are 0.4 m from a body (intimate), 1.0 m apart 0.8 m (personal),
    # 2.0 m apart 1.8 m (social); four steps, one in each of the first three zones and one more in the social zone.
    tally = continuous_tally(unicycle((0.0, 1.0, 0.0, 0.0), (4.0, 1.0, 0.0, math.pi)), [[4.0, 1.0], [0.0, 1.0]])
    for gap in (2.0, 1.0, 0.6, 2.0):
        tally.add_step(unicycle((1.0, 1.0, 0.0, 0.0), (1.0 + gap, 1.0, 0.0, math.pi)), BOTH)
    tally.add_step(unicycle((1.0, 1.0, 0.0, 0.0), (9.0, 1.0, 0.0, math.pi)), ~BOTH)  # not both active: in none
    zones = {key: value for key, value in tally.summary(ego=0).items() if "zone" in key}
    assert zones == {"social/zone_intimate": 0.25, "social/zone_personal": 0.25, "social/zone_social": 0.5,
                     "social/zone_public": 0.0}
    # The grid: a cell is GRID_CELL_M, a body half of it. A neighbouring cell is intimate (0.5 - 0.25 m), a
    # diagonal one personal (0.71 - 0.25 = 0.46 m).
    grid = grid_tally([[2, 3], [2, 9]], [[2, 12], [2, 0]])
    grid.add_step(torch.tensor([[[2, 4], [2, 5]]]), BOTH)
    grid.add_step(torch.tensor([[[2, 4], [3, 5]]]), BOTH)
    summary = grid.summary(ego=0)
    assert (summary["social/zone_intimate"], summary["social/zone_personal"]) == (0.5, 0.5) and GRID_CELL_M == 0.5


def test_the_agent_that_carried_a_collision_ran_into_the_other():
    # The ego steps into the cell where the partner stands still: the ego ran into the partner.
    onto = grid_tally([[2, 3], [2, 5]], [[2, 12], [2, 0]])
    onto.add_step(torch.tensor([[[2, 4], [2, 5]]]), BOTH)
    onto.add_step(torch.tensor([[[2, 5], [2, 5]]]), BOTH, torch.tensor([True]))
    summary = onto.summary(ego=0)
    assert (summary["social/ego_ran_into"], summary["social/partner_ran_into"]) == (1.0, 0.0)
    # Head on, both a cell toward each other (a swap): both ran into each other; only the first collision counts.
    swap = grid_tally([[2, 4], [2, 5]], [[2, 12], [2, 0]])
    swap.add_step(torch.tensor([[[2, 5], [2, 4]]]), BOTH, torch.tensor([True]))
    swap.add_step(torch.tensor([[[2, 5], [2, 5]]]), BOTH, torch.tensor([True]))
    assert swap.summary(ego=None)["social/both_ran_into"] == 1.0
    calm = grid_tally([[2, 3], [2, 9]], [[2, 12], [2, 0]])
    calm.add_step(torch.tensor([[[2, 4], [2, 8]]]), BOTH, torch.tensor([False]))
    assert calm.summary(ego=None)["social/agent0_ran_into"] == 0.0 and calm.summary(ego=None)["social/both_ran_into"] == 0.0


@pytest.mark.parametrize("core_class, opponent", [(DiscreteSidewalkEnv, "dijkstra"), (ContinuousSidewalkEnv, "prm")])
def test_a_real_evaluation_reports_every_measure(core_class, opponent):
    metrics = evaluate(view_for_opponent(core_class(64, seed=0), opponent, 0), None, seed=0)
    social = {key: value for key, value in metrics.items() if key.startswith("social/")}
    assert len(social) == 16
    shares = [social[f"social/{who}"] for who in ("ego_yields_first", "partner_yields_first", "both_yield_first", "no_yield")]
    assert sum(shares) == pytest.approx(1.0)
    assert sum(social[f"social/zone_{zone}"] for zone in ("intimate", "personal", "social", "public")) == pytest.approx(1)
    # Every episode where an agent hit the other (the ego, or the partner, say into the ego parked at its goal) names
    # who ran into whom, and no other does: as many as either agent's, at most both agents' together.
    ran_into = sum(social[f"social/{who}_ran_into"] for who in ("ego", "partner", "both"))
    ego, other = metrics["ego/agent_collision_rate"], metrics["other/agent_collision_rate"]
    assert max(ego, other) - 1e-6 <= ran_into <= ego + other + 1e-6
    assert social["social/salsa_count"] >= 0 and social["social/intrusion_rate"] <= 1
    if core_class is ContinuousSidewalkEnv:
        assert math.isfinite(social["social/jerk"]) and social["social/jerk"] > 0
    else:
        assert math.isnan(social["social/jerk"])  # the grid has no acceleration


def test_worlds_of_three_agents_have_no_social_measures():
    core = DiscreteSidewalkEnv(8, seed=0, layout="door", n_agents=3)
    metrics = evaluate(view_for_opponent(core, "dijkstra", 0), None, seed=0)
    assert not any(key.startswith("social/") for key in metrics)


def test_the_report_gives_each_condition_its_social_measures_with_intervals_and_distinct_episodes(tmp_path):
    root = sweep(tmp_path / "runs")
    for seed, (salsa_count, distinct) in enumerate([(1.0, 40), (3.0, 42)]):
        folder = root / f"seed={seed}"
        write_run(folder, base_config(seed), [1, 0], 0.5, 0.0, None)
        summary = json.loads((folder / "summary.json").read_text())
        summary |= {"social/salsa_count": salsa_count, "social/intrusion_rate": 0.25, "distinct_episodes": distinct}
        (folder / "summary.json").write_text(json.dumps(summary))
    report = write_report([root], tmp_path / "out", SETTINGS).report_md.read_text()
    lines = report.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("| id | condition | measure |"))
    rows = {line.split("|")[3].strip(): [cell.strip() for cell in line.split("|")] for line in lines[header + 2:header + 4]}
    assert set(rows) == {"salsa_count", "intrusion_rate"}
    assert rows["salsa_count"][6] == "40–42"  # the distinct episodes behind each seed's value
    assert rows["salsa_count"][7] == "2.000 ± 1.000" and rows["intrusion_rate"][8].startswith("0.250 [0.250, 0.250]")
