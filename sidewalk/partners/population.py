"""A population of partners, one drawn per world at each of its resets: training for ad-hoc teamwork
(``opponent=population``), and the held-out partners no learner meets in training (``sidewalk-crossplay --partners
heldout``, docs/guide/adhoc.md).

``POPULATIONS`` is the one table of both: per domain, a *training* and a *held-out* population, disjoint by
member. The held-out one holds the domain's planner, the five conventions at their defaults
(``sidewalk.opponents.convention``), the salsa walker (``sidewalk.opponents.salsa``) and three self-play seeds of
MAPPO (continuous) or VDN (grid); the training one holds the planner and the conventions at other settings and three
self-play seeds of IPPO (continuous) or IQL (grid). Learned
members are policy files shipped in the package (``sidewalk/partners/<domain>/<member>/policy.pt``, read as weights
only, like any ``policy.pt``), so no one trains to use them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

from sidewalk._checks import check_choice
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.opponents.base import ACTION_KEY, Opponent, env_domain, make_opponent

PARTNERS_DIR = Path(__file__).resolve().parent  # the shipped learned partners: this package's domain folders
SPLITS = ("training", "heldout")


@dataclass(frozen=True)
class Member:
    """A partner of a population: the opponent registered as ``opponent`` built with ``params``; a learned one
    (``opponent="policy"``) names its shipped folder in ``params["partner"]``."""

    opponent: str
    params: dict[str, Any] = field(default_factory=dict)

    def kwargs(self, domain: str) -> dict[str, Any]:
        """The opponent's keyword arguments; a shipped partner's folder resolved."""
        if self.opponent != "policy":
            return dict(self.params)
        return {"path": str(PARTNERS_DIR / domain / self.params["partner"])}


def _convention(style: str, **params: Any) -> Member:
    return Member("convention", {"style": style, **params})


def _learned(partner: str) -> Member:
    return Member("policy", {"partner": partner})


_HELDOUT_CONVENTIONS = {
    style: _convention(style)
    for style in ("keep_left", "keep_right", "always_yields", "never_yields", "hesitates")
}
# Training conventions: the same five habits at other settings (a nearer lane, a later yield, an offset line,
# shorter and more frequent pauses), so the held-out ones are new partners, not replays.
_TRAINING_CONVENTIONS = {
    "keep_left_wide": _convention("keep_left", lane_fraction=0.85),
    "keep_right_wide": _convention("keep_right", lane_fraction=0.85),
    "always_yields_late": _convention("always_yields", yield_fraction=0.35),
    "never_yields_offset": _convention("never_yields", lane_fraction=0.2),
    "hesitates_often": _convention("hesitates", hesitate_prob=0.2, hesitate_steps=3),
}
POPULATIONS: dict[str, dict[str, dict[str, Member]]] = {
    "continuous": {
        "training": {
            "prm_roadmap1": Member("prm", {"roadmap_seed": 1, "avoid_weight": 2.0}),
            **_TRAINING_CONVENTIONS,
            **{f"ippo_seed{seed}": _learned(f"ippo_seed{seed}") for seed in range(3)},
        },
        "heldout": {
            "prm": Member("prm"),
            **_HELDOUT_CONVENTIONS,
            "salsa": Member("salsa"),
            **{f"mappo_seed{seed}": _learned(f"mappo_seed{seed}") for seed in range(3)},
        },
    },
    "discrete": {
        "training": {
            # The planners of the populations keep fixed tie-breaks (version 1): a member is one style of play.
            "dijkstra_near": Member("dijkstra", {"avoid_radius_cells": 1, "avoid_cost": 5.0, "tie_break": "progress"}),
            **_TRAINING_CONVENTIONS,
            # Self-play policies on vector observations (small MLPs), playing in image worlds too (PolicyOpponent).
            **{f"iql_seed{seed}": _learned(f"iql_seed{seed}") for seed in range(3)},
        },
        "heldout": {
            "dijkstra": Member("dijkstra", {"tie_break": "progress"}), **_HELDOUT_CONVENTIONS, "salsa": Member("salsa"),
            # VDN's seed 2 never passed itself (team success 0.0 at 480 iterations): seed 3 stands in for it.
            **{f"vdn_seed{seed}": _learned(f"vdn_seed{seed}") for seed in (0, 1, 3)},
        },
    },
}


def population(domain: str, split: str) -> dict[str, Member]:
    """The members of ``domain``'s ``split`` population (``"training"`` or ``"heldout"``), by name."""
    check_choice("domain", domain, POPULATIONS)
    check_choice("split", split, SPLITS)
    return dict(POPULATIONS[domain][split])


def check_two_agent_sidewalk(env: SidewalkEnvBase | Any, what: str) -> None:
    """Populations are the two-agent sidewalk's partners: raise naming the layout otherwise."""
    params = env.params
    if params.layout != "sidewalk" or env.n_agents != 2:
        raise ValueError(
            f"{what} plays the two-agent sidewalk (env.layout='sidewalk', env.n_agents=2), not "
            f"env.layout={params.layout!r} with {env.n_agents} agents"
        )


class PopulationOpponent(Opponent):
    """A partner drawn per world from the *training* population of the env's domain (``POPULATIONS``), anew at
    each reset of that world, from the env's generator (one seed, one sequence of partners).

    Every member acts for every world each step, and each world takes its own member's actions: a loop over the
    handful of members, none over worlds. ``members`` narrows the population to some of its names (default: all).
    The held-out population is never drawn here; it is for evaluation only (``sidewalk.crossplay``).
    ``member`` (B,) holds each world's member index into ``names``.
    """

    name = "population"
    scripted = True  # needs no run folder: its learned members ship with the package
    listed = False  # not one of the paper's opponents: chosen by name only
    per_replica = (
        False  # draws through env.randint, which splits by replica; members handle replicas themselves
    )
    batch_invariant = True

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled: Sequence[int] = (1,),
        ego: int | None = 0,
        *,
        members: Sequence[str] | None = None,
    ) -> None:
        super().__init__(env, controlled, ego)
        check_two_agent_sidewalk(env, "opponent=population")
        domain = env_domain(env)
        table = population(domain, "training")
        names = list(table) if members is None else list(members)
        if not names:
            raise ValueError(f"opponent.params.members is empty; valid members: {', '.join(table)}")
        for name in names:
            check_choice("population member", name, table)
        self.names = names
        self.members = torch.nn.ModuleList(
            make_opponent(
                table[name].opponent, env, controlled=self.controlled, ego=ego, **table[name].kwargs(domain)
            )
            for name in names
        )
        self.in_keys = sorted({key for member in self.members for key in member.in_keys}, key=str)
        self.member: torch.Tensor | None = None

    def reset(self, rows: torch.Tensor | None = None) -> None:
        n_worlds = self.env.num_envs
        drawn = self.env.randint(len(self.members), (n_worlds,), rows=rows)
        if self.member is None or rows is None:
            self.member = drawn
        else:
            self.member = torch.where(rows, drawn, self.member)
        for member in self.members:
            member.reset(rows)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.member is None:
            self.reset()
        ego_action = tensordict.get(ACTION_KEY, None)
        joints = []
        for member in self.members:
            if ego_action is not None:
                tensordict.set(ACTION_KEY, ego_action)
            joints.append(member(tensordict).get(ACTION_KEY))  # each member sets a new joint action tensor
        stacked = torch.stack(joints)  # (M, B, N, ...)
        index = self.member.view(1, -1, *[1] * (stacked.dim() - 2)).expand(1, *stacked.shape[1:])
        tensordict.set(ACTION_KEY, stacked.gather(0, index).squeeze(0))
        return tensordict
