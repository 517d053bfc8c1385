"""The exact state of a running trial, to checkpoint it and continue bit for bit: its view, core env and opponent
(every world mid-episode, the generator), its collector (``sidewalk._torchrl``) and the global RNGs."""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from sidewalk.opponents.base import ReplicaOpponent


def _tensor_attributes(obj: Any) -> dict[str, Any]:
    """An object's tensor, tensordict and dict-of-tensor attributes, plus its ``None`` ones (unset memories), but
    for the scratch it declares (``Opponent.scratch``)."""
    state = {}
    scratch = getattr(obj, "scratch", ())
    for name, value in vars(obj).items():
        if name in scratch:
            continue
        if isinstance(value, (torch.Tensor, TensorDictBase)) or (value is None and name.startswith("_")):
            state[name] = value
        elif isinstance(value, dict) and value and all(isinstance(v, torch.Tensor) for v in value.values()):
            state[name] = dict(value)
    return state


def capture_env(view: EnvBase) -> dict[str, Any]:
    """The running state of a view, its core env and its opponent: every world mid-episode, the generator (a
    replicated core's: the list of its replicas' generators; a ``ReplicaOpponent``: each replica's opponent too)."""
    core = view.core
    generators = getattr(core, "generators", [core.generator])
    rng = core.generator.get_state() if len(generators) == 1 else [g.get_state() for g in generators]
    state = {"view": _tensor_attributes(view), "core": _tensor_attributes(core), "rng": rng}
    opponent = getattr(view, "opponent", None)
    if opponent is not None:
        state["opponent"] = _tensor_attributes(opponent)
        if isinstance(opponent, ReplicaOpponent):
            state["opponent_replicas"] = [_tensor_attributes(each) for each in opponent.opponents]
    return state


def restore_env(view: EnvBase, state: dict[str, Any]) -> None:
    for name, value in state["view"].items():
        setattr(view, name, value)
    for name, value in state["core"].items():
        setattr(view.core, name, value)
    for name, value in state.get("opponent", {}).items():
        setattr(view.opponent, name, value)
    opponent = getattr(view, "opponent", None)
    replicas = opponent.opponents if isinstance(opponent, ReplicaOpponent) else ()
    for each, attributes in zip(replicas, state.get("opponent_replicas", ())):
        for name, value in attributes.items():
            setattr(each, name, value)
    rng = state["rng"]
    generators = getattr(view.core, "generators", [view.core.generator])
    if isinstance(rng, list) != (len(generators) > 1) or (isinstance(rng, list) and len(rng) != len(generators)):
        raise ValueError(f"the snapshot's generator state does not fit an env of {len(generators)} replica(s)")
    for generator, generator_state in zip(generators, rng if isinstance(rng, list) else [rng]):
        generator.set_state(generator_state)


def capture_rng() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def restore_rng(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
