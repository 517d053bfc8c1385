"""One vectorised update for R replicas (sidewalk/algos/stacked.py) against the loop it replaces:
``with streams.use(r): algo.update(batch)`` for each replica r, on learners built twice from the same seeds.

No tolerances: linear layers run as batched matmuls where those round exactly as ``F.linear`` does (else per
replica), the autograd graph sums gradients in the loop's order, Adam on the stacks does each replica's arithmetic,
and the scalars a replica's decisions hinge on are computed per replica, so TRPO and PPO on vectors and images are
compared with ``torch.equal``: bit-identical parameters, buffers, Adam state, logs and random streams, at the default
sizes and at small ones (a Fisher-vector product on 13 rows, minibatches of a few rows, batches of odd lengths).
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector

from sidewalk.algos.base import Algorithm
from sidewalk.algos.ppo import PPO, PPOConfig
from sidewalk.algos.stacked import (
    NAIVE_BMM_BELOW,
    StackedAdam,
    StackedNetwork,
    StackedPPO,
    StackedTRPO,
    _runs_per_replica,
    _stacked_linear,
    batched_conjugate_gradient,
    clip_grad_norms_,
    vectorized_update,
)
from sidewalk.algos.trpo import TRPO, TRPOConfig, conjugate_gradient
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.streams import ReplicaStreams
from sidewalk.views import make_view

torch.set_num_threads(1)  # small networks on a 2-core machine: threads only contend

CORES = {"continuous": ContinuousSidewalkEnv, "discrete": DiscreteSidewalkEnv}  # vectors + TanhNormal, images + Categorical
LEARNERS = {"trpo": (TRPO, TRPOConfig), "ppo": (PPO, PPOConfig)}
# Small but complete: several value-fit / PPO minibatches, a short batch of images.
SETTINGS = {
    ("trpo", "continuous"): {"frames_per_batch": 512, "vf_batch_size": 128},
    ("trpo", "discrete"): {"frames_per_batch": 128, "vf_batch_size": 32},
    ("ppo", "continuous"): {"frames_per_batch": 256, "epochs": 2},
    ("ppo", "discrete"): {"frames_per_batch": 128, "epochs": 2, "minibatch_size": 32},
}
UPDATES = 3


def replicas(learner: str, domain: str, seeds, *, num_envs: int = 16, noise: float = 0.0, **config
             ) -> tuple[list[Algorithm], list]:
    """One learner per seed (its own world and initial networks) and its envs; the same seeds give the same set."""
    cls, config_cls = LEARNERS[learner]
    algos, envs = [], []
    for seed in seeds:
        env = make_view("ego", CORES[domain](num_envs=num_envs, seed=seed, noise=noise), opponent="random")
        torch.manual_seed(100 + seed)
        algos.append(cls(config_cls(**config), env))
        envs.append(env)
    return algos, envs


def collect_batches(algos, envs, count: int = UPDATES) -> list[list]:
    """``count`` collector batches per replica, by its initial policy: batches[u][r]."""
    per_replica = []
    for algo, env in zip(algos, envs):
        collector = Collector(env, algo.collection_policy(), frames_per_batch=algo.config.frames_per_batch,
                              total_frames=-1, auto_register_policy_transforms=False)
        batches = iter(collector)
        per_replica.append([next(batches).clone() for _ in range(count)])
        collector.shutdown()
    return [list(update) for update in zip(*per_replica)]


def state(algo: Algorithm) -> dict[str, torch.Tensor]:
    """Every tensor of a learner's checkpoint: parameters, buffers and optimiser state."""
    saved = algo.state_dict()
    tensors = dict(TensorDict(saved["modules"]).flatten_keys().items())
    for name, optimizer in saved["optimizers"].items():
        for index, entries in optimizer["state"].items():
            tensors.update({f"{name}.{index}.{key}": value for key, value in entries.items()})
    return tensors


def max_difference(a: Algorithm, b: Algorithm) -> float:
    first, second = state(a), state(b)
    assert first.keys() == second.keys()
    return max((first[key].double() - second[key].double()).abs().max().item() for key in first)


def identical(a: Algorithm, b: Algorithm) -> bool:
    first, second = state(a), state(b)
    return first.keys() == second.keys() and all(torch.equal(first[key], second[key]) for key in first)


def run_loop(algos, batches, streams) -> list[list[dict[str, float]]]:
    logs = []
    for update in batches:
        row = []
        for replica, (algo, batch) in enumerate(zip(algos, update)):
            with streams.use(replica):
                row.append(algo.update(batch.clone()))
        logs.append(row)
    return logs


def run_stacked(algos, batches, streams) -> list[list[dict[str, float]]]:
    updater = vectorized_update(algos)
    assert updater is not None
    return [updater.update([batch.clone() for batch in update], streams) for update in batches]


def loop_and_stacked(learner: str, domain: str, seeds=(0, 1, 2), updates: int = UPDATES, **config):
    """The loop and the stacked update on two identical sets of learners and the same batches (``config``: the
    learner's settings over ``SETTINGS``, and the envs' ``num_envs`` and ``noise``)."""
    config = {**SETTINGS[learner, domain], **config}
    (looped, envs), (stacked, _) = replicas(learner, domain, seeds, **config), replicas(learner, domain, seeds, **config)
    batches = collect_batches(looped, envs, updates)
    loop_streams, stacked_streams = ReplicaStreams(seeds), ReplicaStreams(seeds)
    loop_logs = run_loop(looped, batches, loop_streams)
    stacked_logs = run_stacked(stacked, batches, stacked_streams)
    return looped, stacked, loop_logs, stacked_logs, loop_streams, stacked_streams


def assert_the_loop(learner: str, domain: str, updates: int = UPDATES, **config) -> None:
    """The stacked update is bit for bit the loop: every learner's tensors, every log, every stream's draws."""
    looped, stacked, loop_logs, stacked_logs, loop_streams, stacked_streams = loop_and_stacked(
        learner, domain, updates=updates, **config)
    for loop_algo, stacked_algo in zip(looped, stacked):
        assert stacked_algo.frames_seen == loop_algo.frames_seen == updates * loop_algo.config.frames_per_batch
        assert state(stacked_algo).keys() == state(loop_algo).keys()  # Adam state created for every parameter
        assert identical(stacked_algo, loop_algo), max_difference(stacked_algo, loop_algo)
    for loop_row, stacked_row in zip(loop_logs, stacked_logs):
        for loop_replica, stacked_replica in zip(loop_row, stacked_row):
            assert list(stacked_replica) == list(loop_replica)
            assert stacked_replica == loop_replica
    for loop_state, stacked_state in zip(loop_streams.state_dict(), stacked_streams.state_dict()):
        assert torch.equal(loop_state["torch"], stacked_state["torch"])  # the same draws from each stream


@pytest.mark.parametrize("learner, domain", [
    ("trpo", "continuous"), ("ppo", "continuous"), ("ppo", "discrete"), ("trpo", "discrete"),
])
def test_stacked_update_is_the_loop(learner, domain):
    assert_the_loop(learner, domain)


# Small sizes, where a matmul or an elementwise kernel can take another path than at the defaults: 8 noisy worlds ×
# 8 steps (TRPO's Fisher-vector products on 64 / 5 → 13 rows, value minibatches of 16; PPO's minibatches of 32), then
# odd lengths (a Fisher-vector product on 8 rows, value minibatches of 4 and a last one of 3, PPO minibatches of 5
# and a last one of 4: a replica's elements short of whole vector steps, matmuls under ATen's naive threshold and
# tiny layers), with the sampled entropy bonus; 4 updates, the statistics and Adam moving between them.
SMALL = {
    "trpo-64": ("trpo", "continuous", {"num_envs": 8, "noise": 0.5, "frames_per_batch": 64, "vf_batch_size": 16}),
    "ppo-64": ("ppo", "continuous", {"num_envs": 8, "noise": 0.5, "frames_per_batch": 64, "minibatch_size": 32}),
    "trpo-odd": ("trpo", "continuous", {"num_envs": 3, "noise": 0.5, "frames_per_batch": 15, "vf_batch_size": 4,
                                        "fvp_subsample": 2, "policy_hidden": [7, 5], "value_hidden": [3]}),
    "ppo-odd": ("ppo", "continuous", {"num_envs": 1, "noise": 0.5, "frames_per_batch": 9, "minibatch_size": 5,
                                      "epochs": 2, "entropy_coef": 0.01}),
    "ppo-odd-images": ("ppo", "discrete", {"num_envs": 2, "frames_per_batch": 10, "minibatch_size": 7, "epochs": 2,
                                           "entropy_coef": 0.01}),
    "trpo-odd-images": ("trpo", "discrete", {"num_envs": 2, "frames_per_batch": 14, "vf_batch_size": 5,
                                             "fvp_subsample": 2}),
}


@pytest.mark.parametrize("case", list(SMALL))
def test_stacked_update_is_the_loop_at_small_sizes(case):
    learner, domain, config = SMALL[case]
    assert_the_loop(learner, domain, updates=4, **config)


@pytest.mark.parametrize("config", [{"max_kl": 1.0, "line_search_steps": 3}, {"max_kl": 5.0, "line_search_steps": 1}])
def test_each_trpo_replica_keeps_its_own_line_search_fraction(config):
    """Replicas accept different fractions of their steps, or none: each keeps the first that qualifies for it."""
    looped, stacked, loop_logs, stacked_logs, _, _ = loop_and_stacked("trpo", "continuous", **config)
    fractions = [replica["step_fraction"] for row in loop_logs for replica in row]
    assert len(set(fractions)) > 1, fractions  # the case under test happens
    assert stacked_logs == loop_logs
    assert all(identical(a, b) for a, b in zip(stacked, looped))


def test_trpo_value_gradient_clipping_per_replica():
    looped, stacked, loop_logs, stacked_logs, _, _ = loop_and_stacked("trpo", "continuous", max_grad_norm=0.05)
    assert stacked_logs == loop_logs
    assert all(identical(a, b) for a, b in zip(stacked, looped))


@pytest.mark.parametrize("learner, domain", [
    ("trpo", "continuous"), ("ppo", "continuous"), ("trpo", "discrete"), ("ppo", "discrete"),
])
def test_a_replica_computes_the_same_alone_as_in_a_group(learner, domain):
    """Replica seed 1 stacked alone and stacked with seeds 0 and 2: bit-identical (images included)."""
    (group, envs), (alone, _) = replicas(learner, domain, (0, 1, 2), **SETTINGS[learner, domain]), replicas(
        learner, domain, (1,), **SETTINGS[learner, domain])
    batches = collect_batches(group, envs)
    group_logs = run_stacked(group, batches, ReplicaStreams((0, 1, 2)))
    alone_logs = run_stacked(alone, [[update[1]] for update in batches], ReplicaStreams((1,)))
    assert identical(group[1], alone[0])
    assert [row[1] for row in group_logs] == [row[0] for row in alone_logs]


def test_only_trpo_and_ppo_groups_of_one_config_are_stacked():
    (trpo, _), (ppo, _) = replicas("trpo", "continuous", (0, 1)), replicas("ppo", "continuous", (0, 1))
    assert isinstance(vectorized_update(trpo), StackedTRPO)
    assert isinstance(vectorized_update(ppo), StackedPPO)
    assert vectorized_update([]) is None
    assert vectorized_update([trpo[0], ppo[0]]) is None
    (other_lr, _) = replicas("trpo", "continuous", (2,), lr=1e-4)
    assert vectorized_update([trpo[0], other_lr[0]]) is None

    class Custom(PPO):  # no name: a subclass the stacked update knows nothing about
        pass

    env = make_view("ego", ContinuousSidewalkEnv(num_envs=4, seed=0), opponent="random")
    assert vectorized_update([Custom(PPOConfig(), env), Custom(PPOConfig(), env)]) is None


@pytest.mark.parametrize("domain, entropy_coef", [("continuous", 0.0), ("continuous", 0.05), ("discrete", 0.05)])
def test_ppo_losses_are_torchrls_clip_ppo_loss(domain, entropy_coef):
    """The objective, entropy and critic terms written out in StackedPPO equal ClipPPOLoss's on the same minibatch,
    the sampled entropy (TanhNormal) from the same draw."""
    (algos, envs) = replicas("ppo", domain, (0,), entropy_coef=entropy_coef, **SETTINGS["ppo", domain])
    algo = algos[0]
    batch = collect_batches(algos, envs, 1)[0][0]
    with torch.no_grad():
        algo.advantage(batch)
    flat = batch.reshape(-1)[:48]
    with torch.no_grad():
        flat.set("action_log_prob", algo.actor.get_dist(flat.copy()).log_prob(flat["action"]) - 0.1)  # ratios ≠ 1
    updater = vectorized_update(algos)
    updater.policy, updater.keys = updater._policy()
    updater.value = StackedNetwork([algo.critic.module])
    inputs = {key: flat[key].unsqueeze(0) for key in ("action", "advantage", "value_target", "action_log_prob")}
    inputs["policy_features"] = updater.policy.features(flat["observation"].unsqueeze(0))
    inputs["value_features"] = updater.value.features(flat["observation"].unsqueeze(0))
    generator_state = torch.get_rng_state()
    expected = algo.loss(flat.copy())
    noise = None
    if domain == "continuous":  # the draw ClipPPOLoss made for its entropy estimate
        torch.set_rng_state(generator_state)
        noise = torch.empty(1, 1, 48, 2).normal_()
    losses = updater._losses(inputs, updater.policy.params, updater.value.params, noise)
    for key, value in losses.items():
        assert torch.equal(value[0], expected[key]), key


def test_batched_conjugate_gradient_stops_each_row_where_the_loop_does():
    torch.manual_seed(0)
    size = 6
    basis = torch.randn(3, size, size)
    matrices = basis @ basis.transpose(1, 2) + 0.1 * torch.eye(size)
    matrices[1] = torch.eye(size)  # exact after one iteration: its residual reaches 0 and it stops
    b = torch.randn(3, size)
    b[2] = 0.0  # starts converged

    def matvec(vectors):
        return torch.stack([matrix @ vector for matrix, vector in zip(matrices, vectors)])

    solved = batched_conjugate_gradient(matvec, b, iters=10)
    for row in range(3):
        assert torch.equal(solved[row], conjugate_gradient(lambda v, m=matrices[row]: m @ v, b[row], iters=10))


def test_stacked_adam_and_clipping_are_each_replicas_own():
    """Replicas at different Adam step counts (one fresh) and gradients clipped by each replica's own norm."""
    torch.manual_seed(0)
    nets = [torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Tanh(), torch.nn.Linear(4, 2)) for _ in range(2)]
    optimizers = [torch.optim.Adam(net.parameters(), lr=1e-2, foreach=True) for net in nets]
    for _ in range(2):  # replica 0 has taken two steps, replica 1 none
        nets[0](torch.randn(5, 3)).square().mean().backward()
        optimizers[0].step()
        optimizers[0].zero_grad()
    stacked = StackedNetwork(nets)
    leaves = [stacked.params[name].requires_grad_(True) for name in stacked.names]
    adam = StackedAdam(optimizers, leaves, [list(net.parameters()) for net in nets])
    x = torch.randn(2, 5, 3)
    grads = list(torch.autograd.grad(stacked(x, dict(zip(stacked.names, leaves))).square().sum(), leaves))
    clip_grad_norms_(grads, 0.1)
    adam.step(grads)
    for replica, (net, optimizer) in enumerate(zip(nets, optimizers)):
        net(x[replica]).square().sum().backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 0.1)
        optimizer.step()
        for index, (name, param) in enumerate(net.named_parameters()):
            assert torch.equal(param, stacked.params[name][replica].detach()), name
            assert torch.equal(optimizer.state[param]["exp_avg"], adam.exp_avg[index][replica])
            assert torch.equal(optimizer.state[param]["exp_avg_sq"], adam.exp_avg_sq[index][replica])
            assert float(optimizer.state[param]["step"]) == adam.steps[replica][index] == (3, 1)[replica]


def test_stacked_linear_is_f_linear_for_any_shape():
    """The batched-or-per-replica choice (``_runs_per_replica``) against ``F.linear`` per replica, forward and
    backward, on random shapes from tiny (ATen's naive batched loop, widths of 1) to past its threshold."""
    generator = torch.Generator().manual_seed(0)

    def draw(*shape):
        return torch.randn(*shape, generator=generator)

    shapes = [(1, 1, 1), (1, 16, 64), (5, 1, 64), (13, 64, 1), (13, 32, 2), (4, 32, 2), (13, 16, 32), (7, 3, 5)]
    shapes += [tuple(int(size) for size in torch.randint(1, 70, (3,), generator=generator)) for _ in range(40)]
    assert any(not _runs_per_replica(torch.empty(1, out, inp), rows) for rows, inp, out in shapes)
    assert any(rows * inp * out < NAIVE_BMM_BELOW for rows, inp, out in shapes)
    for rows, inp, out in shapes:
        for with_bias in (True, False):
            weight, x = draw(3, out, inp).requires_grad_(), draw(3, rows, inp).requires_grad_()
            bias = draw(3, out).requires_grad_() if with_bias else None
            y = _stacked_linear(weight, bias, x)
            upstream = draw(*y.shape)
            leaves = [weight, x] + ([bias] if with_bias else [])
            grads = torch.autograd.grad(y, leaves, upstream)
            for replica in range(3):
                own = [leaf[replica].detach().clone().requires_grad_() for leaf in leaves]
                expected = torch.nn.functional.linear(own[1], own[0], own[2] if with_bias else None)
                assert torch.equal(y[replica], expected), (rows, inp, out)
                expected_grads = torch.autograd.grad(expected, own, upstream[replica])
                for grad, expected_grad in zip(grads, expected_grads):
                    assert torch.equal(grad[replica], expected_grad), (rows, inp, out)


@pytest.mark.parametrize("rows", [3, 13, 64])
def test_stacked_fisher_vector_products_are_each_replicas_own(rows):
    """A Hessian-vector product (a double backward, as TRPO's Fisher-vector products) through a stacked tanh MLP
    equals each replica's own: batched and per-replica layers alike hand each tanh output its gradients in the
    loop's order."""
    torch.manual_seed(0)
    nets = [torch.nn.Sequential(torch.nn.Linear(16, 32), torch.nn.Tanh(), torch.nn.Linear(32, 32), torch.nn.Tanh(),
                                torch.nn.Linear(32, 2)) for _ in range(3)]
    stacked = StackedNetwork(nets)
    params = {name: tensor.requires_grad_(True) for name, tensor in stacked.params.items()}
    x, target = torch.randn(3, rows, 16), torch.randn(3, rows, 2)
    vector = torch.randn(3, sum(param.numel() for param in nets[0].parameters()))
    loss = (stacked(x, params) - target).square().sum()
    first = stacked.flatten(torch.autograd.grad(loss, list(params.values()), create_graph=True))
    product = stacked.flatten(torch.autograd.grad((first * vector).sum(), list(params.values())))
    for replica, net in enumerate(nets):
        own = list(net.parameters())
        own_first = torch.autograd.grad((net(x[replica]) - target[replica]).square().sum(), own, create_graph=True)
        own_first = torch.cat([grad.reshape(-1) for grad in own_first])
        expected = torch.autograd.grad(own_first @ vector[replica], own)
        assert torch.equal(product[replica], torch.cat([grad.reshape(-1) for grad in expected]))
