"""Which pairings a cross-play matrix can play, in which world: the evaluation world of the rows, the checks before
any cell, and whether a row met a partner in training (from its training World)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sidewalk.config import protocol_env_params
from sidewalk.crossplay.players import (
    Column,
    CrossplayError,
    Player,
)
from sidewalk.envs import core_class
from sidewalk.partners.policy import (
    PartnerMismatch,
    check_partner,
)
from sidewalk.schema import NOMINAL_PROTOCOL
from sidewalk.world import World


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
    others = [agent for agent in range(n_agents(row.partner.world.domain, world)) if agent != row.agent]
    try:
        check_partner(column.player.path, World(row.partner.world.domain, world, ego=row.agent), controlled=others)
    except PartnerMismatch as error:
        return str(error)
    return ""


def n_agents(domain: str, world: Any) -> int:
    """The number of agents of ``domain``'s worlds with env parameters ``world``."""
    return core_class(domain).layout_for(world).n_agents
