"""A human-proxy partner: a policy cloned from a dataset of recorded episodes plays some agents (``opponent=proxy``).

``ProxyOpponent(env, controlled, ego, dataset="sidewalk/walks-v0")`` reads the Minari dataset (``sidewalk.datasets``:
episodes of one recorded agent, a person at the play page or a scripted walker) and clones the recorded agent's
(observation, action) pairs by supervised learning: a classifier over the grid's four moves (cross-entropy), a
regressor of the continuous world's (acceleration, turn) scaled to the action bounds (mean squared error), each a small
MLP over the standardised observation, trained full-batch with Adam from ``seed`` (bit for bit the same on one
machine). The weights are cached beside the dataset (``proxy/<key>.pt``, weights only), keyed by the dataset's files
and the training settings, so training and cross-play reuse them.

It plays agent ``j`` from ``j``'s observation as the recorded agent ``e`` would: as is where the two roles are drawn
alike, turned by half a turn where that symmetry maps ``e``'s role onto ``j``'s (``sidewalk.partners.policy``'s
``role_map`` and ``play_roles``, as a learned partner does). A dataset of another domain, observation or scenario (any
env setting but noise, rewards, the time limit and the jitters) is refused, naming what differs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn

from sidewalk.datasets import load, pins_of
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.opponents.base import Opponent, env_domain
from sidewalk.partners.policy import MAY_DIFFER, OBSERVATION_KEY, play_roles, role_map, write_actions

WEIGHTS_FOLDER = "proxy"
GRID_MOVES = 4
PROGRESS_AFTER_S = 1.0  # training that takes longer shows a progress bar


class ProxyMismatch(ValueError):
    """A dataset a proxy cannot play from in this world (the message names what differs)."""


@dataclasses.dataclass(frozen=True)
class CloneSettings:
    """How a proxy is cloned: part of its cache key."""

    seed: int = 0
    hidden_units: int = 128
    epochs: int = 400
    learning_rate: float = 3e-3


class Clone(nn.Module):
    """An MLP from one agent's standardised observation to its action's logits (grid) or its action scaled to
    [-1, 1] (continuous); the standardisation and the action bounds are buffers, saved with the weights."""

    def __init__(self, observation_shape: tuple[int, ...], outputs: int, hidden_units: int,
                 bounds: torch.Tensor | None, cell_pixels: int = 1) -> None:
        super().__init__()
        size = math.prod(observation_shape)
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("scale", torch.ones(size))
        self.register_buffer("bounds", torch.ones(outputs) if bounds is None else bounds.float())
        self.discrete = bounds is None
        if len(observation_shape) == 3:  # a grid image (C, H, W): each cell's pixels pooled to one value
            self.encoder: nn.Module = nn.Sequential(nn.Unflatten(1, observation_shape), nn.AvgPool2d(cell_pixels),
                                                    nn.Flatten())
            size = self.encoder(torch.zeros(1, size)).shape[1]
        else:
            self.encoder = nn.Identity()
        self.net = nn.Sequential(nn.Linear(size, hidden_units), nn.ReLU(),
                                 nn.Linear(hidden_units, hidden_units), nn.ReLU(), nn.Linear(hidden_units, outputs))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.net(self.encoder((observation.flatten(1).float() - self.mean) / self.scale))

    def act(self, observation: torch.Tensor) -> torch.Tensor:
        """Greedy moves (B,) in the grid; (acceleration, turn) (B, 2) in physical units in the continuous world."""
        out = self(observation)
        return out.argmax(-1) if self.discrete else out.clamp(-1.0, 1.0) * self.bounds


def demonstrations(dataset: Any) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """The recorded agent's (observation, action) pairs of ``dataset`` (its last observation of each episode has no
    action) and each pair's episode index."""
    observations, actions, episode = [], [], []
    for index, data in enumerate(dataset.iterate_episodes()):
        steps = len(data.actions)
        observations.append(np.asarray(data.observations)[:steps])
        actions.append(np.asarray(data.actions))
        episode.append(np.full(steps, index))
    if not observations:
        raise ProxyMismatch(f"dataset {dataset.spec.dataset_id!r} holds no episodes")
    return (torch.as_tensor(np.concatenate(observations)), torch.as_tensor(np.concatenate(actions)),
            np.concatenate(episode))


def check_fits(pins: dict[str, Any], dataset_id: str, env: SidewalkEnvBase) -> int:
    """The agent recorded in a dataset (``pins``: ``sidewalk.datasets.pins_of``) once a proxy can play from it in
    ``env``: same domain and the same env settings but those that may differ (``MAY_DIFFER``); else ``ProxyMismatch``."""
    config, domain = pins["env_config"], env_domain(env)
    shown = f"opponent.params.dataset={dataset_id!r}"
    if config["domain"] != domain:
        raise ProxyMismatch(f"{shown} was recorded in the {config['domain']} domain; this world is {domain}")
    if config["ego"] is None:
        raise ProxyMismatch(f"{shown} recorded every agent at once (opponent=centralized); a proxy clones one agent")
    params = json.loads(json.dumps(dataclasses.asdict(env.params), default=repr))
    differ = [f"{name}={config.get(name)!r} (here {value!r})" for name, value in params.items()
              if name not in MAY_DIFFER and config.get(name) != value]
    if differ:
        raise ProxyMismatch(f"{shown} was recorded in another world than this one: {'; '.join(differ)}")
    return int(config["ego"])


def cache_key(dataset: Any, settings: CloneSettings) -> str:
    """A digest of ``dataset``'s files (data and metadata) and the clone's ``settings``."""
    digest = hashlib.sha256(json.dumps(dataclasses.asdict(settings), sort_keys=True).encode())
    for file in sorted(Path(dataset.storage.data_path).iterdir()):
        digest.update(file.name.encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()[:20]


def train_clone(observations: torch.Tensor, actions: torch.Tensor, bounds: torch.Tensor | None,
                settings: CloneSettings, show_progress: bool = True, cell_pixels: int = 1) -> Clone:
    """A ``Clone`` fitted to (``observations``, ``actions``) pairs: grid moves when ``bounds`` is None, else
    continuous actions within ±``bounds``; deterministic for ``settings.seed`` on one machine, one CPU thread."""
    from tqdm import tqdm

    inputs = observations.flatten(1).float()
    outputs = GRID_MOVES if bounds is None else int(bounds.numel())
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(settings.seed)
            clone = Clone(tuple(observations.shape[1:]), outputs, settings.hidden_units, bounds, cell_pixels)
            clone.mean.copy_(inputs.mean(0))
            spread = inputs.std(0) if len(inputs) > 1 else torch.ones(inputs.shape[1])
            # Features that never varied get the typical spread, so a value unseen in the data stays moderate.
            clone.scale.copy_(spread.clamp_min(float(spread.mean().clamp_min(1e-6))))
            if bounds is None:
                target, loss_fn = actions.long(), nn.functional.cross_entropy
            else:
                target, loss_fn = (actions.float() / clone.bounds).clamp(-1.0, 1.0), nn.functional.mse_loss
            optimizer = torch.optim.Adam(clone.parameters(), lr=settings.learning_rate)
            for _ in tqdm(range(settings.epochs), desc="cloning the proxy", unit="epoch", delay=PROGRESS_AFTER_S,
                          disable=not show_progress, leave=False):
                optimizer.zero_grad()
                loss_fn(clone(inputs), target).backward()
                optimizer.step()
    finally:
        torch.set_num_threads(threads)
    return clone.eval()


def action_bounds(env: SidewalkEnvBase) -> torch.Tensor | None:
    """The continuous world's action bounds (max acceleration, max turn); None for the grid."""
    if env_domain(env) == "discrete":
        return None
    return torch.tensor([env.params.max_accel_mps2, env.params.max_turn_rad])


def cloned_policy(dataset_id: str, env: SidewalkEnvBase, data_path: str | None = None,
                  settings: CloneSettings = CloneSettings(), show_progress: bool = True) -> tuple[Clone, int]:
    """The clone of ``dataset_id``'s recorded agent (from the cache beside the dataset, else trained and cached)
    and that agent's index, once the dataset fits ``env`` (``check_fits``)."""
    if not isinstance(dataset_id, str) or not dataset_id:
        raise ProxyMismatch("opponent=proxy needs opponent.params.dataset=NAMESPACE/NAME-vN: a dataset recorded by "
                            "sidewalk.datasets (sidewalk-play records one)")
    dataset = load(dataset_id, data_path=data_path)
    recorded = check_fits(pins_of(dataset), dataset_id, env)
    bounds = action_bounds(env)
    file = Path(dataset.storage.data_path).parent / WEIGHTS_FOLDER / f"{cache_key(dataset, settings)}.pt"
    observations, actions, _ = demonstrations(dataset)
    cell_pixels = getattr(env.params, "pixels_per_cell", 1)
    if file.is_file():
        clone = Clone(tuple(observations.shape[1:]), GRID_MOVES if bounds is None else 2, settings.hidden_units, bounds,
                      cell_pixels)
        clone.load_state_dict(torch.load(file, weights_only=True))
        return clone.eval(), recorded
    clone = train_clone(observations, actions, bounds, settings, show_progress, cell_pixels)
    file.parent.mkdir(exist_ok=True)
    temporary = file.with_suffix(".tmp")
    torch.save(clone.state_dict(), temporary)
    temporary.replace(file)  # whole or not at all, for a reader in another process
    return clone, recorded


class ProxyOpponent(Opponent):
    """The clone of a dataset's recorded agent playing the ``controlled`` agents (see the module docstring).

    ``dataset`` is a dataset id under the datasets root ``data_path`` (else Minari's: ``MINARI_DATASETS_PATH`` or
    ``~/.minari/datasets``); ``seed``, ``hidden_units``, ``epochs`` and ``learning_rate`` set the cloning
    (``CloneSettings``). It reads the agents' observations, ``("agents", "observation")``, as a learned partner does.
    """

    name = "proxy"
    scripted = False
    per_replica = False  # a frozen network, cloned from the dataset, not from the env's seed

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled=(1,),
        ego: int | None = 0,
        *,
        dataset: str = "",
        data_path: str | None = None,
        seed: int = 0,
        hidden_units: int = CloneSettings.hidden_units,
        epochs: int = CloneSettings.epochs,
        learning_rate: float = CloneSettings.learning_rate,
    ) -> None:
        super().__init__(env, controlled=controlled, ego=ego)
        settings = CloneSettings(seed=seed, hidden_units=hidden_units, epochs=epochs, learning_rate=learning_rate)
        clone, recorded = cloned_policy(dataset, env, data_path, settings)
        self.clone = clone.to(env.device)
        self.recorded_agent = recorded
        maps = [role_map(env_domain(env), env.params, recorded, agent) for agent in self.controlled]
        unmapped = [agent for agent, kind in zip(self.controlled, maps) if kind is None]
        if unmapped:
            raise ProxyMismatch(
                f"opponent.params.dataset={dataset!r} recorded agent {recorded}; no symmetry of "
                f"env.layout={env.params.layout!r} maps its role onto agent(s) {unmapped}: record that agent instead"
            )
        self._maps = maps
        self._policy = TensorDictModule(self.clone.act, in_keys=["observation"], out_keys=["action"])
        self.in_keys = [OBSERVATION_KEY]

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = tensordict.get(OBSERVATION_KEY)
        action = play_roles(self._policy, observation, self._controlled_index, self._maps, self.env.layout)
        return write_actions(self, tensordict, action)
