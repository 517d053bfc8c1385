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
