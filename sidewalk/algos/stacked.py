"""One vectorised update for R replicas (seeds) of one on-policy learner: TRPO or PPO, trained together in one process.

Each replica stays its own learner object, with its own modules, optimiser and checkpoints. ``vectorized_update``
returns a ``StackedUpdate`` whose ``update(batches, streams)`` stacks the replicas' parameters, buffers and Adam
state into (R, ...) tensors, runs the learner's update once for all of them, and copies the results back into each
learner's own tensors in place. It computes what ``[algo.update(batch) for algo, batch in zip(algos, batches)]``
computes, each replica's logs under the same keys, with each replica's random draws from its own source (TRPO's
value-fit permutations and PPO's sampled entropy noise from its ``ReplicaStreams`` stream, PPO's minibatch orders
from the learner's own generator), in the loop's order and sizes.

How it stays the loop's arithmetic: linear layers run as one batched matmul (``torch.baddbmm``) only where that rounds
exactly as ``F.linear`` does for each replica, which the BLAS decides by sizes and, on some CPUs (MKL on an AMD EPYC),
by the operands' memory alignment too: a product under ATen's naive-loop threshold and a width of 1 always run per
replica, any other size is measured once on this machine (``_batched_rounds_as_linear``: forward, first and second
derivatives), and every per-replica operand is laid out as a lone run's tensor (``_lone``: contiguous from an
aligned address). Where the order of the arithmetic decides the rounding, the stacked update keeps the loop's: no
view stands between a linear layer and its input (the autograd engine sums the gradients reaching a tensor in the
order they arrive, and a Fisher-vector product, a double backward, sums three at each tanh output: ``_run``); GAE
runs per replica, by each learner's own module (its value network under TorchRL's ``vmap``, its discounted sums
through a matmul); the distribution math runs per replica where a replica's elements do not fill whole vector steps
(``_aligned``); the sampled entropy takes TorchRL's operations in its order. Adam runs on the stacks with each
replica's own scalars; the scalars a replica's decisions hinge on (the conjugate-gradient dot products, the line
search's tests, the advantage statistics, the logs) are computed per replica with the loop's kernels. Measured
(``tests/test_stacked_updates.py``): TRPO and PPO on vectors and on images are bit-identical to the loop, at the
default sizes and at small odd ones (on an AMD EPYC, where the BLAS rounds by alignment), hence a replica's results
do not depend on R or on the other replicas.
"""

from __future__ import annotations

import abc
import functools
import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale
from torch import nn
from torch.distributions.utils import _sum_rightmost
from torch.func import functional_call
from torchrl.modules import MLP, TanhNormal
from torchrl.modules.distributions import has_analytic_entropy

from sidewalk.algos.base import Algorithm
from sidewalk.algos.networks import RunningNorm
from sidewalk.algos.ppo import LOSS_LOGS, PPO
from sidewalk.algos.trpo import TRPO, mean_kl, surrogate_terms

if TYPE_CHECKING:
    from sidewalk.streams import ReplicaStreams

# What both learners read from a collector batch (PPO's loss also reads what GAE and the reference log-prob add).
BATCH_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"),
              ("next", "terminated"))
# Layers whose parameters act per feature and broadcast over the samples: given (R, 1, *shape) copies, their own
# forward computes every replica at once.
PER_FEATURE = (RunningNorm, AddStateIndependentNormalScale)


# ---- stacked networks -------------------------------------------------------------------------------------------


def _is_chain(module: nn.Module) -> bool:
    """A container whose forward is its children in order (TorchRL's MLP is, for one input and an int width)."""
    return type(module) is nn.Sequential or (isinstance(module, MLP) and isinstance(module.out_features, int))


def _unbind(stack: torch.Tensor | tuple[torch.Tensor, ...] | dict[str, torch.Tensor]) -> list[Any]:
    """An (R, ...) tensor, or a tuple or dict of them, as R per-replica slices (``unbind``: its backward is one
    stack, not a zero-filled copy per replica)."""
    if isinstance(stack, tuple):
        return list(zip(*(tensor.unbind(0) for tensor in stack)))
    if isinstance(stack, dict):
        unbound = {key: tensor.unbind(0) for key, tensor in stack.items()}
        return [dict(zip(unbound, values)) for values in zip(*unbound.values())]
    return list(stack.unbind(0))


def _per_replica_call(function: Callable[..., torch.Tensor], *stacks: Any) -> torch.Tensor:
    """``function`` on each replica's slices of ``stacks``, the results stacked: the loop's own kernels."""
    return torch.stack([function(*arguments) for arguments in zip(*map(_unbind, stacks))])


# ATen's vectorised elementwise loop takes a contiguous tensor two vectors at a time (2 × 64 bytes at most, with
# AVX-512) and its remainder with scalar code, which rounds some functions (atanh, softplus, sigmoid: TanhNormal's
# log-prob) otherwise than the vector code does.
VECTOR_STEP_BYTES = 128


def _aligned(stack: torch.Tensor) -> bool:
    """Whether each replica's block of the (R, ...) ``stack`` is a whole number of vectorised steps: then an
    elementwise kernel on the stack computes each element as that replica's own (smaller) tensor would."""
    return stack[0].numel() * stack.element_size() % VECTOR_STEP_BYTES == 0


# ATen's CPU batched matmul (bmm, baddbmm) runs its own naive loop for a product of fewer than this many
# multiply-adds (rows × in × out, the same count for the products of its backward), a gemm per matrix above it.
NAIVE_BMM_BELOW = 400


def _runs_per_replica(weight: torch.Tensor, rows: int, bias: bool = True) -> bool:
    """Whether a linear layer of ``weight`` (R, out, in) on ``rows`` rows a replica runs per replica (``F.linear``)
    rather than as one batched matmul: where the batched matmul would round otherwise than ``F.linear`` does. That is
    always a product under ``NAIVE_BMM_BELOW`` (ATen's naive loop, where ``F.linear`` calls the BLAS gemm) and an
    output or input width of 1 (the BLAS runs a gemv for ``F.linear``'s forward, or its input gradient, and the
    batched gemm does not); anything else the BLAS of this machine decides, measured once per size
    (``_batched_rounds_as_linear``): MKL on an AMD EPYC sums a batched weight gradient otherwise than a lone one's
    for most sizes, where on an Intel Xeon it did not."""
    out_features, in_features = weight.shape[-2:]
    if out_features == 1 or in_features == 1 or rows * out_features * in_features < NAIVE_BMM_BELOW:
        return True
    return not _batched_rounds_as_linear(len(weight), rows, in_features, out_features, bias, weight.dtype,
                                         str(weight.device))


# The alignment of a lone tensor's memory (PyTorch's CPU allocator): MKL on some CPUs (an AMD EPYC here) picks its
# gemm kernel, and so the order of its sums, by the operands' alignment as well as their sizes.
ALIGNMENT_BYTES = 64


def _lone(tensor: torch.Tensor) -> torch.Tensor:
    """``tensor`` in memory laid out as a lone run's own tensor would be: contiguous from an aligned address (a copy,
    gradients flowing through, where a view of a stack is not)."""
    if tensor.is_contiguous() and tensor.data_ptr() % ALIGNMENT_BYTES == 0:
        return tensor
    return tensor.clone(memory_format=torch.contiguous_format)


def _batched_linear(weight: torch.Tensor, bias: torch.Tensor | None, x: torch.Tensor) -> torch.Tensor:
    """Every replica's ``F.linear`` as one batched matmul: ``x`` (R, N, in), ``weight`` (R, out, in), each stack
    from an aligned address (``_batched_rounds_as_linear`` measures that layout)."""
    weight, x = _lone(weight), _lone(x)
    bias = None if bias is None else _lone(bias)
    transposed = weight.transpose(1, 2)
    return x @ transposed if bias is None else torch.baddbmm(bias.unsqueeze(1), x, transposed)


@functools.cache
def _batched_rounds_as_linear(replicas: int, rows: int, in_features: int, out_features: int, bias: bool,
                              dtype: torch.dtype, device: str) -> bool:
    """Whether one batched matmul gives each of ``replicas`` replicas exactly its own ``F.linear``, forward, first
    and second derivatives (TRPO's Fisher-vector products), at these sizes on this machine. Measured on random
    values, once: the BLAS picks its kernels, and so the order of its sums, by sizes, not by values."""
    generator = torch.Generator().manual_seed(0)

    def draw(*shape: int) -> torch.Tensor:
        with torch.inference_mode(False):
            return torch.randn(*shape, generator=generator, dtype=dtype).to(device)

    leaves = [draw(replicas, out_features, in_features), draw(replicas, rows, in_features)]
    leaves += [draw(replicas, out_features)] if bias else []
    upstream, direction = draw(replicas, rows, out_features), [draw(*leaf.shape) for leaf in leaves]

    def derivatives(parts: list[torch.Tensor], up: torch.Tensor, along: list[torch.Tensor], batched: bool):
        parts = [part.detach().clone().requires_grad_() for part in parts]  # fresh, aligned: a lone run's layout
        out = _batched_linear(*_ordered(parts)) if batched else F.linear(parts[1], parts[0], *parts[2:])
        grads = torch.autograd.grad(out, parts, up, create_graph=True)
        second = torch.autograd.grad(sum((g * v).sum() for g, v in zip(grads, along)), parts, allow_unused=True)
        return [out, *grads, *(torch.zeros_like(p) if g is None else g for p, g in zip(parts, second))]

    with torch.inference_mode(False), torch.enable_grad():  # callers may be in no_grad (GAE) or inference mode
        together = derivatives(leaves, upstream, direction, batched=True)
        for replica in range(replicas):
            alone = derivatives([leaf[replica] for leaf in leaves], upstream[replica],
                                [v[replica] for v in direction], batched=False)
            if not all(torch.equal(a[replica], b) for a, b in zip(together, alone)):
                return False
    return True


def _ordered(parts: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
    """(weight, bias or None, x) from [weight, x] or [weight, x, bias]."""
    return parts[0], (parts[2] if len(parts) > 2 else None), parts[1]


# A layer's input or output for R replicas: one (R, N, ...) stack, or a list of R per-replica (N, ...) tensors.
Activations = torch.Tensor | list[torch.Tensor]


def _as_stack(x: Activations) -> torch.Tensor:
    return torch.stack(x) if isinstance(x, list) else x


def _as_list(x: Activations) -> list[torch.Tensor]:
    return x if isinstance(x, list) else list(x.unbind(0))


def _rows(x: Activations) -> int:
    """The rows a replica has (its samples: every dimension but the features)."""
    return x[0].numel() // x[0].shape[-1]


def _linear(weight: torch.Tensor, bias: torch.Tensor | None, x: Activations) -> Activations:
    """``F.linear`` for each replica: a list of per-replica outputs where ``_runs_per_replica``, else one batched
    matmul on the stack (``x`` used as it is when it is (R, N, in): no view between it and the matmul, see
    ``_run``)."""
    if _runs_per_replica(weight, _rows(x), bias is not None):
        biases = [None] * len(weight) if bias is None else [_lone(b) for b in bias.unbind(0)]
        return [F.linear(_lone(rows), _lone(w), b) for rows, w, b in zip(_as_list(x), weight.unbind(0), biases)]
    x = _as_stack(x)
    flat = x if x.dim() == 3 else x.reshape(x.shape[0], -1, x.shape[-1])
    out = _batched_linear(weight, bias, flat)
    return out if x.dim() == 3 else out.reshape(*x.shape[:-1], weight.shape[1])


def _stacked_linear(weight: torch.Tensor, bias: torch.Tensor | None, x: torch.Tensor) -> torch.Tensor:
    """``F.linear`` per replica: ``weight`` (R, out, in), ``bias`` (R, out) or None, ``x`` (R, ..., in); the
    outputs stacked."""
    return _as_stack(_linear(weight, bias, x))


def _own(state: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    return {name[len(prefix):]: tensor for name, tensor in state.items() if name.startswith(prefix)}


def _layers(module: nn.Module, prefix: str = "") -> list[tuple[str, nn.Module]]:
    """The layers ``module`` runs, in order, each with the prefix of its state's names: a chain's children,
    recursively, or ``module`` itself."""
    if not _is_chain(module):
        return [(prefix, module)]
    return [layer for name, child in module.named_children() for layer in _layers(child, f"{prefix}{name}.")]


def _run(layers: Sequence[tuple[str, nn.Module]], state: dict[str, torch.Tensor], x: Activations) -> torch.Tensor:
    """``layers`` in order for R replicas (see ``stacked_forward``); returns the (R, ...) stack.

    The output of a linear layer is turned at once into the form (stack or per-replica list) of the next layer with
    state, so that the input of every linear layer is the very tensor the layers before it made, as in the loop. A
    view taken at a layer's input instead (a reshape, or ``unbind`` for a per-replica layer) would gather the
    gradients that reach it through that layer before they meet the one through the activation's own backward (a
    tanh output is read by both): the loop sums those three in another order, and a Fisher-vector product (a double
    backward) would round otherwise."""
    for index, (prefix, layer) in enumerate(layers):
        own = _own(state, prefix)
        if isinstance(layer, nn.Linear):
            x = _linear(own["weight"], own.get("bias"), x)
            following = next(((name, nxt) for name, nxt in layers[index + 1:] if _own(state, name)), None)
            per_replica = following is not None and isinstance(following[1], nn.Linear) and _runs_per_replica(
                state[following[0] + "weight"], _rows(x), following[0] + "bias" in state)
            x = _as_list(x) if per_replica else _as_stack(x)
        elif not own:  # no state: the layer acts on each sample alone, whatever the leading dimensions
            x = [layer(rows) for rows in x] if isinstance(x, list) else layer(x)
        elif isinstance(layer, PER_FEATURE):
            x = functional_call(layer, {name: tensor.unsqueeze(1) for name, tensor in own.items()}, (_as_stack(x),))
        else:
            x = _per_replica_call(lambda tensors, inputs, layer=layer: functional_call(layer, tensors, (inputs,)),
                                  own, _as_stack(x))
    return _as_stack(x)


def stacked_forward(module: nn.Module, state: dict[str, torch.Tensor], x: torch.Tensor, prefix: str = "") -> Any:
    """``module``'s forward for R replicas at once: ``state`` maps each parameter and buffer name (under
    ``prefix``) to its (R, ...) stack, ``x`` is (R, N, *features); replica r's rows see replica r's tensors.
    Linear layers run batched (where that rounds as ``F.linear``, else per replica: ``_runs_per_replica``), layers
    without state and per-feature layers (``PER_FEATURE``) on the stacks directly (a layer without state after a
    per-replica linear layer, per replica), chains of layers as their layers in turn; any other layer with state
    (the image encoder) runs per replica with its own kernels."""
    return _run(_layers(module, prefix), state, x)


class StackedNetwork:
    """R copies of one network (the same architecture): ``params`` and ``buffers`` as (R, ...) stacks by name, read
    from the copies when built; called on (R, N, *features) it runs each copy on its own rows.

    The leading layers of a chain that have no parameters (the vector encoder, the running normaliser) give the same
    output whatever the parameters: ``features`` runs them alone, and a call with ``from_features=True`` starts
    after them, so an update computes them once rather than once per minibatch."""

    def __init__(self, networks: Sequence[nn.Module]) -> None:
        self.networks = list(networks)
        self.template = self.networks[0]
        self.named = [dict(net.named_parameters()) for net in self.networks]
        self.names = list(self.named[0])
        self.params = {name: torch.stack([named[name].detach() for named in self.named]) for name in self.names}
        self.chain = _is_chain(self.template)
        children = list(self.template.named_children()) if self.chain else []
        self.frozen = next((index for index, (_, child) in enumerate(children)
                            if any(True for _ in child.parameters())), len(children))
        self.refresh_buffers()

    def refresh_buffers(self) -> None:
        """Read the copies' buffers again (after, e.g., their observation statistics moved)."""
        buffers = [dict(net.named_buffers()) for net in self.networks]
        self.buffers = {name: torch.stack([named[name] for named in buffers]) for name in buffers[0]}

    def __call__(self, x: torch.Tensor, params: dict[str, torch.Tensor] | None = None, from_features: bool = False
                 ) -> Any:
        state = {**self.buffers, **(self.params if params is None else params)}
        if not (from_features and self.chain):
            return stacked_forward(self.template, state, x)
        children = list(self.template.named_children())[self.frozen:]
        return _run([layer for name, child in children for layer in _layers(child, f"{name}.")], state, x)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """The output of the leading parameter-free layers (``x`` itself if there are none)."""
        children = list(self.template.named_children())[: self.frozen]
        return _run([layer for name, child in children for layer in _layers(child, f"{name}.")], self.buffers, x)

    def flatten(self, tensors: Sequence[torch.Tensor] | None = None) -> torch.Tensor:
        """The parameters (or ``tensors`` shaped as them, in their order) as one (R, P) matrix, each row
        ``parameters_to_vector`` of a copy."""
        tensors = [self.params[name] for name in self.names] if tensors is None else tensors
        return torch.cat([tensor.reshape(len(self.networks), -1) for tensor in tensors], 1)

    def unflatten(self, vector: torch.Tensor) -> dict[str, torch.Tensor]:
        sizes = [self.params[name][0].numel() for name in self.names]
        return {name: chunk.reshape(self.params[name].shape)
                for name, chunk in zip(self.names, vector.split(sizes, dim=1))}

    @torch.no_grad()
    def write_back(self, params: dict[str, torch.Tensor] | None = None) -> None:
        """Copy ``params`` (default: ``self.params``) into each copy's own parameters, in place."""
        params = self.params if params is None else params
        for replica, named in enumerate(self.named):
            for name, param in named.items():
                param.copy_(params[name][replica])


# ---- optimisation -----------------------------------------------------------------------------------------------


def _dots(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Each row's dot product with the loop's own kernel (``torch.dot``), so a replica's scalars do not depend on R."""
    return torch.stack([torch.dot(_lone(x), _lone(y)) for x, y in zip(a, b)])  # the BLAS dot, on a lone's layout


def _per_replica(values: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """(R,) values shaped to broadcast against an (R, ...) tensor."""
    return values.reshape(-1, *[1] * (like.ndim - 1))


def clip_grad_norms_(grads: Sequence[torch.Tensor], max_norm: float) -> None:
    """``torch.nn.utils.clip_grad_norm_`` for each replica's gradients, rows of the (R, ...) ``grads``, in place."""
    norms = torch.stack([torch.linalg.vector_norm(grad.flatten(1), dim=1) for grad in grads], 1)
    total = torch.linalg.vector_norm(norms, dim=1)
    coefficient = torch.clamp(max_norm / (total + 1e-6), max=1.0)
    for grad in grads:
        grad.mul_(_per_replica(coefficient, grad))


def _scalar_dtype() -> torch.dtype:
    # Adam's step counter dtype (torch.optim.optimizer._get_scalar_dtype, non-fused).
    return torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32


class StackedAdam:
    """Adam over (R, ...) parameter stacks with, per element, the arithmetic of each replica's
    ``torch.optim.Adam(foreach=True)`` (one parameter group, no weight decay, amsgrad or maximize: see
    ``supported``). Reads the replicas' state when built; ``write_back`` stores it in their optimisers."""

    def __init__(self, optimizers: Sequence[torch.optim.Optimizer], params: Sequence[torch.Tensor],
                 replica_params: Sequence[Sequence[torch.Tensor]]) -> None:
        self.optimizers, self.params, self.replica_params = list(optimizers), list(params), replica_params
        group = optimizers[0].param_groups[0]
        (self.beta1, self.beta2), self.eps = group["betas"], group["eps"]
        self.lr = [float(opt.param_groups[0]["lr"]) for opt in optimizers]
        states = [[opt.state.get(param, {}) for param in own] for opt, own in zip(optimizers, replica_params)]
        self.steps = [[float(state["step"]) if state else 0.0 for state in row] for row in states]
        self.exp_avg, self.exp_avg_sq = (
            [torch.stack([row[i][key] if row[i] else torch.zeros_like(stack[0]) for row in states])
             for i, stack in enumerate(self.params)]
            for key in ("exp_avg", "exp_avg_sq")
        )

    @staticmethod
    def supported(optimizers: Sequence[torch.optim.Optimizer]) -> bool:
        settings = [opt.param_groups[0] for opt in optimizers]
        first = settings[0]
        return all(
            type(opt) is torch.optim.Adam and len(opt.param_groups) == 1 and group["weight_decay"] == 0
            and not group["amsgrad"] and not group["maximize"] and not group.get("capturable")
            and not group.get("fused") and group["betas"] == first["betas"] and group["eps"] == first["eps"]
            for opt, group in zip(optimizers, settings)
        )

    @torch.no_grad()
    def step(self, grads: Sequence[torch.Tensor]) -> None:
        """One Adam step of every replica (every parameter has a gradient, as in both learners)."""
        for index, (param, grad, exp_avg, exp_avg_sq) in enumerate(
            zip(self.params, grads, self.exp_avg, self.exp_avg_sq)
        ):
            for row in self.steps:
                row[index] += 1
            exp_avg.lerp_(grad, 1 - self.beta1)
            exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
            denominator = exp_avg_sq.sqrt()
            # Python scalars, as Adam computes them from each replica's step count.
            scalars = [((lr / (1 - self.beta1 ** row[index])) * -1, (1 - self.beta2 ** row[index]) ** 0.5)
                       for lr, row in zip(self.lr, self.steps)]
            if all(pair == scalars[0] for pair in scalars):
                denominator.div_(scalars[0][1]).add_(self.eps)
                param.addcdiv_(exp_avg, denominator, value=scalars[0][0])
                continue
            for replica, (step_size, correction) in enumerate(scalars):
                denominator[replica].div_(correction).add_(self.eps)
                param[replica].addcdiv_(exp_avg[replica], denominator[replica], value=step_size)

    @torch.no_grad()
    def write_back(self) -> None:
        for replica, (opt, own) in enumerate(zip(self.optimizers, self.replica_params)):
            for index, param in enumerate(own):
                state = opt.state[param]
                if not state:  # first step: the entries Adam would have created, in its order
                    state.update(step=torch.tensor(0.0, dtype=_scalar_dtype()),
                                 exp_avg=torch.zeros_like(param), exp_avg_sq=torch.zeros_like(param))
                state["step"].fill_(self.steps[replica][index])
                state["exp_avg"].copy_(self.exp_avg[index][replica])
                state["exp_avg_sq"].copy_(self.exp_avg_sq[index][replica])


def _optimizer_params(optimizers: Sequence[torch.optim.Optimizer], networks: Sequence[StackedNetwork]
                      ) -> tuple[list[tuple[StackedNetwork, str]], list[list[torch.Tensor]]]:
    """Each optimiser's parameters, in its order, as (stacked network, name), and each replica's own tensors."""
    places = []
    for replica, opt in enumerate(optimizers):
        where = {id(param): (net, name) for net in networks for name, param in net.named[replica].items()}
        places.append([where[id(param)] for param in opt.param_groups[0]["params"]])
    if any([(id(net), name) for net, name in row] != [(id(net), name) for net, name in places[0]] for row in places):
        raise ValueError("the replicas' optimisers hold their parameters in different orders")
    return places[0], [list(opt.param_groups[0]["params"]) for opt in optimizers]


def batched_conjugate_gradient(
    matvec: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor, iters: int, residual_tol: float = 1e-10
) -> torch.Tensor:
    """``trpo.conjugate_gradient`` for R systems at once (rows of ``b``, (R, P); ``matvec`` maps (R, P) to (R, P)):
    each row stops on its own residual exactly where the loop would, and is left as it was from then on."""
    x = torch.zeros_like(b)
    residual = b.clone()
    direction = b.clone()
    residual_sq = _dots(residual, residual)
    active = torch.ones(len(b), dtype=torch.bool, device=b.device)
    for _ in range(iters):
        active &= ~(residual_sq < residual_tol)
        if not active.any():
            break
        a_direction = matvec(direction)
        alpha = residual_sq / _dots(direction, a_direction)
        keep = active.unsqueeze(1)
        x = torch.where(keep, x + _per_replica(alpha, x) * direction, x)
        residual = torch.where(keep, residual - _per_replica(alpha, x) * a_direction, residual)
        new_residual_sq = _dots(residual, residual)
        ratio = _per_replica(new_residual_sq / residual_sq, x)
        direction = torch.where(keep, residual + ratio * direction, direction)
        residual_sq = torch.where(active, new_residual_sq, residual_sq)
    return x


# ---- the updates ------------------------------------------------------------------------------------------------


class StackedUpdate(abc.ABC):
    """The update of R learners of one class and config, run once for all of them (see the module docstring)."""

    def __init__(self, algos: Sequence[Algorithm]) -> None:
        self.algos = list(algos)
        self.config = self.algos[0].config
        self.device = self.algos[0].device

    @classmethod
    def supported(cls, algos: Sequence[Algorithm]) -> bool:
        """Whether this updater computes these learners' updates (else the caller loops over ``algo.update``)."""
        first = algos[0]
        return all(type(algo) is type(first) and algo.config == first.config and algo.device == first.device
                   for algo in algos) and cls._same_networks(algos)

    @staticmethod
    def _same_networks(algos: Sequence[Algorithm]) -> bool:
        def shapes(algo: Algorithm) -> list[tuple[str, torch.Size, torch.dtype]]:
            return [(f"{key}.{name}", tensor.shape, tensor.dtype) for key, module in algo.modules().items()
                    for name, tensor in [*module.named_parameters(), *module.named_buffers()]]

        return all(shapes(algo) == shapes(algos[0]) for algo in algos)

    @abc.abstractmethod
    def update(self, batches: Sequence[TensorDictBase], streams: ReplicaStreams) -> list[dict[str, float]]:
        """Replica r learns from ``batches[r]`` (its collector batch, (B, T) with time last, as ``algo.update``
        takes it) with its random draws from ``streams``' stream r; returns each replica's logs."""

    @torch.no_grad()
    def _advantages(self, batches: Sequence[TensorDictBase]) -> TensorDictBase:
        """Every replica's GAE by its own module (its value network inside) on a fresh copy of its own batch's
        ``BATCH_KEYS``, stacked (R, B, T); counts the frames. The very arithmetic of its lone update, whose value
        network TorchRL runs under ``vmap`` and whose discounted sums run through a matmul, either of which a batched
        computation could round otherwise."""
        if len(batches) != len(self.algos):
            raise ValueError(f"{len(batches)} batches for {len(self.algos)} replicas")
        own = []
        for algo, batch in zip(self.algos, batches):
            algo.frames_seen += batch.numel()
            copy = TensorDict({key: batch.get(key).to(self.device).clone(memory_format=torch.contiguous_format)
                               for key in BATCH_KEYS}, batch_size=batch.batch_size, device=self.device)
            algo.advantage(copy)
            own.append(copy)
        return torch.stack(own)

    @staticmethod
    def _flat(data: TensorDictBase) -> dict[str, torch.Tensor]:
        """Each replica's (B, T) samples as N rows, the tensors (R, N, ...), as ``batch.reshape(-1)`` orders them."""
        replicas = data.batch_size[0]
        return {key: tensor.reshape(replicas, -1, *tensor.shape[data.batch_dims:])
                for key, tensor in data.items(include_nested=False, leaves_only=True)}

    def _policy(self) -> tuple[StackedNetwork, list[str]]:
        """The stacked network behind each actor (observation → distribution parameters) and its output keys."""
        modules = [algo.actor.module[0] for algo in self.algos]
        return StackedNetwork([module.module for module in modules]), list(modules[0].out_keys)

    def _dist(self, outputs: Any, keys: list[str], batch_dims: int = 2) -> torch.distributions.Distribution:
        """The distribution of R × N samples from the stacked policy's outputs (a tensor or a tuple, as ``keys``),
        or with ``batch_dims=1`` of one replica's N samples from its own outputs."""
        outputs = outputs if isinstance(outputs, tuple) else (outputs,)
        params = TensorDict(dict(zip(keys, outputs)), batch_size=outputs[0].shape[:batch_dims])
        return self.algos[0].actor.build_dist_from_params(params)

    @staticmethod
    def _distribution_math(function: Callable[..., Any], outputs: tuple[torch.Tensor, ...], *stacks: Any) -> Any:
        """``function(outputs, *stacks, batch_dims)`` on the policy's stacked ``outputs`` (R, N, ...) and the other
        (R, ...) ``stacks``: at once when each replica's block of the outputs is ``_aligned``, else on each
        replica's slices (``batch_dims=1``; the loop's kernels on the loop's shapes) with the results stacked: an
        elementwise kernel on a stack would compute a replica's last elements with vector code where its own
        tensor's scalar remainder rounds otherwise."""
        if _aligned(outputs[0]):
            return function(outputs, *stacks, 2)
        results = [function(*arguments, 1) for arguments in zip(*map(_unbind, (outputs, *stacks)))]
        if isinstance(results[0], tuple):
            return tuple(torch.stack(parts) for parts in zip(*results))
        return torch.stack(results)

    def _log_prob(self, outputs: tuple[torch.Tensor, ...], action: torch.Tensor) -> torch.Tensor:
        """(R, N) log-probabilities of ``action`` under the distributions of the stacked policy ``outputs``."""
        return self._distribution_math(
            lambda params, taken, dims: self._dist(params, self.keys, dims).log_prob(taken), outputs, action)

    def _update_observation_statistics(self, observation: torch.Tensor, *networks: StackedNetwork) -> None:
        for algo, rows in zip(self.algos, observation):
            if algo.obs_norm is not None:
                algo.obs_norm.update(rows)
        for network in networks:
            network.refresh_buffers()


class StackedTRPO(StackedUpdate):
    """``TRPO.update`` for R replicas: GAE, per-replica standardisation and observation statistics, the snapshot,
    the natural-gradient step (conjugate gradient on batched Fisher-vector products, each replica stopping on its
    own residual) with each replica's own step size and backtracking line search, then the value fit."""

    @classmethod
    def supported(cls, algos: Sequence[Algorithm]) -> bool:
        return super().supported(algos) and StackedAdam.supported([algo.value_optimizer for algo in algos])

    def update(self, batches: Sequence[TensorDictBase], streams: ReplicaStreams) -> list[dict[str, float]]:
        self.policy, self.keys = self._policy()
        self.value = StackedNetwork([algo.value.module for algo in self.algos])
        flat = self._flat(self._advantages(batches))
        self._update_observation_statistics(flat["observation"], self.policy, self.value)
        # Each replica's standardisation on its own rows, with the loop's kernels.
        flat["advantage"] = torch.stack([(adv - adv.mean()) / (adv.std() + 1e-8) for adv in flat["advantage"]])
        permutations = self._draw_permutations(streams, flat["observation"].shape[1])
        with torch.no_grad():
            flat["features"] = self.policy.features(flat["observation"])
            outputs = self.policy(flat["features"], from_features=True)
            flat["old_policy"] = outputs if isinstance(outputs, tuple) else (outputs,)
            flat["action_log_prob"] = self._log_prob(flat["old_policy"], flat["action"])
        logs = self._policy_step(flat)
        for replica_logs, value_logs in zip(logs, self._fit_value(flat, permutations)):
            replica_logs.update(value_logs)
        return logs

    def _draw_permutations(self, streams: ReplicaStreams, samples: int) -> list[torch.Tensor]:
        """Each replica's value-fit orders, ``vf_iters`` permutations drawn on its own stream as ``_fit_value`` draws
        them (nothing else in ``TRPO.update`` draws from it); (vf_iters, R, N)."""
        if len(streams) != len(self.algos):
            raise ValueError(f"{len(streams)} streams for {len(self.algos)} replicas")
        orders = []
        for replica in range(len(self.algos)):
            with streams.use(replica):
                orders.append([torch.randperm(samples, device=self.device) for _ in range(self.config.vf_iters)])
        return [torch.stack(epoch) for epoch in zip(*orders)]

    def _terms(self, params: dict[str, torch.Tensor], flat: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """(minus the surrogate, mean KL, entropy), each (R,), at the stacked policy parameters ``params``."""
        outputs = self.policy(flat["features"], params, from_features=True)

        def terms(new: tuple[torch.Tensor, ...], old: tuple[torch.Tensor, ...], action: torch.Tensor,
                  old_log_prob: torch.Tensor, advantage: torch.Tensor, dims: int) -> tuple[torch.Tensor, ...]:
            return surrogate_terms(self._dist(new, self.keys, dims), self._dist(old, self.keys, dims), action,
                                   old_log_prob, advantage, self.config.entropy_coef)

        return self._distribution_math(terms, outputs if isinstance(outputs, tuple) else (outputs,),
                                       flat["old_policy"], flat["action"], flat["action_log_prob"], flat["advantage"])

    def _fisher(self, params: dict[str, torch.Tensor], flat: dict[str, torch.Tensor]
                ) -> Callable[[torch.Tensor], torch.Tensor]:
        """``TRPOLoss.fisher_operator`` for every replica: (R, P) vectors, each row through its replica's Hessian."""
        step = self.config.fvp_subsample
        old = self._dist(tuple(tensor[:, ::step] for tensor in flat["old_policy"]), self.keys)
        features = flat["features"][:, ::step]
        kl = mean_kl(old, self._dist(self.policy(features, params, from_features=True), self.keys))
        leaves = list(params.values())
        kl_grad = self.policy.flatten(torch.autograd.grad(kl.sum(), leaves, create_graph=True))
        damping = self.config.cg_damping

        def product(vector: torch.Tensor) -> torch.Tensor:
            hessian_vector = torch.autograd.grad((kl_grad * vector).sum(), leaves, retain_graph=True)
            return self.policy.flatten(hessian_vector) + damping * vector

        return product

    def _policy_step(self, flat: dict[str, torch.Tensor]) -> list[dict[str, float]]:
        """``trpo_step`` for every replica; writes each replica's new (or unchanged) policy parameters back."""
        cfg = self.config
        old_theta = self.policy.flatten()
        # Gradients by parameter tensor, then flattened, as TRPOLoss takes them.
        params = {name: tensor.requires_grad_(True) for name, tensor in self.policy.params.items()}
        loss_before, _, entropy = self._terms(params, flat)
        logs = [dict.fromkeys(("kl", "surrogate_improvement", "expected_improvement", "step_accepted",
                               "step_fraction"), 0.0) | {"entropy": value} for value in entropy.tolist()]
        gradient = self.policy.flatten(torch.autograd.grad(-loss_before.sum(), list(params.values())))
        usable = torch.isfinite(gradient).all(1) & gradient.any(1)
        fisher = self._fisher(params, flat)
        # A replica with no usable gradient starts at a zero residual: its conjugate gradient never moves.
        direction = batched_conjugate_gradient(fisher, torch.where(usable.unsqueeze(1), gradient, 0.0), cfg.cg_iters)
        curvature = _dots(direction, fisher(direction))
        usable &= curvature > 0
        full_step = _per_replica(torch.sqrt(2 * cfg.max_kl / curvature), direction) * direction
        full_step = torch.where(usable.unsqueeze(1), full_step, 0.0)  # no step tried: no NaN parameters built
        new_theta = self._line_search(flat, old_theta, full_step, gradient, loss_before.detach(), usable, logs)
        self.policy.write_back(self.policy.unflatten(new_theta))
        return logs

    @torch.no_grad()
    def _line_search(self, flat: dict[str, torch.Tensor], old_theta: torch.Tensor, full_step: torch.Tensor,
                     gradient: torch.Tensor, loss_before: torch.Tensor, searching: torch.Tensor,
                     logs: list[dict[str, float]]) -> torch.Tensor:
        """Every replica still searching tries each fraction of its full step; each keeps the first that
        ``trpo_step`` would keep (measured KL within the bound, surrogate improved) and logs it as ``trpo_step``
        does. Returns the new parameters: the old ones where no fraction qualified."""
        cfg = self.config
        new_theta = old_theta.clone()
        searching = searching.clone()
        for attempt in range(cfg.line_search_steps):
            if not searching.any():
                break
            fraction = cfg.line_search_shrink**attempt
            candidate = old_theta + fraction * full_step
            loss_after, kl, _ = self._terms(self.policy.unflatten(candidate), flat)
            # The loop's tests, in float64 as its Python floats are.
            improvement = -loss_after.double() - -loss_before.double()
            kl = kl.double()
            accepted = searching & improvement.isfinite() & kl.isfinite() & (kl <= cfg.max_kl) & (improvement > 0)
            for replica in accepted.nonzero().flatten().tolist():
                expected = fraction * torch.dot(_lone(gradient[replica]), _lone(full_step[replica])).item()
                logs[replica].update(kl=kl[replica].item(), surrogate_improvement=improvement[replica].item(),
                                     expected_improvement=expected, step_accepted=1.0, step_fraction=fraction)
                new_theta[replica] = candidate[replica]
            searching &= ~accepted
        return new_theta

    def _fit_value(self, flat: dict[str, torch.Tensor], permutations: list[torch.Tensor]) -> list[dict[str, float]]:
        """``TRPO._fit_value`` for every replica: the same epochs and minibatches, one stacked Adam step each."""
        cfg = self.config
        target, value_before = flat["value_target"], flat["state_value"]
        logs = [{"value_loss": F.mse_loss(v, t).item(),
                 "explained_variance": 1.0 - ((t - v).var() / t.var().clamp_min(1e-8)).item()}
                for t, v in zip(target, value_before)]
        if not permutations:
            return logs
        params = {name: tensor.requires_grad_(True) for name, tensor in self.value.params.items()}
        places, replica_params = _optimizer_params([algo.value_optimizer for algo in self.algos], [self.value])
        leaves = [params[name] for _, name in places]
        adam = StackedAdam([algo.value_optimizer for algo in self.algos], leaves, replica_params)
        rows = torch.arange(len(self.algos), device=self.device).unsqueeze(1)
        with torch.no_grad():
            features = self.value.features(flat["observation"])
        for order in permutations:
            losses = []
            epoch_features, epoch_target = features[rows, order], target[rows, order]
            for start in range(0, order.shape[1], cfg.vf_batch_size):
                batch = slice(start, start + cfg.vf_batch_size)
                prediction = self.value(epoch_features[:, batch], params, from_features=True)
                loss = F.mse_loss(prediction, epoch_target[:, batch], reduction="none").flatten(1).mean(1)
                grads = list(torch.autograd.grad(loss.sum(), leaves))
                if math.isfinite(cfg.max_grad_norm):
                    clip_grad_norms_(grads, cfg.max_grad_norm)
                adam.step(grads)
                losses.append(loss.detach())
        self.value.write_back({name: tensor.detach() for name, tensor in params.items()})
        adam.write_back()
        for replica_logs, column in zip(logs, torch.stack(losses, 1).tolist()):
            replica_logs["value_loss"] = sum(column) / len(column)
        return logs


class StackedPPO(StackedUpdate):
    """``clipped_ppo_update`` for R replicas of ``PPO``: GAE standardised per replica, the observation statistics,
    the reference log-prob, then ``epochs`` × minibatches of ``ClipPPOLoss``'s objective (written out for PPO's
    settings, see ``supported``; ``tests/test_stacked_updates.py`` checks it against TorchRL's on the same inputs)
    with every replica's gradient clipped by its own norm and one stacked Adam step."""

    LOSS_INPUTS = ("policy_features", "value_features", "action", "advantage", "value_target", "action_log_prob")

    @classmethod
    def supported(cls, algos: Sequence[Algorithm]) -> bool:
        loss = algos[0].loss
        plain = (loss.clip_value is None and loss.loss_critic_type == "smooth_l1" and not loss.normalize_advantage
                 and loss.entropy_bonus and loss.samples_mc_entropy == 1 and not loss.delay_actor
                 and loss.max_importance_ratio is None and loss.advantage_norm is None and not loss.separate_losses
                 and loss.reduction == "mean" and isinstance(getattr(loss, "clip_epsilon", None), torch.Tensor))
        return plain and super().supported(algos) and StackedAdam.supported([algo.optimizer for algo in algos])

    def update(self, batches: Sequence[TensorDictBase], streams: ReplicaStreams) -> list[dict[str, float]]:
        if any(("collector", "mask") in batch.keys(True) for batch in batches):
            raise NotImplementedError("StackedPPO reads no loss mask; loop over PPO.update for masked batches")
        cfg = self.config
        self.policy, self.keys = self._policy()
        self.value = StackedNetwork([algo.critic.module for algo in self.algos])
        flat = self._flat(self._advantages(batches))  # each replica's own GAE standardises its advantages
        self._update_observation_statistics(flat["observation"], self.policy, self.value)
        with torch.no_grad():
            flat["policy_features"] = self.policy.features(flat["observation"])
            flat["value_features"] = self.value.features(flat["observation"])
            outputs = self.policy(flat["policy_features"], from_features=True)
            outputs = outputs if isinstance(outputs, tuple) else (outputs,)
            reference = self._dist(outputs, self.keys)
            flat["action_log_prob"] = self._log_prob(outputs, flat["action"])
        samples = flat["observation"].shape[1]
        orders = [torch.stack([torch.randperm(samples, generator=algo._generator) for algo in self.algos])
                  .to(self.device) for _ in range(cfg.epochs)]
        noise = None if has_analytic_entropy(reference) else self._draw_noise(streams, reference, samples)
        return self._epochs({key: flat[key] for key in self.LOSS_INPUTS}, orders, noise)

    def _draw_noise(self, streams: ReplicaStreams, reference: torch.distributions.Distribution,
                    samples: int) -> list[torch.Tensor]:
        """ClipPPOLoss estimates an entropy with no closed form (TanhNormal's) from one reparameterised sample per
        minibatch, drawn on the global generator: each replica's draws, in the loop's order and shapes
        (``torch.distributions.utils._standard_normal``), from its own stream; one (1, R, M, *event) per minibatch."""
        if not isinstance(reference, TanhNormal):
            raise NotImplementedError(f"no sampled entropy for {type(reference).__name__}; loop over algo.update")
        if len(streams) != len(self.algos):
            raise ValueError(f"{len(streams)} streams for {len(self.algos)} replicas")
        loc = reference.root_dist.loc
        size = self.config.minibatch_size
        shapes = [(1, min(size, samples - start), *loc.shape[2:]) for start in range(0, samples, size)]
        drawn = []
        for replica in range(len(self.algos)):
            with streams.use(replica):
                drawn.append([torch.empty(shape, dtype=loc.dtype, device=loc.device).normal_()
                              for _ in range(self.config.epochs) for shape in shapes])
        return [torch.stack(step, 1) for step in zip(*drawn)]

    def _epochs(self, flat: dict[str, torch.Tensor], orders: list[torch.Tensor],
                noise: list[torch.Tensor] | None) -> list[dict[str, float]]:
        """The minibatch loop of ``clipped_ppo_update`` for every replica; writes the networks and Adam back."""
        cfg = self.config
        policy_params = {name: tensor.requires_grad_(True) for name, tensor in self.policy.params.items()}
        value_params = {name: tensor.requires_grad_(True) for name, tensor in self.value.params.items()}
        places, replica_params = _optimizer_params([algo.optimizer for algo in self.algos], [self.policy, self.value])
        leaves = [(policy_params if net is self.policy else value_params)[name] for net, name in places]
        adam = StackedAdam([algo.optimizer for algo in self.algos], leaves, replica_params)
        rows = torch.arange(len(self.algos), device=self.device).unsqueeze(1)
        samples, step, logged = orders[0].shape[1], 0, []
        for order in orders:
            shuffled = {key: tensor[rows, order] for key, tensor in flat.items()}
            for start in range(0, samples, cfg.minibatch_size):
                minibatch = {key: tensor[:, start : start + cfg.minibatch_size] for key, tensor in shuffled.items()}
                losses = self._losses(minibatch, policy_params, value_params, None if noise is None else noise[step])
                step += 1
                grads = list(torch.autograd.grad(sum(losses.values()).sum(), leaves))
                clip_grad_norms_(grads, cfg.max_grad_norm)
                adam.step(grads)
                logged.append(torch.stack([losses[key].detach() for key in LOSS_LOGS], 1))
        self.policy.write_back({name: tensor.detach() for name, tensor in policy_params.items()})
        self.value.write_back({name: tensor.detach() for name, tensor in value_params.items()})
        adam.write_back()
        table = torch.stack(logged, 2)  # (R, 3, minibatches): each row contiguous, as the loop's stacked logs
        return [{key: float(table[replica, index].mean()) for index, key in enumerate(LOSS_LOGS)}
                for replica in range(len(self.algos))]

    def _losses(self, minibatch: dict[str, torch.Tensor], policy_params: dict[str, torch.Tensor],
                value_params: dict[str, torch.Tensor], noise: torch.Tensor | None) -> dict[str, torch.Tensor]:
        """``ClipPPOLoss``'s ``loss_objective``, ``loss_entropy`` and ``loss_critic`` (each (R,), in the order
        ``clipped_ppo_update`` sums them) for PPO's settings: no advantage normalisation, no value clipping,
        smooth-L1 critic loss, mean reduction."""
        loss = self.algos[0].loss
        outputs = self.policy(minibatch["policy_features"], policy_params, from_features=True)
        # The sampled entropy's draw, (1, R, M, ...), as an (R, ...) stack: one (1, M, ...) draw a replica.
        draws = () if noise is None else (noise.transpose(0, 1),)
        log_prob, entropy = self._distribution_math(self._log_prob_and_entropy,
                                                    outputs if isinstance(outputs, tuple) else (outputs,),
                                                    minibatch["action"], *draws)
        log_weight = (log_prob - minibatch["action_log_prob"]).unsqueeze(-1)
        advantage = minibatch["advantage"]
        gain1 = log_weight.exp() * advantage
        gain2 = log_weight.clamp((-loss.clip_epsilon).log1p(), loss.clip_epsilon.log1p()).exp() * advantage
        gain = torch.stack([gain1, gain2], -1).min(dim=-1).values
        entropy = entropy.unsqueeze(-1)
        value = self.value(minibatch["value_features"], value_params, from_features=True)
        critic = loss.critic_coeff * F.smooth_l1_loss(minibatch["value_target"], value, reduction="none")
        terms = {"loss_objective": -gain, "loss_entropy": -loss.entropy_coeff * entropy, "loss_critic": critic}
        return {key: term.flatten(1).mean(1) for key, term in terms.items()}

    def _log_prob_and_entropy(self, outputs: tuple[torch.Tensor, ...], action: torch.Tensor, *rest: Any
                              ) -> tuple[torch.Tensor, torch.Tensor]:
        """The log-probability of ``action`` and the entropy (analytic, or sampled from the draw that ``rest`` holds
        before ``batch_dims``) of the policy's distribution, for ``_distribution_math``."""
        *draw, batch_dims = rest
        dist = self._dist(outputs, self.keys, batch_dims)
        log_prob = dist.log_prob(action)
        if not draw:
            return log_prob, dist.entropy()
        # Stacked, the draw comes replica-first, (R, 1, M, ...): sample-first, as the loss draws it.
        return log_prob, self._sampled_entropy(dist, draw[0] if batch_dims == 1 else draw[0].transpose(0, 1))

    @staticmethod
    def _sampled_entropy(dist: TanhNormal, noise: torch.Tensor) -> torch.Tensor:
        """``-log_prob`` of one reparameterised sample per row, TorchRL's ``TanhNormal.rsample_and_log_prob`` with
        ``noise`` in place of its draw (``Normal.rsample``: loc + noise · scale)."""
        root = dist.root_dist
        preimage = root.loc + noise * root.scale
        transform = dist.transforms[0]
        sample = transform(preimage)
        # Its operations in its order (the base log-prob before the Jacobian): the order the autograd engine sums
        # the gradients that reach ``preimage`` along them follows it.
        log_prob = dist.base_dist.log_prob(preimage) - _sum_rightmost(
            transform.log_abs_det_jacobian(preimage, sample), len(dist.event_shape))
        return -log_prob.mean(0)


UPDATERS: dict[type[Algorithm], type[StackedUpdate]] = {TRPO: StackedTRPO, PPO: StackedPPO}


def vectorized_update(algos: Sequence[Algorithm]) -> StackedUpdate | None:
    """A ``StackedUpdate`` for these learners (one class, one config, the same networks; TRPO or PPO, single-agent),
    or None, and the caller loops over ``algo.update``."""
    if not algos:
        return None
    updater = UPDATERS.get(type(algos[0]))
    if updater is None or not updater.supported(algos):
        return None
    return updater(algos)
