"""Cross-play: every learned policy (a row) playing with every partner (a column) on the same seeded worlds.

``crossplay(rows, partners, ...)`` evaluates each pairing and returns the long table (one row per pairing) that
``runners/crossplay.py`` writes as ``crossplay.csv`` and ``sidewalk.report.crossplay`` draws; the coordination
literature's zero-shot test (Other-Play): does a policy still succeed with a partner it never trained with?

The pairing:

- a row is a run folder (its ``policy.pt``, or the ``checkpoint.pt`` of a run from before ``policy.pt``); it plays the agent it trained as: its ego for a single-agent
  learner, agent 0 for a centralized or self-play learner (both were trained as every agent);
- a column is a scripted opponent of the domain (``random``, ``dijkstra``/``prm``) or a learned partner (a run
  folder, ``sidewalk.partners.policy.PolicyOpponent``); it plays every other agent. By default the columns are
  the domain's scripted opponents and every row, so the matrix holds each run with itself (self-pairs), with the
  other seeds of its condition (cross-seed pairs) and with the other conditions. ``heldout`` adds the domain's
  held-out partner population (``sidewalk.partners.population``), whose team success per condition is the ad-hoc
  score (``sidewalk.report.crossplay.adhoc_table``): partners no learner met in training;
- both sides act greedily (the evaluation policy: greedy Q, the distribution's mode), as in the runs' own
  evaluations;
- every cell plays one episode in each of ``episodes`` worlds of the core env seeded ``seed + EVAL_SEED_OFFSET``
  (the stream a run of seed ``seed`` is evaluated on, so a run paired with its own training opponent, at the same
  seed, episodes and noise, reproduces its ``summary.json``); the world is the first row's training world (its
  domain, scenario, rewards and time limit) at the noise given, by default the rows' training noise when they all
  agree; with ``nominal``, from the scenario's own starts and goals (the paper's evaluation, ``eval=nominal``) even for
  rows trained under ``eval=perturbed``.

Checks before any evaluation: every row and learned partner has a ``policy.pt`` and shares the first row's domain,
scenario and observation (``check_partner``; noise, rewards, time limit may differ), every partner name is a
scripted opponent of that domain. A learned partner that cannot play the other agent's role (a single-agent
learner in a layout without the half-turn symmetry that maps its role onto the other's) leaves that cell empty
with the reason in the ``skipped`` column rather than stopping the matrix.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase

from sidewalk._checks import check_keys
from sidewalk.config import protocol_env_params
from sidewalk.envs import core_class
from sidewalk.evaluate import distinct_rows, evaluate, run_episodes
from sidewalk.experiment import EVAL_SEED_OFFSET
from sidewalk.opponents.base import ACTION_KEY, Opponent
from sidewalk.partners.policy import (
    OBSERVATION_KEY,
    Partner,
    PartnerMismatch,
    PolicyOpponent,
    check_partner,
    read_partner,
)
from sidewalk.schema import NOMINAL_PROTOCOL
from sidewalk.world import World

SCRIPTED = "scripted"  # --partners shorthand: the domain's scripted opponents
ROWS = "rows"  # --partners shorthand: every row's run folder
HELDOUT = "heldout"  # --partners shorthand: the held-out partner population of the rows' domain (ad-hoc teamwork)
DEFAULT_PARTNERS = (SCRIPTED, ROWS)
# The CSV's columns, in order (see ``crossplay``'s docstring).
COLUMNS = (
    "row_run",
    "row_label",
    "row_seed",
    "row_agent",
    "partner",
    "partner_label",
    "partner_kind",
    "partner_seed",
    "self_pair",
    "same_condition",
    "success",
    "partner_success",
    "collision_rate",
    "partner_collision_rate",
    "team_success",
    "return",
    "path_efficiency",
    "partner_path_efficiency",
    "episodes",
    "distinct_episodes",
    "skipped",
    "heldout",
    "met_in_training",
)
METRICS = {  # CSV column -> key of sidewalk.evaluate's metrics in the row's ego view
    "success": "ego/success_rate",
    "partner_success": "other/success_rate",
    "collision_rate": "ego/collision_rate",
    "partner_collision_rate": "other/collision_rate",
    "team_success": "team/success_rate",
    "return": "ego/return",
    "path_efficiency": "ego/path_efficiency",  # straight-line distance over the path walked, arrived episodes only
    "partner_path_efficiency": "other/path_efficiency",
    "episodes": "episodes",
    "distinct_episodes": "distinct_episodes",  # how many different episodes the cell's worlds played
}


class CrossplayError(ValueError):
    """A cross-play matrix that cannot be evaluated (the message names the run or partner and why)."""


@dataclass
class Player:
    """A learned policy of the matrix: a row, a partner, or both."""

    path: Path  # the run folder, as given
    partner: Partner  # what its policy.pt says (sidewalk.partners.policy.read_partner)
    seed: int | None  # the run's seed (config.yaml), None when the folder does not say
    condition: str  # its config without the seed and bookkeeping keys, and its folder, as JSON: seeds share it
    label: str = ""  # the condition's label: "dqn vs dijkstra", plus what sets it apart from same-named ones

    @property
    def agent(self) -> int:
        """The agent it plays as a row: the one it trained as (agent 0 for a learner of every agent)."""
        return 0 if self.partner.ego is None else self.partner.ego


@dataclass
class Column:
    """A partner: a scripted opponent (``player`` None) or a learned policy."""

    name: str  # the opponent's name, or the run folder as given; a held-out member: "heldout:<member>"
    player: Player | None = None
    opponent: str = ""  # a scripted partner's registered opponent, when ``name`` is not one
    params: dict[str, Any] = field(default_factory=dict)  # ... and its settings
    heldout: bool = False  # a member of the held-out population

    @property
    def kind(self) -> str:
        return "scripted" if self.player is None else "learned"

    @property
    def label(self) -> str:
        if self.heldout:
            return self.name.split(":", 1)[1]
        return self.name if self.player is None else self.player.label


def find_runs(paths: Sequence[str | Path]) -> list[Path]:
    """The run folders named by ``paths``: a folder with a ``policy.pt`` (or, from before runs wrote one, a
    ``checkpoint.pt``) is one; a folder holding run folders (a sweep) stands for those, in sorted order. Raises
    ``CrossplayError`` naming a path that is missing, a run folder without a policy (a run that failed or has not
    reached its first checkpoint) or a folder with no run."""
    from sidewalk.report.runs import POLICY_FILES, find_run_folders
    from sidewalk.run_folder import policy_file

    found: list[Path] = []
    for path in map(Path, paths):
        if not path.is_dir():
            raise CrossplayError(f"{path} is not a folder; give run folders (with {POLICY_FILES}) or sweep folders")
        if policy_file(path) is not None:
            found.append(path)
            continue
        folders = find_run_folders([path])
        if not folders:
            raise CrossplayError(
                f"{path} is neither a run folder (with {POLICY_FILES}) nor a folder holding run folders"
            )
        for folder in folders:
            if policy_file(folder) is None:
                raise CrossplayError(
                    f"{folder} has no {POLICY_FILES}: the run failed or has not reached its first checkpoint; "
                    "leave it out or let it finish"
                )
            found.append(folder)
    unique: list[Path] = []
    for path in found:  # a run named twice (itself and its sweep) is one row
        if all(path.resolve() != seen.resolve() for seen in unique):
            unique.append(path)
    return unique


def load_player(path: str | Path) -> Player:
    """The learned policy in the run folder ``path`` (see ``find_runs``), its seed and condition."""
    from omegaconf import OmegaConf

    from sidewalk.report.conditions import condition_config
    from sidewalk.run_folder import CONFIG, flatten

    path = Path(path)
    try:
        partner = read_partner(path)
    except FileNotFoundError as error:
        raise CrossplayError(f"{path}: {error}") from error
    seed, flat = None, None
    if (path / CONFIG).exists():
        config = OmegaConf.to_container(OmegaConf.load(path / CONFIG), resolve=True)
        seed = int(config["seed"]) if "seed" in config else None
        flat = condition_config(flatten(config))
    if flat is None:  # policy.pt alone: its own description of the learner and its world
        flat = {"algo": dataclasses.asdict(partner.algo_config), "env": dataclasses.asdict(partner.world.env_params),
                "opponent": partner.world.opponent, "ego": partner.ego}
    # Runs of one config from different folders are different conditions (two sweeps, two machines): the folder
    # that holds a run is part of its condition, so their rows stay apart and their labels name the folders.
    flat = {**flat, "folder": str(path.parent)}
    return Player(path, partner, seed, json.dumps(sorted(flat.items()), default=str))


def learner_name(partner: Partner) -> str:
    """"dqn vs dijkstra", "dqn centralized", "iql self-play" (``Partner.label``)."""
    return partner.label

def label_players(players: Sequence[Player]) -> None:
    """Label each player by its learner (``learner_name``: "dqn vs dijkstra", "iql self-play"), plus the config
    values that tell apart conditions sharing that name (``noise=0.1``)."""
    conditions: dict[str, dict[str, Any]] = {}
    for player in players:
        conditions.setdefault(player.condition, dict(json.loads(player.condition)))
    by_name: dict[str, list[str]] = {}
    for player in players:
        names = by_name.setdefault(learner_name(player.partner), [])
        if player.condition not in names:
            names.append(player.condition)
    labels: dict[str, str] = {}
    for name, keys in by_name.items():
        if len(keys) == 1:
            labels[keys[0]] = name
            continue
        flats = [conditions[key] for key in keys]
        differ = sorted(k for k in set().union(*flats) if len({json.dumps(f.get(k), default=str) for f in flats}) > 1)
        for key, flat in zip(keys, flats):
            shown = ", ".join(f"{k.split('.', 1)[-1] if k.startswith(('env.', 'algo.')) else k}={flat.get(k)}"
                              for k in differ[:3])
            labels[key] = f"{name}, {shown}" + (f", +{len(differ) - 3} more" if len(differ) > 3 else "")
    for player in players:
        player.label = labels[player.condition]


def heldout_columns(domain: str, known: dict[Path, Player]) -> list[Column]:
    """The held-out partner population of ``domain`` (``sidewalk.partners.population``) as columns named
    ``heldout:<member>``; a shipped learned member already in ``known`` shares its ``Player``."""
    from sidewalk.partners.population import population

    return [heldout_column(domain, name, member, known) for name, member in population(domain, "heldout").items()]


def heldout_column(domain: str, name: str, member: Any, known: dict[Path, Player] | None = None) -> Column:
    """Held-out ``member`` (a ``population.Member``) named ``name`` as the column ``heldout:<name>``; a learned one's
    ``Player`` taken from, or added to, ``known``."""
    kwargs = member.kwargs(domain)
    if member.opponent != "policy":
        return Column(f"{HELDOUT}:{name}", opponent=member.opponent, params=kwargs, heldout=True)
    known = {} if known is None else known
    path = Path(kwargs["path"])
    player = known.get(path.resolve()) or load_player(path)
    known[path.resolve()] = player
    return Column(f"{HELDOUT}:{name}", player, heldout=True)


def resolve_partners(spec: str | Sequence[str] | None, rows: Sequence[Player], domain: str) -> list[Column]:
    """The columns of the matrix from ``--partners`` (a comma-separated string or a list; default
    ``scripted,rows``): a scripted opponent's name, ``scripted`` (every scripted opponent of ``domain``), ``rows``
    (every row's run), ``heldout`` (the held-out partner population: the ad-hoc score's partners), a run or sweep
    folder (its learned policies), or a scripted opponent with settings, ``NAME:KEY=VALUE[:KEY=VALUE...]``
    (``dijkstra:tie_break=progress``: the version-1 Dijkstra agent). Rows' folders given again share their
    ``Player``. Raises ``CrossplayError`` for an unknown name or setting, or an opponent of another domain."""
    from sidewalk.opponents.base import available_opponents
    from sidewalk.registry import OPPONENTS

    if spec is None:
        items = list(DEFAULT_PARTNERS)
    elif isinstance(spec, str):
        items = [item.strip() for item in spec.split(",") if item.strip()]
    else:
        items = [str(item) for item in spec]
    if not items:
        raise CrossplayError("--partners is empty; give scripted opponents' names and/or run folders")
    scripted = available_opponents(domain, scripted_only=True)  # a run folder names a learned one
    known = {player.path.resolve(): player for player in rows}
    columns: list[Column] = []

    def add(column: Column) -> None:
        if all(column.name != c.name and (column.player is None or c.player is not column.player) for c in columns):
            columns.append(column)

    for item in items:
        if item == SCRIPTED:
            for name in scripted:
                add(Column(name))
        elif item == ROWS:
            for player in rows:
                add(Column(str(player.path), player))
        elif item == HELDOUT:
            for column in heldout_columns(domain, known):
                add(column)
        elif item in scripted:
            add(Column(item))
        elif ":" in item and item.split(":", 1)[0] in scripted:
            add(_scripted_with_settings(item))
        elif item in OPPONENTS:
            raise CrossplayError(
                f"partner {item!r} does not play the {domain} domain of the rows; "
                f"scripted opponents of the {domain} domain: {', '.join(scripted)}"
            )
        elif Path(item).is_dir():
            for path in find_runs([item]):
                player = known.get(path.resolve()) or load_player(path)
                known[path.resolve()] = player
                add(Column(str(path), player))
        else:
            raise CrossplayError(
                f"unknown partner {item!r}: not a scripted opponent of the {domain} domain "
                f"({', '.join(scripted)}), not {SCRIPTED!r}, {ROWS!r} or {HELDOUT!r}, and not a folder"
            )
    return columns


def _scripted_with_settings(item: str) -> Column:
    """The column of ``NAME:KEY=VALUE[:KEY=VALUE...]``: opponent NAME with those settings (values read as YAML
    scalars, as on Hydra's command line), each key checked against what NAME's constructor takes."""
    import yaml

    from sidewalk.config import opponent_settings

    name, *pairs = item.split(":")
    params = {}
    for pair in pairs:
        key, equals, value = pair.partition("=")
        if not equals or not key:
            raise CrossplayError(f"partner {item!r}: {pair!r} is not KEY=VALUE (give NAME:KEY=VALUE[:KEY=VALUE...])")
        params[key] = yaml.safe_load(value)
    settings = opponent_settings(name)
    if settings is not None:
        check_keys(f"partner {item!r}", params, settings, kind="setting", error=CrossplayError)
    return Column(item, opponent=name, params=params)


def check_scripted_settings(columns: Sequence[Column], domain: str, world: Any) -> None:
    """Every scripted partner given settings is built once on a one-world core of ``world``, so that a bad value
    stops the matrix with ``CrossplayError`` naming it before any cell is played."""
    for column in columns:
        if column.player is None and column.params and not column.heldout:
            try:
                World(domain, world, column.opponent, column.params).make(1)
            except (ValueError, TypeError) as error:
                raise CrossplayError(f"partner {column.name!r}: {error}") from error


def evaluation_world(rows: Sequence[Player], noise: float | None, nominal: bool = False) -> Any:
    """The env parameters every cell is played in: the first row's training world, at ``noise`` (default: the
    rows' training noise, which must then agree); ``nominal``: from the scenario's own starts and goals, the paper's
    evaluation (``eval=nominal``), whatever protocol the rows trained under."""
    if not rows:
        raise CrossplayError("give at least one run folder (a row)")
    if noise is None:
        noises = sorted({float(player.partner.world.env_params.noise) for player in rows})
        if len(noises) > 1:
            raise CrossplayError(
                f"the rows were trained at different noise levels ({', '.join(f'{n:g}' for n in noises)}): "
                "give --noise to evaluate every cell at one"
            )
        noise = noises[0]
    world = dataclasses.replace(rows[0].partner.world.env_params, noise=float(noise))
    if nominal:
        world = protocol_env_params(NOMINAL_PROTOCOL, rows[0].partner.world.domain, world)
    return world


def check_players(players: Sequence[Player], world: Any, reference: Player) -> None:
    """Every learned policy plays in ``world`` (the first row's domain, scenario and observation), else
    ``CrossplayError`` naming the run, before anything is evaluated."""
    domain = reference.partner.world.domain
    for player in players:
        try:
            check_partner(player.path, World(domain, world), controlled=[])
        except PartnerMismatch as error:
            raise CrossplayError(
                f"{player.path} cannot be paired with {reference.path} (the first row, whose world every cell is "
                f"played in): {error}"
            ) from error


def met_in_training(row: Player, column: Column) -> bool:
    """Whether ``row`` trained beside ``column``'s partner, as its training World says: the same scripted opponent
    with the same settings (its defaults but where either says otherwise, ``opponent_config``; a version of an
    opponent, such as the Dijkstra agent's tie-break, is a setting), the same learned policy (``opponent=policy``),
    or a member of the training population it drew from (``opponent=population``). Such a partner is not new to
    the row: the ad-hoc score leaves its cells out."""
    from sidewalk.opponents.base import opponent_config

    trained = row.partner.world
    if column.player is not None:
        path = trained.opponent_params.get("path") if trained.opponent == "policy" else None
        return path is not None and Path(path).resolve() == column.player.path.resolve()
    if trained.opponent == "population":
        from sidewalk.partners.population import population

        table = population(trained.domain, "training")
        met = [table[name] for name in trained.opponent_params.get("members") or table]
        partners = [(member.opponent, member.params) for member in met]
    else:
        partners = [(trained.opponent, trained.opponent_params)]
    name = column.opponent or column.name
    return any(opponent == name and opponent_config(opponent, params) == opponent_config(name, column.params)
               for opponent, params in partners)


def cell_problem(row: Player, column: Column, world: Any) -> str:
    """Why ``column`` cannot play every agent but ``row``'s in ``world`` ("" when it can)."""
    if column.player is None:
        return ""
    others = [agent for agent in range(_n_agents(row.partner.world.domain, world)) if agent != row.agent]
    try:
        check_partner(column.player.path, World(row.partner.world.domain, world, ego=row.agent), controlled=others)
    except PartnerMismatch as error:
        return str(error)
    return ""


def _n_agents(domain: str, world: Any) -> int:
    return core_class(domain).layout_for(world).n_agents


class DistinctPlayer(Opponent):
    """A learned player (a greedy ``PolicyOpponent``) run once per distinct observation of the worlds, as
    ``sidewalk.evaluate.act_on_distinct`` runs a policy: its actions are a function of every agent's observation in
    that world alone, so worlds that look alike get the same actions. At noise 0 two deterministic players (or one
    and the Dijkstra agent) play the same episode in every world, so a cell costs one world's networks, not 256."""

    def __init__(self, player: PolicyOpponent) -> None:
        if player.sample:
            raise ValueError("a sampling player acts differently in worlds that look alike: run it on every world")
        super().__init__(player.env, controlled=player.controlled, ego=player.ego)
        self.player = player
        self.in_keys = list(player.in_keys)  # the observation, or what the env computes a partner's own one from
        self._zero_action = player.env.full_action_spec[ACTION_KEY].zero()

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        inputs = tensordict.select(*self.in_keys)
        batch = inputs.batch_size[0]
        first_of, inverse = distinct_rows(
            torch.cat([inputs.get(key).reshape(batch, -1).to(torch.float64) for key in self.in_keys], dim=-1))
        seen = TensorDict({key: inputs.get(key)[first_of] for key in self.in_keys}, batch_size=[first_of.numel()])
        seen.set(ACTION_KEY, self._zero_action[first_of])  # the player fills in its agents' columns of a joint action
        acted = self.player(seen).get(ACTION_KEY)[inverse]  # (B, N, ...): the controlled agents' columns set
        joint = tensordict.get(ACTION_KEY, None)
        joint = acted if joint is None else joint.clone()
        joint.index_copy_(1, self._controlled_index, acted.index_select(1, self._controlled_index).to(joint.dtype))
        tensordict.set(ACTION_KEY, joint)
        return tensordict


class LearnedAgent(TensorDictModuleBase):
    """A learned policy acting for the ego of an ``EgoView``: its player (controlling the ego alone) reads every
    agent's observation from the view's last core output, which a centralized or self-play learner needs, and the
    ego's share of its action is the view's action.

    It acts on all worlds at once: evaluate it with ``deterministic=False`` (``act_on_distinct`` would hand it a
    subset of worlds that the view's output does not match); it is greedy all the same.
    """

    def __init__(self, view: Any, player: Opponent) -> None:
        super().__init__()
        if list(player.controlled) != [view.ego]:
            raise ValueError(f"the player controls agents {player.controlled}; the view's ego is {view.ego}")
        self.player = player
        self._view = [view]  # a list: the view is not a submodule of its own policy
        self.in_keys = ["observation"]
        self.out_keys = ["action"]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = self._view[0]._last.get(OBSERVATION_KEY)
        joint = self.player(TensorDict({OBSERVATION_KEY: observation}, batch_size=observation.shape[:1]))
        tensordict.set("action", joint.get(ACTION_KEY).select(1, self._view[0].ego))
        return tensordict


CONVENTION_COLUMNS = ("row_run", "row_label", "row_seed", "passing_side", "passing_fraction", "yielder", "episodes")


def convention(trajectories: np.ndarray, domain: str, layout: Any) -> dict[str, Any]:
    """The convention two agents followed on the two-agent sidewalk, from positions (T, k, 2, 2) of k episodes (NaN
    once an agent finished; grid (row, col), continuous (x, y)); agent 0 walks along +col / +x, agent 1 the other way.

    - ``passing_side``: at the first step where the agents' along-the-sidewalk coordinates cross, "left" if agent 0
      is on its own left of agent 1 (grid: a smaller row; continuous: a larger y) -- by the half turn agent 1 is then
      on its own left too: both keep left -- "right" the other way; the majority over the episodes that crossed with
      a lateral gap ("none" if none did, crashes and standoffs among them), ``passing_fraction`` its share of all k;
    - ``yielder``: in the episodes that crossed, the agent whose largest distance from the centre line was larger by
      a clear margin (a cell; 0.1 m), in most of them: "agent 0", "agent 1", or "both" (they swerved alike).
    """
    along, lateral, left = (1, 0, -1.0) if domain == "discrete" else (0, 1, 1.0)
    centre, margin = (layout.center_row, 1.0) if domain == "discrete" else (layout.width_m / 2, 0.1)
    episodes = trajectories.shape[1]
    with np.errstate(invalid="ignore"):
        crossed = trajectories[:, :, 0, along] >= trajectories[:, :, 1, along]  # NaN (finished) compares False
        first = crossed.argmax(0)
        gap = left * (trajectories[first, np.arange(episodes), 0, lateral] - trajectories[first, np.arange(episodes), 1, lateral])
        deviation = np.nanmax(np.abs(trajectories[..., lateral] - centre), axis=0)  # (k, 2)
    passed = crossed.any(0) & (gap != 0)
    sides = np.where(gap > 0, "left", "right")[passed]
    if not passed.any():
        return {"passing_side": "none", "passing_fraction": 0.0, "yielder": "none", "episodes": episodes}
    side = max(("left", "right"), key=lambda s: int((sides == s).sum()))
    swerve = deviation[passed, 0] - deviation[passed, 1]
    yielders = np.where(swerve >= margin, "agent 0", np.where(swerve <= -margin, "agent 1", "both"))
    names, counts = np.unique(yielders, return_counts=True)
    return {
        "passing_side": side,
        "passing_fraction": float((sides == side).sum() / episodes),
        "yielder": str(names[counts.argmax()]),
        "episodes": episodes,
    }


class Arena:
    """The evaluation worlds of a matrix: one core env of ``episodes`` worlds per agent a row plays, and each
    learned player built once on it (a row for its agent, a partner for every other agent), so a matrix rebuilds
    no network per cell. Every evaluation reseeds and resets the whole core, so a cell's worlds do not depend on
    the cells before it."""

    def __init__(self, domain: str, world: Any, episodes: int, seed: int, device: str = "cpu") -> None:
        self.domain, self.world, self.episodes, self.device = domain, world, episodes, device
        self.world_seed = seed + EVAL_SEED_OFFSET
        self._cores: dict[int, Any] = {}
        self._players: dict[tuple[str, int, bool], DistinctPlayer] = {}

    def core(self, ego: int):
        if ego not in self._cores:
            self._cores[ego] = core_class(self.domain)(
                self.episodes, device=self.device, seed=self.world_seed, params=self.world
            )
        return self._cores[ego]

    def _player(self, player: Player, ego: int, as_row: bool) -> DistinctPlayer:
        key = (str(player.path.resolve()), ego, as_row)
        if key not in self._players:
            core = self.core(ego)
            controlled = (ego,) if as_row else tuple(a for a in range(core.n_agents) if a != ego)
            self._players[key] = DistinctPlayer(
                PolicyOpponent(core, controlled=controlled, ego=None if as_row else ego, path=player.path)
            )
        return self._players[key]

    def evaluate(self, row: Player, column: Column) -> dict[str, float]:
        """Metrics (``sidewalk.evaluate``'s keys, the row's agent as ego) of ``row`` with ``column`` playing every
        other agent."""
        from sidewalk.views import view_for_opponent

        ego = row.agent
        if column.player is None:  # a scripted partner: a registered opponent's name, with its settings
            partner = column.opponent or column.name
        else:
            partner = self._player(column.player, ego, as_row=False)
        view = view_for_opponent(self.core(ego), partner, ego, opponent_kwargs=column.params)
        policy = LearnedAgent(view, self._player(row, ego, as_row=True))
        return evaluate(view, policy, seed=self.world_seed, deterministic=False)

    def convention(self, row: Player) -> dict[str, Any]:
        """The convention (``convention``) of ``row``'s policy playing every agent of the two-agent sidewalk, on the
        matrix's worlds; "n/a" for other layouts."""
        from sidewalk.views import EgoView

        core = self.core(row.agent)
        if self.world.layout != "sidewalk" or core.n_agents != 2:
            return {"passing_side": "n/a", "passing_fraction": float("nan"), "yielder": "n/a", "episodes": 0}
        view = EgoView(core, self._player(row, row.agent, as_row=False), ego=row.agent)
        policy = LearnedAgent(view, self._player(row, row.agent, as_row=True))
        record = run_episodes(view, policy, seed=self.world_seed, record_trajectories=self.episodes, deterministic=False)
        return convention(record.trajectories, self.domain, core.layout)


def evaluate_cell(
    row: Player, column: Column, world: Any, episodes: int, seed: int, device: str = "cpu"
) -> dict[str, float]:
    """One cell alone (``Arena.evaluate``): ``row`` with ``column`` playing every other agent, one episode in each
    of ``episodes`` worlds seeded ``seed + EVAL_SEED_OFFSET``."""
    return Arena(row.partner.world.domain, world, episodes, seed, device).evaluate(row, column)


def crossplay(
    rows: Sequence[Player],
    columns: Sequence[Column],
    world: Any,
    episodes: int = 256,
    seed: int = 0,
    device: str = "cpu",
    progress: Callable[[int], Any] | None = None,
) -> pd.DataFrame:
    """The long table of the matrix (``COLUMNS``, one row per (row, column), rows in order, then columns):

    ``row_run``/``partner`` the run folders as given (a scripted partner by name), ``*_label`` their conditions'
    labels, ``*_seed`` their seeds, ``row_agent`` the agent the row played, ``partner_kind`` scripted/learned,
    ``self_pair`` (a run with itself), ``same_condition`` (two seeds of one condition, or a self-pair);
    ``success``/``collision_rate``/``return``/``path_efficiency`` of the row's agent,
    ``partner_success``/``partner_collision_rate``/``partner_path_efficiency`` over the partner's agents,
    ``team_success`` (every agent arrived), ``episodes``; ``skipped`` the reason a cell was not played (its metrics
    empty). ``progress(1)`` is called after each cell.

    Call ``check_players`` first (``run_crossplay`` does).
    """
    records = []
    arena = Arena(rows[0].partner.world.domain, world, episodes, seed, device) if rows else None
    for row in rows:
        for column in columns:
            partner = column.player
            record = {
                "row_run": str(row.path),
                "row_label": row.label,
                "row_seed": row.seed,
                "row_agent": row.agent,
                "partner": column.name,
                "partner_label": column.label,
                "partner_kind": column.kind,
                "partner_seed": None if partner is None else partner.seed,
                "self_pair": partner is not None and partner.path.resolve() == row.path.resolve(),
                "same_condition": partner is not None and partner.condition == row.condition,
                "skipped": cell_problem(row, column, world),
                "heldout": column.heldout,
                "met_in_training": met_in_training(row, column),
            }
            if not record["skipped"]:
                metrics = arena.evaluate(row, column)
                record.update({name: metrics[key] for name, key in METRICS.items()})
            records.append(record)
            if progress is not None:
                progress(1)
    frame = pd.DataFrame(records, columns=list(COLUMNS))
    for column in ("episodes", "distinct_episodes"):
        frame[column] = frame[column].astype("Int64")
    for column in ("row_seed", "partner_seed"):
        frame[column] = frame[column].astype("Int64")
    return frame


@dataclass
class Matrix:
    """A cross-play matrix evaluated: its table, how it was made (``crossplay.json``) and the convention each row's
    policy follows with itself (``CONVENTION_COLUMNS``, ``conventions.csv``)."""

    frame: pd.DataFrame
    meta: dict[str, Any]
    conventions: pd.DataFrame | None = None


def run_crossplay(
    run_paths: Sequence[str | Path],
    partners: str | Sequence[str] | None = None,
    episodes: int = 256,
    seed: int = 0,
    noise: float | None = None,
    device: str = "cpu",
    show_progress: bool = True,
    nominal: bool = False,
) -> Matrix:
    """Resolve the rows (``find_runs``) and partners (``resolve_partners``), check every pairing can be played
    (``check_players``) and evaluate the matrix (``crossplay``), with a tqdm bar over the cells."""
    from tqdm import tqdm

    if episodes < 1:
        raise CrossplayError(f"episodes={episodes} must be at least 1")
    rows = [load_player(path) for path in find_runs(run_paths)]
    if not rows:
        raise CrossplayError("give at least one run folder (a row)")
    domain = rows[0].partner.world.domain
    columns = resolve_partners(partners, rows, domain)
    world = evaluation_world(rows, noise, nominal)
    if any(column.heldout for column in columns) and (world.layout != "sidewalk" or _n_agents(domain, world) != 2):
        raise CrossplayError(
            f"--partners {HELDOUT} holds the two-agent sidewalk's partners; the rows play env.layout={world.layout!r} "
            f"with {_n_agents(domain, world)} agents"
        )
    learned = list(rows) + [c.player for c in columns if c.player is not None and all(c.player is not r for r in rows)]
    label_players(learned)
    check_players(learned, world, rows[0])
    check_scripted_settings(columns, domain, world)
    with tqdm(total=len(rows) * len(columns), desc="cross-play", unit="cell", disable=not show_progress) as bar:
        frame = crossplay(rows, columns, world, episodes, seed, device, progress=bar.update)
    arena = Arena(domain, world, episodes, seed, device)
    conventions = pd.DataFrame(
        [{"row_run": str(row.path), "row_label": row.label, "row_seed": row.seed, **arena.convention(row)} for row in rows],
        columns=list(CONVENTION_COLUMNS),
    )
    meta = {
        "domain": domain,
        "layout": world.layout,
        "noise": world.noise,
        # The starts, goals and headings each world draws (eval=perturbed's bounds where the rows trained under it).
        "jitter": {f.name: getattr(world, f.name) for f in dataclasses.fields(world) if "jitter" in f.name},
        "episodes": episodes,
        "seed": seed,
        "world_seed": seed + EVAL_SEED_OFFSET,
        "world_of": str(rows[0].path),
        "rows": [str(row.path) for row in rows],
        "partners": [column.name for column in columns],
    }
    return Matrix(frame, meta, conventions)


def write_matrix(matrix: Matrix, out: str | Path, command: str, wall_clock_s: float) -> Path:
    """``matrix``'s CSVs and ``crossplay.json`` (with ``command``, the time, the code and package versions) written
    into ``out``, each file atomically, then its report; returns the report's path."""
    from sidewalk.report.crossplay import (
        CONVENTIONS_CSV,
        CROSSPLAY_CSV,
        CROSSPLAY_JSON,
        write_crossplay_report,
    )
    from sidewalk.run_folder import atomic_write, git_revision, package_versions

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "command": command,
        "created": datetime.datetime.now().isoformat(timespec="seconds"),
        **matrix.meta,
        "wall_clock_s": round(wall_clock_s, 1),
        "git_revision": git_revision(),
        "versions": package_versions(),
    }
    atomic_write(out / CROSSPLAY_CSV, lambda tmp: matrix.frame.to_csv(tmp, index=False))
    atomic_write(out / CONVENTIONS_CSV, lambda tmp: matrix.conventions.to_csv(tmp, index=False))
    atomic_write(out / CROSSPLAY_JSON, lambda tmp: tmp.write_text(json.dumps(meta, indent=2) + "\n"))
    return write_crossplay_report(out)
