"""The paper's claims decided by exact permutation tests of two conditions' seeds, Holm-adjusted over the claims table
(``sidewalk.report.claims``): every comparison a verdict states carries its 95 % interval, its p-value and whether it
separates; seeds that overlap separate nothing, nor do 3 seeds a side however far apart, nor one seed; a separated
difference smaller than ``TIE`` is still a tie; a speed is the frames to an absolute criterion, censored where a seed
never gets there, and "sooner" needs ``SPEED_MARGIN``; the differences with their tests go to report.csv's rows."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir

# The claims' synthetic run folders, as tests/test_report.py writes them.
from test_report import CONF, agents, write_run

from sidewalk.report.claims import BOOTSTRAP, SPEED_MARGIN, TIE, check_claims, claims_section
from sidewalk.report.conditions import group_conditions
from sidewalk.report.runs import find_run_folders, load_run
from sidewalk.report.tables import NumberLog
from sidewalk.stats import difference_interval

NOISE = "more noise, lower success (discrete)"
EXPLICIT = "explicit cooperative reward learns better than implicit (continuous)"


def seeded_runs(root: Path, preset: str, key: str, success_by_value: dict, iterations_by_value=None) -> None:
    """A preset's runs for each ``key`` value, one seed per ego success in its list, each run's training success
    rising linearly to it over ``iterations_by_value`` (default 10) iterations."""
    (root / preset).mkdir(parents=True)
    (root / preset / "multirun.yaml").write_text("# a sweep folder\n")
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        for value, successes in success_by_value.items():
            for seed, success in enumerate(successes):
                overrides = [f"+experiment={preset}", f"{key}={value}", f"seed={seed}"]
                cfg = compose(config_name="config", overrides=overrides)
                iterations = (iterations_by_value or {}).get(value, 10)
                write_run(
                    root / preset / f"{key}={value},seed={seed}", cfg, agents(ego_success=success), iterations
                )


def claims_of(root: Path):
    conditions = group_conditions([load_run(folder) for folder in find_run_folders([root])])
    return conditions, {v.claim: v for v in check_claims(conditions)}


def interval_text(a: list[float], b: list[float]) -> str:
    """The interval ``claims`` shows for the difference of the means of ``a`` and ``b``, at its bootstrap."""
    d = difference_interval(a, b, confidence=BOOTSTRAP.confidence, n_resamples=BOOTSTRAP.n_resamples, seed=0)
    return f"[{d.low:.2f}, {d.high:.2f}]"


def test_seeds_that_overlap_do_not_separate_and_the_evidence_says_so(tmp_path):
    # Success falls with noise on average (0.70, 0.60, 0.57), but the seeds overlap: no level is surely lower.
    levels = {"0.0": [0.9, 0.5, 0.7, 0.6, 0.8], "0.1": [0.7, 0.6, 0.5, 0.8, 0.4], "0.2": [0.8, 0.3, 0.6, 0.5, 0.65]}
    seeded_runs(tmp_path, "fig6_discrete", "noise", levels)
    _, verdicts = claims_of(tmp_path)
    noise = verdicts[NOISE]
    assert noise.verdict == "not reproduced"
    overall = f"n=0.2 − n=0: difference -0.13 {interval_text(levels['0.2'], levels['0.0'])}, does not separate at 95% (p "
    assert overall in noise.evidence
    first_step = (
        f"n=0.1 − n=0: difference -0.10 {interval_text(levels['0.1'], levels['0.0'])}, does not separate"
    )
    assert f"between neighbouring levels: {first_step}" in noise.evidence
    assert [d.metric for d in noise.differences] == ["success_rate"] * 3
    # The three tests are one family: each says so, and its p-value is Holm-adjusted.
    assert all(d.interval.test.endswith("; Holm over 3") for d in noise.differences)


def test_three_seeds_a_side_cannot_separate_however_far_apart(tmp_path):
    # Every seed of n=0.2 below every seed of n=0: the bootstrap interval excludes 0, but 3 against 3 seeds allow no
    # p-value below 0.1, and the verdict says so instead of "separates".
    seeded_runs(tmp_path, "fig6_discrete", "noise", {"0.0": [0.9, 0.8, 0.85], "0.2": [0.2, 0.3, 0.1]})
    noise = claims_of(tmp_path)[1][NOISE]
    assert noise.verdict == "not reproduced"
    assert noise.differences[0].interval.high < 0
    assert "cannot separate at 95% (smallest p 0.1: exact Mann-Whitney, 3 v 3 seeds; Holm over 1)" in noise.evidence


def test_two_noise_levels_state_their_difference_once(tmp_path):
    # Two levels have one step between neighbours, the overall difference itself: neither text nor report.csv
    # repeats it.
    levels = {"0.0": [0.9, 0.8, 0.85, 0.95, 0.75], "0.2": [0.2, 0.3, 0.1, 0.25, 0.15]}
    seeded_runs(tmp_path, "fig6_discrete", "noise", levels)
    noise = claims_of(tmp_path)[1][NOISE]
    assert noise.verdict == "reproduced"
    assert noise.evidence.count("difference -0.65") == 1 and "neighbouring" not in noise.evidence
    assert [d.metric for d in noise.differences] == ["success_rate"]


def test_a_separated_difference_smaller_than_tie_is_a_tie_and_learning_sooner_separates(tmp_path):
    # The same end within TIE; training success reaches 0.8 at 10 iterations against 20 (one 128-frame iteration
    # each): explicit learns better by learning sooner. The implicit seeds learn after the explicit runs end, so they
    # are censored there.
    seeded_runs(tmp_path, "fig8", "reward", {"explicit": [0.81] * 5, "implicit": [0.8] * 5}, {"implicit": 20})
    conditions, verdicts = claims_of(tmp_path)
    explicit = verdicts[EXPLICIT]
    assert explicit.verdict == "reproduced"
    assert "difference 0.01 [0.01, 0.01], separates at 95% (p 0.016, exact Mann-Whitney, 5 v 5 seeds; Holm over 2) " \
           f"but within ±{TIE:g}: a tie" in explicit.evidence
    assert ("median 1,280 (5 of 5 seeds reach 0.8) vs median 2,560 (5 of 5 seeds reach 0.8), difference –, "
            "separates at 95% (p 0.016") in explicit.evidence
    numbers = NumberLog()
    section = "\n".join(claims_section(conditions, numbers))
    assert "differences [95% CI]" in section and "Holm-adjusted" in section
    assert f"{BOOTSTRAP.n_resamples:,} resamples, seed {BOOTSTRAP.seed}" in section
    frame = numbers.frame()
    speed = frame[(frame.metric == "frames_to_learn") & (frame.statistic == "median")]
    assert sorted(speed.value) == [1280.0, 2560.0] and speed.note.str.startswith("5 of 5 seeds reach 0.8").all()
    test = frame[(frame.metric == "frames_to_learn") & frame.statistic.str.startswith("difference")]
    assert test.note.str.startswith("separates at 95% (p 0.016").all()
    assert set(test.seeds) == {10} and set(test.condition_id) == {"C1 − C2"}


def test_a_speed_within_the_margin_is_not_sooner(tmp_path):
    # Every explicit seed reaches 0.8 before every implicit one, 9 iterations against 10: the test separates them,
    # but a tenth fewer frames is within SPEED_MARGIN, so explicit does not learn sooner.
    seeded_runs(tmp_path, "fig8", "reward", {"explicit": [0.8] * 5, "implicit": [0.8] * 5}, {"explicit": 9})
    explicit = claims_of(tmp_path)[1][EXPLICIT]
    assert SPEED_MARGIN == 0.2 and explicit.verdict == "not reproduced"
    assert "median 1,152 (5 of 5 seeds reach 0.8) vs median 1,280 (5 of 5 seeds reach 0.8)" in explicit.evidence
    assert explicit.differences[1].interval.p < 0.05


def test_seeds_that_never_learn_are_censored_not_fast(tmp_path):
    # Seeds that end at 0.04 never reach the criterion, however early they reach 90 % of their own final success.
    seeded_runs(tmp_path, "fig8", "reward", {"explicit": [0.04] * 5, "implicit": [0.9] * 5})
    explicit = claims_of(tmp_path)[1][EXPLICIT]
    assert "never (0 of 5 seeds reach 0.8) vs median 1,152 (5 of 5 seeds reach 0.8)" in explicit.evidence
    assert explicit.verdict == "not reproduced"


def test_one_seed_has_no_interval_so_separates_nothing(tmp_path):
    # With one seed each, learning in 10 iterations against 20 is no finding: there is nothing to resample.
    seeded_runs(tmp_path, "fig8", "reward", {"explicit": [0.8], "implicit": [0.8]}, {"implicit": 20})
    _, verdicts = claims_of(tmp_path)
    explicit = verdicts[EXPLICIT]
    assert explicit.verdict == "not reproduced"
    assert "cannot separate at 95% (smallest p 1: exact Mann-Whitney, 1 v 1 seeds" in explicit.evidence
    assert all(d.interval.note.startswith("1 run") or "censored" in d.interval.note for d in explicit.differences)


def test_two_seeds_give_a_coarse_interval_and_cannot_separate(tmp_path):
    seeded_runs(tmp_path, "fig6_discrete", "noise", {"0.0": [0.9, 0.8], "0.1": [0.3, 0.3], "0.2": [0.1, 0.2]})
    _, verdicts = claims_of(tmp_path)
    noise = verdicts[NOISE]
    # Two seeds' means take three values in a resample: 0.80, 0.85, 0.90 against 0.10, 0.15, 0.20.
    # 2 against 2 seeds split 6 ways: p ≥ 1/3 alone, 1 in a family of three.
    assert "n=0.2 − n=0: difference -0.70 [-0.80, -0.60] (coarse), cannot separate at 95% (smallest p 1: exact " \
        "Mann-Whitney, 2 v 2 seeds; Holm over 3)" in noise.evidence
    assert noise.verdict == "not reproduced"
