"""The convention partners (``opponent=convention``): each behaves as its name says, in both domains.

Two scripted agents play the two-agent sidewalk, each one ``ConventionOpponent``; the checks read their paths:
which side they pass on, who leaves its line, who stops, and that pauses come from the env's seed.
"""

from __future__ import annotations

import pytest
import torch

from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.opponents.base import make_opponent
from sidewalk.opponents.convention import STYLES, ConventionOpponent

WORLDS = 4
DOMAINS = ("continuous", "discrete")


pytestmark = pytest.mark.usefixtures("one_thread")


def core(domain: str, seed: int = 0, noise: float = 0.0):
    if domain == "continuous":
        return ContinuousSidewalkEnv(num_envs=WORLDS, seed=seed, noise=noise)
    return DiscreteSidewalkEnv(num_envs=WORLDS, seed=seed, observation="vector", noise=noise)


def play(domain: str, style0: str | None, style1: str, seed: int = 0, steps: int = 60, **kwargs1):
    """Agent 0 follows ``style0`` (None: stands still, continuous only), agent 1 ``style1`` (with ``kwargs1``):
    positions (T, B, 2, 2), speeds (T, B, 2) (continuous; zeros in the grid) and the last step's info."""
    env = core(domain, seed)
    agents = [ConventionOpponent(env, controlled=(1,), ego=None, style=style1, **kwargs1)]
    if style0 is not None:
        agents.insert(0, ConventionOpponent(env, controlled=(0,), ego=None, style=style0))
    td = env.reset()
    positions, speeds = [], []
    for _ in range(steps):
        td.set(("agents", "action"), env.full_action_spec["agents", "action"].zero())
        for agent in agents:
            agent(td)
        td = env.step(td)["next"]
        state = td["agents", "state"].float()
        positions.append(state[..., :2].clone())
        speeds.append(state[..., 2].clone() if domain == "continuous" else torch.zeros(state.shape[:2]))
        if bool(td["done"].all()):
            break
    return torch.stack(positions), torch.stack(speeds), td["agents", "info"]


def lateral_left_of_agent0(domain: str, positions: torch.Tensor) -> torch.Tensor:
    """(T, B): how far agent 0 is on its own left of agent 1 (grid: a smaller row; continuous: a larger y)."""
    if domain == "continuous":
        return positions[..., 0, 1] - positions[..., 1, 1]
    return positions[..., 1, 0] - positions[..., 0, 0]


def along(domain: str, positions: torch.Tensor) -> torch.Tensor:
    return positions[..., 0] if domain == "continuous" else positions[..., 1]


def passing_gap(domain: str, positions: torch.Tensor) -> torch.Tensor:
    """(B,): agent 0's lateral lead to its left at the first step its along-coordinate passes agent 1's."""
    crossed = along(domain, positions)[..., 0] >= along(domain, positions)[..., 1]  # (T, B)
    assert bool(crossed.any(0).all()), "the agents never passed each other"
    first = crossed.float().argmax(0)
    return lateral_left_of_agent0(domain, positions)[first, torch.arange(positions.shape[1])]


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("style, sign", [("keep_left", 1.0), ("keep_right", -1.0)])
def test_keeping_a_side_passes_on_that_side(domain, style, sign):
    positions, _, info = play(domain, style, style)
    assert bool(info["reached_goal"].all()), "both keep to one side: both arrive"
    assert not bool(info["collided_agent"].any() | info["collided_wall"].any())
    assert bool((sign * passing_gap(domain, positions) > 0).all())


@pytest.mark.parametrize("domain", DOMAINS)
def test_never_yields_walks_its_line_into_whoever_stands_on_it(domain):
    positions, _, info = play(domain, "never_yields", "never_yields")
    centre = 1.5 if domain == "continuous" else 3.0
    lateral = positions[..., 1] if domain == "continuous" else positions[..., 0]
    assert bool(((lateral - centre).abs() < 1e-3).all()), "it never leaves the centre line"
    assert bool(info["collided_agent"].all()), "two who never yield meet head on"


@pytest.mark.parametrize("domain", DOMAINS)
def test_always_yields_steps_aside_to_its_right_and_lets_the_other_pass(domain):
    positions, _, info = play(domain, "never_yields", "always_yields")
    assert bool(info["reached_goal"].all()) and not bool(info["collided_agent"].any())
    # Agent 1 walks toward -x / -col: its right is +y in the continuous world and a smaller row in the grid.
    right = positions[..., 1, 1] - 1.5 if domain == "continuous" else 3.0 - positions[..., 1, 0]
    assert bool((right.max(0).values > (0.6 if domain == "continuous" else 2.5)).all()), "it steps aside"
    # Stepping to its own right, it has agent 0 pass on agent 0's right too: both keep right.
    assert bool((passing_gap(domain, positions) < 0).all())
    if domain == "discrete":  # no stay action: by the wall it steps back and forth while the other comes
        walked = along(domain, positions)[:, :, 1]
        assert bool((walked[1:] > walked[:-1]).any(0).all())


def test_always_yields_waits_by_the_wall_while_the_other_stands_ahead():
    positions, speeds, info = play("continuous", None, "always_yields")
    assert not bool(info["collided_agent"].any() | info["collided_wall"].any())
    right = positions[..., 1, 1] - 1.5
    assert bool((right[-1] > 1.0).all()), "it stands by the wall on its right"
    assert bool((speeds[-10:, :, 1].abs() < 0.05).all()), "and waits there"


def pauses(domain: str, positions: torch.Tensor) -> torch.Tensor:
    """(B,): the steps agent 1 (walking toward -x / -col) made no progress before it reached its last place."""
    walked = along(domain, positions)[:, :, 1]
    unfinished = walked[:-1] != walked[-1]
    return ((walked[1:] >= walked[:-1]) & unfinished).sum(0)


@pytest.mark.parametrize("domain", DOMAINS)
def test_hesitates_pauses_at_times_drawn_from_the_envs_seed(domain):
    # Agent 0 keeps left, out of the hesitating agent's way; agent 1 walks the centre line and pauses at random.
    runs = [play(domain, "keep_left", "hesitates", seed=seed, hesitate_prob=0.2)[0] for seed in (0, 0, 1)]
    assert torch.equal(runs[0], runs[1]), "one seed, one path"
    assert bool((pauses(domain, runs[0]) > 0).all()), "every world pauses"
    assert not torch.equal(pauses(domain, runs[0]), pauses(domain, runs[2])), "another seed, other pauses"
    steady = play(domain, "keep_left", "hesitates", hesitate_prob=0.0)[0]
    assert bool((pauses(domain, steady) == 0).all()), "without pauses it walks on"


def test_a_bad_style_names_the_valid_ones():
    env = core("continuous")
    with pytest.raises(
        ValueError, match="style='keep_centre' is not valid; valid: 'keep_left', 'keep_right'"
    ):
        make_opponent("convention", env, style="keep_centre")
    assert STYLES == ("keep_left", "keep_right", "always_yields", "never_yields", "hesitates")
