"""The paper's claims decided by bootstrap intervals of the difference between two conditions' seeds
(``sidewalk.report.claims``): every comparison a verdict states carries its 95 % interval and whether it separates;
seeds that overlap separate nothing, nor does one seed; a separated difference smaller than ``TIE`` is still a tie;
and the differences with their intervals go to report.csv's rows."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir

# The claims' synthetic run folders, as tests/test_report.py writes them.
from test_report import CONF, agents, write_run

from sidewalk.report.claims import BOOTSTRAP, TIE, check_claims, claims_section
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
    levels = {"0.0": [0.9, 0.5, 0.7], "0.1": [0.7, 0.6, 0.5], "0.2": [0.8, 0.3, 0.6]}
    seeded_runs(tmp_path, "fig6_discrete", "noise", levels)
    _, verdicts = claims_of(tmp_path)
    noise = verdicts[NOISE]
    assert noise.verdict == "not reproduced"
    overall = f"n=0.2 − n=0: difference -0.13 {interval_text(levels['0.2'], levels['0.0'])}, does not separate at 95%"
    assert overall in noise.evidence
    first_step = (
        f"n=0.1 − n=0: difference -0.10 {interval_text(levels['0.1'], levels['0.0'])}, does not separate"
    )
    assert f"between neighbouring levels: {first_step}" in noise.evidence
    assert [d.metric for d in noise.differences] == ["success_rate"] * 3


def test_two_noise_levels_state_their_difference_once(tmp_path):
    # Two levels have one step between neighbours, the overall difference itself: neither text nor report.csv
    # repeats it.
    levels = {"0.0": [0.9, 0.8, 0.85], "0.2": [0.2, 0.3, 0.1]}
    seeded_runs(tmp_path, "fig6_discrete", "noise", levels)
    noise = claims_of(tmp_path)[1][NOISE]
    assert noise.verdict == "reproduced"
    assert noise.evidence.count("difference -0.65") == 1 and "neighbouring" not in noise.evidence
    assert [d.metric for d in noise.differences] == ["success_rate"]


def test_a_separated_difference_smaller_than_tie_is_a_tie_and_learning_sooner_separates(tmp_path):
    # The same end within TIE, reached in 10 iterations against 20: explicit learns better by learning sooner.
    seeded_runs(tmp_path, "fig8", "reward", {"explicit": [0.81] * 3, "implicit": [0.8] * 3}, {"implicit": 20})
    conditions, verdicts = claims_of(tmp_path)
    explicit = verdicts[EXPLICIT]
    assert explicit.verdict == "reproduced"
    assert f"difference 0.01 [0.01, 0.01], separates at 95% but within ±{TIE:g}: a tie" in explicit.evidence
    assert "1,280 ± 0 vs 2,304 ± 0, difference -1,024 [-1,024, -1,024], separates at 95%" in explicit.evidence
    numbers = NumberLog()
    section = "\n".join(claims_section(conditions, numbers))
    assert "differences [95% CI]" in section and "the interval of their difference excludes 0" in section
    assert f"{BOOTSTRAP.n_resamples:,} resamples, seed {BOOTSTRAP.seed}" in section
    frame = numbers.frame()
    speed = frame[(frame.metric == "frames_to_learn") & frame.statistic.str.startswith("difference")]
    assert dict(zip(speed.statistic, speed.value)) == {
        "difference": -1024.0,
        "difference_ci_low": -1024.0,
        "difference_ci_high": -1024.0,
    }
    assert speed.note.str.startswith(f"separates at 95%; {EXPLICIT}: reproduced").all()
    assert set(speed.seeds) == {6} and set(speed.condition_id) == {"C1 − C2"}


def test_one_seed_has_no_interval_so_separates_nothing(tmp_path):
    # With one seed each, learning in 10 iterations against 20 is no finding: there is nothing to resample.
    seeded_runs(tmp_path, "fig8", "reward", {"explicit": [0.8], "implicit": [0.8]}, {"implicit": 20})
    _, verdicts = claims_of(tmp_path)
    explicit = verdicts[EXPLICIT]
    assert explicit.verdict == "not reproduced"
    assert "1,280 vs 2,304, difference -1,024, no interval (1 run)" in explicit.evidence
    assert all(d.interval.note.startswith("1 run") for d in explicit.differences)


def test_two_seeds_give_a_coarse_interval_that_can_still_separate(tmp_path):
    seeded_runs(tmp_path, "fig6_discrete", "noise", {"0.0": [0.9, 0.8], "0.1": [0.3, 0.3], "0.2": [0.1, 0.2]})
    _, verdicts = claims_of(tmp_path)
    noise = verdicts[NOISE]
    # Two seeds' means take three values in a resample: 0.80, 0.85, 0.90 against 0.10, 0.15, 0.20.
    assert "n=0.2 − n=0: difference -0.70 [-0.80, -0.60] (coarse), separates at 95%" in noise.evidence
    assert noise.evidence.count("(coarse), separates at 95%") == 3 and noise.verdict == "reproduced"
