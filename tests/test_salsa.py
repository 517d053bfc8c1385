"""The salsa partner: its side bias shows in the sides it picks, a mirroring partner makes it switch back and forth,
it reaches its goal beside a partner that keeps the other side, and one seed gives one game, in both domains."""

import pytest
import torch
from torchrl.envs.utils import step_mdp

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.opponents.base import make_opponent

DOMAINS = [DiscreteSidewalkEnv, ContinuousSidewalkEnv]
WORLDS = 400


def walk(core_class, partner: dict, seed: int = 1, partner_name: str = "convention", **salsa):
    """One episode in each world: ``partner_name`` with ``partner`` as agent 0, the salsa as agent 1."""
    core = core_class(WORLDS, seed=seed)
    walker = make_opponent(partner_name, core, controlled=(0,), ego=1, **partner)
    salsa_agent = make_opponent("salsa", core, controlled=(1,), ego=0, **salsa)
    td = core.reset()
    first_sides = None
    for _ in range(core.params.max_steps):
        td = salsa_agent(walker(td))
        if first_sides is None:
            first_sides = salsa_agent.chosen.clone()
        td = core.step(td)
        if bool(td.get(("next", "done")).all()):
            break
        td = step_mdp(td)
    reached = td.get(("next", "agents", "info", "reached_goal")).squeeze(-1)[:, 1]
    return salsa_agent, first_sides, reached


@pytest.mark.parametrize("core_class", DOMAINS)
@pytest.mark.parametrize("right_prob", [0.8, 0.3])
def test_the_side_bias_shows_in_the_sides_it_picks(core_class, right_prob):
    _, first_sides, _ = walk(core_class, {"style": "keep_right"}, right_prob=right_prob)
    right_share = (first_sides == -1).float().mean().item()
    standard_error = (right_prob * (1 - right_prob) / WORLDS) ** 0.5
    assert abs(right_share - right_prob) < 4 * standard_error


@pytest.mark.parametrize("core_class", DOMAINS)
def test_a_mirroring_partner_makes_it_switch_sides_and_an_agreeing_one_rarely(core_class):
    mirrored, _, reached_mirrored = walk(core_class, {"style": "keep_left"})  # its bias is right: keep_left mirrors
    agreeing, _, reached_agreeing = walk(core_class, {"style": "keep_right"})
    assert mirrored.switches.float().mean() > 0.4
    assert agreeing.switches.float().mean() < mirrored.switches.float().mean() / 2
    assert reached_agreeing.float().mean() >= 0.85
    assert reached_agreeing.float().mean() > reached_mirrored.float().mean()  # the salsa costs passes


def test_two_grid_salsa_walkers_without_a_shared_bias_dance_back_and_forth():
    salsa_agent, _, reached = walk(DiscreteSidewalkEnv, {"right_prob": 0.5}, partner_name="salsa", right_prob=0.5)
    assert (salsa_agent.switches >= 2).float().mean() > 0.03  # a second switch: both switched, mirrored again
    assert reached.float().mean() > 0.8


def test_two_continuous_salsa_walkers_without_a_shared_bias_switch_and_often_collide():
    # Measured: one switch at most, and about half the passes fail.
    salsa_agent, _, reached = walk(ContinuousSidewalkEnv, {"right_prob": 0.5}, partner_name="salsa", right_prob=0.5)
    assert (salsa_agent.switches >= 1).float().mean() > 0.2
    assert reached.float().mean() < 0.8


@pytest.mark.parametrize("core_class", DOMAINS)
def test_one_seed_one_game(core_class):
    first, sides, reached = walk(core_class, {"style": "keep_left"}, seed=3)
    second, sides_again, reached_again = walk(core_class, {"style": "keep_left"}, seed=3)
    assert torch.equal(sides, sides_again) and torch.equal(first.switches, second.switches)
    assert torch.equal(reached, reached_again)


@pytest.mark.parametrize("params, words", [
    ({"right_prob": 1.5}, "right_prob"), ({"reaction_steps": 0}, "reaction_steps"), ({"switch_prob": -0.1}, "switch_prob"),
])
def test_bad_parameters_are_named(params, words):
    with pytest.raises(ValueError, match=words):
        make_opponent("salsa", DiscreteSidewalkEnv(2, seed=0), controlled=(1,), ego=0, **params)
