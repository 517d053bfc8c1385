"""Structured configs of an experiment: the schemas behind ``conf/`` and the checks run before any compute.

Each config group (``env``, ``opponent``, ``algo``, ``reward``, ``logger``) has a dataclass schema registered in
Hydra's ConfigStore under ``schema/<group>/<name>``, outside the groups themselves so that ``env=foo`` lists only
real choices. The env and reward schemas are derived from the environments' own parameter dataclasses, so a
default lives in one place. Range checks run in ``validate``, which turns the composed config into the objects
the experiment builds, raising on the first bad value or combination with a message that names it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf

from sidewalk._checks import check_choice, check_int, check_keys, check_range
from sidewalk.algos.base import AlgoConfig
from sidewalk.envs.grid import DiscreteParams, DiscreteSidewalkEnv
from sidewalk.envs.rewards import RewardParams
from sidewalk.envs.unicycle import ContinuousParams, ContinuousSidewalkEnv
from sidewalk.views import MAX_JOINT_ACTIONS

DOMAINS = ("discrete", "continuous")
OPPONENT_DOMAINS = {
    "random": DOMAINS, "dijkstra": ("discrete",), "prm": ("continuous",), "centralized": DOMAINS,
    "policy": DOMAINS,  # a learned partner: the frozen policy of a finished run (opponent.path)
    "self": DOMAINS,  # self-play: every agent is the learner (the multi-agent learners)
}
ALGO_DOMAINS = {
    "dqn": ("discrete",), "trpo": DOMAINS, "ppo": DOMAINS,
    "ppo_lagrangian": DOMAINS,
    "ippo": DOMAINS, "mappo": DOMAINS, "iql": ("discrete",), "vdn": ("discrete",), "qmix": ("discrete",),
}
LOGGERS = ("csv", "tensorboard", "wandb", "mlflow", "none")
KEEP_CHECKPOINT = ("final", "all")
# Set by the top level (`noise`) and the reward group, so they are not env-group fields.
ENV_FIELDS_SET_ELSEWHERE = ("noise", "rewards")


SCHEMA_TYPES = {"int": int, "float": float, "str": str, "bool": bool, "tuple[int, ...] | None": Optional[list[int]]}


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
    seed: int = 0
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


def with_schema_defaults(cfg: DictConfig) -> DictConfig:
    """A run folder's saved config with every key it lacks filled from today's schemas (top level, algorithm,
    logger): a folder written before a key existed (``keep_checkpoint``, ``algo.dueling``) reads as the run it was,
    since a new key's default keeps the old behaviour. The algorithm and logger sections come back typed."""
    from sidewalk.algos import ALGORITHMS

    cfg = OmegaConf.merge(OmegaConf.structured(ExperimentSchema), cfg)
    cfg.algo = OmegaConf.merge(OmegaConf.structured(ALGORITHMS[cfg.algo.name].Config), cfg.algo)
    cfg.logger = OmegaConf.merge(OmegaConf.structured(LoggerSchema), cfg.logger)
    return cfg


def room_side(*, _parent_: Any, _node_: Any) -> float | int:
    """``${sidewalk.room:}``, the value of a room side in ``conf/env``: the side of the room the layout picks for its
    agents (the default room wherever it holds them, so no result changes), honouring the other side where the user
    gave it. The run's ``config.yaml`` records the number (configs are saved resolved)."""
    from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv

    env_cls = DiscreteSidewalkEnv if _parent_.domain == "discrete" else ContinuousSidewalkEnv
    side = _node_._key()
    given = {key: _parent_[key] for key in ("layout", "n_agents", "agent_radius_m", "goal_radius_m",
                                            "min_start_goal_m", "min_start_goal_cells") if key in _parent_}
    for other in env_cls.room_sides:
        if other != side and not _parent_._get_node(other)._is_interpolation():
            given[other] = _parent_[other]
    return env_cls.with_room(given)[side]


def register_schemas() -> None:
    """Put the schemas in Hydra's ConfigStore and the room resolver in OmegaConf (idempotent)."""
    from sidewalk.algos import ALGORITHMS

    OmegaConf.register_new_resolver("sidewalk.room", room_side, replace=True)
    store = ConfigStore.instance()
    store.store(name="experiment_schema", node=ExperimentSchema)
    store.store(group="schema/env", name="discrete", node=DiscreteEnvSchema)
    store.store(group="schema/env", name="continuous", node=ContinuousEnvSchema)
    store.store(group="schema/reward", name="reward", node=RewardSchema)
    store.store(group="schema/opponent", name="opponent", node=OpponentSchema)
    store.store(group="schema/logger", name="logger", node=LoggerSchema)
    for name in ALGORITHMS:
        store.store(group="schema/algo", name=name, node=ALGORITHMS[name].Config)


@dataclass(frozen=True)
class Experiment:
    """A validated experiment: the objects to build, every value checked."""

    domain: str
    env_params: Any  # DiscreteParams | ContinuousParams
    opponent: str
    opponent_params: dict
    ego: int
    end_on_ego_done: bool
    algo: AlgoConfig
    logger: LoggerSchema
    seed: int
    device: str
    num_envs: int
    iterations: int
    eval_every: int
    eval_episodes: int
    checkpoint_every: int
    resume: bool
    keep_checkpoint: str
    torch_threads: int
    shield: bool = False  # the safety shield guards the learner's actions (training and evaluation)
    other_play: bool = False  # self-play partners act through a random mirror of the game (sidewalk.symmetry)


def _field_names(schema: type) -> list[str]:
    return [f.name for f in dataclasses.fields(schema)]


def check_known_keys(cfg: DictConfig, algo_cls: type) -> None:
    """Raise naming any key no schema has (``+nosie=0.5``, ``+env.widht_m=2``), with the closest valid one.

    Hydra's ``+`` adds a key whatever the schema says, and an unread key would let a typo train on the default.
    """
    top = [key for key in cfg if key != "hydra"]
    check_keys("the experiment (top level)", top, _field_names(ExperimentSchema))
    env_schema = DiscreteEnvSchema if cfg.env.domain == "discrete" else ContinuousEnvSchema
    groups = {
        "env": env_schema, "reward": RewardSchema, "opponent": OpponentSchema, "logger": LoggerSchema,
        "algo": algo_cls,
    }
    for group, schema in groups.items():
        check_keys(f"{group}.* ({group}={cfg[group].get('name', cfg[group].get('domain'))})", list(cfg[group].keys()),
                   _field_names(schema))


def validate(cfg: DictConfig) -> Experiment:
    """Check a composed config and build the typed experiment, raising ``ValueError``/``TypeError`` that names
    the first bad value (and the valid ones) or the combination that makes no sense."""
    from sidewalk.algos import ALGORITHMS

    check_int("seed", cfg.seed, 0)
    check_int("num_envs", cfg.num_envs, 1)
    check_int("iterations", cfg.iterations, 1)
    check_int("eval_every", cfg.eval_every, 0)
    check_int("eval_episodes", cfg.eval_episodes, 1)
    check_int("checkpoint_every", cfg.checkpoint_every, 0)
    check_int("torch_threads", cfg.torch_threads, 1)
    check_choice("keep_checkpoint", cfg.keep_checkpoint, KEEP_CHECKPOINT)
    if not str(cfg.device).startswith(("cpu", "cuda", "mps")):
        raise ValueError(f"device={cfg.device!r} is not valid; valid: 'cpu', 'cuda', 'cuda:N', 'mps'")

    domain = cfg.env.domain
    check_choice("env.domain", domain, DOMAINS)
    opponent = cfg.opponent.name
    check_choice("opponent", opponent, OPPONENT_DOMAINS)
    if domain not in OPPONENT_DOMAINS[opponent]:
        valid = [name for name, domains in OPPONENT_DOMAINS.items() if domain in domains]
        raise ValueError(f"opponent={opponent} does not play env={domain}; valid opponents there: {', '.join(valid)}")
    algo_name = cfg.algo.name
    check_choice("algo", algo_name, ALGORITHMS)
    if domain not in ALGO_DOMAINS[algo_name]:
        valid = [name for name, domains in ALGO_DOMAINS.items() if domain in domains]
        raise ValueError(f"algo={algo_name} does not fit env={domain}; valid algos there: {', '.join(valid)}")
    multi_agent = ALGORITHMS[algo_name].multi_agent
    if multi_agent and opponent != "self":
        raise ValueError(
            f"algo={algo_name} trains every agent (self-play): use opponent=self, not opponent={opponent}; "
            f"single-agent learners for opponent={opponent}: "
            f"{', '.join(n for n in ALGO_DOMAINS if not ALGORITHMS[n].multi_agent and domain in ALGO_DOMAINS[n])}"
        )
    if opponent == "self" and not multi_agent:
        raise ValueError(
            f"opponent=self trains every agent, which algo={algo_name} (single-agent) cannot; multi-agent learners "
            f"for env={domain}: {', '.join(n for n in ALGO_DOMAINS if ALGORITHMS[n].multi_agent and domain in ALGO_DOMAINS[n])}"
        )
    check_choice("logger", cfg.logger.name, LOGGERS)
    check_known_keys(cfg, ALGORITHMS[algo_name].Config)

    # The noise means a random-action probability in the grid and a ±ε uniform noise in the continuous world.
    if domain == "discrete":
        check_range("noise", cfg.noise, 0.0, 1.0)
    else:
        check_range("noise", cfg.noise, 0.0, 10.0)
    reward_fields = {k: v for k, v in OmegaConf.to_container(cfg.reward, resolve=True).items() if k != "name"}
    rewards = RewardParams(**reward_fields)
    env_fields = {k: v for k, v in OmegaConf.to_container(cfg.env, resolve=True).items() if k != "domain"}
    params_cls = DiscreteParams if domain == "discrete" else ContinuousParams
    env_params = params_cls(**env_fields, noise=float(cfg.noise), rewards=rewards)

    if domain == "discrete" and env_params.observation == "image":
        from sidewalk.algos.networks import min_image_side

        side = min_image_side()
        height = env_params.width_cells * env_params.pixels_per_cell
        width = env_params.length_cells * env_params.pixels_per_cell
        if min(height, width) < side:
            raise ValueError(
                f"env.observation=image gives {height}×{width} px (cells × pixels_per_cell={env_params.pixels_per_cell}); "
                f"the paper's conv stack needs at least {side} px per side: raise env.pixels_per_cell or use "
                "env.observation=vector"
            )
    env_cls = DiscreteSidewalkEnv if domain == "discrete" else ContinuousSidewalkEnv
    n_agents = env_cls.layout_for(env_params).n_agents  # raises on a scenario that cannot hold its agents
    rewards.shaping_mask(n_agents, device="cpu")  # raises on agents the layout does not have
    if opponent == "centralized" and domain == "discrete" and 4**n_agents > MAX_JOINT_ACTIONS:
        raise ValueError(
            f"opponent=centralized plays {n_agents} grid agents through 4**{n_agents} = {4**n_agents} joint actions, "
            f"more than the limit {MAX_JOINT_ACTIONS} (5 agents); use fewer agents (env.n_agents) or a scripted opponent"
        )
    ego = cfg.opponent.ego
    check_int("opponent.ego", ego, 0, n_agents - 1)
    opponent_params = dict(OmegaConf.to_container(cfg.opponent.params, resolve=True))
    if opponent == "policy":
        from sidewalk.opponents.policy import check_partner

        # Before any compute: the folder exists, holds a policy, and was trained on this world.
        check_partner(str(cfg.opponent.get("path", "")), domain, env_params, ego)
        opponent_params = {"path": str(cfg.opponent.path), "sample": bool(cfg.opponent.get("sample", False))}
    elif cfg.opponent.get("path", ""):
        raise ValueError(f"opponent.path={cfg.opponent.path!r} applies only to opponent=policy, not opponent={opponent}")
    if cfg.other_play:
        if opponent != "self":
            raise ValueError(f"other_play=true trains self-play partners: use opponent=self, not opponent={opponent}")
        from sidewalk.symmetry import check_mirror_symmetric

        check_mirror_symmetric(env_cls.layout_for(env_params))
    algo_cls = ALGORITHMS[algo_name].Config
    algo = OmegaConf.to_object(cfg.algo) if OmegaConf.get_type(cfg.algo) is algo_cls else algo_cls(**cfg.algo)
    logger = OmegaConf.to_object(cfg.logger) if OmegaConf.get_type(cfg.logger) is LoggerSchema else LoggerSchema(**cfg.logger)
    return Experiment(
        domain=domain,
        env_params=env_params,
        opponent=opponent,
        opponent_params=opponent_params,
        ego=ego,
        end_on_ego_done=bool(cfg.opponent.end_on_ego_done),
        algo=algo,
        logger=logger,
        seed=cfg.seed,
        device=str(cfg.device),
        num_envs=cfg.num_envs,
        iterations=cfg.iterations,
        eval_every=cfg.eval_every,
        eval_episodes=cfg.eval_episodes,
        checkpoint_every=cfg.checkpoint_every,
        resume=bool(cfg.resume),
        keep_checkpoint=str(cfg.keep_checkpoint),
        torch_threads=cfg.torch_threads,
        shield=bool(cfg.shield),
        other_play=bool(cfg.other_play),
    )
