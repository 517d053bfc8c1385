"""The schemas behind ``conf/``: one dataclass per config group, registered in Hydra's ConfigStore.

Each config group (``env``, ``opponent``, ``algo``, ``reward``, ``logger``) has a dataclass schema registered under
``schema/<group>/<name>``, outside the groups themselves so that ``env=foo`` lists only real choices. The env and
reward schemas are derived from the environments' own parameter dataclasses, so a default lives in one place. A run
folder's saved config is read back through them (``with_schema_defaults``), below everything that reads run folders.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf

from sidewalk._omegaconf import node_key
from sidewalk.envs.grid import DiscreteParams
from sidewalk.envs.rewards import RewardParams
from sidewalk.envs.unicycle import ContinuousParams
from sidewalk.later_keys import LATER_ENV_KEYS, NOMINAL_EVAL, later_algo_keys, later_opponent_keys
from sidewalk.registry import LEARNERS

# Set by the top level (`noise`) and the reward group, so they are not env-group fields.
ENV_FIELDS_SET_ELSEWHERE = ("noise", "rewards")


# OmegaConf reads typing.Optional, not X | None.
SCHEMA_TYPES = {
    "int": int, "float": float, "str": str, "bool": bool,
    "tuple[int, ...] | None": Optional[list[int]],  # noqa: UP045
}


def _mutable_schema(name: str, params_cls: type, extra: list[tuple], exclude: tuple[str, ...] = ()) -> type:
    """A plain (non-frozen) dataclass with the fields and defaults of ``params_cls``, for OmegaConf to type-check."""
    fields = []
    for f in dataclasses.fields(params_cls):
        if f.name in exclude:
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        annotation = SCHEMA_TYPES[f.type]  # the params modules use postponed (string) annotations
        fields.append((f.name, annotation, field(default=default)))
    return dataclasses.make_dataclass(name, [*extra, *fields])


DiscreteEnvSchema = _mutable_schema(
    "DiscreteEnvSchema", DiscreteParams, [("domain", str, field(default="discrete"))], ENV_FIELDS_SET_ELSEWHERE
)
ContinuousEnvSchema = _mutable_schema(
    "ContinuousEnvSchema", ContinuousParams, [("domain", str, field(default="continuous"))], ENV_FIELDS_SET_ELSEWHERE
)
RewardSchema = _mutable_schema("RewardSchema", RewardParams, [("name", str, field(default="explicit"))])


@dataclass
class OpponentSchema:
    """Who plays the other agent(s): a scripted opponent by name, a learned partner (``policy``: the frozen policy
    of the run folder ``path``), ``centralized`` (the learner plays all through one joint action) or ``self``
    (every agent is the learner: the multi-agent learners)."""

    name: str = MISSING
    ego: int = 0  # the agent the learner plays (ego views)
    end_on_ego_done: bool = False  # end the learner's episode when the ego is done, not when the world is
    params: dict[str, Any] = field(default_factory=dict)  # the opponent's own settings (planner radii, ...)
    path: str = ""  # opponent=policy: the run folder whose policy.pt plays the other agent(s)
    sample: bool = False  # opponent=policy: sample its actions (ε-greedy / the distribution) instead of greedy


@dataclass
class LoggerSchema:
    """A TorchRL logger writing beside ``metrics.csv``; ``none`` writes only ``metrics.csv``."""

    name: str = "csv"
    project: str = "sidewalk"  # wandb project / mlflow experiment
    offline: bool = True  # wandb: write locally, sync later with `wandb sync`
    tracking_uri: str = ""  # mlflow: empty = a local file store inside the run folder


# The env parameters an evaluation protocol sets, per domain: how its worlds differ from one another.
PROTOCOL_ENV_FIELDS = {
    "discrete": ("start_jitter_rows", "goal_jitter_rows", "start_jitter_cells", "goal_jitter_cells"),
    "continuous": ("start_jitter_m", "goal_jitter_m", "heading_jitter_rad"),
}


@dataclass
class EvalSchema:
    """An evaluation protocol (``eval=NAME``, docs/guide/evaluation.md): how an evaluation's worlds differ from one
    another. Each start and goal is moved within the stated bounds on every reset (grid: rows across the sidewalk, or
    to a free cell within ``*_jitter_cells`` rows and columns where the walls hold no row move;
    continuous: metres in x and y, and the start heading by up to ``heading_jitter_rad``), so that at noise 0 the
    worlds play different episodes and a success rate is a rate. ``train_alike``: training draws its worlds the same
    way (the env group's jitter defaults to the protocol's); false keeps training on the env group's own.
    ``epsilon``: the learner acts ε-greedily in evaluation (each agent's action uniform with this probability, from
    the evaluation's seeded stream; ``sidewalk.evaluate.run_episodes``); 0, the default, is greedy."""

    name: str = MISSING
    start_jitter_rows: int = 0
    goal_jitter_rows: int = 0
    start_jitter_cells: int = 0
    goal_jitter_cells: int = 0
    start_jitter_m: float = 0.0
    goal_jitter_m: float = 0.0
    heading_jitter_rad: float = 0.0
    train_alike: bool = True
    epsilon: float = 0.0


# What a run written before evaluation protocols existed was evaluated on: the scenario's own worlds.
NOMINAL_PROTOCOL = EvalSchema(**NOMINAL_EVAL)


@dataclass
class ExperimentSchema:
    """The root config. ``iterations`` counts collector batches (the paper's unit); ``eval_every`` and
    ``checkpoint_every`` are in iterations; ``num_envs`` worlds are simulated in one batched env (conf: the
    learner's ``algo.default_num_envs`` unless given)."""

    env: Any = MISSING
    opponent: Any = MISSING
    algo: Any = MISSING
    reward: Any = MISSING
    logger: Any = MISSING
    eval: Any = MISSING
    seed: int = 0
    replicas: int = 1
    noise: float = 0.0
    device: str = "cpu"
    num_envs: int = 32
    iterations: int = 500
    eval_every: int = 50
    eval_episodes: int = 256
    checkpoint_every: int = 50
    resume: bool = False
    keep_checkpoint: str = "final"
    torch_threads: int = 1
    shield: bool = False
    other_play: bool = False
    role_frame: bool = False
    plots: bool = True


def with_schema_defaults(cfg: DictConfig) -> DictConfig:
    """A run folder's saved config with every key it lacks filled from today's schemas (top level, algorithm,
    logger): a folder written before a key existed (``keep_checkpoint``, ``algo.dueling``) reads as the run it was,
    since a new key's default keeps the old behaviour, or ``sidewalk.later_keys`` gives the value it ran with (the
    evaluation protocol, the env's jitter, the Dijkstra agent's tie-break). The algorithm, logger and evaluation
    sections come back typed."""
    cfg = OmegaConf.merge(OmegaConf.structured(ExperimentSchema), cfg)
    saved_eval = {} if OmegaConf.is_missing(cfg, "eval") else cfg.eval
    cfg.eval = OmegaConf.merge(OmegaConf.structured(NOMINAL_PROTOCOL), saved_eval)
    env_keys = LATER_ENV_KEYS.get(str(cfg.env.get("domain")), {})
    cfg.env = OmegaConf.merge({key.split(".", 1)[1]: value for key, value in env_keys.items()}, cfg.env)
    cfg.opponent.params = OmegaConf.merge(later_opponent_keys(cfg.opponent.name), cfg.opponent.params)
    cfg.algo = OmegaConf.merge(
        OmegaConf.structured(LEARNERS[cfg.algo.name].Config), later_algo_keys(cfg.algo.name), cfg.algo
    )
    cfg.logger = OmegaConf.merge(OmegaConf.structured(LoggerSchema), cfg.logger)
    return cfg


def room_side(*, _parent_: Any, _node_: Any) -> float | int:
    """``${sidewalk.room:}``, the value of a room side in ``conf/env``: the side of the room the layout picks for its
    agents (the default room wherever it holds them, so no result changes), honouring the other side where the user
    gave it. The run's ``config.yaml`` records the number (configs are saved resolved)."""
    from sidewalk.envs import core_class

    env_cls = core_class(_parent_.domain)
    side = node_key(_node_)
    given = {key: _parent_[key] for key in ("layout", "n_agents", "agent_radius_m", "goal_radius_m",
                                            "min_start_goal_m", "min_start_goal_cells") if key in _parent_}
    for other in env_cls.room_sides:
        if other != side and not OmegaConf.is_interpolation(_parent_, other):
            given[other] = _parent_[other]
    try:
        return env_cls.with_room(given)[side]
    except (ValueError, TypeError):  # a scenario that cannot be built (env.layout=dor): validate names what is wrong
        return getattr(env_cls.Params(), side)


# Self-play's progress shaping (reward.c_progress), per metre (continuous) or per grid cell (every grid view's): without
# it the learners of `opponent=self` end with one agent walking home and the other never learning to
# (docs/guide/multiagent.md).
SELFPLAY_PROGRESS = {"continuous": 0.1, "discrete": 0.02}


def progress_default(*, _root_: Any) -> float:
    """``${sidewalk.progress:}``, the default of ``reward.c_progress`` in ``conf/reward``: the grid's shaping
    (``SELFPLAY_PROGRESS``) in every view of the grid; in the continuous world self-play's when every agent learns
    (``opponent=self``), else 0 (the paper's reward). In the grid, DQN against the Dijkstra agent without it ended
    waiting beside its own start once that agent had parked there, its Q-values for a walk of 14 cells too close to
    pick one (docs/guide/evaluation.md). A value given on the command line or in a preset (the paper's presets
    give 0) is taken as it is; the run's ``config.yaml`` records the number."""
    if _root_.opponent.name != "self" and _root_.env.domain != "discrete":
        return 0.0
    return SELFPLAY_PROGRESS[_root_.env.domain]


def trained_jitter(*, _root_: Any, _node_: Any) -> float | int:
    """``${sidewalk.train_jitter:}``, the default of a jitter bound in ``conf/env`` (``start_jitter_rows``, ...): the
    evaluation protocol's bound when it says training draws its worlds alike (``eval.train_alike``), else 0 (the
    scenario's own starts and goals). The run's ``config.yaml`` records the number."""
    eval_protocol = _root_.get("eval")
    if eval_protocol is None or not eval_protocol.get("train_alike", True) or draws_starts(_root_.env.layout):
        return 0
    return eval_protocol.get(node_key(_node_), 0)


def within_walls(bound: float, *, _root_: Any, _node_: Any) -> float | int:
    """``${sidewalk.within_walls:B}``, a bound of ``conf/eval/perturbed.yaml``: ``B``, or less where the scenario's
    walls allow less (the largest bound that keeps every start, or goal, on free cells: ``sidewalk.envs.layouts.jitter``),
    so the protocol perturbs every scenario as far as it can hold. A grid's cell bound (``start_jitter_cells``) stands
    in where the walls hold no row move at all (the circle's corners, the zipper's lanes, the teams' edge rows: one
    episode a world otherwise), and is 0 where rows move. A bound given on the command line is taken as it is
    and checked (``config.validate`` refuses one that puts an agent into a wall); the run's ``config.yaml`` records
    the number."""
    from sidewalk.envs.layouts import grid_layout, plane_layout
    from sidewalk.envs.layouts.jitter import largest_grid_jitter, largest_plane_jitter

    env, name = _root_.env, node_key(_node_)
    if name.endswith("_cells") and (env.domain != "discrete" or draws_starts(env.layout)):
        return 0  # a cell bound exists only to stand in for rows that cannot move; nowhere else is it drawn
    if (env.domain == "discrete") != name.endswith(("_rows", "_cells")) or draws_starts(env.layout):
        return bound  # the other domain's bound, or a scenario that draws its starts: not applied
    try:
        if env.domain == "discrete":
            layout = grid_layout(env.layout, env.width_cells, env.length_cells, env.n_agents, env.min_start_goal_cells)
            if name.endswith("_cells"):
                return bound if largest_grid_jitter(layout, name.replace("_cells", "_rows")) == 0 else 0
            return min(bound, largest_grid_jitter(layout, name))
        layout = plane_layout(env.layout, env.length_m, env.width_m, env.n_agents, env.agent_radius_m,
                              env.goal_radius_m, env.min_start_goal_m)
    except (ValueError, TypeError):  # a scenario that cannot be built: validate names what is wrong
        return bound
    return min(bound, math.floor(largest_plane_jitter(layout, name, env.agent_radius_m) * 1000 + 1e-6) / 1000)


def draws_starts(layout: Any) -> bool:
    """Whether the scenario ``layout`` (a name) draws every world's starts and goals itself (``random``), so that no
    jitter applies to it; an unknown name is for ``validate`` to refuse."""
    from sidewalk.registry import LAYOUTS

    return isinstance(layout, str) and layout in LAYOUTS.names() and LAYOUTS[layout].draws_starts


def on_images(on_images: Any, otherwise: Any, *, _root_: Any) -> Any:
    """``${sidewalk.on_images:a,b}``, a learner setting in ``conf/algo`` that depends on what the agents observe:
    ``a`` where they see images (the grid's default observation), else ``b``. The run's ``config.yaml`` records the
    value."""
    env = _root_.env
    return on_images if env.domain == "discrete" and env.get("observation", "image") == "image" else otherwise


def plugin_config_paths() -> list[str]:
    """``${sidewalk.searchpath:}``, Hydra's search path in ``conf/config.yaml``: the config folders that installed
    plug-ins declare (entry point group ``sidewalk.configs``, each naming a package that holds config groups), so
    their YAMLs compose like ours (``opponent=theirs``) with no ``hydra.searchpath=`` on the command line."""
    import importlib.metadata

    return [f"pkg://{point.value}" for point in importlib.metadata.entry_points(group="sidewalk.configs")]


def register_schemas() -> None:
    """Put the schemas in Hydra's ConfigStore and the resolvers in OmegaConf (idempotent)."""
    OmegaConf.register_new_resolver("sidewalk.room", room_side, replace=True)
    OmegaConf.register_new_resolver("sidewalk.searchpath", plugin_config_paths, replace=True)
    OmegaConf.register_new_resolver("sidewalk.progress", progress_default, replace=True)
    OmegaConf.register_new_resolver("sidewalk.on_images", on_images, replace=True)
    OmegaConf.register_new_resolver("sidewalk.train_jitter", trained_jitter, replace=True)
    OmegaConf.register_new_resolver("sidewalk.within_walls", within_walls, replace=True)
    store = ConfigStore.instance()
    store.store(name="experiment_schema", node=ExperimentSchema)
    store.store(group="schema/env", name="discrete", node=DiscreteEnvSchema)
    store.store(group="schema/env", name="continuous", node=ContinuousEnvSchema)
    store.store(group="schema/reward", name="reward", node=RewardSchema)
    store.store(group="schema/opponent", name="opponent", node=OpponentSchema)
    store.store(group="schema/logger", name="logger", node=LoggerSchema)
    store.store(group="schema/eval", name="eval", node=EvalSchema)
    for name in LEARNERS:
        store.store(group="schema/algo", name=name, node=LEARNERS[name].Config)


def env_params_of(cfg: DictConfig) -> DiscreteParams | ContinuousParams:
    """The env's parameters a composed (or saved) config describes: its env group, ``noise`` and reward group."""
    reward_fields = {k: v for k, v in OmegaConf.to_container(cfg.reward, resolve=True).items() if k != "name"}
    env_fields = {k: v for k, v in OmegaConf.to_container(cfg.env, resolve=True).items() if k != "domain"}
    params_cls = DiscreteParams if cfg.env.domain == "discrete" else ContinuousParams
    return params_cls(**env_fields, noise=float(cfg.noise), rewards=RewardParams(**reward_fields))
