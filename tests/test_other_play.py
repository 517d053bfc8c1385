"""Other-Play (other_play=true): self-play partners act through a random mirror of the game (sidewalk.symmetry)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from torchrl.envs.utils import check_env_specs

from sidewalk.config import validate
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.layouts import GridLayout
from sidewalk.schema import register_schemas
from sidewalk.symmetry import mirror_action, mirror_observation, turn_action, turn_observation
from sidewalk.views import SelfPlayView

CONF = str(Path(__file__).resolve().parents[1] / "conf")
OBS, ACTION = ("agents", "observation"), ("agents", "action")
CORES = {
    "image": lambda n, seed: DiscreteSidewalkEnv(n, seed=seed),
    "vector": lambda n, seed: DiscreteSidewalkEnv(n, seed=seed, observation="vector"),
    "continuous": lambda n, seed: ContinuousSidewalkEnv(n, seed=seed, noise=0.1),
}


def random_actions(view, generator: torch.Generator) -> torch.Tensor:
    spec = view.full_action_spec[ACTION]
    if view.domain == "discrete":
        return torch.randint(0, 4, spec.shape, generator=generator)
    return (torch.rand(spec.shape, generator=generator) * 2 - 1) * spec.space.high


@pytest.mark.parametrize("kind", CORES)
def test_the_mirror_is_its_own_inverse_and_keeps_removed_agents_at_zero(kind):
    view = SelfPlayView(CORES[kind](64, 0))
    torch.manual_seed(0)
    rollout = view.rollout(40, break_when_any_done=False)
    observation = rollout.get(("next", *OBS))
    layout = view.core.layout
    mirrored = mirror_observation(observation, layout)
    assert not torch.equal(mirrored, observation)
    torch.testing.assert_close(mirror_observation(mirrored, layout), observation, atol=1e-5, rtol=0)
    action = rollout.get(ACTION)
    assert torch.equal(mirror_action(mirror_action(action, view.domain), view.domain), action)
    if kind != "image":
        assert ((observation == 0).all(-1) == (mirrored == 0).all(-1)).all()


@pytest.mark.parametrize("kind", CORES)
def test_a_mirrored_partner_sees_the_mirror_and_its_action_steps_the_world_mirrored_back(kind):
    # Noise off: the mirror draws come from the env's generator, so the noise of the two views' worlds would differ.
    make = (lambda: ContinuousSidewalkEnv(64, seed=3)) if kind == "continuous" else (lambda: CORES[kind](64, 3))
    other_play, plain = SelfPlayView(make(), other_play=True), SelfPlayView(make())
    td, reference = other_play.reset(), plain.reset()
    mirrored = other_play._mirrored
    assert mirrored[:, 1].any() and not mirrored[:, 1].all() and not mirrored[:, 0].any()
    generator = torch.Generator().manual_seed(1)
    for _ in range(25):
        expected = torch.where(
            mirrored.view(*mirrored.shape, *([1] * (td.get(OBS).dim() - 2))),
            mirror_observation(reference.get(OBS), other_play.core.layout), reference.get(OBS),
        )
        torch.testing.assert_close(td.get(OBS), expected)
        action = random_actions(other_play, generator)
        # the plain view steps what the other-play view's agents mean: the mirrored agents' actions mirrored back
        shape = (*mirrored.shape, *([1] * (action.dim() - 2)))
        meant = torch.where(mirrored.view(shape), mirror_action(action, other_play.domain), action)
        td = other_play.step(td.set(ACTION, action))["next"]
        reference = plain.step(reference.set(ACTION, meant))["next"]
        assert torch.equal(td.get(("world", "state")), reference.get(("world", "state")))
        assert torch.equal(td.get(("agents", "reward")), reference.get(("agents", "reward")))


def test_mirror_draws_are_seeded():
    draws = [SelfPlayView(DiscreteSidewalkEnv(64, seed=seed), other_play=True) for seed in (5, 5, 6)]
    for view in draws:
        view.reset()
    assert torch.equal(draws[0]._mirrored, draws[1]._mirrored)
    assert not torch.equal(draws[0]._mirrored, draws[2]._mirrored)
    # a plain view draws nothing: its worlds are those of the env alone
    plain = SelfPlayView(DiscreteSidewalkEnv(64, seed=5))
    plain.reset()
    assert not plain._mirrored.any()


@pytest.mark.parametrize("kind", ["image", "continuous"])
def test_other_play_view_specs(kind):
    check_env_specs(SelfPlayView(CORES[kind](8, 0), other_play=True))


def test_layouts_the_mirror_does_not_map_onto_themselves_are_refused():
    off_centre = GridLayout(rows=7, cols=15, starts=((3, 0), (3, 14)), goals=((3, 14), (3, 0)), center_row=3.0,
                            blocked=((1, 7),))
    with pytest.raises(ValueError, match="other_play=true needs a layout that its mirror"):
        SelfPlayView(DiscreteSidewalkEnv(2, layout=off_centre), other_play=True)
    with pytest.raises(ValueError, match="other_play=true needs a layout"):
        SelfPlayView(ContinuousSidewalkEnv(2, layout="zipper", length_m=6.0, width_m=2.0), other_play=True)


def compose_config(overrides: list[str]):
    register_schemas()
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def test_other_play_needs_self_play_and_a_symmetric_layout():
    with pytest.raises(ValueError, match="other_play=true trains self-play partners: use opponent=self"):
        validate(compose_config(["other_play=true"]))
    with pytest.raises(ValueError, match="mirror across the centre line"):
        validate(compose_config(["other_play=true", "opponent=self", "algo=iql", "env.layout=door", "env.n_agents=3"]))
    assert validate(compose_config(["other_play=true", "opponent=self", "algo=iql"])).world.other_play


@pytest.mark.parametrize("kind", CORES)
def test_in_the_role_frame_agent_1_sees_the_game_as_agent_0_and_its_action_steps_the_world_turned_back(kind):
    # Noise off so that the two views' worlds step alike.
    make = (lambda: ContinuousSidewalkEnv(64, seed=3)) if kind == "continuous" else (lambda: CORES[kind](64, 3))
    role, plain = SelfPlayView(make(), role_frame=True), SelfPlayView(make())
    td, reference = role.reset(), plain.reset()
    assert role._turned.tolist() == [False, True]
    # The nominal sidewalk is the half turn of itself with the roles swapped: both agents see one observation.
    assert torch.equal(td.get(OBS)[:, 0], td.get(OBS)[:, 1])
    generator = torch.Generator().manual_seed(1)
    for _ in range(25):
        expected = reference.get(OBS).clone()
        expected[:, 1] = turn_observation(reference.get(OBS)[:, 1], role.core.layout)
        torch.testing.assert_close(td.get(OBS), expected)
        action = random_actions(role, generator)
        meant = action.clone()
        meant[:, 1] = turn_action(action[:, 1], role.domain)  # agent 1's UP is the world's DOWN, its LEFT the RIGHT
        td = role.step(td.set(ACTION, action))["next"]
        reference = plain.step(reference.set(ACTION, meant))["next"]
        assert torch.equal(td.get(("world", "state")), reference.get(("world", "state")))
    check_env_specs(SelfPlayView(make(), role_frame=True))


def test_one_action_of_both_agents_in_the_role_frame_moves_them_apart():
    # Face to face on the centre row, both take UP in their own frame: agent 0 goes up a row, agent 1 down a row.
    view = SelfPlayView(DiscreteSidewalkEnv(1, seed=0), role_frame=True)
    td = view.reset()
    start = td.get(("world", "state")).clone()
    td = view.step(td.set(ACTION, torch.zeros(1, 2, dtype=torch.long)))["next"]
    rows = td.get(("world", "state"))[0, :, 0] - start[0, :, 0]
    assert rows.tolist() == [-1, 1]


def test_the_role_frame_is_refused_where_a_role_has_no_map():
    with pytest.raises(ValueError, match="role_frame=true needs every agent's role to map onto agent 0's"):
        SelfPlayView(DiscreteSidewalkEnv(4, seed=0, layout="door", n_agents=3), role_frame=True)


def test_the_role_frame_needs_self_play_and_roles_a_half_turn_maps_and_reaches_the_world():
    with pytest.raises(ValueError, match="role_frame=true trains self-play partners: use opponent=self"):
        validate(compose_config(["role_frame=true"]))
    with pytest.raises(ValueError, match=r"maps agents \[1, 2\] onto none"):
        validate(compose_config(["role_frame=true", "opponent=self", "algo=iql", "env.layout=door", "env.n_agents=3"]))
    world = validate(compose_config(["role_frame=true", "opponent=self", "algo=iql"])).world
    assert world.role_frame and world.make(2)._turned.tolist() == [False, True]
