"""sidewalk/_torchrl.py, the one adapter over TorchRL's private attributes, still does its jobs on the installed
TorchRL: a failure here means TorchRL changed what the adapter relies on, and names what."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torchrl
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.data.tensor_specs import ContinuousBox
from torchrl.envs import EnvBase

from sidewalk._torchrl import (
    COLLECTOR_STATE_KEYS,
    collector_state,
    restore_collector_state,
    set_uniform_box,
)
from sidewalk.envs.grid import UniformBounded

WORLDS, STEPS_PER_BATCH, BATCHES, EPISODE_STEPS = 3, 2, 4, 5


class Walk(EnvBase):
    """A stateless batch of walkers: the position adds the action, an episode ends after ``EPISODE_STEPS`` steps.
    Everything a collector carries between batches is in its carrier, none in the env."""

    def __init__(self) -> None:
        super().__init__(batch_size=torch.Size([WORLDS]))
        self.observation_spec = Composite(
            position=Unbounded(shape=(WORLDS, 1)),
            steps=Unbounded(shape=(WORLDS, 1), dtype=torch.long),
            shape=(WORLDS,),
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(WORLDS, 1))
        self.reward_spec = Unbounded(shape=(WORLDS, 1))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        start = torch.arange(WORLDS, dtype=torch.float32).unsqueeze(-1) / WORLDS
        return TensorDict(
            position=start,
            steps=torch.zeros(WORLDS, 1, dtype=torch.long),
            done=torch.zeros(WORLDS, 1, dtype=torch.bool),
            terminated=torch.zeros(WORLDS, 1, dtype=torch.bool),
            batch_size=self.batch_size,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        position = tensordict["position"] + tensordict["action"]
        steps = tensordict["steps"] + 1
        done = steps >= EPISODE_STEPS
        return TensorDict(
            position=position, steps=steps, reward=position.clone(), done=done, terminated=done.clone(),
            batch_size=self.batch_size,
        )

    def _set_seed(self, seed: int | None) -> None:
        pass


def walk_collector() -> Collector:
    # A deterministic policy of the position: the batches depend on where the carrier left the walkers.
    policy = TensorDictModule(lambda position: torch.sin(3.0 * position + 1.0), in_keys=["position"],
                              out_keys=["action"])
    return Collector(Walk(), policy, frames_per_batch=WORLDS * STEPS_PER_BATCH,
                     total_frames=WORLDS * STEPS_PER_BATCH * BATCHES, auto_register_policy_transforms=False)


def without_collector_keys(batch: TensorDictBase) -> TensorDictBase:
    # The trajectory ids count from the collector's own pool, which neither side of a resume restores.
    return batch.exclude("collector", ("next", "collector"))


def test_a_restored_collector_continues_with_the_next_batch_and_stops_on_time():
    original = walk_collector()
    batches = iter(original)
    next(batches)
    state = collector_state(original)
    assert set(state) == set(COLLECTOR_STATE_KEYS)
    expected = [without_collector_keys(batch) for batch in batches]
    assert len(expected) == BATCHES - 1

    resumed = walk_collector()
    restore_collector_state(resumed, {**state, "other": "keys of a checkpoint are left alone"})
    got = [without_collector_keys(batch) for batch in resumed]
    assert len(got) == BATCHES - 1  # the frames collected before the checkpoint count toward total_frames
    for want, have in zip(expected, got):
        assert (want == have).all()
    assert bool(torch.stack([batch["next", "done"].any() for batch in got]).any())  # resets happened in between

    fresh = without_collector_keys(next(iter(walk_collector())))
    assert not (fresh == expected[0]).all()  # the carrier is what made the difference


def test_collector_state_is_a_copy():
    collector = walk_collector()
    batches = iter(collector)
    next(batches)
    state = collector_state(collector)
    carrier = state["carrier"].clone()
    next(batches)
    assert (state["carrier"] == carrier).all()
    assert (state["collector_frames"], state["collector_iter"]) == (WORLDS * STEPS_PER_BATCH, 0)


@pytest.mark.parametrize("call", [collector_state, lambda obj: restore_collector_state(obj, {})])
def test_a_collector_without_the_attributes_raises_naming_torchrl_and_the_attribute(call):
    with pytest.raises(RuntimeError, match=rf"TorchRL {torchrl.__version__}.*'_carrier'"):
        call(object())


def test_the_box_stores_what_torchrls_setter_stores():
    assert {"_low", "_high", "_batch_size"} <= {f.name for f in dataclasses.fields(ContinuousBox)}
    high = torch.full((4, 3, 2), 9, dtype=torch.uint8)
    ours = Bounded(torch.zeros_like(high), high, shape=high.shape, dtype=torch.uint8)
    theirs = ours.clone()
    set_uniform_box(ours.space, ours.space.low[0, 0].clone(), ours.space.high[0, 0].clone(), torch.Size([4, 3]))
    theirs.space.batch_size = torch.Size([4, 3])  # TorchRL's own check, then what it stores
    for name in ("_low", "_high", "_batch_size"):
        assert torch.equal(torch.as_tensor(getattr(ours.space, name)), torch.as_tensor(getattr(theirs.space, name)))


def test_a_uniform_box_keeps_the_spec_valid():
    high = torch.full((4, 3, 2), 9, dtype=torch.uint8)
    spec = Bounded(torch.zeros_like(high), high, shape=high.shape, dtype=torch.uint8)
    set_uniform_box(spec.space, torch.zeros(2, dtype=torch.uint8), torch.full((2,), 9, dtype=torch.uint8),
                    torch.Size([4, 3]))
    assert spec.space.batch_size == (4, 3)
    assert torch.equal(spec.space.low, torch.zeros_like(high)) and torch.equal(spec.space.high, high)
    assert spec.is_in(spec.rand()) and spec.is_in(spec.zero())
    assert not spec.is_in(torch.full_like(high, 10))
    assert torch.equal(spec.project(torch.full_like(high, 200)), high)
    assert spec.clone() == spec and spec[1].shape == (3, 2)


def test_a_box_without_the_attributes_raises_naming_torchrl_and_the_attribute():
    with pytest.raises(RuntimeError, match=rf"TorchRL {torchrl.__version__}.*'_low'"):
        set_uniform_box(object(), torch.zeros(1), torch.ones(1), torch.Size([2]))


def test_composite_registers_the_batch_size_through_uniform_bounded():
    # UniformBounded overrides Bounded._register_batch_size, the hook a Composite calls with its shape.
    high = torch.full((5, 2, 3), 255, dtype=torch.uint8)
    spec = UniformBounded(torch.zeros_like(high), high, shape=high.shape, dtype=torch.uint8)
    composite = Composite(observation=spec, shape=(5, 2))
    kept = composite["observation"]
    assert type(kept) is UniformBounded and kept.space.batch_size == (5, 2)
    assert torch.equal(kept.space.high, high)
