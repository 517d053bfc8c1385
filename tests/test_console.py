"""What a run prints once its bar is full: what the evaluation rests on, the learner's rate before the means over
agents, a line for the long final step (the absolute metric), and a Ctrl-C there that says what it does: the run
finishes (the first Ctrl-C no longer promises a checkpoint at the end of an iteration that will not come)."""

from __future__ import annotations

import json
import os
import signal

from omegaconf import OmegaConf

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.experiment import Trial

TINY = ["num_envs=4", "iterations=2", "eval_every=2", "eval_episodes=8", "logger=none", "checkpoint_every=0",
        "algo.learning_starts=0", "algo.frames_per_batch=16", "algo.batch_size=16"]


def test_the_summary_says_what_the_evaluation_rests_on_and_puts_the_learners_rate_first(runner, capsys):
    main = runner("main")
    summary = {"eval_protocol": {"name": "perturbed"}, "episodes": 256.0, "distinct_episodes": 246.0,
               "success_rate": 0.811, "ego/success_rate": 0.621, "other/success_rate": 1.0, "wall_clock_s": 60.0}
    assert main.report([summary], "results/runs/x", plots=False) == 0.621
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "run folder: results/runs/x" and lines[1] == "  eval: perturbed, 256 episodes (246 distinct)"
    names = [line.split()[0] for line in lines[2:]]
    assert names[0] == "ego/success_rate" and names.index("ego/success_rate") < names.index("success_rate")
    (mean,) = [line for line in lines if line.split()[0] == "success_rate"]
    assert mean.split()[1:] == ["(mean", "over", "agents)", "0.811"]
    assert main.evaluated_on({"eval_protocol": {"name": "nominal"}, "episodes": 16.0, "distinct_episodes": 1.0}) \
        == "eval: nominal, 16 episodes (1 distinct)"


def run_tiny(tmp_path, capsys, interrupt_at: str) -> tuple[dict, str]:
    """A two-iteration run sent one Ctrl-C (SIGINT) in its last iteration's evaluation (``"last_evaluation"``) or
    in the absolute metric after the bar (``"absolute"``); its summary and stderr."""
    cfg = compose(TINY)
    trial = Trial(validate(cfg), tmp_path / "run", OmegaConf.to_container(cfg, resolve=True))

    def ctrl_c(*_):
        os.kill(os.getpid(), signal.SIGINT)  # the handler records it; the run goes on

    if interrupt_at == "absolute":
        absolute = trial._absolute
        trial._absolute = lambda *args: (ctrl_c(), absolute(*args))[1]
    (summary,) = trial.run(progress=True, on_evaluation=(lambda *args: bool(ctrl_c()))
                        if interrupt_at == "last_evaluation" else None)
    return summary, capsys.readouterr().err


def test_a_ctrl_c_in_the_last_iteration_or_the_final_evaluation_says_the_run_finishes_and_it_does(tmp_path, capsys):
    for phase in ("last_evaluation", "absolute"):
        summary, stderr = run_tiny(tmp_path / phase, capsys, phase)
        assert "Ctrl-C: training is over; finishing the run's final evaluation and summary" in stderr, stderr
        assert "checkpointing at the end of this iteration" not in stderr
        assert summary["iterations"] == 2 and summary["absolute"] is not None
        assert json.loads((tmp_path / phase / "run" / "summary.json").read_text())["iterations"] == 2
        assert "absolute metric: the best evaluation's policy (iteration 2) on 80 worlds..." in stderr


def test_a_runs_report_names_it_as_the_user_does_not_by_the_machines_absolute_path(tmp_path, monkeypatch, runner):
    import shutil

    from sidewalk.report.document import write_report
    from sidewalk.report.tables import Settings

    cfg = compose(TINY)
    run = tmp_path / "results" / "runs" / "mine"
    Trial(validate(cfg), run, OmegaConf.to_container(cfg, resolve=True)).run(progress=False, absolute_metric=False)
    monkeypatch.chdir(tmp_path)
    report = write_report([run], run / "report", Settings(n_resamples=100)).report_md.read_text()
    header = report.splitlines()[2]
    assert "from `results/runs/mine`:" in header and str(tmp_path) not in report, header
    assert "`..`" not in report
    shutil.rmtree(run / "report")
    monkeypatch.chdir(tmp_path.parent / tmp_path.name / "results")  # outside the run's parent: still relative there
    assert "from `runs/mine`:" in write_report([run], run / "report", Settings(n_resamples=100)).report_md.read_text()
