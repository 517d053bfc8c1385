"""The training benchmark compares like with like: SB3's features extractor is our encoder plus a dense 256, and
the SB3 adapter of the gymnasium face resets finished worlds within the step, as SB3 expects."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

pytest.importorskip("stable_baselines3")

from sidewalk.algos.networks import ImageEncoder
from sidewalk.bench.training import paper_conv_extractor_class, sb3_greedy_policy, sb3_vec_env


def test_sb3_extractor_is_our_encoder_plus_dense_256():
    envs = sb3_vec_env(2, seed=0)
    extractor = paper_conv_extractor_class()(envs.observation_space, features_dim=256)
    ours = ImageEncoder(torch.Size(envs.observation_space.shape))
    ours_dense = nn.Linear(ours.out_features, 256)

    def shapes(module):
        return [tuple(p.shape) for p in module.parameters()]

    assert shapes(extractor) == shapes(ours) + shapes(ours_dense)
    assert sum(p.numel() for p in extractor.parameters()) == sum(
        p.numel() for p in [*ours.parameters(), *ours_dense.parameters()]
    )
    # Same conv arithmetic: SB3 sees /255-normalised floats, ours takes the uint8 image.
    observation = torch.as_tensor(envs.reset())
    with torch.no_grad():
        for theirs, mine in zip(extractor.cnn, ours.net):
            if isinstance(theirs, nn.Conv2d):
                mine.weight.copy_(theirs.weight)
                mine.bias.copy_(theirs.bias)
        torch.testing.assert_close(extractor.cnn(observation.float() / 255.0), ours(observation))


def test_sb3_adapter_resets_finished_worlds_in_the_same_step():
    from stable_baselines3 import DQN

    envs = sb3_vec_env(4, seed=0)
    first = envs.reset()
    assert first.shape == (4, *envs.observation_space.shape) and first.dtype == np.uint8
    done_seen = np.zeros(4, dtype=bool)
    for _ in range(400):  # UP (0) walks into the wall or times out: every world ends within max_steps
        envs.step_async(np.zeros(4, dtype=np.int64))
        observation, _, done, infos = envs.step_wait()
        for i in np.flatnonzero(done):
            assert "terminal_observation" in infos[i] and "TimeLimit.truncated" in infos[i]
            # The next episode starts at once: the returned observation is a fresh start, not the last frame.
            assert not np.array_equal(observation[i], infos[i]["terminal_observation"])
        done_seen |= done
        if done_seen.all():
            break
    assert done_seen.all()
    # And SB3's DQN accepts the adapter with the paper's extractor; the greedy policy acts on our TensorDicts.
    model = DQN("CnnPolicy", envs, buffer_size=100, learning_starts=0, batch_size=4,
                policy_kwargs={"features_extractor_class": paper_conv_extractor_class()})
    model.learn(total_timesteps=16)
    from tensordict import TensorDict

    td = sb3_greedy_policy(model)(TensorDict({"observation": torch.as_tensor(first)}, batch_size=[4]))
    assert td["action"].shape == (4,) and td["action"].dtype == torch.int64


def test_the_criterion_is_three_evaluations_in_a_row_with_evaluation_time_taken_out():
    from sidewalk.bench.training import CONFIRM, TARGET, _Clock

    assert (TARGET, CONFIRM) == (0.9, 2)
    clock = _Clock(TARGET, seconds=1e9, eval_every_frames=100, confirm=CONFIRM)
    clock.start = 0.0
    # (success, eval start, eval end): each evaluation takes 1 s after 10 s of training.
    evaluations = [(0.95, 10, 11), (0.2, 21, 22), (0.9, 32, 33), (0.91, 43, 44), (1.0, 54, 55)]
    stops = [clock.on_eval(success, start, end) for success, start, end in evaluations]
    assert stops == [False, False, False, False, True]
    row = clock.row()
    # The criterion is met at the fifth evaluation: 50 s of training (4 s of evaluation taken out), 500 frames.
    assert row["met"] and row["seconds_to_criterion"] == 50 and row["frames_to_criterion"] == 500
    assert row["seconds_with_eval"] == 54 and row["seconds_first"] == 10


def test_a_run_that_misses_the_criterion_stops_at_its_cap_and_says_so():
    from sidewalk.bench.training import _Clock, _median

    clock = _Clock(0.9, seconds=30, eval_every_frames=100, confirm=2)
    clock.start = 0.0
    assert not clock.on_eval(0.95, 10, 10) and not clock.on_eval(0.95, 20, 20)
    assert clock.on_eval(0.5, 30, 30)  # the cap, not the criterion
    missed = clock.row()
    assert not missed["met"] and "seconds_to_criterion" not in missed and "no 3 evaluations" in missed["note"]
    met = {"met": True, "seconds_to_criterion": 10.0, "train_seconds": 10.0, "best_success": 1.0}
    base = {"threads": 1, "measure": "time_to_criterion", "setup": "equal", "learner": "ours", "num_envs": 128,
            "settings": ""}
    median = _median([{**base, **met}, {**base, **met, "seconds_to_criterion": 20.0}, {**base, **missed}])
    assert (median["seconds_to_criterion"], median["min_s"], median["max_s"]) == (20.0, 10.0, 30.0)
    assert median["met"] == "2/3" and "1/3 seeds did not meet" in median["note"]


def test_equal_settings_give_our_dqn_sb3s_network():
    """At the equal setup our Q-network (no dueling head) has the parameter shapes of SB3's CnnPolicy Q-network with
    the paper's extractor; at the defaults it has the dueling head's two streams."""
    from sidewalk.algos.dqn import DQN
    from sidewalk.bench.training import BASE_OVERRIDES, EQUAL_NETWORK, make_sb3_dqn, sb3_settings
    from sidewalk.compose import compose_experiment

    def our_shapes(*overrides):
        experiment = compose_experiment([*BASE_OVERRIDES, *overrides])
        algo = DQN(experiment.algo, experiment.world.make(2, 0, experiment.device))
        return [tuple(p.shape) for p in algo.actor.parameters()]

    sb3 = make_sb3_dqn({**sb3_settings(2), "buffer_size": 10}, total_frames=1000, seed=0)
    assert our_shapes(*EQUAL_NETWORK) == [tuple(p.shape) for p in sb3.policy.q_net.parameters()]
    dueling = our_shapes()
    assert len(dueling) == len(our_shapes(*EQUAL_NETWORK)) + 4  # value and advantage streams of two layers each


def test_plain_pytorch_reference_is_the_same_math_as_our_step():
    """The plain-PyTorch row counts the arithmetic of our DQN's step at each setup: 605 MFLOP at SB3's network (two
    passes and a backward), 864 MFLOP at the defaults (the dueling head; double DQN's third pass), and its network
    has our Q-network's parameter shapes."""
    from sidewalk.algos.dqn import DQN
    from sidewalk.bench.training import BASE_OVERRIDES, EQUAL_NETWORK, PlainQNetwork, plain_gradient_steps
    from sidewalk.compose import compose_experiment

    for extra, mflop in ((EQUAL_NETWORK, 605), ((), 864)):
        row = plain_gradient_steps(None, 1, extra, steps=4)
        assert row["learner"] == "plain" and row["cpu_ms_per_gradient_step"] > 0
        assert row["note"].startswith(f"{mflop} MFLOP a step")
        experiment = compose_experiment([*BASE_OVERRIDES, *extra])
        ours = DQN(experiment.algo, experiment.world.make(2, 0, experiment.device))
        plain = PlainQNetwork(ours.observation_spec.shape, 4, experiment.algo.hidden, experiment.algo.dueling)
        assert sorted(p.numel() for p in plain.parameters()) == sorted(p.numel() for p in ours.q_network.parameters())


def test_cost_notes_compare_ours_with_sb3_at_equal_and_with_plain_at_each_setup():
    from sidewalk.bench.training import _add_ratios

    def row(learner, setup, cpu_ms, fps=1000.0):
        return {"measure": "frames_per_s", "setup": setup, "learner": learner, "threads": 1, "frames_per_s": fps,
                "ms_per_gradient_step": 2 * cpu_ms, "cpu_ms_per_gradient_step": cpu_ms}

    rows = [row("ours", "equal", 8.0), row("sb3", "equal", 10.0, 500.0), row("plain", "equal", 8.0, None),
            row("ours", "dueling", 12.0), row("plain", "dueling", 10.0, None)]
    _add_ratios(rows)
    assert rows[0]["note"] == ("2.00x SB3's frames/s; 0.80x (0.80x wall) SB3's cost per gradient step; "
                               "1.00x (1.00x wall) plain PyTorch's")
    assert rows[3]["note"] == "1.20x (1.20x wall) plain PyTorch's"  # SB3 has no dueling head: no SB3 ratio
