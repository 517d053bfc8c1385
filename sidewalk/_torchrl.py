"""The one place where sidewalk touches private attributes of TorchRL (and of torch and tensordict), each for a job
their public API cannot do.

TorchRL may rename or drop a private attribute in any release. Every function here checks that the attributes it
uses exist before it reads or writes them and raises a ``RuntimeError`` naming the TorchRL version and the missing
attribute, so a change shows up as a clear error here (and in ``tests/test_torchrl_adapter.py``), never as a
silently new attribute that TorchRL ignores. Checked against TorchRL 0.14.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torchrl

if TYPE_CHECKING:  # the envs import this module: no collector import on their path
    import torch
    from torchrl.collectors import Collector
    from torchrl.data.tensor_specs import ContinuousBox

# A Collector's running state, under the keys that checkpoints written by ``sidewalk.experiment`` hold it.
COLLECTOR_STATE_KEYS = ("carrier", "collector_frames", "collector_iter")
# The Collector's private attribute behind each key: the tensordict carried from one batch to the next (the worlds
# mid-episode, their running reward sums), the frames collected so far, the iterations run so far.
_COLLECTOR_ATTRIBUTES = {"carrier": "_carrier", "collector_frames": "_frames", "collector_iter": "_iter"}
# A ContinuousBox's bounds and batch size, as its batch_size setter stores them.
_BOX_ATTRIBUTES = ("_low", "_high", "_batch_size")


def _require(obj: Any, names: tuple[str, ...], why: str) -> None:
    """Raise a ``RuntimeError`` unless ``obj`` has every attribute in ``names``."""
    missing = [name for name in names if not hasattr(obj, name)]
    if missing:
        raise RuntimeError(
            f"TorchRL {torchrl.__version__}: {type(obj).__name__} has no attribute {', '.join(map(repr, missing))}, "
            f"which sidewalk uses to {why}; sidewalk/_torchrl.py needs updating for this TorchRL version"
        )


def collector_state(collector: Collector) -> dict[str, Any]:
    """A Collector's running state, to checkpoint a run and resume it exactly: its carrier (cloned), frames and
    iterations, under ``COLLECTOR_STATE_KEYS``.

    Why private: ``Collector.state_dict()`` holds the frames and iterations but not the carrier, the tensordict
    that carries every world mid-episode into the next batch; without it a resumed run would reset every world.
    """
    _require(collector, tuple(_COLLECTOR_ATTRIBUTES.values()), "checkpoint a Collector's running state")
    return {
        "carrier": collector._carrier.clone(),
        "collector_frames": collector._frames,
        "collector_iter": collector._iter,
    }


def restore_collector_state(collector: Collector, state: dict[str, Any]) -> None:
    """Put back a state from ``collector_state`` (extra keys of ``state`` are ignored): the next batch continues
    where the captured collector's would have, given the env, the policy and the RNGs restored as well.

    Why private: ``Collector.load_state_dict()`` restores the frames and iterations but not the carrier, and it
    would reload the policy and env state that the caller restores itself.
    """
    _require(collector, tuple(_COLLECTOR_ATTRIBUTES.values()), "resume a Collector's running state")
    collector._carrier.update(state["carrier"])
    collector._frames, collector._iter = state["collector_frames"], state["collector_iter"]


def set_uniform_box(box: ContinuousBox, low: torch.Tensor, high: torch.Tensor, batch_size: torch.Size) -> None:
    """Give a spec's box bounds that are the same for every item of ``batch_size``: ``low`` and ``high`` are one
    item's bounds, stored as TorchRL's ``ContinuousBox.batch_size`` setter stores them once its check passes.

    Why private: that setter checks that every item's bounds agree with ``torch.allclose`` over the full-size
    bounds, seconds for the images of thousands of worlds; a caller that has checked already (exactly, as
    ``sidewalk.envs.grid.UniformBounded`` does) sets the result directly. No public setter stores it.
    """
    _require(box, _BOX_ATTRIBUTES, "set a spec's uniform bounds without TorchRL's full-size check")
    box._low, box._high, box._batch_size = low, high, batch_size
    if box.batch_size != batch_size:
        raise RuntimeError(
            f"TorchRL {torchrl.__version__}: {type(box).__name__}.batch_size no longer reads _batch_size, which "
            "sidewalk sets to give a spec uniform bounds; sidewalk/_torchrl.py needs updating for this TorchRL version"
        )


def _unchecked_tensordict_constructor() -> Any:
    from tensordict import TensorDict

    _require(TensorDict, ("_new_unsafe",), "build the envs' and views' step outputs without per-call validation")
    return TensorDict._new_unsafe


# ``TensorDict(source, batch_size)`` without its validation of every entry's shape and device, which costs more than
# a step of the envs and views at small batch sizes; they build their outputs with shapes that are right by
# construction (the env tests check them against the specs).
new_tensordict_unchecked = _unchecked_tensordict_constructor()


def multi_agent_mlp_last_layer(mlp: Any) -> str:
    """The parameter key of a ``MultiAgentMLP``'s output layer, to scale its initial weights (PPO's small last
    layer). Why private: the MLP's layer stack is only exposed as its ``_empty_net`` template."""
    _require(mlp, ("_empty_net",), "find a MultiAgentMLP's output layer")
    return str(len(mlp._empty_net) - 1)


def foreach_lerp_(targets: list, sources: list, weight: float) -> None:
    """``target += weight * (source - target)`` for every pair in one call: a Polyak step over a network's tensors.
    Why private: torch offers the fused multi-tensor lerp only as ``torch._foreach_lerp_``."""
    import torch

    _require(torch, ("_foreach_lerp_",), "take a Polyak step over all of a network's tensors in one call")
    torch._foreach_lerp_(targets, sources, weight)


# BenchMARL's modules that build TorchRL's QValueModule with a group's action spec (BenchMARL 1.5).
BENCHMARL_Q_VALUE_MODULES = ("benchmarl.algorithms.iql", "benchmarl.algorithms.vdn", "benchmarl.algorithms.qmix")


def adapt_benchmarl() -> None:
    """Make BenchMARL 1.5 (written for TorchRL 0.10-0.11) import and train on TorchRL 0.14; idempotent. Called only
    by ``sidewalk.interop.benchmarl``, which calls it before it imports BenchMARL. Two differences:

    - ``torchrl.collectors.SyncDataCollector``, which BenchMARL imports, is named ``Collector`` since TorchRL 0.14
      (the arguments BenchMARL passes are the same): the old name is set to the new class.
    - TorchRL 0.14's ``QValueModule`` checks its action's shape against ``spec`` taken as one sample's; BenchMARL's
      IQL, VDN and QMIX give it the agents group's spec (agents first), so every multi-agent action fails the check.
      Those three modules get ``QValueModule`` with ``strict_shape=False``: TorchRL 0.11's behaviour, no check.

    Why here: both write attributes of other packages' modules (TorchRL's, BenchMARL's)."""
    import functools
    import importlib

    from torchrl import collectors
    from torchrl.modules import QValueModule

    _require(collectors, ("Collector",), "alias the collector BenchMARL imports under its old name")
    if not hasattr(collectors, "SyncDataCollector"):
        collectors.SyncDataCollector = collectors.Collector
    for name in BENCHMARL_Q_VALUE_MODULES:
        module = importlib.import_module(name)
        _require(module, ("QValueModule",), "build BenchMARL's Q-value modules without TorchRL 0.14's shape check")
        if module.QValueModule is QValueModule:
            module.QValueModule = functools.partial(QValueModule, strict_shape=False)


def checkpoint_safe_globals() -> list[Any]:
    """What a checkpoint holds beyond tensors and plain data: TensorDicts (the replay buffer, the worlds
    mid-episode, the collector's carrier) and NumPy's RNG state (an array). Their reconstructors only build
    those types from tensors and plain data; every other global in a file is refused (``run_folder.read_torch_file``).
    Two of them are private: tensordict's ``_make_td`` and NumPy's ``_reconstruct``, the names the pickles hold."""
    import numpy as np
    import tensordict
    from tensordict._reductions import _make_td

    try:
        from numpy._core.multiarray import _reconstruct
    except ImportError:  # NumPy 1
        from numpy.core.multiarray import _reconstruct
    return [
        (_reconstruct, "numpy.core.multiarray._reconstruct"),  # the name NumPy 1 wrote
        (_reconstruct, "numpy._core.multiarray._reconstruct"),
        np.ndarray,
        np.dtype,
        type(np.dtype(np.uint32)),
        _make_td,
        tensordict.TensorDict,
    ]
