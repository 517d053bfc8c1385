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
command line.
"""

from __future__ import annotations

import copy
import importlib.util
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sidewalk._torchrl import adapt_benchmarl

adapt_benchmarl()  # before this module imports BenchMARL's names

import torch
from benchmarl import environments as _benchmarl_environments
from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import DTypeCastTransform, EnvBase, ObservationNorm, PermuteTransform, Transform

from sidewalk.envs import CORE_ENVS
from sidewalk.envs.rewards import RewardParams
from sidewalk.schema import SELFPLAY_PROGRESS
from sidewalk.views.selfplay import SelfPlayView

ENV_NAME = "sidewalk"
CONFIG_DIR = Path(__file__).parent / "conf"  # BenchMARL's config layout: conf/task/sidewalk/<task>.yaml
TUNED_DIR = CONFIG_DIR / "tuned" / ENV_NAME  # tuned/sidewalk/<task>/<algorithm>.yaml, as BenchMARL's fine_tuned/
TUNED_SECTIONS = ("task", "experiment", "algorithm", "model", "critic_model")
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


def experiment_configs(task: SidewalkTask, algorithm: str, tuned: bool = True) -> dict[str, Any]:
    """``Experiment``'s arguments but the seed (``task``, ``algorithm_config``, ``model_config``,
    ``critic_model_config``, ``config``) for BenchMARL's ``algorithm`` on ``task``: BenchMARL's defaults (its
    ``base_experiment.yaml``, the algorithm's YAML, ``layers/mlp``) with this package's tuned settings for the pair
    (``conf/tuned/sidewalk/<task>/<algorithm>.yaml``) over them, where it has some and ``tuned``. A setting that is not
    a field of BenchMARL's config is an error naming the valid ones."""
    from benchmarl.algorithms import algorithm_config_registry
    from benchmarl.experiment import ExperimentConfig
    from benchmarl.models import MlpConfig

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
    models = {section: _model_classes(settings.get(section) or {}) for section in ("model", "critic_model")}
    return {
        "task": task_class,
        "algorithm_config": replace_checked(algorithm_config_registry[algorithm].get_from_yaml(),
                                            settings.get("algorithm") or {}, f"algorithm in {owner}"),
        "model_config": replace_checked(MlpConfig.get_from_yaml(), models["model"], f"model in {owner}"),
        "critic_model_config": replace_checked(MlpConfig.get_from_yaml(), models["critic_model"],
                                               f"critic_model in {owner}"),
        "config": replace_checked(ExperimentConfig.get_from_yaml(), settings.get("experiment") or {},
                                  f"experiment in {owner}"),
    }


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
    """Make the tasks known to BenchMARL's command line (``task=sidewalk/<task>``) and config loaders; idempotent."""
    if SidewalkTask not in _benchmarl_environments.tasks:
        _benchmarl_environments.tasks.append(SidewalkTask)
    for task in SidewalkTask:
        _benchmarl_environments.task_config_registry[f"{ENV_NAME}/{task.name.lower()}"] = task


register()

__all__ = [
    "CONFIG_DIR", "TUNED_DIR", "SidewalkTask", "SidewalkTaskClass", "experiment_configs", "make_core", "register",
]
