"""The learners benchmark runs end to end on a tiny budget (ours and each library once), its matched setup reads our
config, the SB3 policy acts in physical units, and a bad flag fails before any training naming the valid values."""

from __future__ import annotations

import importlib.util

import pytest
import torch

pytest.importorskip("stable_baselines3")

from sidewalk.bench import learners
from sidewalk.compose import compose_experiment
from sidewalk.experiment import collector_frames_per_batch

HAS_SB3_CONTRIB = importlib.util.find_spec("sb3_contrib") is not None


def _experiment(algo: str):
    return compose_experiment(learners.experiment_overrides(algo, "random", 0, 0.01, eval_episodes=4))


def test_section_end_to_end_on_a_tiny_budget(capsys):
    frames = 2 * collector_frames_per_batch(_experiment("trpo"))
    rows = learners.run(opponent="random", frames=frames, seeds=[0], setups=list(learners.SETUPS),
                        learners=["ours-trpo", "sb3-contrib-trpo", "sb3-ppo"], eval_episodes=4)
    assert all(tuple(row) == learners.COLUMNS for row in rows)
    kinds = [row["row"] for row in rows]
    runs = [row for row in rows if row["row"] == "run"]
    summaries = [row for row in rows if row["row"] == "summary"]
    expected = {("TRPO", "ours", "conf"), ("PPO", "sb3", "defaults"), ("PPO", "sb3", "matched")}
    if HAS_SB3_CONTRIB:
        expected |= {("TRPO", "sb3-contrib", "defaults"), ("TRPO", "sb3-contrib", "matched")}
    else:
        assert kinds.count("skipped") == 1
    assert {(r["algo"], r["learner"], r["setup"]) for r in runs} == expected
    assert {(r["algo"], r["learner"], r["setup"]) for r in summaries} == expected
    for row in runs + summaries:
        assert 0.0 <= row["success"] <= 1.0 and 0.0 <= row["team_success"] <= 1.0
        assert row["seconds"] > 0 and row["frames"] >= frames
    for row in summaries:
        assert row["success_min"] <= row["success"] <= row["success_max"]
    # Every learner trains the same budget: whole iterations of 1024 (TRPO) or 2048 (PPO) frames.
    assert {r["frames"] for r in runs} == {frames}
    differences = [row for row in rows if row["row"] == "ours − peer"]
    if HAS_SB3_CONTRIB:
        ours = next(r for r in summaries if r["learner"] == "ours")
        assert {r["setup"] for r in differences} == set(learners.SETUPS)
        for diff in differences:
            peer = next(r for r in summaries if r["learner"] == "sb3-contrib" and r["setup"] == diff["setup"])
            assert diff["success"] == pytest.approx(ours["success"] - peer["success"])
    else:
        assert differences == []  # no ours-ppo, no sb3-contrib: nothing to compare
    text = learners.format_rows(rows)
    assert "settings:" in text and "VecNormalize(norm_obs=True, norm_reward=False)" in text
    assert capsys.readouterr().err.count("learners: ") == len(runs)  # one progress line per finished run


def test_matched_setup_reads_our_config():
    for algo in ("trpo", "ppo"):
        experiment = _experiment(algo)
        settings, normalize = learners.matched_settings(experiment)
        cfg = experiment.algo
        assert settings["n_steps"] * experiment.num_envs == collector_frames_per_batch(experiment)
        assert (settings["gamma"], settings["gae_lambda"], settings["learning_rate"]) == (
            cfg.gamma, cfg.gae_lambda, cfg.lr)
        if algo == "trpo":
            assert settings["target_kl"] == cfg.max_kl and settings["n_critic_updates"] == cfg.vf_iters
            assert settings["policy_kwargs"]["net_arch"] == {"pi": cfg.policy_hidden, "vf": cfg.value_hidden}
        else:
            assert settings["n_epochs"] == cfg.epochs and settings["batch_size"] == cfg.minibatch_size
            assert settings["policy_kwargs"]["net_arch"] == {"pi": cfg.hidden, "vf": cfg.hidden}
        assert normalize is cfg.normalize_observations is True  # both of ours normalise vector observations
        defaults, default_normalize = learners.default_settings(experiment)
        assert defaults == {"n_steps": settings["n_steps"]} and default_normalize


def test_sb3_policy_acts_in_physical_units():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from sidewalk.bench.common import sb3_vec_env
    from sidewalk.interop.gymnasium import world_kwargs

    experiment = _experiment("ppo")
    envs = sb3_vec_env(learners.ENV_ID, 4, 0, **world_kwargs(experiment.world))
    assert (envs.action_space.low == -1).all() and (envs.action_space.high == 1).all()
    model = PPO("MlpPolicy", VecNormalize(envs, norm_reward=False), n_steps=8, batch_size=32, seed=0, device="cpu")
    view = experiment.world.make(4, 0, experiment.device)
    td = view.reset()
    action = learners.sb3_deterministic_policy(model, view)(td)["action"]
    high = torch.tensor([experiment.world.env_params.max_accel_mps2, experiment.world.env_params.max_turn_rad])
    raw, _ = model.predict(model.get_vec_normalize_env().normalize_obs(td["observation"].numpy()), deterministic=True)
    torch.testing.assert_close(action, torch.as_tensor(raw) * high)  # symmetric bounds: physical = raw × high
    assert action.shape == view.full_action_spec["action"].shape


def test_bad_flags_fail_before_training_naming_the_valid_values(capsys):
    with pytest.raises(SystemExit):
        learners.main(["--learners", "ours-trpo", "bogus"])
    err = capsys.readouterr().err
    assert "bogus" in err and all(name in err for name in learners.LEARNERS)
    with pytest.raises(ValueError, match="bogus.*ours-trpo.*sb3-contrib-trpo.*ours-ppo.*sb3-ppo"):
        learners.run(learners=["bogus"])
    with pytest.raises(SystemExit):
        learners.main(["--noise", "-1"])
    assert "noise=-1.0" in capsys.readouterr().err
