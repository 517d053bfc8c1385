"""The rows and columns of a cross-play matrix: run folders read as players (their policy, seed and condition),
the ``--partners`` shorthands resolved into columns, and the labels that tell conditions apart."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sidewalk._checks import check_keys
from sidewalk.partners.policy import (
    Partner,
    read_partner,
)

SCRIPTED = "scripted"  # --partners shorthand: the domain's scripted opponents
ROWS = "rows"  # --partners shorthand: every row's run folder
HELDOUT = "heldout"  # --partners shorthand: the held-out partner population of the rows' domain (ad-hoc teamwork)
ZOO = "zoo"  # --partners zoo:NAME: a partner of the zoo by name (sidewalk.partners.zoo)
DEFAULT_PARTNERS = (SCRIPTED, ROWS)
# The CSV's columns, in order (see ``crossplay``'s docstring).


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

    name: str  # the opponent's name, or the run folder as given; "heldout:<member>" a held-out member, "zoo:<name>"
    player: Player | None = None
    opponent: str = ""  # a scripted partner's registered opponent, when ``name`` is not one
    params: dict[str, Any] = field(default_factory=dict)  # ... and its settings
    heldout: bool = False  # a member of the held-out population

    @property
    def kind(self) -> str:
        return "scripted" if self.player is None else "learned"

    @property
    def label(self) -> str:
        if self.heldout or self.name.startswith(f"{ZOO}:"):  # a partner named by its population or zoo name
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


def label_players(players: Sequence[Player]) -> None:
    """Label each player by its learner (``Partner.label``: "dqn vs dijkstra", "iql self-play"), plus the config
    values that tell apart conditions sharing that name (``noise=0.1``)."""
    conditions: dict[str, dict[str, Any]] = {}
    for player in players:
        conditions.setdefault(player.condition, dict(json.loads(player.condition)))
    by_name: dict[str, list[str]] = {}
    for player in players:
        names = by_name.setdefault(player.partner.label, [])
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
    return member_column(f"{HELDOUT}:{name}", domain, member, known, heldout=True)


def zoo_column(domain: str, name: str, known: dict[Path, Player] | None = None) -> Column:
    """The zoo partner ``name`` (``sidewalk.partners.zoo``) as the column ``zoo:<name>``; ``CrossplayError`` naming
    the domain's zoo partners for a name that is not one of them."""
    from sidewalk.partners.zoo import partner

    try:
        entry = partner(name, domain, what=f"partner {ZOO}:NAME")
    except ValueError as error:
        raise CrossplayError(str(error)) from None
    return member_column(f"{ZOO}:{entry.name}", domain, entry.member, known)


def member_column(column_name: str, domain: str, member: Any, known: dict[Path, Player] | None = None,
                  heldout: bool = False) -> Column:
    """A population ``member`` as the column ``column_name``: a scripted one its opponent and settings, a learned
    one's ``Player`` taken from, or added to, ``known``."""
    kwargs = member.kwargs(domain)
    if member.opponent != "policy":
        return Column(column_name, opponent=member.opponent, params=kwargs, heldout=heldout)
    known = {} if known is None else known
    path = Path(kwargs["path"])
    player = known.get(path.resolve()) or load_player(path)
    known[path.resolve()] = player
    return Column(column_name, player, heldout=heldout)


def resolve_partners(spec: str | Sequence[str] | None, rows: Sequence[Player], domain: str) -> list[Column]:
    """The columns of the matrix from ``--partners`` (a comma-separated string or a list; default
    ``scripted,rows``): a scripted opponent's name, ``scripted`` (every scripted opponent of ``domain``), ``rows``
    (every row's run), ``heldout`` (the held-out partner population: the ad-hoc score's partners), ``zoo:NAME`` (a
    partner of the zoo, ``sidewalk.partners.zoo``), a run or sweep folder (its learned policies), or a scripted
    opponent with settings, ``NAME:KEY=VALUE[:KEY=VALUE...]`` (``dijkstra:tie_break=progress``: the version-1
    Dijkstra agent). Rows' folders given again share their ``Player``. Raises ``CrossplayError`` for an unknown name or setting, or an opponent of another domain."""
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
        elif item.startswith(f"{ZOO}:"):
            add(zoo_column(domain, item.split(":", 1)[1], known))
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
                f"({', '.join(scripted)}), not {SCRIPTED!r}, {ROWS!r}, {HELDOUT!r} or {ZOO}:NAME, and not a folder"
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
