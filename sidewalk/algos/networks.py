"""Network pieces shared by the learners: observation encoders and the paper's architectures."""

from __future__ import annotations

import torch
from torch import nn
from torchrl.modules import MLP, ConvNet

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
    """uint8 grey images (..., C, H, W) → features, through the paper's conv stack (ReLU), flattened."""

    def __init__(self, in_shape: torch.Size, conv: dict | None = None) -> None:
        super().__init__()
        conv = dict(PAPER_CONV if conv is None else conv)
        self.net = ConvNet(in_features=in_shape[-3], activation_class=nn.ReLU, **conv)
        with torch.no_grad():
            self.out_features = self.net(torch.zeros(1, *in_shape[-3:])).shape[-1]

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        batch = image.shape[:-3]
        features = self.net(image.reshape(-1, *image.shape[-3:]).to(torch.float32) / 255.0)
        return features.reshape(*batch, -1)


class VectorEncoder(nn.Module):
    """Vectors pass through as float32."""

    def __init__(self, in_shape: torch.Size) -> None:
        super().__init__()
        self.out_features = int(in_shape[-1])

    def forward(self, vector: torch.Tensor) -> torch.Tensor:
        return vector.to(torch.float32)


def make_encoder(observation_shape: torch.Size, is_image: bool) -> nn.Module:
    """The encoder for an observation: the conv stack for images, identity for vectors."""
    return ImageEncoder(observation_shape) if is_image else VectorEncoder(observation_shape)


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


def make_actor(observation_spec, action_spec, hidden: list[int], activation: type[nn.Module] = nn.Tanh):
    """From unbatched specs, a stochastic policy over the spec's actions: Categorical logits for discrete actions, a TanhNormal within
    the spec's bounds for continuous ones. Writes ``action`` and ``action_log_prob``."""
    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torch.distributions import Categorical
    from torchrl.modules import ProbabilisticActor, TanhNormal

    encoder = make_encoder(observation_spec.shape, is_image_spec(observation_spec))
    discrete = not torch.is_floating_point(action_spec.zero())
    if discrete:
        head = mlp(encoder.out_features, int(action_spec.space.n), hidden, activation)
        module = TensorDictModule(nn.Sequential(encoder, head), in_keys=["observation"], out_keys=["logits"])
        return ProbabilisticActor(
            module, spec=action_spec, in_keys=["logits"], distribution_class=Categorical, return_log_prob=True
        )
    n_out = action_spec.shape[-1]
    head = mlp(encoder.out_features, 2 * n_out, hidden, activation)
    module = TensorDictModule(
        nn.Sequential(encoder, head, NormalParamExtractor()), in_keys=["observation"], out_keys=["loc", "scale"]
    )
    return ProbabilisticActor(
        module,
        spec=action_spec,
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
        return_log_prob=True,
    )


def make_critic(observation_spec, hidden: list[int], activation: type[nn.Module] = nn.Tanh):
    """A state-value network V(observation) writing ``state_value``."""
    from torchrl.modules import ValueOperator

    encoder = make_encoder(observation_spec.shape, is_image_spec(observation_spec))
    return ValueOperator(nn.Sequential(encoder, mlp(encoder.out_features, 1, hidden, activation)), in_keys=["observation"])
