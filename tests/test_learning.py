"""Learning actually happens: on a small budget, DQN and TRPO beat a random policy's ego success.

These are the suite's slow tests (marked ``slow``), kept few and small: a 6-cell sidewalk with vector
observations, ~15k frames each, against the Dijkstra opponent. (In the continuous world, with the SPEC's reward
constants and geometry, crashing at once outscores the ~95-step walk to the goal, so reaching the goal is not
what a return-maximising learner should do there; see the README.)
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from sidewalk.config import register_schemas, validate
from sidewalk.evaluate import evaluate
from sidewalk.experiment import EVAL_SEED_OFFSET, Trial, make_view

pytestmark = pytest.mark.slow
CONF = Path(__file__).resolve().parents[1] / "conf"
register_schemas()


def experiment(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return validate(compose(config_name="config", overrides=["logger=none", "eval_episodes=64", *overrides]))


def random_policy_success(exp) -> float:
    view = make_view(exp, exp.eval_episodes, exp.seed + EVAL_SEED_OFFSET)
    return evaluate(view, None, seed=exp.seed + EVAL_SEED_OFFSET)["ego/success_rate"]


SMALL_SIDEWALK = ["opponent=dijkstra", "env.length_cells=6", "env.observation=vector"]


@pytest.mark.parametrize(
    "overrides",
    [
        ["algo=dqn", "iterations=120", "eval_every=0", "algo.eps_decay_frames=5000", "algo.learning_starts=500"],
        ["algo=trpo", "num_envs=16", "iterations=15", "eval_every=0"],
    ],
    ids=["dqn", "trpo"],
)
def test_learner_beats_the_random_policy(tmp_path, overrides):
    exp = experiment(*SMALL_SIDEWALK, *overrides)
    baseline = random_policy_success(exp)
    summary = Trial(exp, tmp_path).run(progress=False)
    assert baseline < 0.3  # the task is not solved by chance ...
    assert summary["ego/success_rate"] >= baseline + 0.5, summary  # ... and the learner solves it
