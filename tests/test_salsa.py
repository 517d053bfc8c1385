"""The salsa partner: its side bias shows in the sides it picks, a mirrored pass makes it switch and two of it dance
back and forth (counted by the social measures' mirrored dodges too), it reaches its goal beside a straight walker
and the keep-side conventions, and one seed gives one game, in both domains."""

import pytest
import torch
from torchrl.envs.utils import step_mdp

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.opponents.base import make_opponent
from sidewalk.social import SocialTally

DOMAINS = [DiscreteSidewalkEnv, ContinuousSidewalkEnv]
WORLDS = 400


def walk(core_class, partner: dict, seed: int = 1, partner_name: str = "convention", **salsa):
    """One episode in each world: ``partner_name`` with ``partner`` as agent 0, the salsa as agent 1; returns the
    salsa, the sides it first picked, whether it reached its goal, and each world's mirrored dodges (``SocialTally``)."""
    core = core_class(WORLDS, seed=seed)
    walker = make_opponent(partner_name, core, controlled=(0,), ego=1, **partner)
    salsa_agent = make_opponent("salsa", core, controlled=(1,), ego=0, **salsa)
    td = core.reset()
    grid = core_class is DiscreteSidewalkEnv
    tally = SocialTally.begin(td.get(("agents", "state")), td.get(("agents", "goal")), grid,
                              getattr(core.params, "dt_s", 1.0), getattr(core.params, "agent_radius_m", 0.5))
    first_sides = None
    for _ in range(core.params.max_steps):
        td = salsa_agent(walker(td))
        if first_sides is None:
            first_sides = salsa_agent.chosen.clone()
        active = ~td.get(("agents", "done")).squeeze(-1)
        td = core.step(td)
        tally.add_step(td.get(("next", "agents", "state")), active)
        if bool(td.get(("next", "done")).all()):
            break
        td = step_mdp(td)
    reached = td.get(("next", "agents", "info", "reached_goal")).squeeze(-1)[:, 1]
    return salsa_agent, first_sides, reached, tally.salsa


@pytest.mark.parametrize("core_class", DOMAINS)
@pytest.mark.parametrize("right_prob", [0.6, 0.3])
def test_the_side_bias_shows_in_the_sides_it_picks(core_class, right_prob):
    _, first_sides, _, _ = walk(core_class, {"style": "keep_right"}, right_prob=right_prob)
    right_share = (first_sides == -1).float().mean().item()
    standard_error = (right_prob * (1 - right_prob) / WORLDS) ** 0.5
    assert abs(right_share - right_prob) < 4 * standard_error


@pytest.mark.parametrize("core_class", DOMAINS)
def test_a_mirroring_partner_makes_it_switch_sides_and_an_agreeing_one_never(core_class):
    # Always first to its right: a keep_left walker mirrors it in every world, a keep_right one in none.
    mirrored, _, reached_mirrored, _ = walk(core_class, {"style": "keep_left"}, right_prob=1.0)
    agreeing, _, reached_agreeing, _ = walk(core_class, {"style": "keep_right"}, right_prob=1.0)
    assert (mirrored.switches >= 1).float().mean() > 0.9
    assert int(agreeing.switches.sum()) == 0
    assert reached_agreeing.float().mean() >= 0.9
    assert reached_mirrored.float().mean() >= 0.8  # the switch comes in time in most worlds (0.87 measured, 400)


@pytest.mark.parametrize("core_class, dancing, reaching", [(DiscreteSidewalkEnv, 0.08, 0.9),
                                                           (ContinuousSidewalkEnv, 0.25, 0.5)])
def test_two_salsa_walkers_without_a_shared_bias_dance_back_and_forth(core_class, dancing, reaching):
    salsa_agent, _, reached, mirrored_dodges = walk(core_class, {"right_prob": 0.5}, partner_name="salsa",
                                                    right_prob=0.5)
    assert (salsa_agent.switches >= 2).float().mean() > dancing  # a second switch: both switched, mirrored again
    assert (mirrored_dodges >= 2).float().mean() > dancing / 2  # the social measures see the dance too
    assert reached.float().mean() > reaching


@pytest.mark.parametrize("core_class", DOMAINS)
@pytest.mark.parametrize("style", ["never_yields", "keep_left", "keep_right"])
def test_it_reaches_its_goal_beside_a_straight_walker_and_the_keep_side_conventions(core_class, style):
    _, _, reached, _ = walk(core_class, {"style": style})
    assert reached.float().mean() >= 0.9


@pytest.mark.parametrize("core_class", DOMAINS)
def test_one_seed_one_game(core_class):
    first, sides, reached, dodges = walk(core_class, {"style": "keep_left"}, seed=3)
    second, sides_again, reached_again, dodges_again = walk(core_class, {"style": "keep_left"}, seed=3)
    assert torch.equal(sides, sides_again) and torch.equal(first.switches, second.switches)
    assert torch.equal(reached, reached_again) and torch.equal(dodges, dodges_again)
    _, other_sides, _, _ = walk(core_class, {"style": "keep_left"}, seed=4)
    assert not torch.equal(sides, other_sides)


@pytest.mark.parametrize("params, words", [
    ({"right_prob": 1.5}, "right_prob"), ({"reaction_steps": 0}, "reaction_steps"), ({"switch_prob": -0.1}, "switch_prob"),
])
def test_bad_parameters_are_named(params, words):
    with pytest.raises(ValueError, match=words):
        make_opponent("salsa", DiscreteSidewalkEnv(2, seed=0), controlled=(1,), ego=0, **params)
