"""The committed reference results say whether today's code still makes them: each reference folder's probe was
recorded at its commit, today's code gives the same probe for every job (else this fails, naming the job), the
freshness page says so, and a change to what a job computes is caught."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from sidewalk.reference import (
    FOLDERS,
    META,
    PROBE,
    STATUS,
    Reference,
    collect,
    compare,
    find_reference_root,
    main,
    probe,
    rate_tolerance,
    references,
    status_table,
)
from sidewalk.report.runs import load_run

REFERENCE_ROOT = find_reference_root(Path(__file__).parent)  # this clone's results/reference
JOBS = [(folder, job) for folder in FOLDERS for job in Reference.load(REFERENCE_ROOT / folder).jobs]


@pytest.mark.parametrize("folder", FOLDERS)
def test_each_reference_records_its_commit_and_a_probe_made_there(folder):
    reference = Reference.load(REFERENCE_ROOT / folder)
    assert len(reference.meta["commit"]) == 40
    assert reference.meta.get("probe_made_at") == reference.meta["commit"], "record the probe at the commit"
    recorded = reference.recorded_probe()
    assert list(dict.fromkeys(recorded["job"])) == list(reference.jobs)


@pytest.mark.parametrize("folder, job", JOBS, ids=[f"{folder or 'paper'}:{job}" for folder, job in JOBS])
def test_todays_code_makes_the_reference(folder, job):
    """A failure names the job and the first metric that moved: re-make that reference (its run.sh), or say in its
    reference.json ("explained") why the change leaves its numbers true."""
    reference = Reference.load(REFERENCE_ROOT / folder, REFERENCE_ROOT)
    recorded = reference.recorded_probe()
    (result,) = compare(recorded[recorded["job"] == job], probe({job: reference.jobs[job]}, progress=False))
    explained = reference.meta.get("explained", {}).get(job)
    assert result.same or explained, f"{reference.name}/ {job}: today's code changed its probe: {result.detail}"


def test_the_freshness_page_says_what_the_probes_say():
    page = (REFERENCE_ROOT / STATUS).read_text()
    for reference in references(REFERENCE_ROOT):
        (row,) = [line for line in page.splitlines() if line.startswith(f"| `{reference.name}/`")]
        assert f"commit `{reference.meta['commit'][:7]}`" in row
        committed = len(reference.committed_jobs())
        assert ("| all |" in row) == (committed == len(reference.jobs)), f"{STATUS} is older than the runs: {row!r}"
        assert committed == len(reference.jobs) or f"**{committed} of {len(reference.jobs)}**" in row, row
        # The probes are checked job by job above; a folder's "yes" is true when each of its jobs passes there.
        assert row.rstrip(" |").endswith("yes"), f"{STATUS} says {row!r}: re-run python -m sidewalk.reference check " \
                                                 "--write-status"


def test_the_reference_root_is_found_above_the_current_folder_or_given(tmp_path, monkeypatch, capsys):
    root = tmp_path / "clone" / "results" / "reference"
    (root / "safe").mkdir(parents=True)
    (tmp_path / "clone" / "docs").mkdir()
    assert find_reference_root(tmp_path / "clone" / "docs") == root.resolve()
    with pytest.raises(FileNotFoundError, match=r"no results/reference in .*: .* give the reference root with --root"):
        find_reference_root(tmp_path)
    monkeypatch.chdir(tmp_path)  # no clone here: the command names where it looked and how to give a root
    for argv in (["check"], ["check", "--root", str(tmp_path / "nowhere")]):
        assert main(argv) == 2
        (error,) = capsys.readouterr().err.splitlines()
        assert error.startswith("error: ") and tmp_path.name in error and "--root" in error
    assert [reference.name for reference in references(REFERENCE_ROOT)] == ["results/reference",
                                                                            "results/reference/safe"]


def test_a_change_in_what_a_job_computes_is_caught_and_named():
    recorded = pd.DataFrame({"job": ["a", "a", "b"], "iteration": [1, 2, 1], "eval/ego/return": [0.5, 0.7, 0.1]})
    today = recorded.copy()
    assert [r.same for r in compare(recorded, today)] == [True, True]
    today.loc[1, "eval/ego/return"] = 0.7 * (1 + 1e-9)  # another CPU's rounding
    assert compare(recorded, today)[0].detail.startswith("equal within rounding")
    today.loc[1, "eval/ego/return"] = 0.8  # a reward constant changed
    changed = compare(recorded, today)[0]
    assert not changed.same and changed.detail == "eval/ego/return at iteration 2: recorded 0.7, today 0.8"
    assert "no longer written" in compare(recorded, today.drop(columns="eval/ego/return"))[0].detail
    assert compare(recorded, recorded.assign(**{"eval/distinct_episodes": 1.0}))[0].same  # a metric added since
    today.loc[1, "eval/ego/return"] = 0.7 * (1 + 1e-3)  # two CI machines' kernels, over a probe's iterations
    assert compare(recorded, today)[0].same
    table = status_table([(Reference(REFERENCE_ROOT, {"commit": "0" * 40, "jobs": {"a": [], "b": []}}), [changed])])
    assert "**no**: `a`: eval/ego/return" in table
    assert "**0 of 2**: its report still shows the runs of an earlier commit" in table


def test_one_deterministic_episode_that_ends_otherwise_is_rounding_only_after_the_same_training():
    """At noise 0 the evaluation plays one episode 16 times: 300 steps of a shielded policy carry a CPU's rounding
    to a collision instead of a timeout (seen between two CI machines), which is not a change of the code."""
    recorded = pd.DataFrame({"job": ["a", "a"], "iteration": [1, 2], "train/kl": [0.0077, 0.0064],
                             "eval/distinct_episodes": [None, 1.0], "eval/episodes": [None, 16.0],
                             "eval/ego/collision_rate": [None, 0.0], "eval/ego/episode_length": [None, 300.0]})
    diverged = recorded.assign(**{"eval/ego/collision_rate": [None, 1.0], "eval/ego/episode_length": [None, 263.0]})
    (result,) = compare(recorded, diverged)
    assert result.same and result.detail.startswith("training equal within rounding; the evaluation's outcomes moved "
                                                    "within sampling error over 1 distinct episodes")
    assert not compare(recorded, diverged.assign(**{"train/kl": [0.0077, 0.0070]}))[0].same  # training moved too
    assert not compare(recorded, diverged.assign(**{"eval/episodes": [None, 32.0]}))[0].same  # another protocol
    many = {"eval/distinct_episodes": [None, 16.0]}  # 16 worlds: a rate moves by a share, not by rounding
    assert not compare(recorded.assign(**many), diverged.assign(**many))[0].same


def test_collected_runs_read_back_as_the_runs(tmp_path):
    """The committed small files of a run (metrics compressed at float32 precision) give the report what the run
    folder gives it."""
    from sidewalk.compose import compose
    from sidewalk.config import validate
    from sidewalk.experiment import Trial

    sweep = tmp_path / "sweeps" / "fig0"  # a sweep folder (multirun.yaml) in the root that is collected
    overrides = ["iterations=3", "eval_every=3", "eval_episodes=4", "num_envs=4", "logger=none", "checkpoint_every=0"]
    cfg = compose(overrides)
    from omegaconf import OmegaConf

    Trial(validate(cfg), sweep / "job" / "seed0", OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    (sweep / "multirun.yaml").write_text("{}\n")
    unfinished = tmp_path / "sweeps" / "fig1"  # a sweep still running: nothing of it is collected
    (unfinished / "job" / "seed0").mkdir(parents=True)
    (unfinished / "multirun.yaml").write_text("{}\n")
    assert collect(sweep.parent, tmp_path / "runs") == 1
    assert (tmp_path / "runs" / "fig0" / "multirun.yaml").exists() and not (tmp_path / "runs" / "fig1").exists()
    copied = tmp_path / "runs" / "fig0" / "job" / "seed0"
    assert sorted(p.name for p in copied.iterdir()) == ["config.yaml", "history.jsonl", "metrics.csv.xz",
                                                        "policy.pt", "summary.json"]  # seed 0: Fig. 10 replays it
    original, kept = load_run(sweep / "job" / "seed0"), load_run(copied)
    assert kept.family == original.family == "fig0" and kept.summary == original.summary
    diagnostics = [c for c in original.metrics.columns if c not in kept.metrics.columns]
    assert all(c.startswith("train/") for c in diagnostics)
    pd.testing.assert_frame_equal(kept.metrics, original.metrics.drop(columns=diagnostics), check_exact=False,
                                  check_dtype=False, rtol=1e-7)


def test_a_reference_json_names_every_job_it_ran():
    for folder in FOLDERS:
        meta = json.loads((REFERENCE_ROOT / folder / META).read_text())
        assert meta["jobs"] and all(overrides[0].startswith("+experiment=") for overrides in meta["jobs"].values())
        assert (REFERENCE_ROOT / folder / PROBE).exists()


def _config(job) -> dict:
    return json.loads(job.config_key)


def _but(config: dict, **settings) -> dict:
    """``config`` with ``settings`` (dotted keys one level deep: ``reward__c_step``) set."""
    config = json.loads(json.dumps(config))
    for key, value in settings.items():
        *parents, leaf = key.split("__")
        node = config
        for parent in parents:
            node = node[parent]
        node[leaf] = value
    return config


def test_the_claim_experiments_vary_their_papers_jobs_in_what_they_test_alone():
    """The step-cost experiment is fig5_continuous's centralized job at other step costs, Fig. 8 under noise is
    fig6_continuous's jobs with either reward; both at their own budgets, and both in the reference."""
    from sidewalk.reproduce import jobs

    queue = {job.folder: job for job in jobs(["fig5_continuous", "fig6_continuous", "fig8", "step_cost_centralized",
                                              "fig8_noise"], overrides=["replicas=5"])}
    step_costs = sorted(folder for folder in queue if folder.startswith("step_cost_centralized/"))
    assert [_config(queue[folder])["reward"]["c_step"] for folder in step_costs] == [-0.01, -0.001, 0]
    centralized = _config(queue["fig5_continuous/2_opponent=centralized"])
    for folder in step_costs:
        config = _config(queue[folder])
        assert _but(centralized, reward__c_step=config["reward"]["c_step"], iterations=1000) == config
    noisy = sorted(folder for folder in queue if folder.startswith("fig8_noise/"))
    assert len(noisy) == 4
    implicit = _config(queue["fig8/1_reward=implicit"])["reward"]
    for folder in noisy:
        config = _config(queue[folder])
        paper = _config(queue[f"fig6_continuous/{1 if config['noise'] == 0.5 else 2}_noise={config['noise']}"])
        reward = implicit if config["reward"]["name"] == "implicit" else paper["reward"]
        assert _but(paper, reward=reward, iterations=500) == config
    reference = Reference.load(REFERENCE_ROOT)
    assert set(step_costs + noisy) <= set(reference.jobs), "the reference runs the claim experiments too"


def test_a_job_whose_run_folders_hydra_named_counts_by_its_runs_config(tmp_path):
    """The safe reference's sweeps name their run folders by their overrides (one per seed): a job counts as committed
    where a run with its config lies under its domain's folder, and not where only other jobs' runs do."""
    safe = Reference.load(REFERENCE_ROOT / "safe")
    runs = tmp_path / "runs"
    for summary in (safe.folder / "runs").rglob("summary.json"):
        if "ppo_lagrangian" in str(summary.parent):
            continue  # one job's runs left out
        kept = runs / summary.parent.relative_to(safe.folder / "runs")
        kept.mkdir(parents=True)
        for name in ("summary.json", "config.yaml"):
            (kept / name).write_bytes((summary.parent / name).read_bytes())
    partial = Reference(tmp_path, {**safe.meta, "runs": "runs"})
    assert sorted(partial.committed_jobs()) == sorted(job for job in safe.jobs if "ppo_lagrangian" not in job)


def test_a_job_counts_once_every_group_of_seeds_has_run_it(tmp_path):
    """A reference trained as groups of seeds (``runs``: one folder per group) has a job in the repository when
    every group's folder holds a finished run of it, and not while one group's is missing."""
    reference = Reference.load(REFERENCE_ROOT)
    job = next(iter(reference.jobs))
    groups = ["runs/seeds0-4", "runs/seeds5-9"]
    split = Reference(tmp_path, {**reference.meta, "runs": groups})
    assert split.runs_folders == [tmp_path / group for group in groups]

    def add_run(group: str) -> None:
        run = tmp_path / group / job / "seed0"
        run.mkdir(parents=True)
        for name in ("summary.json", "config.yaml"):
            (run / name).write_bytes((reference.runs_folders[0] / job / "seed0" / name).read_bytes())

    add_run(groups[0])
    assert split.committed_jobs() == []
    add_run(groups[1])
    assert split.committed_jobs() == [job]


# The shielded continuous TRPO's probe, recorded at its commit and made on an AMD EPYC Zen 3 and Zen 4 (and with
# ATEN_CPU_CAPABILITY=default): training equal to 6e-5, 2 of 16 evaluation episodes ending otherwise.
SHIELDED_TRPO = {"iteration": [1, 2], "train/kl": [0.006970343645662069, 0.006222985684871674],
                 "eval/episodes": [None, 16.0], "eval/distinct_episodes": [None, 16.0],
                 "eval/ego/success_rate": [None, 0.5], "eval/ego/timeout_rate": [None, 0.4375],
                 "eval/deadlock_rate": [None, 0.4375], "eval/return": [None, -0.4642132520675659],
                 "eval/social/jerk": [None, 1.247406244277954]}
OTHER_KERNELS = {"train/kl": [0.0069704498164355755, 0.00622307974845171], "eval/ego/success_rate": [None, 0.625],
                 "eval/ego/timeout_rate": [None, 0.3125], "eval/deadlock_rate": [None, 0.3125],
                 "eval/return": [None, -0.27438557147979736], "eval/social/jerk": [None, 1.4410121440887451]}


def test_an_evaluation_whose_outcomes_another_cpu_moved_is_compared_as_rates_at_its_distinct_episodes():
    recorded = pd.DataFrame({"job": "trpo", **SHIELDED_TRPO})
    (result,) = compare(recorded, recorded.assign(**OTHER_KERNELS))
    assert result.same and "moved within sampling error over 16 distinct episodes" in result.detail, result.detail
    # What it protects: training beyond rounding; a rate moved further than 16 episodes' sampling allows; a mean that
    # moved while no outcome did (a change of what the evaluation computes); another episode count.
    for moved, named in [({"train/kl": [0.0069704, 0.0064]}, "train/kl at iteration 2"),
                         ({"eval/ego/success_rate": [None, 0.0], "eval/ego/timeout_rate": [None, 1.0]},
                          "eval/ego/success_rate at iteration 2: recorded 0.5, today 0"),
                         ({"eval/social/jerk": [None, 1.3]}, "eval/social/jerk at iteration 2"),
                         ({"eval/distinct_episodes": [None, 15.0]}, "eval/distinct_episodes at iteration 2")]:
        changed = {**(OTHER_KERNELS if "eval/social/jerk" not in moved else {}), **moved}
        (result,) = compare(recorded, recorded.assign(**changed))
        assert not result.same and result.detail.startswith(named), (moved, result.detail)
    assert rate_tolerance(0.5, 0.625, 16) == pytest.approx(3 * (2 * 0.5625 * 0.4375 / 16) ** 0.5 + 1 / 16)
    assert rate_tolerance(0.0, 0.0, 256) == 1 / 256


# Probed in a process whose ATen kernels are another CPU kind's (ATEN_CPU_CAPABILITY=default: no AVX2/AVX-512
# vectorisation, other reduction orders): the jobs whose evaluations measured chaotic there and on an AVX-512 EPYC.
OTHER_KERNELS_PROBE = """
import sys
from pathlib import Path
from sidewalk.reference import Reference, compare, probe
import torch
reference = Reference.load(Path(sys.argv[1]))
jobs = {job: reference.jobs[job] for job in sys.argv[2:]}
recorded = reference.recorded_probe()
for result in compare(recorded[recorded["job"].isin(jobs)], probe(jobs, progress=False)):
    print(torch.backends.cpu.get_cpu_capability(), result.job, result.same, result.detail, sep="|")
"""


def test_the_probe_holds_on_another_cpu_kinds_kernels_and_still_catches_a_reward_constant():
    import os
    import subprocess
    import sys

    safe = REFERENCE_ROOT / "safe"
    done = subprocess.run([sys.executable, "-c", OTHER_KERNELS_PROBE, str(safe), "continuous/trpo,shield=true"],
                          env={**os.environ, "ATEN_CPU_CAPABILITY": "default"}, capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    ((capability, job, same, detail),) = [line.split("|", 3) for line in done.stdout.splitlines()]
    assert (capability, job, same) == ("DEFAULT", "continuous/trpo,shield=true", "True"), detail
    # The same job with the goal reward changed (0.5 -> 0.45) is caught, in its training, within the probe.
    reference = Reference.load(safe)
    recorded = reference.recorded_probe()
    changed = probe({"continuous/trpo,shield=true": [*reference.jobs["continuous/trpo,shield=true"],
                                                     "reward.c_goal=0.45"]}, progress=False)
    (result,) = compare(recorded[recorded["job"] == "continuous/trpo,shield=true"], changed)
    assert not result.same and result.detail.startswith("train/"), result.detail
