"""The Sidewalk and its §7 scenarios as BenchMARL tasks: every BenchMARL algorithm (MAPPO, IPPO, MASAC, IQL, VDN,
QMIX, ...) trains on them as on its own tasks (docs/guide/benchmarl.md). From Python::

    from sidewalk.interop.benchmarl import SidewalkTask  # first: adapts BenchMARL to this TorchRL
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig

    experiment = Experiment(
        task=SidewalkTask.DOOR_CONTINUOUS.get_from_yaml(), algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(), seed=0,
        config=ExperimentConfig.get_from_yaml(),
    )
    experiment.run()

or from the command line, BenchMARL's ``run.py`` with the sidewalk's tasks on its search path::

    python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous

Each task is a self-play view (``sidewalk.views.SelfPlayView``, keys without the deprecated ones) of one of the
self-play presets' worlds (``conf/experiment/selfplay_*.yaml``: the env, the noise and the reward with self-play's
progress shaping), its config in ``conf/task/sidewalk/<task>.yaml`` here. The observation is
``("agents", "observation")``; ``("agents", "info")`` (outcome flags, cost, mask) is logged as BenchMARL logs
infos; the root ``state`` goes to centralised critics and mixers. Grid images are given channels last and scaled to
[0, 1], as BenchMARL's CNN takes them (``model=layers/cnn``).

Importing this module makes BenchMARL 1.5 work with TorchRL 0.14 (``sidewalk._torchrl.adapt_benchmarl``: the
collector's old name, and no action-shape check in its Q-value modules) and registers the tasks with BenchMARL's
command line, and this package's models (``models.MODELS``: the dueling Q-value model, ``model=layers/dueling_mlp``)
with its model registry.
"""

from __future__ import annotations

import copy
import importlib.util
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sidewalk._torchrl import adapt_benchmarl

adapt_benchmarl()  # before this module imports BenchMARL's names

import torch
from benchmarl import environments as _benchmarl_environments
from benchmarl import models as _benchmarl_models
from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import DTypeCastTransform, EnvBase, ObservationNorm, PermuteTransform, Transform

from sidewalk.envs import CORE_ENVS
from sidewalk.envs.rewards import RewardParams
from sidewalk.interop.benchmarl.models import MODELS, DuelingMlpConfig
from sidewalk.schema import SELFPLAY_PROGRESS
from sidewalk.views.selfplay import SelfPlayView

ENV_NAME = "sidewalk"
CONFIG_DIR = Path(__file__).parent / "conf"  # BenchMARL's config layout: conf/task/sidewalk/<task>.yaml
TUNED_DIR = CONFIG_DIR / "tuned" / ENV_NAME  # tuned/sidewalk/<task>/<algorithm>.yaml, as BenchMARL's fine_tuned/
TUNED_SECTIONS = ("defaults", "task", "experiment", "algorithm", "model", "critic_model")
# A tuned file's defaults list may choose a section's model (Hydra merges that model's YAML over layers/mlp's, then
# the file's section over both): BenchMARL's command line composes it, experiment_configs reads it here.
MODEL_CHOICE = re.compile(r"/model/layers/(?P<name>\w+)@(?P<section>model|critic_model)")
MODEL_CHOICE_FORMS = ("/model/layers/<model>@model", "/model/layers/<model>@critic_model", "_self_")
TASK_CONFIG_KEYS = ("domain", "noise", "env", "reward", "state")
OBSERVATION_KEY = ("agents", "observation")


def make_core(config: dict[str, Any], num_envs: int, seed: int | None, device: Any):
    """The core env of ``num_envs`` worlds that a task's ``config`` describes: its ``domain``, ``noise``, ``env``
    fields (``sidewalk.envs`` params; the room of the layout where not given) and ``reward`` fields (the explicit
    reward; ``c_progress`` defaults to self-play's shaping, ``sidewalk.schema.SELFPLAY_PROGRESS``). ``state`` (default
    true) is the task's: whether BenchMARL is given the root state for its critics and mixers."""
    unknown = sorted(set(config) - set(TASK_CONFIG_KEYS))
    if unknown:
        raise ValueError(f"sidewalk task config: unknown key(s) {unknown}; valid: {list(TASK_CONFIG_KEYS)}")
    domain = config["domain"]
    if domain not in CORE_ENVS:
        raise ValueError(f"sidewalk task config: domain={domain!r} is not valid; valid: {list(CORE_ENVS)}")
    reward = {"c_progress": SELFPLAY_PROGRESS[domain], **(config.get("reward") or {})}
    return CORE_ENVS[domain](
        num_envs, device=device, seed=seed, noise=float(config.get("noise", 0.0)), rewards=RewardParams(**reward),
        **(config.get("env") or {}),
    )


class SidewalkTaskClass(TaskClass):
    """A sidewalk task for BenchMARL: its config (``TASK_CONFIG_KEYS``) names the domain, env, noise and reward, and
    whether BenchMARL gets the root state."""

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        config = copy.deepcopy(self.config)
        return lambda: SelfPlayView(make_core(config, num_envs, seed, device))

    def supports_continuous_actions(self) -> bool:
        return self.config["domain"] == "continuous"

    def supports_discrete_actions(self) -> bool:
        return self.config["domain"] == "discrete"

    def max_steps(self, env: EnvBase) -> int:
        return env.max_steps

    def has_render(self, env: EnvBase) -> bool:
        # TorchRL 0.14 writes BenchMARL's evaluation videos with torchcodec: without it, BenchMARL's default
        # render=true would fail at the first evaluation, so the task then says it has nothing to render.
        return importlib.util.find_spec("torchcodec") is not None

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def observation_spec(self, env: EnvBase) -> Composite:
        # Every entry of the group but "info" (the cost and mask are there): what BenchMARL's models take as input.
        groups = {}
        for group in self.group_map(env):
            groups[group] = env.full_observation_spec_unbatched[group].clone()
            del groups[group]["info"]
        return Composite(groups)

    def info_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched
        return Composite({
            group: Composite(info=spec[group, "info"].clone(), shape=spec[group].shape) for group in self.group_map(env)
        })

    def state_spec(self, env: EnvBase) -> Composite | None:
        # state: false leaves BenchMARL's critics and mixers on every agent's observation, as for VMAS's tasks.
        if not self.config.get("state", True):
            return None
        return Composite(state=env.full_observation_spec_unbatched["state"])

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    def action_mask_spec(self, env: EnvBase) -> None:
        return None

    def get_env_transforms(self, env: EnvBase) -> list[Transform]:
        if len(env.full_observation_spec[OBSERVATION_KEY].shape) - len(env.batch_size) < 4:
            return []  # vectors (the continuous world, the grid's vector observation)
        # Images (C, H, W) uint8 -> (H, W, C) in [0, 1]: BenchMARL's CNN takes images channels last.
        return [PermuteTransform((-2, -1, -3), in_keys=[OBSERVATION_KEY]),
                DTypeCastTransform(torch.uint8, torch.float32, in_keys=[OBSERVATION_KEY]),
                ObservationNorm(loc=0.0, scale=1 / 255, in_keys=[OBSERVATION_KEY], standard_normal=False)]

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


class SidewalkTask(Task):
    """The sidewalk's BenchMARL tasks: the self-play presets' worlds (``conf/experiment/selfplay_*.yaml``)."""

    SIDEWALK_CONTINUOUS = None
    SIDEWALK_DISCRETE = None
    CIRCLE_CONTINUOUS = None
    CIRCLE_DISCRETE = None
    TEAMS_CONTINUOUS = None
    TEAMS_DISCRETE = None
    DOOR_CONTINUOUS = None
    DOOR_DISCRETE = None
    ZIPPER_CONTINUOUS = None
    ZIPPER_DISCRETE = None

    @staticmethod
    def associated_class() -> type[SidewalkTaskClass]:
        return SidewalkTaskClass

    def get_from_yaml(self, path: str | None = None) -> SidewalkTaskClass:
        """The task with its config read from ``path``, by default this package's YAML of the task."""
        return super().get_from_yaml(path or str(self.config_path()))

    def config_path(self) -> Path:
        return CONFIG_DIR / "task" / ENV_NAME / f"{self.name.lower()}.yaml"

    def tuned_algorithms(self) -> list[str]:
        """The BenchMARL algorithms this package ships tuned settings for on this task."""
        return sorted(path.stem for path in (TUNED_DIR / self.name.lower()).glob("*.yaml"))

    def tuned_models(self, algorithm: str) -> dict[str, str]:
        """The models this package's tuned settings for ``algorithm`` on this task choose, by section
        (``{"model": "dueling_mlp"}``); empty where they choose none or there are none."""
        path = TUNED_DIR / self.name.lower() / f"{algorithm}.yaml"
        return _chosen_models(_read_yaml(path).get("defaults") or [], str(path)) if path.exists() else {}


def experiment_configs(task: SidewalkTask, algorithm: str, tuned: bool = True) -> dict[str, Any]:
    """``Experiment``'s arguments but the seed (``task``, ``algorithm_config``, ``model_config``,
    ``critic_model_config``, ``config``) for BenchMARL's ``algorithm`` on ``task``: BenchMARL's defaults (its
    ``base_experiment.yaml``, the algorithm's YAML, ``layers/mlp``) with this package's tuned settings for the pair
    (``conf/tuned/sidewalk/<task>/<algorithm>.yaml``) over them, where it has some and ``tuned``. A tuned file's
    ``defaults`` list may choose another model (``- /model/layers/dueling_mlp@model``), whose YAML its ``model``
    section then goes over. A setting that is not a field of BenchMARL's config, or a model it does not know, is an
    error naming the valid ones."""
    from benchmarl.algorithms import algorithm_config_registry
    from benchmarl.experiment import ExperimentConfig

    from sidewalk._checks import check_keys, replace_checked

    check_keys("BenchMARL", [algorithm], sorted(algorithm_config_registry), kind="algorithm")
    path = TUNED_DIR / task.name.lower() / f"{algorithm}.yaml"
    settings = _read_yaml(path) if tuned and path.exists() else {}
    check_keys(str(path), settings, TUNED_SECTIONS, kind="section")
    task_class = task.get_from_yaml()
    for key, value in (settings.get("task") or {}).items():  # one level deep: env and reward are dicts
        task_class.config[key] = {**task_class.config[key], **value} if isinstance(value, dict) else value
    make_core(task_class.config, 1, 0, "cpu")  # a bad task setting fails here, before any compute
    owner = f"{path.name} of {task.name.lower()}"
    chosen = _chosen_models(settings.get("defaults") or [], str(path))
    models = {}
    for section in ("model", "critic_model"):
        name = chosen.get(section, "mlp")
        check_keys(str(path), [name], sorted(_benchmarl_models.model_config_registry), kind="model")
        models[section] = replace_checked(_benchmarl_models.model_config_registry[name].get_from_yaml(),
                                          _model_classes(settings.get(section) or {}), f"{section} in {owner}")
    return {
        "task": task_class,
        "algorithm_config": replace_checked(algorithm_config_registry[algorithm].get_from_yaml(),
                                            settings.get("algorithm") or {}, f"algorithm in {owner}"),
        "model_config": models["model"],
        "critic_model_config": models["critic_model"],
        "config": replace_checked(ExperimentConfig.get_from_yaml(), settings.get("experiment") or {},
                                  f"experiment in {owner}"),
    }


def _chosen_models(defaults: list[Any], owner: str) -> dict[str, str]:
    """The model each section of a tuned file's ``defaults`` list chooses (``{"model": "dueling_mlp"}``); an entry
    of another form is an error naming the forms this package reads (``MODEL_CHOICE_FORMS``)."""
    chosen = {}
    for entry in defaults:
        match = MODEL_CHOICE.fullmatch(entry) if isinstance(entry, str) else None
        if match:
            chosen[match["section"]] = match["name"]
        elif entry != "_self_":
            raise ValueError(f"{owner}: defaults entry {entry!r} is not one a tuned file may have; valid: "
                             f"{', '.join(MODEL_CHOICE_FORMS)}")
    return chosen


def _model_classes(model: dict[str, Any]) -> dict[str, Any]:
    """A model section with its ``*_class`` names (``torch.nn.ReLU``) made classes, as BenchMARL's own YAML loader
    (``parse_model_config``) makes them."""
    from benchmarl.utils import _class_from_name

    return {key: _class_from_name(value) if key.endswith("class") and isinstance(value, str) else value
            for key, value in model.items()}


def _read_yaml(path: Path) -> dict[str, Any]:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(path))


def register() -> None:
    """Make the tasks known to BenchMARL's command line (``task=sidewalk/<task>``) and config loaders, and this
    package's models to its model registry (``model=layers/<name>``); idempotent."""
    _benchmarl_models.model_config_registry.update(MODELS)
    if SidewalkTask not in _benchmarl_environments.tasks:
        _benchmarl_environments.tasks.append(SidewalkTask)
    for task in SidewalkTask:
        _benchmarl_environments.task_config_registry[f"{ENV_NAME}/{task.name.lower()}"] = task


register()

__all__ = [
    "CONFIG_DIR", "TUNED_DIR", "DuelingMlpConfig", "SidewalkTask", "SidewalkTaskClass", "experiment_configs",
    "make_core", "register",
]
