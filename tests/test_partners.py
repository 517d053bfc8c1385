"""Self-play and learned partners: the self-play view, the configs that select them, ``policy.pt`` as a partner
(round trip, role mapping by the sidewalk's half turn) and the mismatches that must fail before compute."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from torchrl.envs.utils import check_env_specs

from sidewalk.config import validate
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.evaluate import evaluate
from sidewalk.experiment import EVAL_SEED_OFFSET, Trial
from sidewalk.partners.policy import (
    PartnerMismatch,
    PolicyOpponent,
    check_partner_of,
    read_partner,
    role_map,
    turn_observation,
)
from sidewalk.report.checkpoints import load_experiment, load_policy
from sidewalk.schema import register_schemas
from sidewalk.views import EgoView, SelfPlayView

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
TINY = ["num_envs=4", "iterations=2", "eval_every=0", "eval_episodes=8", "checkpoint_every=0", "logger=none"]
TINY_DQN = ["algo.frames_per_batch=16", "algo.batch_size=16", "algo.learning_starts=0", "algo.updates_per_batch=1"]
register_schemas()


def checked(cfg):
    """What the runner does before any compute: validate the config, then check a learned partner's folder."""
    experiment = validate(cfg)
    check_partner_of(experiment)
    return experiment


def composed(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def train(run_dir: Path, *overrides: str) -> Path:
    """A finished run folder, trained in this process (a subprocess would add seconds of imports per run)."""
    cfg = composed(*TINY, *overrides)
    Trial(validate(cfg), run_dir, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    return run_dir


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """Tiny finished runs: grid DQN as agent 0 and as agent 1 (vs Dijkstra), grid centralized, continuous PPO."""
    base = tmp_path_factory.mktemp("partners")
    return {
        "dqn": train(base / "dqn", *TINY_DQN, "noise=0.1"),
        "dqn_ego1": train(base / "dqn_ego1", *TINY_DQN, "opponent.ego=1"),
        "centralized": train(base / "centralized", *TINY_DQN, "opponent=centralized"),
        "ppo": train(base / "ppo", "env=continuous", "opponent=prm", "algo=ppo", "algo.frames_per_batch=64",
                     "algo.minibatch_size=32", "algo.epochs=1"),
    }


# ---- the self-play view ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("core_cls", [DiscreteSidewalkEnv, ContinuousSidewalkEnv])
def test_self_play_view_specs_and_each_agents_own_life_cycle(core_cls):
    view = SelfPlayView(core_cls(16, seed=3))
    check_env_specs(view)
    rollout = view.rollout(200, break_when_any_done=False)
    nxt = rollout.get("next")
    world = {key: nxt.get(key).unsqueeze(-2) for key in ("done", "terminated", "truncated")}  # (B, T, 1, 1)
    info = nxt.get(("world", "info"))
    crashed = info.get("collided_agent") | info.get("collided_wall")  # (B, T, N, 1)
    agents = {key: nxt.get(("agents", key)) for key in ("done", "terminated", "truncated")}
    agents["mask"] = nxt.get(("agents", "info", "mask"))
    assert torch.equal(agents["terminated"], crashed | world["terminated"].expand_as(crashed))
    assert torch.equal(agents["truncated"], world["truncated"].expand_as(crashed) & ~crashed)
    assert torch.equal(agents["done"], agents["terminated"] | agents["truncated"])
    assert torch.equal(agents["mask"], ~agents["done"])
    # the world is done exactly when every agent is; an agent ends alone when it crashes and its partner goes on
    assert torch.equal(world["done"].squeeze(-1), agents["done"].all(-2))
    assert world["done"].any() and (agents["done"].any(-2) & ~agents["done"].all(-2)).any()
    # each agent's reward is the core's, also in the world group
    assert torch.equal(nxt.get(("agents", "reward")), nxt.get(("world", "reward")))


def test_self_play_evaluation_reports_team_metrics_without_an_ego():
    view = SelfPlayView(DiscreteSidewalkEnv(32, seed=0))
    metrics = evaluate(view, None, seed=1)
    assert "team/success_rate" in metrics and "agent1/success_rate" in metrics
    assert not any(key.startswith(("ego/", "other/")) for key in metrics)


# ---- configs ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (["opponent=self", "algo=dqn"], "multi-agent learners for env=discrete: ippo, iql, mappo, qmix, vdn"),
        (["opponent=dijkstra", "algo=iql"], "use opponent=self, not opponent=dijkstra"),
        (["env=continuous", "opponent=self", "algo=qmix"], "algo=qmix does not fit env=continuous"),
        (["opponent=random", "opponent.path=/tmp"], "opponent.path='/tmp' applies only to opponent=policy"),
    ],
)
def test_learner_and_opponent_combinations_fail_naming_the_fix(overrides, named):
    with pytest.raises(ValueError) as error:
        checked(composed(*overrides))
    assert named in str(error.value)


def test_policy_opponent_needs_an_existing_run_folder(tmp_path):
    with pytest.raises(Exception, match="opponent.path"):
        checked(composed("opponent=policy"))  # ??? (missing) path
    with pytest.raises(FileNotFoundError, match="is not a folder"):
        checked(composed("opponent=policy", f"opponent.path={tmp_path / 'nowhere'}"))
    with pytest.raises(FileNotFoundError, match="has no policy.pt"):
        checked(composed("opponent=policy", f"opponent.path={tmp_path}"))


# ---- policy.pt as a partner ---------------------------------------------------------------------------------------


def test_a_partner_from_the_other_domain_or_scenario_fails_before_compute(runs):
    with pytest.raises(PartnerMismatch, match="trained in the discrete domain .* this run is env=continuous"):
        checked(composed("env=continuous", "opponent=policy", f"opponent.path={runs['dqn']}"))
    with pytest.raises(PartnerMismatch, match=r"env.layout='sidewalk' \(this run: 'door'\)"):
        checked(composed("opponent=policy", f"opponent.path={runs['dqn']}", "env.layout=door", "env.n_agents=2"))
    with pytest.raises(PartnerMismatch, match=r"env.observation='image' \(this run: 'vector'\)"):
        checked(composed("opponent=policy", f"opponent.path={runs['dqn']}", "env.observation=vector"))
    # noise, rewards and the time limit may differ
    checked(composed("opponent=policy", f"opponent.path={runs['dqn']}", "noise=0.3", "reward=implicit"))


def test_policy_pt_describes_its_world(runs):
    partner = read_partner(runs["dqn"])
    assert (partner.algo_name, partner.world.domain, partner.world.opponent, partner.ego) == ("dqn", "discrete", "dijkstra", 0)
    assert partner.world.env_params.noise == 0.1
    assert read_partner(runs["centralized"]).ego is None


@pytest.mark.parametrize("name", ["dqn", "dqn_ego1", "centralized", "ppo"])
def test_a_loaded_partner_acts_as_the_runs_evaluation_policy(runs, name):
    """The partner playing the agent the run trained as gives the actions of the run's own evaluation policy on
    the same worlds, step after step."""
    run_dir = runs[name]
    experiment = load_experiment(run_dir)
    view = experiment.world.make(16, experiment.seed + EVAL_SEED_OFFSET, experiment.device)
    policy = load_policy(run_dir, experiment, view)
    core = view.core
    agent = experiment.world.ego if experiment.world.opponent != "centralized" else 0
    partner = PolicyOpponent(core, controlled=(agent,), ego=None, path=run_dir)
    td = view.reset()
    for _ in range(25):
        with torch.no_grad():
            td = policy(td)
        played = partner(core._last.clone() if hasattr(core, "_last") else view._last.clone())
        action = td.get("action")
        if experiment.world.opponent == "centralized":
            action = view.decode_action(action)[:, agent] if experiment.world.domain == "discrete" else action.view(16, -1, 2)[:, agent]
        assert torch.equal(played.get(("agents", "action"))[:, agent], action)
        td = view.step(td).get("next")


@pytest.mark.parametrize(
    ("core_cls", "params"),
    [(DiscreteSidewalkEnv, None), (DiscreteSidewalkEnv, {"observation": "vector"}), (ContinuousSidewalkEnv, None)],
)
def test_the_half_turn_shows_agent_1_what_agent_0_sees(core_cls, params):
    """In the sidewalk, agent 1's observation turned by half a turn is agent 0's (the starts mirror each other),
    so a learner trained as agent 0 can play agent 1; the door has no such symmetry."""
    core = core_cls(4, seed=0, **(params or {}))
    domain = "discrete" if core_cls is DiscreteSidewalkEnv else "continuous"
    assert role_map(domain, core.params, 0, 1) == "half_turn"
    observation = core.reset().get(("agents", "observation"))
    turned = turn_observation(observation[:, 1], core.layout)
    if domain == "continuous":  # headings compare modulo 2π
        gap = torch.remainder(turned - observation[:, 0] + math.pi, 2 * math.pi) - math.pi
        assert gap.abs().max() < 1e-5
    else:
        assert torch.equal(turned, observation[:, 0])
    door = DiscreteSidewalkEnv(2, seed=0, layout="door", n_agents=2).params
    assert role_map("discrete", door, 0, 1) is None


def test_a_single_agent_partner_cannot_play_a_role_without_symmetry(runs, tmp_path):
    """A DQN trained as agent 0 of the three-agent door (here: the sidewalk run's policy.pt relabelled) has no map
    onto agents 1 and 2: the door's roles differ."""
    state = torch.load(runs["dqn"] / "policy.pt", weights_only=True)
    state["description"]["world"]["env_params"].update(layout="door", n_agents=3)
    (tmp_path / "door").mkdir()
    torch.save(state, tmp_path / "door" / "policy.pt")
    door = ["env.layout=door", "env.n_agents=3"]
    with pytest.raises(PartnerMismatch, match="trained as agent 0 .* cannot play agent 1 in env.layout='door'"):
        checked(composed("opponent=policy", f"opponent.path={tmp_path / 'door'}", *door))


def test_a_learner_trains_against_a_learned_partner(runs, tmp_path):
    """opponent=policy end to end: DQN as agent 0 against the agent-0 DQN turned to play agent 1."""
    run = train(tmp_path / "vs_dqn", *TINY_DQN, "opponent=policy", f"opponent.path={runs['dqn']}")
    assert (run / "summary.json").exists() and (run / "policy.pt").exists()
    assert read_partner(run).world.opponent == "policy"


def test_policy_opponent_fills_only_its_agents(runs):
    core = DiscreteSidewalkEnv(8, seed=0)
    view = EgoView(core, opponent="policy", ego=1, opponent_kwargs={"path": str(runs["dqn"])})
    td = view.reset()
    td.set("action", torch.full((8,), 3))
    out = view._last.clone()
    out.set(("agents", "action"), torch.full((8, 2), 3))
    played = view.opponent(out)
    assert (played.get(("agents", "action"))[:, 1] == 3).all()
    assert played.get(("agents", "action")).shape == (8, 2)
    assert isinstance(view.opponent, PolicyOpponent)


@pytest.mark.parametrize(
    ("preset", "domain", "learners"),
    [("selfplay_discrete", "discrete", "iql,vdn,qmix,ippo,mappo"), ("selfplay_continuous", "continuous", "ippo,mappo")]
    + [(f"selfplay_{scenario}_{domain}", domain, "iql,vdn,qmix" if domain == "discrete" else "ippo,mappo")
       for scenario in ("door", "zipper", "circle", "teams") for domain in ("discrete", "continuous")],
)
def test_self_play_presets_sweep_every_learner_of_their_domain(preset, domain, learners):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"+experiment={preset}"], return_hydra_config=True)
        jobs = [compose(config_name="config", overrides=[f"+experiment={preset}", f"algo={name}"])
                for name in learners.split(",")]
    assert dict(cfg.hydra.sweeper.params) == {"algo": learners, "seed": "0,1,2"}
    for name, job in zip(learners.split(","), jobs):
        experiment = validate(job)
        assert (experiment.world.domain, experiment.world.opponent, experiment.algo.name) == (domain, "self", name)


def test_a_vector_partner_plays_in_an_image_world_on_the_vector_a_vector_world_shows(runs, tmp_path):
    import dataclasses

    vector_run = train(tmp_path / "vector", *TINY_DQN, "env.observation=vector")
    checked(composed("opponent=policy", f"opponent.path={vector_run}"))  # the default image world takes it
    vector_core = DiscreteSidewalkEnv(8, seed=0, params=dataclasses.replace(DiscreteSidewalkEnv(1).params,
                                                                            observation="vector"))
    td = vector_core.reset()
    for _ in range(4):  # the env's own vector observations are what observe_as computes from its output's state
        assert torch.equal(td.get(("agents", "observation")), vector_core.observe_as("vector", td))
        assert torch.equal(td.get(("agents", "observation"))[2:5], vector_core.observe_as("vector", td[2:5]))
        td = vector_core.step(td.set(("agents", "action"), torch.randint(0, 4, (8, 2)))).get("next")
    image_core = DiscreteSidewalkEnv(8, seed=0)
    in_image = PolicyOpponent(image_core, controlled=(1,), ego=0, path=vector_run)
    in_vector = PolicyOpponent(vector_core, controlled=(1,), ego=0, path=vector_run)
    image_td = image_core.reset()
    image_td.set(("agents", "action"), torch.zeros(8, 2, dtype=torch.long))
    seen = image_td.clone().set(("agents", "observation"), image_core.observe_as("vector", image_td))
    assert torch.equal(in_image(image_td).get(("agents", "action")), in_vector(seen).get(("agents", "action")))
    with pytest.raises(ValueError, match="'image'"):
        vector_core.observe_as("image", td)


def test_cross_play_pairs_an_image_row_with_a_vector_partner(runs, tmp_path):
    from sidewalk.crossplay import run_crossplay

    vector_run = train(tmp_path / "vector", *TINY_DQN, "env.observation=vector")
    frame = run_crossplay([runs["dqn"]], [str(vector_run)], episodes=8, noise=0.0, show_progress=False).frame
    assert (frame["skipped"] == "").all() and frame["episodes"].tolist() == [8]
