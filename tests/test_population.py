"""Partner populations (``opponent=population``): a training population disjoint from the held-out one, a member drawn
per world at its resets from the env's seed, each world played by its own member, and the shipped learned partners."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

import pytest
import torch

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.opponents.base import ACTION_KEY, make_opponent
from sidewalk.partners.policy import read_partner
from sidewalk.partners.population import PARTNERS_DIR, POPULATIONS, PopulationOpponent, population
from sidewalk.run_folder import read_torch_file
from sidewalk.views import EgoView

ROOT = Path(__file__).resolve().parents[1]


pytestmark = pytest.mark.usefixtures("one_thread")


def core(domain: str, num_envs: int = 16, seed: int = 0, **kwargs):
    if domain == "continuous":
        return ContinuousSidewalkEnv(num_envs=num_envs, seed=seed, **kwargs)
    return DiscreteSidewalkEnv(num_envs=num_envs, seed=seed, observation="vector", **kwargs)


@pytest.mark.parametrize("domain", ["continuous", "discrete"])
def test_the_held_out_population_never_trains(domain):
    training, heldout = population(domain, "training"), population(domain, "heldout")
    assert not set(training) & set(heldout), "no member is in both"
    assert {(m.opponent, tuple(sorted(m.params.items()))) for m in training.values()}.isdisjoint(
        {(m.opponent, tuple(sorted(m.params.items()))) for m in heldout.values()}
    ), "no held-out partner hides in training under another name"
    opponent = PopulationOpponent(core(domain))
    assert opponent.names == list(training)
    with pytest.raises(
        ValueError, match="population member='keep_left' is not valid; valid: 'dijkstra_near'|'prm_r"
    ):
        PopulationOpponent(core(domain), members=["keep_left"])  # a held-out member asked for in training


def test_a_member_is_drawn_per_world_at_its_resets_from_the_envs_seed():
    draws = []
    for seed in (0, 0, 1):
        opponent = PopulationOpponent(core("discrete", num_envs=64, seed=seed))
        opponent.reset()
        draws.append(opponent.member.clone())
    assert torch.equal(draws[0], draws[1]) and not torch.equal(draws[0], draws[2])
    assert set(draws[0].tolist()) == set(range(len(opponent.names))), "64 worlds meet every member"
    rows = torch.arange(64) < 32
    before = opponent.member.clone()
    opponent.reset(rows)
    assert torch.equal(opponent.member[~rows], before[~rows]), "worlds not reset keep their partner"
    assert not torch.equal(opponent.member[rows], before[rows])


# Members without random draws: played alone beside the population, they act as its copies do.
DETERMINISTIC = {
    "discrete": ["dijkstra_near", "keep_left_wide", "always_yields_late", "iql_seed1"],  # a vector MLP, image world
    "continuous": ["prm_roadmap1", "keep_right_wide", "always_yields_late", "ippo_seed1"],
}


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
def test_each_world_plays_its_own_member(domain):
    env = core(domain)
    view = EgoView(env, opponent="population", opponent_kwargs={"members": DETERMINISTIC[domain]})
    td = view.reset()
    table = population(domain, "training")
    alone = [
        make_opponent(table[name].opponent, env, controlled=(1,), ego=0, **table[name].kwargs(domain))
        for name in DETERMINISTIC[domain]
    ]
    worlds = torch.arange(env.num_envs)
    for step in range(6):
        core_in = view._last  # the view writes the joint action into it, then steps the core
        expected = torch.stack([member(core_in.clone()).get(ACTION_KEY)[:, 1] for member in alone])
        td = view.step(td.set("action", view.action_spec.zero()))["next"]
        assert torch.equal(core_in.get(ACTION_KEY)[:, 1], expected[view.opponent.member, worlds]), (
            f"step {step}"
        )
    assert len(set(view.opponent.member.tolist())) > 1


def test_a_population_plays_the_two_agent_sidewalk_only():
    with pytest.raises(ValueError, match="two-agent sidewalk .* not env.layout='door' with 3 agents"):
        PopulationOpponent(core("discrete", layout="door", n_agents=3), controlled=(1, 2))


@pytest.mark.parametrize(("domain", "names"), [
    ("continuous", [f"{algo}_seed{seed}" for algo in ("ippo", "mappo") for seed in range(3)]),
    ("discrete", [f"iql_seed{seed}" for seed in range(3)] + [f"vdn_seed{seed}" for seed in (0, 1, 3)]),
])
def test_the_shipped_partners_are_small_weights_only_files_in_the_wheel(domain, names):
    learned = [
        m.params["partner"]
        for split in POPULATIONS[domain].values()
        for m in split.values()
        if m.opponent == "policy"
    ]
    assert sorted(learned) == sorted(names)
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"][
        "sidewalk.partners"
    ]
    for name in learned:
        file = PARTNERS_DIR / domain / name / "policy.pt"
        assert file.stat().st_size < 100_000
        read_torch_file(file)  # weights only: raises on anything else
        assert read_partner(file.parent).world.opponent == "self"
        relative = str(file.relative_to(PARTNERS_DIR))
        assert any(fnmatch.fnmatch(relative, pattern) for pattern in patterns), relative
