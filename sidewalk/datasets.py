"""Episodes of the Gymnasium face as Minari datasets (``pip install 'sidewalk-problem[data]'``).

::

    env = sidewalk.datasets.record(gymnasium.make("sidewalk/Discrete-v0", opponent="dijkstra"))
    obs, info = env.reset(seed=0)
    ...                                          # step it: every reset and step is recorded
    sidewalk.datasets.save(env, "sidewalk/walks-v0", env_config={"opponent": "dijkstra"}, author="me")
    dataset = sidewalk.datasets.load("sidewalk/walks-v0")   # minari.load_dataset, plus a version check

A dataset holds, per episode, the recorded agent's observations (one more than its actions), actions, rewards,
terminations, truncations and the face's whole ``info`` of every step (``is_success``, ``cost``, every agent's
outcome flags, rewards and costs under ``agents``, and the true ``state`` and ``goal`` of every agent). Its metadata
pins, under the key ``"sidewalk"`` as a JSON text, the env's id and version, the package's version and the full env
config (``pinned_config``); ``DATACARD.md`` beside the data says what was recorded. ``load`` warns
(``DatasetEnvMismatchWarning``) naming every pinned field that the installed package would build differently.
Minari itself is imported only by these functions: ``import sidewalk`` stays light.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import re
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np

from sidewalk._minari import jax_free_collector_class
from sidewalk.envs import INFO_KEYS
from sidewalk.interop.gymnasium import CENTRALIZED, ENV_IDS, SidewalkGymEnv
from sidewalk.later_keys import LATER_ENV_KEYS
from sidewalk.opponents.base import opponent_config
from sidewalk.version import __version__
from sidewalk.world import World

if TYPE_CHECKING:
    import minari

METADATA_KEY = "sidewalk"
CARD_NAME = "DATACARD.md"
# Minari's own pattern (minari.dataset.minari_dataset.DATASET_ID_RE), with the namespace and version required.
DATASET_ID_RE = re.compile(r"^(?P<namespace>[\w-][\w/-]*[\w-])/(?P<name>[\w-]+?)-v(?P<version>\d+)$")
# What the face's SidewalkGymEnv takes besides the core env's own keywords (its Params fields).
VIEW_KEYWORDS = ("opponent", "ego", "end_on_ego_done", "opponent_kwargs", "shield")


class DatasetEnvMismatchWarning(UserWarning):
    """A dataset recorded under an env (version, package version or config) that the installed package would build
    differently; the message names every differing field."""


def check_dataset_id(dataset_id: Any) -> str:
    """``dataset_id`` once it has Minari's ``namespace/name-vN`` form, else a ``ValueError`` naming it."""
    if not isinstance(dataset_id, str) or not DATASET_ID_RE.match(dataset_id):
        raise ValueError(
            f"dataset id {dataset_id!r} is not of Minari's form 'namespace/name-vN' (letters, digits, '_' and '-', a namespace of 2 characters or more; "
            "for example 'sidewalk/grid-walks-v0')"
        )
    return dataset_id


@contextlib.contextmanager
def datasets_root(data_path: str | os.PathLike | None) -> Iterator[Path]:
    """Minari's datasets root for the block: ``data_path`` where given (Minari reads ``MINARI_DATASETS_PATH`` on
    every call), else the one Minari uses (``MINARI_DATASETS_PATH`` or ``~/.minari/datasets``)."""
    if data_path is None:
        yield Path(os.environ.get("MINARI_DATASETS_PATH", Path.home() / ".minari" / "datasets"))
        return
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(Path(data_path).resolve())
    try:
        yield Path(os.environ["MINARI_DATASETS_PATH"])
    finally:
        if before is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = before


def dataset_ids(root: str | os.PathLike) -> list[str]:
    """The ids of the datasets under the datasets root ``root`` (``<root>/<namespace>/<name-vN>/data``), sorted."""
    root = Path(root)
    found = (folder.parent.relative_to(root).as_posix() for folder in root.glob("**/data") if folder.is_dir())
    return sorted(dataset_id for dataset_id in found if DATASET_ID_RE.match(dataset_id))


def check_dataset(dataset_id: Any, data_path: str | os.PathLike | None = None) -> Path:
    """The folder of dataset ``dataset_id`` under the datasets root ``data_path`` (else Minari's:
    ``MINARI_DATASETS_PATH`` or ``~/.minari/datasets``), without loading it; ``ValueError`` for an id not of Minari's
    form, ``FileNotFoundError`` naming the root, the datasets there and both ways to point at another root."""
    check_dataset_id(dataset_id)
    with datasets_root(data_path) as root:
        if (root / dataset_id / "data").is_dir():
            return root / dataset_id
        there = dataset_ids(root) if root.is_dir() else []
    # A dataset recorded under data_path= is found only where one of the two points at its root (the guide's case).
    raise FileNotFoundError(
        f"no dataset {dataset_id!r} under {root} ({'datasets there: ' + ', '.join(there) if there else 'none there'});"
        " give its root as opponent.params.data_path=DIR (data_path= in Python) or MINARI_DATASETS_PATH=DIR"
    )


def _face(env: gymnasium.Env) -> SidewalkGymEnv:
    face = env.unwrapped
    if not isinstance(face, SidewalkGymEnv):
        raise TypeError(
            f"record() takes a sidewalk Gymnasium env (gymnasium.make('sidewalk/Discrete-v0', ...) or "
            f"SidewalkGymEnv), not {type(face).__name__}"
        )
    return face


def record(env: gymnasium.Env, *, data_path: str | os.PathLike | None = None) -> minari.DataCollector:
    """``env`` (a sidewalk Gymnasium env, ``gymnasium.make("sidewalk/...-v0", ...)`` or ``SidewalkGymEnv``) wrapped so
    that every reset and step is recorded, with the whole ``info`` of each step and raw (not JPEG) images. Minari
    keeps the episodes in a temporary folder under the datasets root (``data_path``, else Minari's) until ``save``."""
    _face(env)
    with datasets_root(data_path):
        return jax_free_collector_class()(env, record_infos=True, jpeg_encoding=False)


def _jsonable(value: Any) -> Any:
    """``value`` as JSON types: dataclasses and mappings as dicts, tuples as lists, paths as text."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if isinstance(value, Mapping):
        return {str(key): _jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(item) for item in value]
    if isinstance(value, (np.generic,)):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return repr(value)


def _world_config(world: World) -> dict[str, Any]:
    """A World as a dataset pins it (JSON types): domain, opponent and every one of its settings (defaults
    included), the recorded agent and its episode's end (None for the centralized view), shield, every core env
    parameter."""
    centralized = world.opponent == CENTRALIZED
    return _jsonable({
        "domain": world.domain,
        "opponent": world.opponent,
        "opponent_kwargs": opponent_config(world.opponent, world.opponent_params),
        "ego": None if centralized else world.ego,
        "end_on_ego_done": None if centralized else world.end_on_ego_done,
        "shield": world.shield,
        **dataclasses.asdict(world.env_params),
    })


def pinned_config(env: gymnasium.Env, env_config: Mapping[str, Any]) -> dict[str, Any]:
    """The full config of the sidewalk env ``env`` made with the keywords ``env_config`` (those of
    ``gymnasium.make``), written from its World (``_world_config``). Raises ``ValueError`` naming each keyword of
    ``env_config`` that the env does not take or that disagrees with it."""
    world = _face(env).world
    config = dict(env_config)
    if config.pop("domain", world.domain) != world.domain:
        raise ValueError(f"env_config domain={env_config['domain']!r}, but the env is of the {world.domain!r} domain")
    full = _world_config(world)
    unknown = sorted(set(config) - set(full))
    if unknown:
        raise ValueError(f"env_config keyword(s) {unknown} are none of the env's: {sorted(full)}")
    given = _jsonable(config)
    given["opponent_kwargs"] = opponent_config(world.opponent, given.get("opponent_kwargs") or {})
    differ = [f"{key}={given[key]!r} (the env has {full[key]!r})" for key in given
              if key != "rewards" and given[key] is not None and given[key] != full[key]]
    differ += [f"rewards.{key}={value!r} (the env has {full['rewards'].get(key)!r})"
               for key, value in (given.get("rewards") or {}).items() if full["rewards"].get(key) != value]
    if differ:
        raise ValueError(f"env_config does not describe the recorded env: {'; '.join(differ)}")
    return full


def _make_kwargs(env: gymnasium.Env, env_config: Mapping[str, Any]) -> dict[str, Any]:
    """The keywords that make ``env`` again: those of ``gymnasium.make`` (its spec's) and ``env_config``, with the
    view's own settings (opponent, ego, ...) from its World; the core's and the opponent's defaults left out, so
    that a later package's changed defaults show on ``load``."""
    spec_kwargs = dict(env.spec.kwargs) if env.spec is not None else {}
    kwargs = {**spec_kwargs, **env_config}
    kwargs.pop("domain", None)
    kwargs.pop("render_mode", None)  # how it is shown, not the world: gymnasium.make keeps it in the spec
    world = _face(env).world
    kwargs["opponent"] = world.opponent
    if world.opponent != CENTRALIZED:
        kwargs["ego"], kwargs["end_on_ego_done"] = world.ego, world.end_on_ego_done
    kwargs["shield"] = world.shield
    return _jsonable(kwargs)


def _env_id(domain: str) -> str:
    return ENV_IDS[domain]


def env_version(env_id: str) -> int:
    """The version N of a Gymnasium id ``name-vN``."""
    match = re.search(r"-v(\d+)$", env_id)
    if match is None:
        raise ValueError(f"env id {env_id!r} has no version (-vN)")
    return int(match.group(1))


def _card(dataset: minari.MinariDataset, pins: Mapping[str, Any]) -> str:
    """The data card (Markdown) of ``dataset``: what was recorded and how to load it."""
    config = pins["env_config"]
    ego = config["ego"]
    controlled = "every agent (the centralized view's joint action)" if ego is None else f"agent {ego}"
    partner = ("none (one controller for every agent)" if config["opponent"] == CENTRALIZED
               else f"`{config['opponent']}` with {json.dumps(config['opponent_kwargs'])}")
    meta = dataset.storage.metadata
    lines = [
        f"# {meta['dataset_id']}",
        "",
        meta.get("description") or "Episodes of the Sidewalk Problem recorded through its Gymnasium face.",
        "",
        (f"- env: `{pins['env_id']}` (version {pins['env_version']}), sidewalk {pins['sidewalk_version']}, "
         f"minari {meta.get('minari_version')}"),
        f"- author: {', '.join(sorted(meta.get('author', []))) or 'not given'}",
        f"- recorded agent: {controlled}; who drove it: {pins['driver']}",
        f"- partner (the other agents): {partner}",
        f"- episodes: {dataset.total_episodes}; steps: {dataset.total_steps}",
        f"- observation space: {dataset.observation_space}; action space: {dataset.action_space}",
        "",
        ("Each episode holds the recorded agent's observations (one more than its steps), actions, rewards, "
         "terminations, truncations and the face's `info` of every step: `is_success` (the recorded agent reached "
         "its goal), `cost` (its safety cost), `agents/{reached_goal, collided_agent, collided_wall, timed_out, "
         "reward, cost}` (one entry per agent), `state` and `goal` (every agent's true state and goal)."),
        "",
        "## Env config (pinned in the metadata under `sidewalk`)",
        "",
        "```json",
        json.dumps(config, indent=2, sort_keys=True),
        "```",
        "",
        "## Loading",
        "",
        "```python",
        "import sidewalk.datasets",
        f"dataset = sidewalk.datasets.load({meta['dataset_id']!r})  # warns if this package builds another env",
        "# or, without sidewalk: MINARI_DATASETS_PATH=<root> and minari.load_dataset(...)",
        "```",
        "",
    ]
    return "\n".join(lines)


def pins_of(dataset: minari.MinariDataset) -> dict[str, Any]:
    """What ``save`` pinned in ``dataset``'s metadata (env id and version, sidewalk version, driver, full env config);
    ``ValueError`` for a dataset that sidewalk did not write."""
    text = dataset.storage.metadata.get(METADATA_KEY)
    if text is None:
        raise ValueError(f"dataset {dataset.spec.dataset_id!r} has no {METADATA_KEY!r} metadata: not a sidewalk dataset")
    return json.loads(text)


def check_can_append(
    env: gymnasium.Env,
    dataset_id: str,
    *,
    env_config: Mapping[str, Any],
    data_path: str | os.PathLike | None = None,
    driver: str = "a scripted policy",
) -> dict[str, Any]:
    """The pins ``save`` would write for episodes of ``env`` (made with ``env_config``) under ``dataset_id``; a
    ``ValueError`` naming each difference when that dataset exists under another env (so a recorder can refuse
    before any episode is played)."""
    import minari

    check_dataset_id(dataset_id)
    env_id = env.spec.id if env.spec is not None else _env_id(_face(env).world.domain)
    pins = {
        "env_id": env_id,
        "env_version": env_version(env_id),
        "sidewalk_version": __version__,
        "driver": driver,
        "make_kwargs": _make_kwargs(env, env_config),
    }
    pins["env_config"] = pinned_config(env, pins["make_kwargs"])
    with datasets_root(data_path) as root:
        if not (root / dataset_id / "data").is_dir():
            return pins
        before = pins_of(minari.load_dataset(dataset_id))
    if before["env_config"] != pins["env_config"] or before["env_id"] != env_id:
        raise ValueError(f"dataset {dataset_id!r} was recorded under another env: "
                         f"{'; '.join(_differences(before, pins)) or 'its env id differs'}; "
                         "save these episodes under another id")
    return pins


def save(
    collector: minari.DataCollector,
    dataset_id: str,
    *,
    env_config: Mapping[str, Any],
    description: str = "",
    author: str | None = None,
    data_path: str | os.PathLike | None = None,
    driver: str = "a scripted policy",
) -> minari.MinariDataset:
    """Create ``dataset_id`` from ``collector``'s finished episodes (an unfinished one ends truncated), or append them
    when it exists (the pinned config must then be the same). Pins the env id, its version, the sidewalk version,
    ``driver`` (who drove the recorded agent: ``"a person (sidewalk-play)"``, ...) and the full env config of the
    env made with ``env_config`` (``pinned_config``) in the metadata, and writes the data card beside the data."""
    import minari

    pins = check_can_append(collector.env, dataset_id, env_config=env_config, data_path=data_path, driver=driver)
    with datasets_root(data_path) as root:
        if (root / dataset_id / "data").is_dir():
            dataset = minari.load_dataset(dataset_id)
            collector.add_to_dataset(dataset)
        else:
            with warnings.catch_warnings():  # Minari's nudges for fields we leave out (code permalink, email, ...)
                warnings.simplefilter("ignore", UserWarning)
                dataset = collector.create_dataset(
                    dataset_id, author=author, description=description or None, algorithm_name=driver)
        dataset.storage.update_metadata({METADATA_KEY: json.dumps(pins, sort_keys=True)})
        (root / dataset_id / CARD_NAME).write_text(_card(dataset, pins))
    return dataset


def _differences(pinned: Mapping[str, Any], current: Mapping[str, Any]) -> list[str]:
    """Each field of the pinned env that ``current`` has otherwise: versions, and config keys changed, missing
    from or added to the current package's config."""
    differ = [f"{key} {pinned.get(key)!r} (now {current[key]!r})"
              for key in ("env_version", "sidewalk_version") if pinned.get(key) != current[key]]
    old, new = pinned.get("env_config", {}), current["env_config"]
    # A key that came in later, at the value the env had before it (sidewalk.later_keys), builds the recorded env.
    later = {key.removeprefix("env."): value for key, value in LATER_ENV_KEYS.get(new.get("domain"), {}).items()}
    for key in sorted(set(old) | set(new)):
        if key not in new:
            differ.append(f"env config key {key!r} (pinned {old[key]!r}) is no longer one of the env's")
        elif key not in old:
            if not (key in later and new[key] == later[key]):
                differ.append(f"env config key {key!r} is new (now {new[key]!r})")
        elif isinstance(old[key], dict) and isinstance(new[key], dict):
            differ += [f"env config {key}.{item}" + _change(old[key], new[key], item)
                       for item in sorted(set(old[key]) | set(new[key])) if old[key].get(item) != new[key].get(item)]
        elif old[key] != new[key]:
            differ.append(f"env config {key} {old[key]!r} (now {new[key]!r})")
    return differ


def _change(old: Mapping[str, Any], new: Mapping[str, Any], key: str) -> str:
    if key not in new:
        return f" (pinned {old[key]!r}) is gone"
    if key not in old:
        return f" is new (now {new[key]!r})"
    return f" {old[key]!r} (now {new[key]!r})"


def current_pins(pins: Mapping[str, Any]) -> dict[str, Any]:
    """What the installed package builds from the keywords a dataset was made with (``pins["make_kwargs"]``)."""
    domain = pins["env_config"]["domain"]
    env = SidewalkGymEnv(domain, **pins["make_kwargs"])
    env_id = _env_id(domain)
    return {"env_id": env_id, "env_version": env_version(env_id), "sidewalk_version": __version__,
            "env_config": pinned_config(env, pins["make_kwargs"])}


def load(dataset_id: str, *, data_path: str | os.PathLike | None = None) -> minari.MinariDataset:
    """``minari.load_dataset(dataset_id)`` from the datasets root ``data_path`` (else Minari's), warning with a
    ``DatasetEnvMismatchWarning`` that names each pinned field the installed package would build otherwise (env
    version, sidewalk version, env config values whose defaults changed, keys gone or new)."""
    import minari

    check_dataset(dataset_id, data_path)
    with datasets_root(data_path):
        dataset = minari.load_dataset(dataset_id)
    pins = pins_of(dataset)
    try:
        differ = _differences(pins, current_pins(pins))
    except (TypeError, ValueError, KeyError) as error:  # the keywords it was made with are refused now
        differ = [f"the env it was made with cannot be built now ({error})"]
    if differ:
        warnings.warn(
            f"dataset {dataset_id!r} was recorded under another env than this package builds: {'; '.join(differ)}",
            DatasetEnvMismatchWarning, stacklevel=2,
        )
    return dataset


class ScriptedDriver:
    """A scripted opponent (``name``, with ``kwargs``) driving the recorded agent of the sidewalk Gymnasium env
    ``env`` from what its ``info`` shows (every agent's ``state``, ``goal`` and outcome flags): ``driver(info)`` is
    the action for ``env.step``. Call ``reset()`` at every ``env.reset`` (a planner forgets its warm start)."""

    def __init__(self, env: gymnasium.Env, name: str, **kwargs: Any) -> None:
        import torch

        from sidewalk.opponents.base import make_opponent

        view = _face(env).view
        if getattr(view, "opponent", None) is None:
            raise ValueError("a scripted driver drives the ego of an ego view, not the centralized view")
        self._torch = torch
        self._core = view.core
        self.walker = make_opponent(name, view.core, controlled=(view.ego,), ego=None, **kwargs)

    def reset(self) -> None:
        self.walker.reset(None)

    def __call__(self, info: Mapping[str, Any]) -> Any:
        torch, device = self._torch, self._core.device
        flags = info["agents"]
        done = np.logical_or.reduce([flags[key] for key in INFO_KEYS])
        state = torch.as_tensor(np.asarray(info["state"]), device=device).unsqueeze(0)
        goal = torch.as_tensor(np.asarray(info["goal"]), device=device).unsqueeze(0)
        done = torch.as_tensor(done, device=device).view(1, -1, 1)
        action = self.walker.act(state, goal, done)[0, 0]
        return int(action) if action.dim() == 0 else action.cpu().numpy().astype(np.float32)
