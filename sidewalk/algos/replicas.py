"""R copies of a learner's networks trained as one: the replica axis, for ``replicas=R`` (several seeds in one run).

A replicated network is the lone network with every parameter and buffer stacked on a leading replica axis, under
the lone network's own names: ``replicate_(network, R)`` gives each unit (TorchRL's MLP and conv stack, a linear or
conv layer, a state-independent scale) a class whose forward maps the lone unit over the replica axis
(``torch.func.functional_call`` of it, under ``torch.vmap`` on an accelerator, over each replica's slice on a CPU;
a unit whose only weights are linear layers, an MLP, runs its own forward with each layer one batched matmul).
Everything between the units (activations, flattening, TorchRL's actors, distributions and value estimators) is
shape-agnostic, so a
learner's update is written once for data with an optional leading replica axis: ``lead`` is ``()`` for a lone
learner and ``(R,)`` for R replicas, and its reductions run over the sample axes only (``sample_mean``). Replicas
draw from one global stream: a replica is statistically its lone run, not bit for bit.

A lone learner is the network as it always was (no replica axis), so its arithmetic is the one a run of one seed has
always had. ``replica_state`` takes one replica out of a replicated learner's state in the lone learner's format,
which is what ``policy.pt`` holds.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Sequence
from typing import Any

import torch
from tensordict.nn import AddStateIndependentNormalScale
from torch import nn
from torch.func import functional_call
from torchrl.modules import MLP, ConvNet

# The units a replicated network maps over the replica axis: TorchRL's MLP and conv stack (whose forward folds every
# leading axis into one) and the parameter-holding leaves outside them. RunningNorm and ImageEncoder keep a replica
# axis of their own (their ``replicate_``).
REPLICATED_UNITS: tuple[type[nn.Module], ...] = (MLP, ConvNet, nn.Linear, nn.Conv2d, AddStateIndependentNormalScale)


class _Replicated:
    """What a replicated unit's class adds to the unit's own: a forward mapped over the replica axis."""

    def forward(self, *inputs: torch.Tensor) -> Any:
        if self.__dict__.get("linear_only"):
            return self.forward_batched(*inputs)
        # On a CPU each replica's slice runs as a lone unit does: vmap's batched kernels were slower than a loop here
        # for our conv stack (``python -m sidewalk.bench.replica_updates --units``).
        if inputs[0].device.type != "cpu":
            return self.forward_vmapped(*inputs)
        return self.forward_looped(*inputs)

    def forward_batched(self, *inputs: torch.Tensor) -> Any:
        """The unit's own forward, its linear layers (``_BatchedLinear``, the unit itself when it is one) each one
        matmul over the replica axis: for a small MLP a loop's cost is each replica's call, not its arithmetic."""
        return super().forward(*inputs)

    def forward_vmapped(self, *inputs: torch.Tensor) -> Any:
        """The forward under ``torch.vmap`` over the replica axis."""
        return torch.vmap(self._one_replica, randomness="different")(self._replica_state(), inputs)

    def forward_looped(self, *inputs: torch.Tensor) -> Any:
        """The forward of each replica's slice in turn, stacked."""
        state = self._replica_state()
        outputs = [
            self._one_replica({name: tensor[r] for name, tensor in state.items()}, tuple(x[r] for x in inputs))
            for r in range(self.replicas)
        ]
        return torch.stack(outputs) if isinstance(outputs[0], torch.Tensor) else tuple(map(torch.stack, zip(*outputs)))

    def _replica_state(self) -> dict[str, torch.Tensor]:
        state = dict(self.named_parameters())
        state.update(self.named_buffers())
        return state

    def _one_replica(self, state: dict[str, torch.Tensor], inputs: tuple[torch.Tensor, ...]) -> Any:
        return functional_call(self.__dict__["replica_template"], state, inputs)


def batched_linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """Each replica's ``F.linear``: ``x`` (R, ..., in) with ``weight`` (R, out, in) and ``bias`` (R, out)."""
    flat = x.reshape(x.shape[0], -1, x.shape[-1])
    transposed = weight.transpose(1, 2)
    out = torch.bmm(flat, transposed) if bias is None else torch.baddbmm(bias.unsqueeze(1), flat, transposed)
    return out.reshape(*x.shape[:-1], weight.shape[1])


class _BatchedLinear(nn.Linear):
    """A linear layer of a replicated unit, its weight and bias stacked on the replica axis."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return batched_linear(x, self.weight, self.bias)


def _linear_only(unit: nn.Module) -> bool:
    """Whether ``unit`` is a linear layer, or an MLP whose every weight lies in its linear layers (the rest are its
    elementwise activations)."""

    def holds_state(module: nn.Module) -> bool:
        return any(module.parameters(recurse=False)) or any(module.buffers(recurse=False))

    return isinstance(unit, (MLP, nn.Linear)) and all(
        isinstance(module, nn.Linear) or not holds_state(module) for module in unit.modules()
    )


_REPLICATED_CLASSES: dict[type, type] = {}


def _replicated_class(cls: type) -> type:
    if cls not in _REPLICATED_CLASSES:
        _REPLICATED_CLASSES[cls] = type(f"Replicated{cls.__name__}", (_Replicated, cls), {})
    return _REPLICATED_CLASSES[cls]


def _replicate_unit_(unit: nn.Module, replicas: int) -> None:
    """Stack ``replicas`` copies of ``unit``'s state in place, under its own names (the first copy is ``unit`` as it
    is, the others re-drawn by each layer's ``reset_parameters``), and map its forward over the leading axis."""
    copies = [unit]
    for _ in range(replicas - 1):
        fresh = copy.deepcopy(unit)
        for layer in fresh.modules():
            if hasattr(layer, "reset_parameters"):
                layer.reset_parameters()
        copies.append(fresh)
    params, buffers = torch.func.stack_module_state(copies)
    template = copy.deepcopy(unit).to("meta")
    for name, tensor in {**params, **buffers}.items():
        owner_name, _, leaf = name.rpartition(".")
        owner = unit.get_submodule(owner_name)
        if name in params:
            setattr(owner, leaf, nn.Parameter(tensor.detach().clone()))
        else:
            owner.register_buffer(leaf, tensor.clone())
    if _linear_only(unit):
        unit.__dict__["linear_only"] = True
        for layer in unit.modules():
            if type(layer) is nn.Linear:
                layer.__class__ = _BatchedLinear
    unit.__class__ = _replicated_class(type(unit))
    unit.__dict__["replica_template"] = template  # not a submodule: it holds no state
    unit.replicas = replicas


def replicate_(network: nn.Module, replicas: int) -> nn.Module:
    """Give every unit of ``network`` (``REPLICATED_UNITS``, and modules with a ``replicate_`` of their own) a
    leading replica axis of ``replicas`` independently initialised copies, in place, keeping every state name; a
    module reached twice is replicated once. Returns ``network``."""
    seen: set[int] = set()

    def visit(module: nn.Module) -> None:
        if id(module) in seen:
            return
        seen.add(id(module))
        if isinstance(module, REPLICATED_UNITS):
            _replicate_unit_(module, replicas)
            return
        if hasattr(module, "replicate_") and module.replicas is None:
            module.replicate_(replicas)
        for child in module.children():
            visit(child)

    visit(network)
    return network


def logged(value: torch.Tensor, lead: Sequence[int]) -> float | torch.Tensor:
    """A value to log: a float for a lone learner, a detached (R,) tensor for R replicas (one float each)."""
    return value.detach() if lead else float(value)


def sample_mean(value: torch.Tensor, lead: Sequence[int]) -> torch.Tensor:
    """The mean over every axis but the replica axis: a scalar for a lone learner (``lead == ()``), (R,) for R."""
    if not lead:
        return value.mean()
    return value.reshape(*lead, -1).mean(-1)


def sample_std(value: torch.Tensor, lead: Sequence[int]) -> torch.Tensor:
    """The (unbiased) standard deviation over every axis but the replica axis, shaped to broadcast against ``value``."""
    if not lead:
        return value.std()
    return value.reshape(*lead, -1).std(-1).reshape(*lead, *([1] * (value.dim() - len(lead))))


def sample_var(value: torch.Tensor, lead: Sequence[int]) -> torch.Tensor:
    """The (unbiased) variance over every axis but the replica axis: a scalar alone, (R,) for R replicas."""
    return value.var() if not lead else value.reshape(*lead, -1).var(-1)


def mse_per_replica(value: torch.Tensor, target: torch.Tensor, lead: Sequence[int]) -> torch.Tensor:
    """Each replica's mean squared error (``F.mse_loss``): a scalar alone, (R,) for R replicas."""
    if not lead:
        return torch.nn.functional.mse_loss(value, target)
    return sample_mean(torch.nn.functional.mse_loss(value, target, reduction="none"), lead)


def rowwise_dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The dot product of vectors (P,), or of each row of (R, P) with its row of ``b``."""
    return a @ b if a.dim() == 1 else torch.linalg.vecdot(a, b)


def broadcast_lead(value: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """A per-replica value (``lead``-shaped) shaped to broadcast against ``like`` (``lead`` followed by sample axes)."""
    return value.reshape(*value.shape, *([1] * (like.dim() - value.dim())))


def clip_grad_norm_(parameters: Iterable[torch.Tensor], max_norm: float, lead: Sequence[int]) -> None:
    """``torch.nn.utils.clip_grad_norm_`` for each replica on its own: each replica's gradient scaled to a norm of
    at most ``max_norm``, over its slice of every parameter."""
    parameters = [p for p in parameters if p.grad is not None]
    if not lead:
        torch.nn.utils.clip_grad_norm_(parameters, max_norm)
        return
    if not parameters or not math.isfinite(max_norm):
        return
    squares = torch.stack([p.grad.reshape(*lead, -1).pow(2).sum(-1) for p in parameters]).sum(0)
    scale = (max_norm / (squares.sqrt() + 1e-6)).clamp(max=1.0)
    for p in parameters:
        p.grad.mul_(broadcast_lead(scale, p.grad))


def flat_vector(tensors: Iterable[torch.Tensor], lead: Sequence[int]) -> torch.Tensor:
    """Each replica's tensors as one vector: (P,) for a lone learner, (R, P) for R (``parameters_to_vector``)."""
    return torch.cat([tensor.reshape(*lead, -1) for tensor in tensors], -1)


def assign_flat_(parameters: Sequence[torch.Tensor], vector: torch.Tensor, lead: Sequence[int]) -> None:
    """Write ``vector`` ((P,) or (R, P), as ``flat_vector`` lays it out) into ``parameters``, in place."""
    offset = 0
    for param in parameters:
        size = param[(0,) * len(lead)].numel() if lead else param.numel()
        param.data.copy_(vector[..., offset : offset + size].reshape(param.shape))
        offset += size


def replica_state(state: Any, lone: Any, replica: int) -> Any:
    """Replica ``replica``'s part of a replicated learner's ``state`` (nested dicts and lists of tensors), in the
    layout of ``lone``, the same state of a lone learner: a tensor shaped ``(R, *s)`` where the lone one is ``s``
    is the replica's slice (a copy), one shaped alike is shared by every replica."""
    if isinstance(state, dict):
        return {key: replica_state(value, lone[key], replica) for key, value in state.items() if key in lone}
    if isinstance(state, (list, tuple)):
        return type(state)(replica_state(value, other, replica) for value, other in zip(state, lone))
    if isinstance(state, torch.Tensor) and isinstance(lone, torch.Tensor) and state.dim() == lone.dim() + 1:
        return state[replica].clone()
    return state
