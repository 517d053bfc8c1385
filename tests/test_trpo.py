"""TRPO (sidewalk/algos/trpo.py): conjugate gradient, Fisher-vector products, the trust region, policies, learning."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, check_env_specs, set_exploration_type

from sidewalk.algos.trpo import TRPO, TRPOConfig, TRPOLoss, conjugate_gradient, trpo_step

torch.set_num_threads(1)  # small networks on a 2-core machine: threads only contend


class LineWalk(EnvBase):
    """A batched 1-D walk from 0 towards ``length`` within ``max_steps``: +1 on arrival, -0.01 a step.

    Actions: Categorical(2) (0 left, 1 right: ±1) or, with ``continuous``, a Bounded move in [-1, 1]. The
    observation is the position (a 1-vector) or, with ``image``, a uint8 (1, 16, 16) image with the position's
    column lit. A random policy arrives in about one episode in five (±1 moves) or fewer (continuous moves);
    heading right always arrives.
    """

    def __init__(
        self,
        num_envs: int = 8,
        continuous: bool = False,
        image: bool = False,
        length: int = 8,
        max_steps: int = 30,
    ) -> None:
        super().__init__(batch_size=torch.Size([num_envs]))
        self.continuous, self.image, self.length, self.max_steps = continuous, image, length, max_steps
        shape = (num_envs,)
        observation = (
            Bounded(0, 255, shape=(*shape, 1, 16, 16), dtype=torch.uint8)
            if image
            else Unbounded(shape=(*shape, 1))
        )
        self.observation_spec = Composite(observation=observation, shape=shape)
        if continuous:
            self.action_spec = Bounded(-torch.ones(*shape, 1), torch.ones(*shape, 1), shape=(*shape, 1))
        else:
            self.action_spec = Categorical(2, shape=shape)
        self.reward_spec = Unbounded(shape=(*shape, 1))
        flag = Categorical(2, shape=(*shape, 1), dtype=torch.bool)
        self.done_spec = Composite(done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=shape)
        self.position = torch.zeros(num_envs)
        self.steps = torch.zeros(num_envs, dtype=torch.long)

    def _observe(self) -> torch.Tensor:
        if not self.image:
            return self.position[:, None].clone()
        image = torch.zeros(self.batch_size[0], 1, 16, 16, dtype=torch.uint8)
        image[torch.arange(self.batch_size[0]), 0, :, self.position.round().long().clamp(0, 15)] = 255
        return image

    def _reset(self, tensordict):
        reset = None if tensordict is None else tensordict.get("_reset", None)
        rows = torch.ones(self.batch_size, dtype=torch.bool) if reset is None else reset.reshape(-1)
        self.position[rows] = 0.0
        self.steps[rows] = 0
        false = torch.zeros(*self.batch_size, 1, dtype=torch.bool)
        return TensorDict(
            observation=self._observe(),
            done=false,
            terminated=false.clone(),
            truncated=false.clone(),
            batch_size=self.batch_size,
        )

    def _step(self, tensordict):
        action = tensordict["action"]
        move = action.reshape(-1) if self.continuous else action.float() * 2 - 1
        self.position = (self.position + move).clamp_min(0.0)
        self.steps += 1
        arrived = self.position >= self.length
        truncated = (self.steps >= self.max_steps) & ~arrived
        return TensorDict(
            observation=self._observe(),
            reward=(arrived.float() - 0.01)[:, None],
            done=(arrived | truncated)[:, None],
            terminated=arrived[:, None],
            truncated=truncated[:, None],
            batch_size=self.batch_size,
        )

    def _set_seed(self, seed):  # deterministic dynamics
        pass


ACTIONS = {"discrete": {"continuous": False}, "continuous": {"continuous": True}}


def make(kind: str = "discrete", num_envs: int = 8, image: bool = False, seed: int = 0, **config):
    torch.manual_seed(seed)
    env = LineWalk(num_envs, image=image, **ACTIONS[kind])
    return env, TRPO(TRPOConfig(**config), env)


def collect(env: EnvBase, algo: TRPO, frames: int):
    collector = Collector(
        env,
        algo.collection_policy(),
        frames_per_batch=frames,
        total_frames=frames,
        auto_register_policy_transforms=False,
    )
    batch = next(iter(collector))
    collector.shutdown()
    return batch


def prepared(algo: TRPO, batch):
    """The flat, snapshotted batch that ``TRPO.update`` hands to ``trpo_step``."""
    batch = batch.clone()
    with torch.no_grad():
        algo.advantage(batch)
    flat = batch.reshape(-1)
    advantage = flat["advantage"]
    flat["advantage"] = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
    return algo.loss.snapshot(flat)


def policy_vector(algo: TRPO) -> torch.Tensor:
    return torch.nn.utils.parameters_to_vector(algo.loss.policy_parameters).detach().clone()


# ---- config -----------------------------------------------------------------------------------------------------


def test_config_defaults_are_baselines_mujoco_preset_but_the_batch():
    cfg = TRPOConfig()
    assert (cfg.policy_hidden, cfg.max_kl, cfg.cg_iters, cfg.cg_damping) == ([32, 32], 0.01, 10, 0.1)
    assert (cfg.gamma, cfg.gae_lambda, cfg.vf_iters, cfg.lr) == (0.99, 0.98, 5, 1e-3)
    assert (cfg.entropy_coef, cfg.line_search_steps, cfg.line_search_shrink) == (0.0, 10, 0.5)
    # The stated deviations (TRPOConfig): twice baselines' 1024 frames an iteration, and value minibatches twice
    # its 64, so an epoch of the value fit still takes baselines' 16 Adam steps.
    assert (cfg.frames_per_batch, cfg.vf_batch_size) == (2048, 128)
    assert cfg.frames_per_batch // cfg.vf_batch_size == 1024 // 64


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("max_kl", 0.0, r"algo\.max_kl=0\.0 is out of range; valid: \(0\.0, \+inf\)"),
        ("gae_lambda", 1.5, r"algo\.gae_lambda=1\.5 .*\[0\.0, 1\.0\]"),
        ("line_search_shrink", 0.0, r"algo\.line_search_shrink=0\.0 .*\(0\.0, 1\.0\]"),
        ("cg_iters", 0, r"algo\.cg_iters=0 .*\[1, \+inf\)"),
        ("policy_hidden", [32, 0], r"algo\.policy_hidden\[1\]=0"),
    ],
)
def test_config_rejects_out_of_range_values(field, value, message):
    with pytest.raises(ValueError, match=message):
        TRPOConfig(**{field: value})


def test_config_rejects_wrong_types():
    with pytest.raises(TypeError, match="algo.normalize_observations"):
        TRPOConfig(normalize_observations="yes")
    with pytest.raises(TypeError, match="algo.vf_iters"):
        TRPOConfig(vf_iters=2.5)


# ---- the pieces of the step --------------------------------------------------------------------------------


def test_conjugate_gradient_solves_spd_system():
    generator = torch.Generator().manual_seed(0)
    m = torch.randn(8, 8, generator=generator, dtype=torch.float64)
    matrix = m @ m.T + 0.5 * torch.eye(8, dtype=torch.float64)
    b = torch.randn(8, generator=generator, dtype=torch.float64)
    x = conjugate_gradient(lambda v: matrix @ v, b, iters=8)
    torch.testing.assert_close(x, torch.linalg.solve(matrix, b), rtol=1e-8, atol=1e-8)
    # Fewer iterations than dimensions still descend: the residual shrinks.
    x3 = conjugate_gradient(lambda v: matrix @ v, b, iters=3)
    assert (matrix @ x3 - b).norm() < b.norm()


@pytest.mark.parametrize("kind", ACTIONS)
def test_fisher_vector_product_is_the_kl_hessian(kind):
    _, algo = make(kind, num_envs=4, policy_hidden=[5], normalize_observations=False, cg_damping=0.0)
    batch = torch.randn(6, 1)
    td = TensorDict(observation=batch, batch_size=[6])
    with set_exploration_type(ExplorationType.RANDOM):
        algo.actor(td)
    td["advantage"] = torch.randn(6, 1)
    algo.loss.snapshot(td)
    # Move away from the snapshot so the Hessian is taken at a generic point, not only where KL = 0.
    with torch.no_grad():
        for param in algo.loss.policy_parameters:
            param.add_(0.3 * torch.randn_like(param))

    params = algo.loss.policy_parameters
    names = [name for name, p in algo.actor.named_parameters() if any(p is q for q in params)]
    shapes = [p.shape for p in params]
    theta = torch.nn.utils.parameters_to_vector(params).detach()

    class KL(torch.nn.Module):
        def __init__(self, loss: TRPOLoss) -> None:
            super().__init__()
            self.loss = loss

        def forward(self, tensordict):
            return self.loss.kl(tensordict)

    kl_module = KL(algo.loss)

    def kl_of(flat: torch.Tensor) -> torch.Tensor:
        chunks = flat.split([s.numel() for s in shapes])
        named = {f"loss.actor_network.{n}": c.reshape(s) for n, c, s in zip(names, chunks, shapes)}
        return torch.func.functional_call(kl_module, named, (td,))

    hessian = torch.autograd.functional.hessian(kl_of, theta)
    fisher = algo.loss.fisher_operator(td)
    for _ in range(3):
        vector = torch.randn_like(theta)
        torch.testing.assert_close(fisher(vector), hessian @ vector, rtol=1e-4, atol=1e-5)


def test_fisher_vector_product_adds_damping():
    env, algo = make("continuous", num_envs=4, cg_damping=0.25)
    td = prepared(algo, collect(env, algo, 64))
    fisher = algo.loss.fisher_operator(td)
    algo.loss.cg_damping = 0.0
    undamped = algo.loss.fisher_operator(td)
    vector = torch.randn(policy_vector(algo).numel())
    torch.testing.assert_close(fisher(vector), undamped(vector) + 0.25 * vector)


# ---- the trust region --------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ACTIONS)
@pytest.mark.parametrize("max_kl", [0.01, 0.001])
def test_accepted_step_stays_in_trust_region_and_improves(kind, max_kl):
    env, algo = make(kind, num_envs=8)
    td = prepared(algo, collect(env, algo, 8 * 40))
    before = algo.loss(td)
    assert before["kl"].item() == pytest.approx(0.0, abs=1e-6)  # the snapshot is the current policy
    logs = trpo_step(
        algo.loss,
        td,
        max_kl=max_kl,
        cg_iters=10,
        line_search_steps=10,
        line_search_shrink=0.5,
        fvp_subsample=5,
    )
    assert logs["step_accepted"] == 1.0
    with torch.no_grad():
        after = algo.loss(td)
    measured_kl = after["kl"].item()
    improvement = before["loss_objective"].item() - after["loss_objective"].item()
    assert 0.0 < measured_kl <= max_kl * (1 + 1e-5)
    assert improvement > 0.0
    assert logs["kl"] == pytest.approx(measured_kl, rel=1e-5)
    assert logs["surrogate_improvement"] == pytest.approx(improvement, rel=1e-4)


class InflatedKLLoss(TRPOLoss):
    """Reports every candidate as outside the trust region, so the line search must reject all of them."""

    def forward(self, tensordict):
        out = super().forward(tensordict)
        out["kl"] = out["kl"] + 1.0
        return out


@pytest.mark.parametrize("kind", ACTIONS)
def test_rejected_step_leaves_parameters_unchanged(kind):
    env, algo = make(kind, num_envs=8)
    td = prepared(algo, collect(env, algo, 8 * 40))
    loss = InflatedKLLoss(algo.actor, cg_damping=0.1)
    theta = policy_vector(algo)
    logs = trpo_step(loss, td, max_kl=0.01, cg_iters=10, line_search_steps=4, line_search_shrink=0.5)
    assert logs["step_accepted"] == 0.0 and logs["kl"] == 0.0 and logs["surrogate_improvement"] == 0.0
    assert torch.equal(policy_vector(algo), theta)


def test_zero_advantage_means_no_step():
    env, algo = make("discrete", num_envs=4)
    td = prepared(algo, collect(env, algo, 64))
    td["advantage"] = torch.zeros_like(td["advantage"])
    theta = policy_vector(algo)
    logs = trpo_step(algo.loss, td, max_kl=0.01, cg_iters=10, line_search_steps=10, line_search_shrink=0.5)
    assert logs["step_accepted"] == 0.0
    assert torch.equal(policy_vector(algo), theta)


# ---- the algorithm -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind, image", [("discrete", False), ("continuous", False), ("discrete", True)])
def test_update_on_collector_batch(kind, image):
    env, algo = make(kind, num_envs=4, image=image, vf_iters=2)
    check_env_specs(env)
    batch = collect(env, algo, 4 * 40)
    assert batch.shape == (4, 40)
    value_before = copy.deepcopy(algo.value.state_dict())
    logs = algo.update(batch)
    expected = {
        "kl",
        "surrogate_improvement",
        "expected_improvement",
        "step_accepted",
        "step_fraction",
        "entropy",
        "value_loss",
        "explained_variance",
    }
    assert expected <= logs.keys() and all(isinstance(v, float) for v in logs.values())
    assert logs["kl"] <= algo.config.max_kl * (1 + 1e-5)
    assert algo.frames_seen == 160
    assert any(not torch.equal(value_before[k], v) for k, v in algo.value.state_dict().items())


def test_update_on_single_env_time_batch():
    """A (T,) batch, as a collector returns for an env without batch dimensions, is one trajectory in time."""
    env, algo = make("continuous", num_envs=1)
    batch = collect(env, algo, 60)[0]
    assert batch.shape == (60,)
    logs = algo.update(batch)
    assert logs["kl"] <= algo.config.max_kl * (1 + 1e-5)


@pytest.mark.parametrize("kind", ACTIONS)
def test_policies_sample_and_act_deterministically_whatever_the_context(kind):
    env, algo = make(kind, num_envs=64)
    td = env.reset()
    for context in (ExplorationType.RANDOM, ExplorationType.DETERMINISTIC):
        with set_exploration_type(context):
            greedy = [algo.evaluation_policy()(td.clone())["action"] for _ in range(2)]
            sampled = [algo.collection_policy()(td.clone())["action"] for _ in range(2)]
        assert torch.equal(greedy[0], greedy[1])
        assert not torch.equal(sampled[0], sampled[1])
        spec = env.full_action_spec["action"]
        assert all(spec.is_in(action) for action in greedy + sampled)


def test_checkpoint_round_trip_restores_policy_value_and_normaliser():
    env, algo = make("continuous", num_envs=4)
    algo.update(collect(env, algo, 4 * 30))
    state = algo.state_dict()
    other = make("continuous", num_envs=4, seed=1)[1]
    other.load_state_dict(state)
    td = env.reset()
    torch.testing.assert_close(
        other.evaluation_policy()(td.clone())["action"], algo.evaluation_policy()(td.clone())["action"]
    )
    torch.testing.assert_close(other.value(td.clone())["state_value"], algo.value(td.clone())["state_value"])
    assert other.frames_seen == algo.frames_seen == 120
    assert other.obs_norm.count.item() == algo.obs_norm.count.item() == 120


# ---- learning ----------------------------------------------------------------------------------------------


def success_rate(env: EnvBase, policy) -> float:
    with torch.no_grad():
        rollout = env.rollout(env.max_steps, policy, break_when_any_done=False)
    done = rollout["next", "done"].squeeze(-1)
    first_end = done & done.long().cumsum(-1).eq(1)
    return rollout["next", "terminated"].squeeze(-1)[first_end].float().mean().item()


@pytest.mark.slow
@pytest.mark.parametrize("kind", ACTIONS)
def test_trpo_learns_to_walk_to_the_goal(kind):
    env, algo = make(kind, num_envs=16, seed=0, frames_per_batch=16 * 30)
    random_success = success_rate(env, algo.collection_policy())
    collector = Collector(
        env,
        algo.collection_policy(),
        frames_per_batch=16 * 30,
        total_frames=16 * 30 * 25,
        auto_register_policy_transforms=False,
    )
    for batch in collector:
        algo.update(batch)
    collector.shutdown()
    assert random_success < 0.6
    assert success_rate(env, algo.evaluation_policy()) == 1.0
    assert success_rate(env, algo.collection_policy()) > max(0.8, random_success + 0.3)


@pytest.mark.parametrize("domain", ["discrete", "continuous"])
def test_update_on_sidewalk_ego_view(domain):
    """The Sidewalk's own single-agent view: grid images with Categorical(4) moves, unicycle vectors with
    Bounded (acceleration, turn)."""
    views = pytest.importorskip("sidewalk.views")
    from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv

    core = {"discrete": DiscreteSidewalkEnv, "continuous": ContinuousSidewalkEnv}[domain](num_envs=4, seed=0)
    env = views.make_view("ego", core, opponent="random")
    algo = TRPO(TRPOConfig(frames_per_batch=4 * 32, vf_iters=1), env)
    assert (algo.obs_norm is None) == (domain == "discrete")  # images skip the running normaliser
    logs = algo.update(collect(env, algo, 4 * 32))
    assert logs["kl"] <= algo.config.max_kl * (1 + 1e-5)
    action = algo.evaluation_policy()(env.reset())["action"]
    assert env.full_action_spec["action"].is_in(action)
