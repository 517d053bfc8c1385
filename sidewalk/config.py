"""The checks run before any compute: ``validate`` turns a composed config into the typed ``Experiment``.

The config groups' schemas live in ``sidewalk.schema``. ``validate`` raises on the first bad value or combination
with a message that names it and the valid choices, which it reads from what the opponents and learners declare
(``sidewalk.registry``). It opens no file: a learned partner's run folder is checked by ``check_partner``
(``sidewalk.partners.policy``), which the runner calls beside it, still before any compute.
"""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

from sidewalk._checks import check_choice, check_int, check_keys, check_range
from sidewalk.algos.base import AlgoConfig
from sidewalk.envs import CORE_ENVS, core_class
from sidewalk.opponents.base import OPPONENT_PLACES
from sidewalk.registry import LAYOUTS, LEARNERS, OPPONENTS
from sidewalk.schema import (
    PROTOCOL_ENV_FIELDS,
    ContinuousEnvSchema,
    DiscreteEnvSchema,
    EvalSchema,
    ExperimentSchema,
    LoggerSchema,
    OpponentSchema,
    RewardSchema,
    draws_starts,
    env_params_of,
)
from sidewalk.views import MAX_JOINT_ACTIONS
from sidewalk.world import LEARNER_PLAYS_ALL, World

DOMAINS = tuple(CORE_ENVS)
LOGGERS = ("csv", "tensorboard", "wandb", "mlflow", "none")
KEEP_CHECKPOINT = ("final", "all")


def opponent_domains() -> dict[str, tuple[str, ...]]:
    """Every ``opponent`` choice and the domains it plays: the registered opponents, ``centralized`` and ``self``."""
    return {**{name: OPPONENTS[name].domains for name in OPPONENTS}, **dict.fromkeys(LEARNER_PLAYS_ALL, DOMAINS)}


@dataclass(frozen=True)
class Experiment:
    """A validated experiment, every value checked: the ``world`` it trains in (``eval_world``: the worlds its
    protocol evaluates on), the learner, the budget and the seeds."""

    world: World
    evaluation: EvalSchema  # the evaluation protocol (conf/eval): how evaluation worlds differ from the training's
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
    replicas: int = 1  # seeds seed .. seed+replicas-1 trained together in this process (sidewalk.experiment.Trial)

    def describe(self) -> str:
        """What this experiment trains, as the overrides that choose it: the world, the learner, the opponent, the
        noise, the seeds and the budget."""
        seeds = f"seeds={self.seed}..{self.seed + self.replicas - 1}" if self.replicas > 1 else f"seed={self.seed}"
        world = self.world
        return (f"env={world.domain} env.layout={world.env_params.layout} algo={self.algo.name} "
                f"opponent={world.opponent} noise={world.env_params.noise:g} {seeds} iterations={self.iterations}")

    @property
    def eval_world(self) -> World:
        """The worlds an evaluation plays: the training world with the protocol's jitter bounds."""
        return dataclasses.replace(
            self.world, env_params=protocol_env_params(self.evaluation, self.world.domain, self.world.env_params))

    def protocol_summary(self) -> dict[str, Any]:
        """The evaluation protocol as ``summary.json`` records it: its name, the bounds of this domain, and whether
        training drew its worlds alike."""
        bounds = {name: getattr(self.evaluation, name) for name in PROTOCOL_ENV_FIELDS[self.world.domain]}
        return {"name": self.evaluation.name, **bounds, "train_alike": self.evaluation.train_alike,
                "epsilon": self.evaluation.epsilon}


def protocol_env_params(protocol: EvalSchema, domain: str, env_params: Any) -> Any:
    """``env_params`` with the jitter bounds of ``protocol`` (this domain's: ``PROTOCOL_ENV_FIELDS``); a scenario that
    draws its starts and goals itself (``random``) keeps its own."""
    if draws_starts(env_params.layout):
        return env_params
    return dataclasses.replace(env_params, **{name: getattr(protocol, name) for name in PROTOCOL_ENV_FIELDS[domain]})


def _field_names(schema: type) -> list[str]:
    return [f.name for f in dataclasses.fields(schema)]


def check_known_keys(cfg: DictConfig, algo_cls: type | None) -> None:
    """Raise naming any key no schema has (``+nosie=0.5``, ``+env.widht_m=2``), with the closest valid one; the
    learner's keys against ``algo_cls`` (None: not checked, where nothing learns).

    Hydra's ``+`` adds a key whatever the schema says, and an unread key would let a typo train on the default.
    """
    top = [key for key in cfg if key != "hydra"]
    check_keys("the experiment (top level)", top, _field_names(ExperimentSchema))
    env_schema = DiscreteEnvSchema if cfg.env.domain == "discrete" else ContinuousEnvSchema
    groups = {
        "env": env_schema, "reward": RewardSchema, "opponent": OpponentSchema, "logger": LoggerSchema,
        "algo": algo_cls, "eval": EvalSchema,
    }
    for group, schema in groups.items():
        if schema is None:
            continue
        check_keys(f"{group}.* ({group}={cfg[group].get('name', cfg[group].get('domain'))})", list(cfg[group].keys()),
                   _field_names(schema))


def unknown_override(error: OmegaConfBaseException) -> str | None:
    """The message ``check_keys`` gives for a plain override of a key no schema has (``nosie=0.5``, no ``+``), from
    the error OmegaConf raised under Hydra's (which advises adding the typo with ``+``); None for any other error and
    for Hydra's own settings (``hydra.*``)."""
    parent = error.parent_node
    if not isinstance(error, (ConfigAttributeError, ConfigKeyError)) or not isinstance(parent, DictConfig):
        return None
    full_key, key = str(error.full_key), str(error.key)
    group = full_key[: -len(key) - 1] if full_key.endswith(f".{key}") else ""
    if group.split(".")[0] == "hydra" or full_key == "hydra":
        return None
    owner = f"{group}.*" if group else "the experiment (top level)"
    try:
        check_keys(owner, [key], [name for name in parent if name != "hydra"])
    except ValueError as unknown:
        return str(unknown)
    return None


def validate(cfg: DictConfig) -> Experiment:
    """Check a composed config and build the typed experiment, raising ``ValueError``/``TypeError`` that names
    the first bad value (and the valid ones) or the combination that makes no sense."""
    _check_run_settings(cfg)
    domain, opponent, algo_name = _check_pairing(cfg)
    check_choice("logger", cfg.logger.name, LOGGERS)
    check_known_keys(cfg, LEARNERS[algo_name].Config)
    world, evaluation = _checked_world(cfg, domain, opponent)
    algo_cls = LEARNERS[algo_name].Config
    algo = OmegaConf.to_object(cfg.algo) if OmegaConf.get_type(cfg.algo) is algo_cls else algo_cls(**cfg.algo)
    logger = OmegaConf.to_object(cfg.logger) if OmegaConf.get_type(cfg.logger) is LoggerSchema else LoggerSchema(**cfg.logger)
    return Experiment(
        world=world,
        evaluation=evaluation,
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
        replicas=cfg.replicas,
    )


def validate_world(cfg: DictConfig) -> World:
    """The World of a composed config (its env, partner, shield, other-play), checked as ``validate`` checks it, with
    no learner or run: for scripted play (the play page, renders), where nothing learns."""
    domain, opponent = _check_partner_pairing(cfg)
    check_known_keys(cfg, algo_cls=None)
    return _checked_world(cfg, domain, opponent)[0]


def _checked_world(cfg: DictConfig, domain: str, opponent: str) -> tuple[World, EvalSchema]:
    """The training world of ``cfg`` and its evaluation protocol, every value checked."""
    check_choice("env.layout", cfg.env.layout, LAYOUTS.names())
    # The noise means a random-action probability in the grid and a ±ε uniform noise in the continuous world.
    check_range("noise", cfg.noise, 0.0, 1.0 if domain == "discrete" else 10.0)
    env_params = env_params_of(cfg)
    evaluation = _check_protocol(cfg, domain, env_params)
    n_agents = _check_world(cfg, domain, opponent, env_params)
    ego = cfg.opponent.ego
    check_int("opponent.ego", ego, 0, n_agents - 1)
    world = World(domain, env_params, opponent, _opponent_params(cfg, opponent), ego,
                  end_on_ego_done=bool(cfg.opponent.end_on_ego_done), shield=bool(cfg.shield),
                  other_play=bool(cfg.other_play), role_frame=bool(cfg.get("role_frame", False)))
    return world, evaluation


def _check_run_settings(cfg: DictConfig) -> None:
    """The run's own numbers: seed, sizes, budgets, threads, what it keeps and where it runs."""
    check_int("seed", cfg.seed, 0)
    check_int("replicas", cfg.replicas, 1)
    check_int("num_envs", cfg.num_envs, 1)
    check_int("iterations", cfg.iterations, 1)
    check_int("eval_every", cfg.eval_every, 0)
    check_int("eval_episodes", cfg.eval_episodes, 1)
    check_int("checkpoint_every", cfg.checkpoint_every, 0)
    check_int("torch_threads", cfg.torch_threads, 1)
    check_choice("keep_checkpoint", cfg.keep_checkpoint, KEEP_CHECKPOINT)
    if not str(cfg.device).startswith(("cpu", "cuda", "mps")):
        raise ValueError(f"device={cfg.device!r} is not valid; valid: 'cpu', 'cuda', 'cuda:N', 'mps'")
    if str(cfg.device) not in available_devices():
        raise ValueError(f"device={cfg.device!r} is not available on this machine (torch {torch.__version__}); "
                         f"available: {', '.join(map(repr, available_devices()))}")


def available_devices() -> list[str]:
    """The devices this torch build can run on here: ``cpu``, ``cuda`` and ``cuda:N`` for each GPU, ``mps``."""
    devices = ["cpu"]
    if torch.cuda.is_available():
        devices += ["cuda", *(f"cuda:{index}" for index in range(torch.cuda.device_count()))]
    if torch.backends.mps.is_available():
        devices.append("mps")
    return devices


def _check_partner_pairing(cfg: DictConfig) -> tuple[str, str]:
    """The domain and the opponent, checked to fit each other (as the opponent declares the domains it plays)."""
    domain = cfg.env.domain
    check_choice("env.domain", domain, DOMAINS)
    opponents = opponent_domains()
    opponent = cfg.opponent.name
    check_choice("opponent", opponent, opponents)
    if domain not in opponents[opponent]:
        valid = [name for name, domains in opponents.items() if domain in domains]
        raise ValueError(f"opponent={opponent} does not play env={domain}; valid opponents there: {', '.join(valid)}")
    return domain, opponent


def _check_pairing(cfg: DictConfig) -> tuple[str, str, str]:
    """The domain, the opponent and the learner, checked to fit one another (as each declares what it plays)."""
    domain, opponent = _check_partner_pairing(cfg)
    algo_name = cfg.algo.name
    check_choice("algo", algo_name, LEARNERS)
    learners = {name: LEARNERS[name] for name in LEARNERS}
    if domain not in learners[algo_name].domains:
        valid = [name for name, cls in learners.items() if domain in cls.domains]
        raise ValueError(f"algo={algo_name} does not fit env={domain}; valid algos there: {', '.join(valid)}")
    multi_agent = learners[algo_name].multi_agent

    def fitting(multi: bool) -> str:
        return ", ".join(name for name, cls in learners.items() if cls.multi_agent == multi and domain in cls.domains)

    if multi_agent and opponent != "self":
        raise ValueError(
            f"algo={algo_name} trains every agent (self-play): use opponent=self, not opponent={opponent}; "
            f"single-agent learners for opponent={opponent}: {fitting(False)}"
        )
    if opponent == "self" and not multi_agent:
        raise ValueError(
            f"opponent=self trains every agent, which algo={algo_name} (single-agent) cannot; multi-agent learners "
            f"for env={domain}: {fitting(True)}"
        )
    return domain, opponent, algo_name


def _check_protocol(cfg: DictConfig, domain: str, env_params: Any) -> EvalSchema:
    """The evaluation protocol, its bounds checked against the scenario's walls (the env raises naming the largest
    bound that keeps every agent off them), before the training world's check: with ``eval.train_alike`` training
    takes the same bounds, and the user gave them as ``eval.*``."""
    protocol = OmegaConf.to_object(cfg.eval) if OmegaConf.get_type(cfg.eval) is EvalSchema else EvalSchema(**cfg.eval)
    check_range("eval.epsilon", protocol.epsilon, 0.0, 1.0)
    if protocol.epsilon == 1.0:  # check_range's bound is closed; a policy that never acts is no evaluation of it
        raise ValueError("eval.epsilon=1.0 is out of range; valid: [0.0, 1.0)")
    try:
        core_class(domain).layout_for(protocol_env_params(protocol, domain, env_params))
    except ValueError as error:
        if not str(error).startswith(PROTOCOL_ENV_FIELDS[domain]):
            raise  # the scenario itself cannot be built: the message names what is wrong with it
        raise ValueError(f"eval={protocol.name}: eval.{error}") from None
    return protocol


def _check_world(cfg: DictConfig, domain: str, opponent: str, env_params: Any) -> int:
    """The world the env params describe can be built and played this way; returns its number of agents."""
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
    layout = core_class(domain).layout_for(env_params)  # raises on a scenario that cannot hold its agents
    n_agents = layout.n_agents
    env_params.rewards.shaping_mask(n_agents, device="cpu")  # raises on agents the layout does not have
    if opponent == "centralized" and domain == "discrete" and 4**n_agents > MAX_JOINT_ACTIONS:
        raise ValueError(
            f"opponent=centralized plays {n_agents} grid agents through 4**{n_agents} = {4**n_agents} joint actions, "
            f"more than the limit {MAX_JOINT_ACTIONS} (5 agents); use fewer agents (env.n_agents) or a scripted opponent"
        )
    if cfg.other_play:
        if opponent != "self":
            raise ValueError(f"other_play=true trains self-play partners: use opponent=self, not opponent={opponent}")
        from sidewalk.symmetry import check_mirror_symmetric

        check_mirror_symmetric(layout)
    if cfg.get("role_frame", False):  # a run written before the key played in the world's frame
        if opponent != "self":
            raise ValueError(f"role_frame=true trains self-play partners: use opponent=self, not opponent={opponent}")
        from sidewalk.symmetry import role_turns

        role_turns(domain, env_params)  # raises naming the agents no symmetry maps onto agent 0
    return n_agents


def _opponent_params(cfg: DictConfig, opponent: str) -> dict[str, Any]:
    """The opponent's own settings; a learned partner's are its run folder and whether it samples."""
    if opponent == "policy":
        return {"path": str(cfg.opponent.get("path", "")), "sample": bool(cfg.opponent.get("sample", False))}
    if cfg.opponent.get("path", ""):
        raise ValueError(f"opponent.path={cfg.opponent.path!r} applies only to opponent=policy, not opponent={opponent}")
    params = dict(OmegaConf.to_container(cfg.opponent.params, resolve=True))
    settings = opponent_settings(opponent)
    if settings is not None:
        check_keys(f"opponent.params (opponent={opponent})", params, settings, kind="parameter")
    return params


def opponent_settings(opponent: str) -> list[str] | None:
    """The settings ``opponent.params`` may give ``opponent``, read from its constructor: the keywords after the env,
    the agents it plays and the ego; none for the views ``centralized`` and ``self``; None (any) for a constructor
    that takes ``**kwargs``."""
    if opponent not in OPPONENTS:
        return []
    parameters = inspect.signature(OPPONENTS[opponent].__init__).parameters.values()
    if any(p.kind == p.VAR_KEYWORD for p in parameters):
        return None
    return [p.name for p in parameters if p.name not in OPPONENT_PLACES and p.kind != p.VAR_POSITIONAL]
