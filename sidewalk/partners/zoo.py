"""The zoo of named partners: every shipped learned partner and every scripted one under a stable name, with a card,
one config choice away, and a learned one's policy exportable to run outside this package.

    sidewalk-partners list                                        # one line a partner, its name first
    sidewalk-partners show discrete/vdn_seed0                     # its card: a Hugging Face model card
    sidewalk-partners export continuous/mappo_seed1 --format onnx --out mappo_seed1.onnx
    python runners/main.py opponent=zoo opponent.params.name=keep_left           # training (the play page alike)
    python runners/crossplay.py RUN_DIR --partners zoo:discrete/vdn_seed0 --out DIR  # cross-play

Names: a learned partner is ``<domain>/<member>`` (``discrete/iql_seed0``), its folder under ``sidewalk/partners/``;
a scripted one is its population member's name (``keep_left``, ``dijkstra_near``, ``prm``, ...) or ``random``, the
one scripted opponent in no population. Who a partner is, how it is built and which split holds it are
``population.POPULATIONS``'s; the domains a scripted one plays, its opponent class's; a learned one's learner and
world, its ``policy.pt``'s. What no code holds -- a learned partner's training command and commit, and every score
the repository recorded with it -- is ``zoo.yaml``'s, one entry a partner, which ``tests/test_partner_zoo.py`` holds
equal to README.md's table and to the result files each score cites. A score recorded nowhere is said to be not
measured.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.interop.gymnasium import ENV_IDS, agent_spaces
from sidewalk.opponents.base import ACTION_KEY, Opponent, env_domain, make_opponent
from sidewalk.partners.policy import OBSERVATION_KEY, Partner, partner_policy, read_partner
from sidewalk.partners.population import PARTNERS_DIR, POPULATIONS, Member
from sidewalk.registry import OPPONENTS

FACTS_FILE = PARTNERS_DIR / "zoo.yaml"
OUTSIDE_POPULATIONS = {"random": Member("random")}  # the paper's moving obstacle (§4.1): no population draws it
EXPORT_FORMATS = ("onnx",)
NOT_MEASURED = "not measured"


@dataclass(frozen=True)
class ZooPartner:
    """A partner of the zoo: its ``name``, the population ``member`` that builds it and ``splits``, the split that
    holds it in each domain whose populations do (``"training"`` or ``"heldout"``)."""

    name: str
    member: Member
    splits: Mapping[str, str]

    @property
    def learned(self) -> bool:
        return self.member.opponent == "policy"

    @property
    def domains(self) -> tuple[str, ...]:
        """Where it plays: a learned partner its folder's domain, a scripted one what its opponent class declares."""
        return (self.name.split("/", 1)[0],) if self.learned else OPPONENTS[self.member.opponent].domains

    @property
    def folder(self) -> Path:
        """A learned partner's shipped folder (its ``policy.pt``)."""
        return PARTNERS_DIR / self.name

    @property
    def facts(self) -> dict[str, Any]:
        """Its entry of ``zoo.yaml``: ``trained`` (learned ones) and ``scores``."""
        return facts()["partners"].get(self.name, {})

    def scores(self, domain: str | None = None) -> list[dict[str, Any]]:
        """The recorded scores (``zoo.yaml``), those of ``domain`` where given."""
        return [score for score in self.facts.get("scores", []) if domain in (None, score["domain"])]


@functools.cache
def facts() -> dict[str, Any]:
    """``zoo.yaml``, read once."""
    import yaml

    return yaml.safe_load(FACTS_FILE.read_text())


@functools.cache
def partners() -> dict[str, ZooPartner]:
    """Every zoo partner by name: the learned ones (sorted), then the scripted ones (sorted)."""
    members: dict[str, Member] = {}
    splits: dict[str, dict[str, str]] = {}
    for domain, populations in POPULATIONS.items():
        for split, table in populations.items():
            for member_name, member in table.items():
                name = f"{domain}/{member_name}" if member.opponent == "policy" else member_name
                if members.setdefault(name, member) != member:  # one name, one partner, in both domains
                    raise ValueError(f"two population members are named {name!r}: {members[name]} and {member}")
                splits.setdefault(name, {})[domain] = split
    members.update(OUTSIDE_POPULATIONS)
    entries = [ZooPartner(name, member, splits.get(name, {})) for name, member in members.items()]
    entries.sort(key=lambda entry: (not entry.learned, entry.name))
    return {entry.name: entry for entry in entries}


def names(domain: str | None = None, learned: bool | None = None) -> list[str]:
    """The zoo's names: those playing ``domain``, and learned (or scripted) only, where given."""
    return [name for name, entry in partners().items()
            if (domain is None or domain in entry.domains) and learned in (None, entry.learned)]


def partner(name: Any, domain: str | None = None, what: str = "partner") -> ZooPartner:
    """The zoo partner ``name``, playing ``domain`` where given; ``ValueError`` naming ``what={name!r}`` and the
    valid names (those of ``domain``) otherwise."""
    entry = partners().get(name) if isinstance(name, str) else None
    where = "" if domain is None else f" of the {domain} domain"
    if entry is None:
        raise ValueError(f"{what}={name!r} is not a zoo partner{where}; valid: {', '.join(names(domain))}")
    if domain is not None and domain not in entry.domains:
        raise ValueError(f"{what}={name!r} plays the {' and '.join(entry.domains)} domain, not {domain}; valid in "
                         f"the {domain} domain: {', '.join(names(domain))}")
    return entry


def learned_partner(name: Any) -> ZooPartner:
    """The learned zoo partner ``name``: ``ValueError`` naming the learned ones for a scripted or unknown one."""
    entry = partner(name)
    if not entry.learned:
        raise ValueError(f"{name!r} is scripted: only a learned partner's policy exports; learned partners: "
                         f"{', '.join(names(learned=True))}")
    return entry


class ZooOpponent(Opponent):
    """The zoo partner ``name`` playing the ``controlled`` agents (``opponent=zoo opponent.params.name=NAME``): the
    opponent its population member names, built with the member's settings (a learned one: ``PolicyOpponent`` on its
    shipped folder). A name that is not a zoo partner of the env's domain raises naming the valid ones."""

    name = "zoo"
    scripted = True  # needs no run folder: its learned partners ship with the package
    listed = False  # chosen by name only, as the populations are
    per_replica = False  # the partner it builds is made for a replicated env by make_opponent itself
    batch_invariant = True

    def __init__(
        self, env: SidewalkEnvBase, controlled: Sequence[int] = (1,), ego: int | None = 0, *, name: str | None = None
    ) -> None:
        super().__init__(env, controlled, ego)
        domain = env_domain(env)
        self.partner_name = partner(name, domain, what="opponent.params.name").name
        member = partners()[self.partner_name].member
        self.player = make_opponent(member.opponent, env, controlled=self.controlled, ego=ego, **member.kwargs(domain))
        self.in_keys = list(self.player.in_keys)

    def reset(self, rows: torch.Tensor | None = None) -> None:
        self.player.reset(rows)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self.player(tensordict)


class AgentPolicy(torch.nn.Module):
    """A self-play partner's action for ``agent`` from that agent's observation alone: ``forward(observation)``
    (B, ...) -> action, (B,) int64 moves in the grid, (B, 2) float32 (acceleration m/s², turn rad) in the continuous
    world. The observation stands in every agent's row of the policy's input: a decentralized actor's ``agent`` row
    reads its own only."""

    def __init__(self, policy: Any, n_agents: int, agent: int) -> None:
        super().__init__()
        self.policy, self.n_agents, self.agent = policy, n_agents, agent

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        joint = observation.unsqueeze(1).expand(observation.shape[0], self.n_agents, *observation.shape[1:])
        out = self.policy(TensorDict({OBSERVATION_KEY: joint}, batch_size=observation.shape[:1]))
        return out.get(ACTION_KEY)[:, self.agent]


def agent_policy(name: str, agent: int = 1) -> tuple[AgentPolicy, Partner]:
    """The learned zoo partner ``name`` as agent ``agent``'s policy (``AgentPolicy``, in eval mode: greedy, as it
    plays as a partner) and what its ``policy.pt`` says; ``ValueError`` for a scripted partner or a bad agent."""
    from sidewalk._checks import check_int

    saved = read_partner(learned_partner(name).folder)
    if saved.world.opponent != "self" or saved.ego is not None:  # what AgentPolicy's stand-in rows rest on
        raise ValueError(f"{name!r} is not a self-play policy of every agent in the world's frame ({saved.label}): "
                         "its actions depend on more than one agent's own observation")
    check_int("agent", agent, 0, saved.world.n_agents - 1)
    policy, _ = partner_policy(saved)
    return AgentPolicy(policy, saved.world.n_agents, agent).eval(), saved


def gymnasium_kwargs(world: Any, agent: int) -> dict[str, Any]:
    """The ``gymnasium.make`` keywords whose observation is agent ``agent``'s in ``world``: ``ego`` and the env
    parameters that differ from the defaults (rewards aside: they change no observation)."""
    defaults = dataclasses.asdict(world.core_class.Params())
    own = dataclasses.asdict(world.env_params)
    return {"ego": agent, **{key: value for key, value in own.items() if key != "rewards" and value != defaults[key]}}


def export_onnx(name: str, out: str | Path, agent: int = 1) -> Path:
    """The learned zoo partner ``name``'s policy as agent ``agent`` (``AgentPolicy``) written to the ONNX file ``out``
    (one file, weights inside): input ``observation`` (batch, ...) as ``gymnasium.make`` gives that agent in the
    partner's world (``gymnasium_kwargs``), output ``action`` as its ``step`` takes it. The file's metadata names the
    partner, the Gymnasium id and keywords and the license."""
    import logging
    import warnings

    module, saved = agent_policy(name, agent)
    observation_space = agent_spaces(saved.world.core(1))[0]
    example = torch.as_tensor(observation_space.sample()).unsqueeze(0).expand(2, *observation_space.shape)
    exporter_log = logging.getLogger("torch.onnx")
    level = exporter_log.level
    # The exporter's notes (deprecated internals, torchvision's operators skipped) are not the user's to act on.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exporter_log.setLevel(logging.ERROR)
        try:
            program = torch.onnx.export(module, (example.contiguous(),), dynamo=True, input_names=["observation"],
                                        output_names=["action"], dynamic_shapes=({0: torch.export.Dim("batch")},),
                                        verbose=False)
        finally:
            exporter_log.setLevel(level)
    program.model.metadata_props.update({
        "sidewalk.partner": name,
        "sidewalk.gymnasium_id": ENV_IDS[saved.world.domain],
        "sidewalk.gymnasium_kwargs": json.dumps(gymnasium_kwargs(saved.world, agent)),
        "license": license_id(),
    })
    out = Path(out)
    program.save(out, external_data=False)
    return out


def license_id() -> str:
    """The package's license as a Hugging Face license id (its metadata's: pyproject's ``license``)."""
    import importlib.metadata

    metadata = importlib.metadata.metadata("sidewalk-problem")
    return str(metadata.get("License-Expression") or metadata.get("License")).lower()

