"""Evaluation computes the policy once per distinct input, plays one world for all where every world plays the same
episode, and gives what the plain batched loop gives."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from torchrl.envs import RewardSum, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

import sidewalk.evaluate as evaluation
from sidewalk.config import validate
from sidewalk.envs import DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate
from sidewalk.registry import LEARNERS
from sidewalk.schema import register_schemas

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
register_schemas()


def learner_and_view(*overrides: str, worlds: int = 64):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        exp = validate(compose(config_name="config", overrides=["logger=none", *overrides]))
    torch.manual_seed(0)
    algo = LEARNERS[exp.algo.name](exp.algo, TransformedEnv(exp.world.make(8, 0, exp.device), RewardSum()))
    return algo.evaluation_policy(), exp.world.make(worlds, 7, exp.device)


class CountingPolicy(torch.nn.Module):
    """The policy, counting the inputs it is called on."""

    def __init__(self, policy) -> None:
        super().__init__()
        self.policy, self.in_keys, self.out_keys, self.inputs = policy, policy.in_keys, policy.out_keys, []

    def forward(self, td):
        self.inputs.append(td.batch_size[0])
        return self.policy(td)


def test_policy_runs_once_per_distinct_observation_of_the_running_worlds():
    policy, view = learner_and_view("env=discrete", "eval=nominal", worlds=8)
    td = view.reset()  # noise 0, the fixed starts: every world starts alike
    observation = td.get("observation").clone()
    observation[5:] = torch.randint_like(observation[5:], 0, 255)  # three more distinct worlds
    td.set("observation", observation)
    running = torch.tensor([True, True, True, True, True, True, True, False])
    counting = CountingPolicy(policy)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = evaluation.act_on_distinct(counting, td.clone(), running)
        plain = policy(td.clone())
    assert counting.inputs == [3]  # worlds 0-4 share one image; 5 and 6 differ; 7 has finished
    assert torch.equal(out.get("action")[:7], plain.get("action")[:7])
    assert torch.equal(out.get("action")[7], out.get("action")[0])  # a finished world gets a valid action


def test_distinct_rows_are_exact():
    flat = torch.randint(0, 3, (64, 5), dtype=torch.uint8, generator=torch.Generator().manual_seed(1))
    for rows in (flat, flat[:1].expand(8, 5)):
        first_of, inverse = evaluation.distinct_rows(rows)
        assert torch.equal(rows[first_of][inverse], rows)
        assert len(first_of) == len(torch.unique(rows, dim=0))
        assert all(int(first) == int((inverse == group).nonzero()[0]) for group, first in enumerate(first_of))


@pytest.mark.parametrize(
    "overrides",
    [("env=discrete", "noise=0.1"), ("env=continuous", "noise=0.5"), ("env=discrete", "opponent=centralized")],
    ids=["grid-dqn", "continuous-trpo", "grid-centralized"],
)
def test_evaluation_equals_the_plain_batched_loop(monkeypatch, overrides):
    policy, view = learner_and_view(*overrides)
    fast = evaluation.evaluate(view, policy, seed=11)
    monkeypatch.setattr(evaluation, "act_on_distinct", lambda policy, td, running: policy(td))
    plain = evaluation.evaluate(view, policy, seed=11)
    assert fast.keys() == plain.keys()
    for key in fast:
        assert fast[key] == pytest.approx(plain[key], nan_ok=True), key


def test_a_sampling_policy_draws_for_every_world():
    policy, view = learner_and_view("env=continuous", worlds=16)
    counting = CountingPolicy(policy)
    evaluation.run_episodes(view, counting, seed=3, deterministic=False)
    assert set(counting.inputs) == {16}  # never deduplicated: equal inputs would share one draw


NOMINAL_V1 = ("eval=nominal", "opponent.params.tie_break=progress")  # the paper's fixed starts, a deterministic partner


@pytest.mark.parametrize("overrides, distinct", [(NOMINAL_V1, 1), (("noise=0.3", *NOMINAL_V1), 16)])
def test_distinct_episodes_says_how_many_different_episodes_an_evaluation_played(overrides, distinct):
    policy, view = learner_and_view("env=discrete", *overrides, worlds=16)
    metrics = evaluation.evaluate(view, policy, seed=11)
    # noise 0 in the fixed sidewalk: 16 worlds, one episode (its rates are 0 or 1); noise: every world its own
    assert (metrics["episodes"], metrics["distinct_episodes"]) == (16, distinct)


ONCE_CASES = {  # overrides: whether one world plays for all (every world starts alike and nothing draws)
    "grid-centralized": (("env=discrete", "opponent=centralized", "eval=nominal"), True),
    "continuous-prm": (("env=continuous", "opponent=prm", "eval=nominal"), True),
    "grid-selfplay": (("env=discrete", "opponent=self", "algo=iql", "eval=nominal"), True),
    "grid-dijkstra-random-ties": (("env=discrete", "opponent=dijkstra", "eval=nominal"), False),  # draws each step
    "grid-noise": (("env=discrete", "opponent=centralized", "eval=nominal", "noise=0.2"), False),
    "grid-perturbed": (("env=discrete", "opponent=centralized", "eval=perturbed"), False),  # worlds start apart
}


@pytest.mark.parametrize("case", list(ONCE_CASES))
def test_one_world_plays_for_all_exactly_where_every_world_plays_the_same_episode(case, monkeypatch):
    overrides, once = ONCE_CASES[case]
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        exp = validate(compose(config_name="config", overrides=["logger=none", *overrides]))
    torch.manual_seed(0)
    policy = LEARNERS[exp.algo.name](exp.algo, TransformedEnv(exp.world.make(8, 0, exp.device), RewardSum())).evaluation_policy()
    view = exp.eval_world.make(32, 7, exp.device)
    plain = evaluation.run_episodes(view, policy, seed=11, record_trajectories=3)
    steps, built = [], []
    step = view.step
    monkeypatch.setattr(view, "step", lambda td: steps.append(1) or step(td))

    def one_world():
        built.append(exp.eval_world.make(1, 7, exp.device))
        return built[-1]

    global_rng = torch.get_rng_state()
    record = evaluation.run_episodes(view, policy, seed=11, record_trajectories=3, one_world=one_world)
    assert torch.equal(torch.get_rng_state(), global_rng)
    assert (not steps) == once and len(built) == (0 if case == "grid-perturbed" else 1)  # perturbed: no world built
    fast, slow = evaluation.summarize(record), evaluation.summarize(plain)
    assert fast.keys() == slow.keys()
    assert all(fast[key] == slow[key] or (math.isnan(fast[key]) and math.isnan(slow[key])) for key in fast), case
    np.testing.assert_array_equal(record.trajectories, plain.trajectories)


def test_an_epsilon_greedy_evaluation_draws_its_own_seeded_stream_and_zero_is_greedy():
    # A shipped grid IQL policy in self-play, on 64 worlds of the perturbed protocol's rows.
    from sidewalk.partners.policy import partner_policy, read_partner
    from sidewalk.views.selfplay import SelfPlayView

    partner = read_partner(ROOT / "sidewalk/partners/discrete/iql_seed0")
    policy, _ = partner_policy(partner)
    params = dataclasses.replace(partner.world.env_params, start_jitter_rows=1, goal_jitter_rows=1)

    def metrics(epsilon: float) -> dict:
        return evaluate(SelfPlayView(DiscreteSidewalkEnv(64, seed=7, params=params)), policy, seed=7, epsilon=epsilon)

    greedy = metrics(0.0)
    assert greedy == evaluate(SelfPlayView(DiscreteSidewalkEnv(64, seed=7, params=params)), policy, seed=7)
    exploring = metrics(0.05)
    assert exploring == metrics(0.05)  # the same seed, the same draws
    # Random actions part worlds that started alike: more distinct episodes than the greedy pair plays.
    assert exploring["distinct_episodes"] > greedy["distinct_episodes"]
    with pytest.raises(ValueError, match=r"epsilon=1.0 is out of range; valid: \[0, 1\)"):
        metrics(1.0)


def test_eval_epsilon_is_checked_and_written_into_the_protocol():
    from sidewalk.report.document import protocol_text

    with pytest.raises(ValueError, match="eval.epsilon=1.0 is out of range"):
        validate(compose_config(["eval.epsilon=1.0"]))
    with pytest.raises(ValueError, match="eval.epsilon=-0.1 is out of range"):
        validate(compose_config(["eval.epsilon=-0.1"]))
    experiment = validate(compose_config(["eval.epsilon=0.01", "opponent=self", "algo=iql"]))
    assert experiment.protocol_summary()["epsilon"] == 0.01
    flat = {"env.domain": "discrete", "eval.name": "perturbed", "eval.start_jitter_rows": 1, "eval.epsilon": 0.01}
    assert protocol_text(flat) == "perturbed (starts ±1 rows; ε-greedy at 0.01)"


def compose_config(overrides: list[str]):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)
