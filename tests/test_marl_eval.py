"""The report's marl-eval files (sidewalk.report.marl_eval) loaded by marl-eval's own code: every file the report writes
for a set of runs of several conditions, tasks and evaluation counts, and the reference's committed files, pass
``DiagnoseData(...).check_data()`` and load through ``data_process_pipeline`` and ``create_matrices_for_rliable``;
one merges with a file that BenchMARL's own writer made for a BenchMARL run of our task. marl-eval (id-marl-eval,
installed with --no-deps by the README's test command) is imported for real."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
from marl_eval.utils.data_processing_utils import create_matrices_for_rliable, data_process_pipeline
from marl_eval.utils.diagnose_data_errors import DiagnoseData
from omegaconf import OmegaConf

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial
from sidewalk.report.conditions import group_conditions
from sidewalk.report.document import write_report
from sidewalk.report.marl_eval import ABSOLUTE, ENVIRONMENT, MARL_EVAL_DIR, marl_eval_sets, merge_marl_eval
from sidewalk.report.runs import find_run_folders, load_run
from sidewalk.report.tables import Settings

ROOT = Path(__file__).resolve().parents[1]
SMALL = ("eval_episodes=8", "num_envs=4", "logger=none")
PPO = ("algo=ppo", "opponent=random", "iterations=2", "eval_every=1", "algo.frames_per_batch=16",
       "algo.minibatch_size=8", "algo.epochs=1", *SMALL)
# Two algorithms (PPO at two discounts) on two tasks, seeds 0 and 1, two evaluations: one file of two tasks. Self-play
# MAPPO (BenchMARL's task) at three evaluations, seed 0 alone: a file of its own, which merges with BenchMARL's run.
CONDITIONS = {
    "ppo_discrete": ("env=discrete", *PPO),
    "ppo_discrete_gamma": ("env=discrete", "algo.gamma=0.9", *PPO),
    "ppo_continuous": ("env=continuous", *PPO),
    "ppo_continuous_gamma": ("env=continuous", "algo.gamma=0.9", *PPO),
}
SELFPLAY = ("+experiment=selfplay_continuous", "algo=mappo", "iterations=3", "eval_every=1",
            "algo.frames_per_batch=100", "algo.minibatch_size=50", "algo.epochs=1", *SMALL)
MULTI_TASK = "sidewalk_discrete+sidewalk_continuous_2_evaluations_32_frames"
SELFPLAY_FILE = "sidewalk_continuous_3_evaluations_300_frames"


def train(run_dir: Path, *overrides: str) -> None:
    cfg = compose(list(overrides))
    Trial(validate(cfg), run_dir, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """The report's folder for ten small runs of five conditions (two tasks, two evaluation counts, two seed sets)."""
    root = tmp_path_factory.mktemp("marl_eval")
    for name, overrides in CONDITIONS.items():
        for seed in (0, 1):
            train(root / "runs" / name / str(seed), f"seed={seed}", *overrides)
    train(root / "runs" / "selfplay" / "0", "seed=0", *SELFPLAY)
    write_report([root / "runs"], root / "report", Settings(n_resamples=200, trajectory_episodes=0))
    return root / "report"


def loads_whole(raw: dict) -> tuple[dict, dict]:
    """marl-eval's checks all pass on ``raw``, and its matrices for rliable: (absolute, per-step)."""
    checks = DiagnoseData(raw).check_data()
    assert checks and all(all(check.values()) for check in checks.values()), checks
    processed = data_process_pipeline(raw, metrics_to_normalize=[])
    assert "extra" in processed  # the pipeline returns the raw data unprocessed when the format is wrong
    return create_matrices_for_rliable(processed, ENVIRONMENT, metrics_to_normalize=[])


def test_each_file_the_report_writes_loads_whole_in_marl_eval(report):
    files = {path.stem: json.loads(path.read_text()) for path in sorted((report / MARL_EVAL_DIR).glob("*.json"))}
    assert sorted(files) == sorted([MULTI_TASK, SELFPLAY_FILE])
    absolute, steps = loads_whole(files[MULTI_TASK])
    algorithms = {"ppo vs random; gamma=0.99", "ppo vs random; gamma=0.9"}  # the same in both tasks
    assert set(absolute["mean_success_rate"]) == algorithms
    for algorithm in algorithms:
        assert absolute["mean_success_rate"][algorithm].shape == (2, 2)  # seeds x tasks
        assert steps["mean_success_rate"][algorithm].shape == (2, 2, 2)  # seeds x tasks x evaluations
    absolute, steps = loads_whole(files[SELFPLAY_FILE])
    assert {name: matrix.shape for name, matrix in absolute["mean_success_rate"].items()} == {"mappo vs self": (1, 1)}
    assert "## marl-eval files" in (report / "report.md").read_text()
    assert f"[`{MARL_EVAL_DIR}/{MULTI_TASK}.json`]" in (report / "report.md").read_text()


def test_runs_are_named_as_benchmarl_names_them_and_carry_their_episode_counts(report):
    data = json.loads((report / MARL_EVAL_DIR / f"{MULTI_TASK}.json").read_text())
    runs = report.parent / "runs" / "ppo_continuous"
    (algorithm, algorithm_runs), = ((a, r) for a, r in data[ENVIRONMENT]["sidewalk_continuous"].items()
                                    if a.endswith("0.99"))
    assert "," not in algorithm  # marl-eval refuses commas in algorithm names
    assert sorted(algorithm_runs) == ["seed_0", "seed_1"]
    for seed, run in enumerate(algorithm_runs.values()):
        summary = json.loads((runs / str(seed) / "summary.json").read_text())
        assert list(run) == ["step_1", "step_2", ABSOLUTE]  # BenchMARL's step names: frames / evaluation interval
        assert [run[step]["step_count"] for step in ("step_1", "step_2")] == [16, 32]
        final = run["step_2"]
        assert sorted(final) == ["collision_rate", "distinct_episodes", "episodes", "return", "step_count",
                                 "success_rate"]
        assert final["success_rate"] == [summary["ego/success_rate"]]  # one value: the evaluation's rate
        assert final["return"] == [pytest.approx(summary["ego/return"])]
        assert final["episodes"] == [8] and final["distinct_episodes"] == [summary["distinct_episodes"]]
        assert run[ABSOLUTE]["success_rate"] == [summary["absolute"]["ego/success_rate"]]  # best policy, 10x episodes
        assert run[ABSOLUTE]["episodes"] == [80]
        assert run[ABSOLUTE]["distinct_episodes"] == [summary["absolute"]["distinct_episodes"]]


def benchmarl_json(folder: Path, seed: int) -> dict:
    """The file BenchMARL's own ``JsonWriter`` writes for its MAPPO on our sidewalk_continuous task: three iterations of
    100 frames, each evaluated, as our self-play run above."""
    from sidewalk.interop.benchmarl import SidewalkTask  # first: adapts BenchMARL to this TorchRL

    task = SidewalkTask.SIDEWALK_CONTINUOUS.get_from_yaml()
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig

    config = ExperimentConfig.get_from_yaml()
    config.max_n_iters, config.max_n_frames = 3, None
    config.loggers, config.render, config.save_folder, config.create_json = [], False, str(folder), True
    config.on_policy_collected_frames_per_batch, config.on_policy_n_envs_per_worker = 100, 4
    config.on_policy_minibatch_size, config.on_policy_n_minibatch_iters = 50, 1
    config.evaluation_interval, config.evaluation_episodes = 100, 2
    experiment = Experiment(
        task=task, algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(), seed=seed,
        config=config,
    )
    experiment.run()
    return json.loads(Path(experiment.logger.json_writer.path).read_text())


@pytest.mark.skipif(importlib.util.find_spec("benchmarl") is None,
                    reason="BenchMARL is installed by the README's test command")
def test_our_self_play_file_merges_with_a_file_benchmarl_wrote_for_our_task(report, tmp_path):
    ours = json.loads((report / MARL_EVAL_DIR / f"{SELFPLAY_FILE}.json").read_text())
    theirs = benchmarl_json(tmp_path, seed=0)
    (their_run,) = theirs[ENVIRONMENT]["sidewalk_continuous"]["mappo"].values()
    assert sorted(their_run) == [ABSOLUTE, "step_1", "step_2", "step_3"]  # BenchMARL's names, as ours
    assert sorted(their_run["step_1"]) == ["agents_return", "return", "step_count"]
    merged = merge_marl_eval(ours, theirs)
    absolute, steps = loads_whole(merged)
    assert set(absolute) == {"mean_return"}  # the one metric both write
    assert {name: matrix.shape for name, matrix in steps["mean_return"].items()} == {
        "mappo vs self": (1, 1, 3), "mappo": (1, 1, 3)}
    with pytest.raises(ValueError, match="mappo/seed_0 is in two files"):
        merge_marl_eval(theirs, theirs)


@pytest.mark.parametrize("reference", ["results/reference", "results/reference/safe"])
def test_the_reference_s_committed_files_are_what_the_report_writes_and_load_whole(reference):
    folder = ROOT / reference / MARL_EVAL_DIR
    committed = {path.name: path.read_text() for path in sorted(folder.glob("*.json"))}
    assert committed, f"no marl-eval file under {folder}"
    for text in committed.values():
        loads_whole(json.loads(text))
    conditions = group_conditions([load_run(path) for path in find_run_folders([ROOT / reference / "runs"])])
    written = {f"{marl_set.name}.json": json.dumps(marl_set.data, separators=(",", ":")) + "\n"
               for marl_set in marl_eval_sets(conditions)}
    assert written == committed, "re-make them: python runners/report.py (results/reference/run.sh's last line)"
