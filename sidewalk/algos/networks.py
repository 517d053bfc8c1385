"""Network pieces shared by the learners: observation encoders, the paper's architectures, and the policy and value
networks of the on-policy learners (TRPO, PPO)."""

from __future__ import annotations

from typing import Any

import torch
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.data import Bounded, Categorical, OneHot
from torchrl.modules import MLP, ConvNet, OneHotCategorical, ProbabilisticActor, TanhNormal, ValueOperator

from sidewalk.algos.replicas import replicate_

# The paper's DQN feature stack (§6.1): 32 filters 4×4 stride 2, 64 filters 4×4 stride 2, 64 filters 2×2 stride 1.
PAPER_CONV = {"num_cells": [32, 64, 64], "kernel_sizes": [4, 4, 2], "strides": [2, 2, 1]}


def min_image_side(conv: dict | None = None) -> int:
    """The smallest image side the conv stack accepts (14 px for the paper's), working back from one output."""
    conv = PAPER_CONV if conv is None else conv
    side = 1
    for kernel, stride in reversed(list(zip(conv["kernel_sizes"], conv["strides"]))):
        side = (side - 1) * stride + kernel
    return side


class ImageEncoder(nn.Module):
    """uint8 grey images (..., C, H, W) → features, through the paper's conv stack (ReLU), flattened.

    ``channels_last``: the weights are stored channels-last, so oneDNN runs its faster channels-last kernels
    (docs/guide/benchmarks.md, "Training loop speed").
    Weights keep that layout through ``.to(device)``, clones and ``load_state_dict``; a state dict written either
    way loads into either. Off for TRPO and PPO, whose flat parameter vectors (``parameters_to_vector``) need
    contiguous weights."""

    def __init__(self, in_shape: torch.Size, conv: dict | None = None, channels_last: bool = False) -> None:
        super().__init__()
        conv = dict(PAPER_CONV if conv is None else conv)
        self.net = ConvNet(in_features=in_shape[-3], activation_class=nn.ReLU, **conv)
        if channels_last:
            self.net = self.net.to(memory_format=torch.channels_last)
        with torch.no_grad():
            self.out_features = self.forward(torch.zeros(1, *in_shape[-3:], dtype=torch.uint8)).shape[-1]

    replicas: int | None = None  # set by ``replicate_``: the leading axis is the replica axis, kept apart

    def replicate_(self, replicas: int) -> None:
        self.replicas = replicas

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        batch = image.shape[:-3]
        lead = batch[:1] if self.replicas else ()
        pixels = image.reshape(*lead, -1, *image.shape[-3:]).to(torch.float32) / 255.0
        # The weights' layout picks the kernels (PyTorch runs a conv channels-last when its input or weight is), so
        # the input needs no conversion, which also keeps the encoder usable under torch.func.vmap (TRPO's
        # per-sample Fisher products), where querying a memory format is not implemented.
        features = self.net(pixels)
        return features.reshape(*batch, -1)


class VectorEncoder(nn.Module):
    """Vectors pass through as float32."""

    def __init__(self, in_shape: torch.Size) -> None:
        super().__init__()
        self.out_features = int(in_shape[-1])

    def forward(self, vector: torch.Tensor) -> torch.Tensor:
        return vector.to(torch.float32)


def make_encoder(observation_shape: torch.Size, is_image: bool, channels_last: bool = False) -> nn.Module:
    """The encoder for an observation: the conv stack for images (``channels_last`` as in ``ImageEncoder``),
    identity for vectors."""
    return ImageEncoder(observation_shape, channels_last=channels_last) if is_image else VectorEncoder(observation_shape)


def is_image_spec(spec) -> bool:
    """Images are uint8 with at least (C, H, W) event dimensions."""
    return spec.dtype == torch.uint8 and len(spec.shape) >= 3


def mlp(in_features: int, out_features: int, hidden: list[int], activation: type[nn.Module] = nn.Tanh) -> MLP:
    return MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden), activation_class=activation)


class DuelingHead(nn.Module):
    """Q(s, a) = V(s) + A(s, a) - mean_a A(s, a) over a hidden layer (Wang et al. 2016, used by the paper)."""

    def __init__(self, in_features: int, n_actions: int, hidden: int = 256) -> None:
        super().__init__()
        self.value = MLP(in_features=in_features, out_features=1, num_cells=[hidden], activation_class=nn.ReLU)
        self.advantage = MLP(
            in_features=in_features, out_features=n_actions, num_cells=[hidden], activation_class=nn.ReLU
        )

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        advantage = self.advantage(features)
        return self.value(features) + advantage - advantage.mean(-1, keepdim=True)


class RunningNorm(nn.Module):
    """Standardises vectors by running mean and std, clipped to ±``clip`` (baselines' ``RunningMeanStd`` as its
    policies use it: std floored at ``min_std``, output clipped to ±5). The identity until the first ``update``.
    Replicated (``replicate_``), it keeps one set of statistics per replica on a leading axis."""

    replicas: int | None = None

    def __init__(self, size: int, clip: float = 5.0, min_std: float = 0.1) -> None:
        super().__init__()
        self.clip = clip
        self.min_std = min_std
        # float64 statistics: the count grows into the millions and float32 sums would drift.
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("mean", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("var", torch.ones(size, dtype=torch.float64))

    def replicate_(self, replicas: int) -> None:
        """One set of statistics per replica, on a leading axis: ``update`` and ``forward`` then take (R, ..., size)."""
        for name in ("count", "mean", "var"):
            setattr(self, name, getattr(self, name).expand(replicas, *getattr(self, name).shape).clone())
        self.replicas = replicas

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Merge the samples ``x`` (..., size) into the statistics (Chan et al.'s parallel mean/variance); replicated,
        replica r's statistics take ``x[r]``."""
        size = self.mean.shape[-1]
        lead = (self.replicas,) if self.replicas else ()
        x = x.reshape(*lead, -1, size).to(torch.float64)
        n = x.shape[-2]
        batch_mean, batch_var = x.mean(-2), x.var(-2, unbiased=False)
        count = self.count.unsqueeze(-1)
        total = count + n
        delta = batch_mean - self.mean
        self.var.copy_((self.var * count + batch_var * n + delta**2 * count * n / total) / total)
        self.mean.add_(delta * n / total)
        self.count.add_(n)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x.to(torch.float32)
        mean, var = self.mean, self.var
        if self.replicas:  # (R, size) against (R, ..., size)
            mean = mean.reshape(self.replicas, *([1] * (x.dim() - 2)), -1)
            var = var.reshape(mean.shape)
        std = var.clamp_min(self.min_std**2).sqrt().to(x.dtype)
        return ((x - mean.to(x.dtype)) / std).clamp(-self.clip, self.clip)


def _trunk(encoder: nn.Module, norm: RunningNorm | None, out_features: int, hidden: list[int]) -> nn.Sequential:
    """observation → encoder → running norm (vectors) → tanh MLP → ``out_features``."""
    head = mlp(encoder.out_features, out_features, list(hidden), nn.Tanh)
    return nn.Sequential(*([encoder] if norm is None else [encoder, norm]), head)


def tanh_normal(action_spec: Bounded, mean_bound: float = 0.0) -> dict[str, Any]:
    """``ProbabilisticActor``'s distribution arguments for a ``TanhNormal`` within ``action_spec``. With ``mean_bound``
    > 0 the pre-squash mean is ``mean_bound·tanh(loc / mean_bound)`` (TorchRL's ``tanh_loc``): an unbounded mean can
    run off to where every sample is squashed onto the bound and exploration stops (docs/multiagent.md)."""
    kwargs: dict[str, Any] = {"low": action_spec.space.low, "high": action_spec.space.high}
    if mean_bound > 0:
        kwargs.update(tanh_loc=True, upscale=float(mean_bound))
    return {"distribution_class": TanhNormal, "distribution_kwargs": kwargs}


def on_policy_networks(
    observation_spec, action_spec, policy_hidden: list[int], value_hidden: list[int], normalize_observations: bool,
    mean_bound: float = 0.0, replicas: int | None = None,
) -> tuple[ProbabilisticActor, ValueOperator, RunningNorm | None]:
    """The policy and value networks of OpenAI baselines' TRPO/PPO (and CleanRL's continuous PPO), from unbatched
    specs: ``observation`` (a vector, standardised by one ``RunningNorm`` both networks share, or a uint8 image
    through the paper's conv encoder) → tanh MLPs. The policy samples ``action`` from a ``TanhNormal`` within a
    ``Bounded`` spec, with a learned state-independent log-std (0 at the start), or from a ``Categorical`` /
    ``OneHotCategorical`` over discrete actions; its output layer starts at 1 % of its default scale, so the first
    policy is centred / near uniform; ``mean_bound``: see ``tanh_normal``. The value network writes
    ``state_value``. Returns (actor, value, norm)."""
    image = is_image_spec(observation_spec)
    norm = RunningNorm(observation_spec.shape[-1]) if normalize_observations and not image else None
    if isinstance(action_spec, Bounded):
        n_out, dist_keys, dist = action_spec.shape[-1], ["loc", "scale"], tanh_normal(action_spec, mean_bound)
    elif isinstance(action_spec, (Categorical, OneHot)):
        n_out, dist_keys = action_spec.space.n, ["logits"]
        dist = {"distribution_class": OneHotCategorical if isinstance(action_spec, OneHot) else torch.distributions.Categorical}
    else:
        raise TypeError(f"needs a Categorical, OneHot or Bounded action spec; got {type(action_spec).__name__}")
    policy_net = _trunk(make_encoder(observation_spec.shape, image), norm, n_out, policy_hidden)
    value_net = _trunk(make_encoder(observation_spec.shape, image), norm, 1, value_hidden)
    if replicas:  # ``replicas`` independent copies on a leading axis (sidewalk.algos.replicas)
        replicate_(policy_net, replicas)
        replicate_(value_net, replicas)
    out_layer = policy_net[-1][-1]
    with torch.no_grad():
        out_layer.weight.mul_(0.01)
        out_layer.bias.zero_()
    if isinstance(action_spec, Bounded):
        scale = AddStateIndependentNormalScale(n_out, scale_mapping="exp")
        policy_net.append(replicate_(scale, replicas) if replicas else scale)
    module = TensorDictModule(policy_net, in_keys=["observation"], out_keys=dist_keys)
    actor = ProbabilisticActor(module, in_keys=dist_keys, out_keys=["action"], spec=action_spec, **dist)
    return actor, ValueOperator(value_net, in_keys=["observation"]), norm
