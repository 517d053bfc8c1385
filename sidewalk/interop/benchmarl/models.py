"""A dueling Q-value model for BenchMARL, ``model=layers/dueling_mlp`` (``DuelingMlpConfig`` from Python): each
agent's observation through an optional MLP trunk, then our learners' dueling head (``sidewalk.algos.networks.
DuelingHead``: value and advantage streams of one hidden layer each, Q = V + A - mean(A), Wang et al. 2016).
BenchMARL's models have no dueling head; without it our VDN on the grid ends at 0.09 team success against 0.90.

Written as BenchMARL's ``benchmarl/models/mlp.py``: a ``Model`` and its ``ModelConfig``, with BenchMARL's MLP's
fields for the trunk and ``share_params`` / ``centralised`` / ``input_has_agent_dim`` handled as its ``Mlp`` handles
them: it is its ``Mlp`` with another network, and reads what ``Mlp`` keeps to itself (its ``mlp`` attribute, which
its ``_forward`` runs, and ``_perform_checks``), so this is the one module of the package that reaches inside
BenchMARL's models. Meant for Q-values (IQL, VDN, QMIX); on another output the head is a network still, but its
split into a value and advantages means nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import MISSING, dataclass
from pathlib import Path
from typing import Any

import torch
from benchmarl.models.common import Model, ModelConfig
from benchmarl.models.mlp import Mlp
from torch import nn
from torchrl.modules import MLP, MultiAgentMLP

from sidewalk.algos.networks import DuelingHead

DUELING_MLP_YAML = Path(__file__).parent / "conf" / "model" / "layers" / "dueling_mlp.yaml"


class DuelingMlpNet(nn.Module):
    """One agent's network: ``trunk`` (an MLP of ``num_cells`` ending in its activation; none where ``num_cells`` is
    empty), then ``head``, a ``DuelingHead`` of ``hidden`` giving ``n_actions`` Q-values."""

    def __init__(self, in_features: int, n_actions: int, num_cells: Sequence[int], hidden: int, device: Any,
                 **trunk_kwargs: Any) -> None:
        super().__init__()
        num_cells = list(num_cells)
        with torch.device(device):  # also "meta": MultiAgentMLP builds a parameter-free copy to run
            self.trunk = MLP(in_features=in_features, out_features=num_cells[-1], num_cells=num_cells[:-1],
                             activate_last_layer=True, **trunk_kwargs) if num_cells else nn.Identity()
            self.head = DuelingHead(num_cells[-1] if num_cells else in_features, n_actions, hidden)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.head(self.trunk(features))


class MultiAgentDuelingMlp(MultiAgentMLP):
    """TorchRL's ``MultiAgentMLP`` (one set of weights or one per agent, centralised or not) with each agent's
    network a ``DuelingMlpNet``."""

    def __init__(self, *args: Any, hidden: int, **kwargs: Any) -> None:
        self.hidden = hidden  # read by _build_single_net, which MultiAgentMLP's __init__ calls
        super().__init__(*args, **kwargs)

    def _build_single_net(self, *, device: Any, **trunk_kwargs: Any) -> nn.Module:
        in_features = self.n_agent_inputs * (self.n_agents if self.centralized else 1)
        return DuelingMlpNet(in_features, self.n_agent_outputs, self.num_cells, self.hidden, device,
                             activation_class=self.activation_class, **trunk_kwargs)


class DuelingMlp(Mlp):
    """BenchMARL's ``Mlp`` with a dueling network (``MultiAgentDuelingMlp``, or a ``DuelingMlpNet`` per agent or
    shared where the input has no agent dimension): the same input checks and forward, Q = V + A - mean(A) out.

    Args:
        num_cells, layer_class, activation_class, activation_kwargs, norm_class, norm_kwargs, num_feature_dims: the
            trunk's, as BenchMARL's ``Mlp`` takes them; ``num_cells=[]`` is no trunk.
        hidden: the width of the value and the advantage streams' hidden layer (ReLU).
    """

    def __init__(self, **kwargs: Any) -> None:
        self.num_feature_dims = kwargs.pop("num_feature_dims", 1)  # read by Mlp's _perform_checks
        hidden, num_cells = kwargs.pop("hidden"), kwargs.pop("num_cells")
        # Model's __init__, not Mlp's (which builds its own network); ours goes under Mlp's name, which its _forward reads
        Model.__init__(self, **{name: kwargs.pop(name) for name in (
            "input_spec", "output_spec", "agent_group", "input_has_agent_dim", "n_agents", "centralised",
            "share_params", "device", "action_spec", "model_index", "is_critic")})
        self.input_features = sum(
            int(torch.prod(torch.tensor(spec.shape[-self.num_feature_dims:]))) for spec in self.input_spec.values(True, True)
        )
        self.output_features = self.output_leaf_spec.shape[-1]
        if self.input_has_agent_dim:
            self.mlp = MultiAgentDuelingMlp(
                n_agent_inputs=self.input_features, n_agent_outputs=self.output_features, n_agents=self.n_agents,
                centralised=self.centralised, share_params=self.share_params, device=self.device,
                num_cells=num_cells, hidden=hidden, **kwargs,
            )
        else:
            self.mlp = nn.ModuleList([
                DuelingMlpNet(self.input_features, self.output_features, num_cells, hidden, self.device, **kwargs)
                for _ in range(1 if self.share_params else self.n_agents)
            ])


@dataclass
class DuelingMlpConfig(ModelConfig):
    """Dataclass config for a ``DuelingMlp``: the fields of BenchMARL's ``MlpConfig`` (the trunk's) and ``hidden``.
    Its defaults, ``get_from_yaml()``, are ``conf/model/layers/dueling_mlp.yaml`` here: our learners' network (no
    trunk, streams of 256)."""

    num_cells: Sequence[int] = MISSING
    layer_class: type[nn.Module] = MISSING
    activation_class: type[nn.Module] = MISSING
    hidden: int = MISSING
    activation_kwargs: dict | None = None
    norm_class: type[nn.Module] | None = None
    norm_kwargs: dict | None = None
    num_feature_dims: int = 1

    @staticmethod
    def associated_class() -> type[DuelingMlp]:
        return DuelingMlp

    @classmethod
    def get_from_yaml(cls, path: str | None = None) -> DuelingMlpConfig:
        """The config read from ``path``, by default this package's ``layers/dueling_mlp.yaml`` (BenchMARL's own
        lookup reads its package's folder)."""
        return super().get_from_yaml(path or str(DUELING_MLP_YAML))


# The models this package adds to BenchMARL, by the name its configs give (``name:`` in the YAML, the registry key).
MODELS = {"dueling_mlp": DuelingMlpConfig}
