"""Training frames/s of our IPPO self-play on the continuous sidewalk beside TorchRL's own MAPPO/IPPO example on VMAS
``navigation``, at 4096 worlds and two agents, with the same networks, batch, epochs and minibatches.

    python runners/bench.py multiagent                          # 4096 worlds, 1 and 2 threads
    python runners/bench.py multiagent --num-envs 1024 --threads 1 --ma-iterations 5
    python -m sidewalk.bench.multiagent --num-envs 64 --ma-steps 2 --ma-iterations 1 --ma-warmup 0

Ours is ``algo=ippo opponent=self env=continuous`` as ``runners/main.py`` builds it (``sidewalk.experiment``: the
experiment composed from ``conf/``, so IPPO's defaults are read at run time; ``SelfPlayView`` over
``ContinuousSidewalkEnv`` with ``RewardSum``; TorchRL's ``Collector``; ``IPPO.update``), with ``num_envs`` worlds and
``algo.frames_per_batch = num_envs × steps``: ``steps`` = 4 (16,384 frames an iteration at 4096 worlds; IPPO's
default batch is 16 steps of 128 worlds, ``--ma-steps 16``). Frames/s should depend little on ``steps``: the
update's work grows with the frames (epochs × frames / minibatch size gradient steps), as the collection's does.
Everything else is IPPO's default: ``hidden`` [64, 64] (tanh), parameters shared by the agents, 10 epochs of
minibatches of 64 frames (256 minibatches an epoch at 16,384 frames), Adam at 3e-4, γ 0.99, λ 0.95.

The peer follows ``sota-implementations/multiagent/mappo_ippo.py`` (and its ``mappo_ippo.yaml``) of pytorch/rl at
commit ae9719f (2026-08-22; the file last changed in 71f103e), with ``model.centralised_critic=False`` (IPPO) and
``model.shared_parameters=True``, written out below (``peer_learner``) as the script runs it: ``VmasEnv`` with
``continuous_actions=True``, ``max_steps`` 100 and ``seed`` 0 under ``RewardSum``; a ``MultiAgentMLP`` +
``NormalParamExtractor`` policy in a ``TanhNormal`` ``ProbabilisticActor`` with ``return_log_prob=True``; a
``MultiAgentMLP`` critic; a ``Collector`` with the script's ``DoneTransform`` postproc; ``ClipPPOLoss`` with its
``GAE`` value estimator run on the whole batch; the batch in a ``TensorDictReplayBuffer`` with
``SamplerWithoutReplacement``, ``num_epochs`` × ``frames_per_batch // minibatch_size`` minibatches each with the loss,
backward, ``clip_grad_norm_``, Adam step and the loss logs stacked per iteration; ``update_policy_weights_``.
Matched to ours: the scenario's agents (``navigation`` with ``n_agents=2``), the worlds (``num_envs`` set directly
rather than ``frames_per_batch // max_steps``), ``frames_per_batch``, ``num_epochs`` (10, not 45),
``minibatch_size`` (64, not 4096) and the network size (``depth=2``, ``num_cells`` 64 rather than 256, tanh). Left
as the example has them (they do not change the work of an iteration): γ 0.9, λ 0.9, clip 0.2, no entropy, lr 5e-5,
max grad norm 40. Logging and evaluation are off (the script runs both only with a logger backend), as ours runs
without logger or evaluation.

What differs, and stays: the envs (ours: unicycles, 16 observation features an agent, walls, crashes, episodes that
end at different steps, the finished worlds reset in one batched op; VMAS: holonomic point masses with 12 lidar rays,
18 features an agent, every world timing out together at step 100 and reset at once, ``reset_at`` one world at a
time otherwise), and each learner's own small parts: ours normalises observations (``RunningNorm``: one pass over
the batch) and recomputes the log-probabilities after the statistics moved (one more policy forward over the batch);
its policy has a state-independent log-std (2 outputs an agent, not 4); it draws minibatches by ``randperm`` indexing
rather than from a replay buffer. The ``parameters`` column counts both networks. ``Trial``'s own per-iteration work
(episode metrics, divergence check, metrics.csv) is not timed: ours is timed as the collector and the learner
``Trial`` builds, as the peer is its script's collector and loop body.

Timing: an iteration is ``next(collector)`` (collection) then the update (GAE, epochs, ``update_policy_weights_``),
timed together; after ``warmup`` untimed iterations, the median of ``iterations`` timed ones gives frames/s
(``frames_per_batch`` / median seconds; a frame is a world-step holding both agents' transitions, as TorchRL's
collector counts them). Both learners run in this process at each thread count, back to back
(``torch.set_num_threads``); ``cpu %`` is the CPU time the process got over the timed wall-clock (100 per thread
on an idle machine; lower means other work shared the cores), ``load`` the 1-minute load average then.
On shared cores the two learners may get different shares of them (other jobs start and stop): ``frames/cpu-s``
(timed frames over the process's CPU seconds) and its ratio ``ours/peer cpu`` hold the comparison steadier, and at
1 thread they are about the frames/s an idle core would give.

Threads on shared cores: at 2 threads, with other busy processes on the 2 cores, OpenMP's default wait policy (a
thread spins at each parallel region's barrier, then sleeps) makes small ops wait for a descheduled partner thread,
so a gradient step of either learner slows by orders of magnitude; run with ``OMP_WAIT_POLICY=PASSIVE`` in the
environment (read when the OpenMP runtime starts, so set it before Python starts; 1 thread is unaffected). The
printout ends with the policy the run had. Measured figures: docs/guide/benchmarks.md, "IPPO beside TorchRL's multi-agent example".
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDictBase, unravel_key
from tensordict.nn import TensorDictModule
from tensordict.nn.distributions import NormalParamExtractor
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.data.replay_buffers.storages import LazyTensorStorage
from torchrl.envs import RewardSum, Transform, TransformedEnv
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.modules.models.multiagent import MultiAgentMLP
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from sidewalk.bench.common import format_table, torch_threads
from sidewalk.compose import compose_experiment

NUM_ENVS = (4096,)
THREADS = (1, 2)
STEPS = 4  # steps of every world an iteration: frames_per_batch = worlds × STEPS
ITERATIONS = 3  # timed iterations; the median is kept
WARMUP = 1  # untimed iterations first
N_AGENTS = 2  # the sidewalk's two agents
LEARNERS = ("peer", "ours")  # measured in this order at each thread count
SEED = 0
OURS_OVERRIDES = ("env=continuous", "opponent=self", "algo=ippo", "logger=none")
# The example's mappo_ippo.yaml (model.centralised_critic=False: IPPO); the rest of the peer's settings come from ours.
PEER_SCENARIO = "navigation"
PEER_EXAMPLE = {"max_steps": 100, "gamma": 0.9, "lmbda": 0.9, "entropy_eps": 0.0, "clip_epsilon": 0.2, "lr": 5e-5,
                "max_grad_norm": 40.0, "shared_parameters": True, "centralised_critic": False}
COLUMNS = ("learner", "env", "threads", "worlds", "frames/it", "minibatches/it", "obs/agent", "parameters",
           "collect s", "update s", "frames/s", "ours/peer", "frames/cpu-s", "ours/peer cpu", "episodes/it", "cpu %",
           "load")


@dataclass
class Learner:
    """One learner ready to train: its collector, its update (GAE, epochs, weights to the collector) and its size."""

    name: str
    env_name: str
    collector: Collector
    update: Callable[[TensorDictBase], None]
    frames_per_batch: int
    minibatches: int  # gradient steps an iteration
    observation_size: int
    parameters: int


def ours_learner(num_envs: int, steps: int, seed: int = SEED) -> Learner:
    """Our IPPO self-play on the continuous sidewalk as ``Trial`` builds it, at ``num_envs`` worlds and
    ``num_envs × steps`` frames an iteration; IPPO's defaults otherwise."""
    from sidewalk.experiment import collector_frames_per_batch
    from sidewalk.registry import LEARNERS

    experiment = compose_experiment(
        [*OURS_OVERRIDES, f"num_envs={num_envs}", f"algo.frames_per_batch={num_envs * steps}", f"seed={seed}"]
    )
    torch.manual_seed(seed)
    env = TransformedEnv(experiment.world.make(experiment.num_envs, experiment.seed, experiment.device), RewardSum())
    algo = LEARNERS[experiment.algo.name](experiment.algo, env, device=experiment.device)
    frames_per_batch = collector_frames_per_batch(experiment)
    collector = Collector(env, algo.collection_policy(), frames_per_batch=frames_per_batch, total_frames=-1,
                          device=experiment.device, auto_register_policy_transforms=False)

    def update(batch: TensorDictBase) -> None:
        algo.update(batch)
        collector.update_policy_weights_()

    cfg = experiment.algo
    return Learner(
        name="ours IPPO", env_name="sidewalk continuous", collector=collector, update=update,
        frames_per_batch=frames_per_batch, minibatches=cfg.epochs * -(-frames_per_batch // cfg.minibatch_size),
        observation_size=algo.observation_spec.shape[-1],
        parameters=sum(p.numel() for p in algo.loss.parameters()),
    )


class DoneTransform(Transform):
    """The example's ``utils/utils.py`` ``DoneTransform``: the root done entries expanded to the reward's shape under
    the agents' group (``("next", "agents", "done")``, ...), as its ``Collector`` postproc."""

    def __init__(self, reward_key, done_keys):
        super().__init__()
        self.reward_key = reward_key
        self.done_keys = done_keys

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        for done_key in self.done_keys:
            new_name = _swap_last(self.reward_key, done_key)
            reward_shape = tensordict.get(("next", self.reward_key)).shape
            tensordict.set(("next", new_name), tensordict.get(("next", done_key)).unsqueeze(-1).expand(reward_shape))
        return tensordict


def _swap_last(source, dest):
    source, dest = unravel_key(source), unravel_key(dest)
    if isinstance(source, str):
        return dest if isinstance(dest, str) else dest[-1]
    return source[:-1] + (dest,) if isinstance(dest, str) else source[:-1] + (dest[-1],)


def peer_learner(num_envs: int, frames_per_batch: int, epochs: int, minibatch_size: int, hidden: Sequence[int],
                 seed: int = SEED) -> Learner | None:
    """TorchRL's ``mappo_ippo.py`` (IPPO) on VMAS ``navigation`` with two agents, ``num_envs`` worlds, our batch,
    epochs, minibatch size and hidden widths; None when VMAS is not installed."""
    if importlib.util.find_spec("vmas") is None:
        return None
    ex = PEER_EXAMPLE
    device = "cpu"
    torch.manual_seed(seed)
    env = _peer_env(num_envs, seed, device)
    observation_size = env.observation_spec["agents", "observation"].shape[-1]
    policy, value_module = _peer_networks(env, observation_size, hidden, device)
    collector = Collector(
        env, policy, device=device, storing_device=device, frames_per_batch=frames_per_batch, total_frames=-1,
        postproc=DoneTransform(reward_key=env.reward_key, done_keys=env.done_keys),
        auto_register_policy_transforms=False,  # no recurrent policy here: only silences a FutureWarning
    )
    replay_buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(frames_per_batch, device=device),
                                           sampler=SamplerWithoutReplacement(), batch_size=minibatch_size)
    loss_module = ClipPPOLoss(actor_network=policy, critic_network=value_module, clip_epsilon=ex["clip_epsilon"],
                              entropy_coeff=ex["entropy_eps"], normalize_advantage=False)
    loss_module.set_keys(reward=env.reward_key, action=env.action_key, done=("agents", "done"),
                         terminated=("agents", "terminated"))
    loss_module.make_value_estimator(ValueEstimators.GAE, gamma=ex["gamma"], lmbda=ex["lmbda"])
    optim = torch.optim.Adam(loss_module.parameters(), ex["lr"])
    update = _peer_update(collector, replay_buffer, loss_module, optim, epochs, frames_per_batch // minibatch_size)
    return Learner(
        name="TorchRL example IPPO", env_name=f"VMAS {PEER_SCENARIO}", collector=collector, update=update,
        frames_per_batch=frames_per_batch, minibatches=epochs * (frames_per_batch // minibatch_size),
        observation_size=observation_size, parameters=sum(p.numel() for p in loss_module.parameters()),
    )


def _peer_env(num_envs: int, seed: int, device: str) -> TransformedEnv:
    """The example's ``VmasEnv`` on ``navigation`` with our two agents, its episode reward summed."""
    from torchrl.envs.libs.vmas import VmasEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # VMAS's own deprecation notes
        env = VmasEnv(scenario=PEER_SCENARIO, num_envs=num_envs, continuous_actions=True,
                      max_steps=PEER_EXAMPLE["max_steps"], device=device, seed=seed, n_agents=N_AGENTS)
    return TransformedEnv(env, RewardSum(in_keys=[env.reward_key], out_keys=[("agents", "episode_reward")]))


def _peer_networks(
    env: TransformedEnv, observation_size: int, hidden: Sequence[int], device: str
) -> tuple[ProbabilisticActor, ValueOperator]:
    """The example's policy (``MultiAgentMLP`` + ``NormalParamExtractor`` in a ``TanhNormal`` actor) and critic,
    at our hidden widths; built in the example's order, so one seed gives the same weights."""
    ex = PEER_EXAMPLE
    network = {"n_agents": env.n_agents, "share_params": ex["shared_parameters"], "device": device,
               "depth": len(hidden), "num_cells": list(hidden), "activation_class": nn.Tanh}
    actor_net = nn.Sequential(
        MultiAgentMLP(n_agent_inputs=observation_size,
                      n_agent_outputs=2 * env.full_action_spec_unbatched[env.action_key].shape[-1],
                      centralised=False, **network),
        NormalParamExtractor(),
    )
    policy_module = TensorDictModule(actor_net, in_keys=[("agents", "observation")],
                                     out_keys=[("agents", "loc"), ("agents", "scale")])
    policy = ProbabilisticActor(
        module=policy_module,
        spec=env.full_action_spec_unbatched,
        in_keys=[("agents", "loc"), ("agents", "scale")],
        out_keys=[env.action_key],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": env.full_action_spec_unbatched[("agents", "action")].space.low,
                             "high": env.full_action_spec_unbatched[("agents", "action")].space.high},
        return_log_prob=True,
    )
    critic = MultiAgentMLP(n_agent_inputs=observation_size, n_agent_outputs=1,
                           centralised=ex["centralised_critic"], **network)
    return policy, ValueOperator(module=critic, in_keys=[("agents", "observation")])


def _peer_update(
    collector: Collector,
    replay_buffer: TensorDictReplayBuffer,
    loss_module: ClipPPOLoss,
    optim: torch.optim.Optimizer,
    epochs: int,
    minibatches_per_epoch: int,
) -> Callable[[TensorDictBase], None]:
    """The example's loop body, logging off: GAE over the batch, then ``epochs`` × ``minibatches_per_epoch``
    minibatches from the replay buffer, each with the loss, backward, clipping and an Adam step."""

    def update(tensordict_data: TensorDictBase) -> None:
        with torch.no_grad():
            loss_module.value_estimator(tensordict_data, params=loss_module.critic_network_params,
                                        target_params=loss_module.target_critic_network_params)
        replay_buffer.extend(tensordict_data.reshape(-1))
        training_tds = []
        for _ in range(epochs):
            for _ in range(minibatches_per_epoch):
                subdata = replay_buffer.sample()
                loss_vals = loss_module(subdata)
                training_tds.append(loss_vals.detach())
                loss_value = loss_vals["loss_objective"] + loss_vals["loss_critic"] + loss_vals["loss_entropy"]
                loss_value.backward()
                total_norm = torch.nn.utils.clip_grad_norm_(loss_module.parameters(), PEER_EXAMPLE["max_grad_norm"])
                training_tds[-1].set("grad_norm", total_norm.mean())
                optim.step()
                optim.zero_grad()
        collector.update_policy_weights_()
        torch.stack(training_tds)

    return update


def measure(learner: Learner, iterations: int, warmup: int) -> dict[str, float]:
    """Median seconds of collection and update over ``iterations`` timed iterations after ``warmup`` untimed ones,
    frames/s of the median whole iteration, frames per CPU-second of the process over the timed iterations,
    episodes ended an iteration (median), and the CPU share while timed."""
    batches = iter(learner.collector)

    def one() -> tuple[float, float, int]:
        start = time.perf_counter()
        batch = next(batches)
        collected = time.perf_counter()
        learner.update(batch)
        return collected - start, time.perf_counter() - collected, int(batch.get(("next", "done")).sum())

    torchrl_log = logging.getLogger("torchrl")
    level = torchrl_log.level
    torchrl_log.setLevel(logging.WARNING)  # the replay buffer's "Initialized LazyTensorStorage" note, in the table
    try:
        for _ in range(warmup):
            one()
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        timed = [one() for _ in range(iterations)]
        cpu_s, wall_s = time.process_time() - cpu_start, time.perf_counter() - wall_start
    finally:
        torchrl_log.setLevel(level)
        learner.collector.shutdown()
    return {
        "collect s": statistics.median(t[0] for t in timed),
        "update s": statistics.median(t[1] for t in timed),
        "frames/s": learner.frames_per_batch / statistics.median(t[0] + t[1] for t in timed),
        "frames/cpu-s": iterations * learner.frames_per_batch / cpu_s,
        "episodes/it": statistics.median(t[2] for t in timed),
        "cpu %": 100 * cpu_s / wall_s,
    }


def run(
    num_envs: Sequence[int] = NUM_ENVS,
    threads: Sequence[int] = THREADS,
    steps: int = STEPS,
    iterations: int = ITERATIONS,
    warmup: int = WARMUP,
    learners: Sequence[str] = LEARNERS,
) -> list[dict]:
    """One row per (threads, worlds, learner) with the ``COLUMNS``; ``ours/peer`` and ``ours/peer cpu`` on our row,
    from the peer's row at the same threads and worlds (None without VMAS, whose rows are then left out). ``steps``: steps of every
    world an iteration (``frames_per_batch = worlds × steps`` for both learners)."""
    ippo = compose_experiment(OURS_OVERRIDES).algo
    too_small = [batch for batch in num_envs if batch * steps < ippo.minibatch_size]
    if too_small:  # the example's loop takes frames // minibatch_size minibatches an epoch: none
        raise ValueError(f"worlds × steps must be at least IPPO's minibatch size {ippo.minibatch_size}; "
                         f"{too_small} worlds × {steps} steps is less")
    rows = []
    for n_threads in threads:
        with torch_threads(n_threads):
            for batch in num_envs:
                measured: dict[str, dict[str, Any]] = {}
                for side in learners:
                    if side == "ours":
                        learner = ours_learner(batch, steps)
                    else:
                        learner = peer_learner(batch, batch * steps, ippo.epochs, ippo.minibatch_size, ippo.hidden)
                        if learner is None:
                            continue
                    result = measure(learner, iterations, warmup)
                    measured[side] = {
                        "learner": learner.name, "env": learner.env_name, "threads": n_threads, "worlds": batch,
                        "frames/it": learner.frames_per_batch, "minibatches/it": learner.minibatches,
                        "obs/agent": learner.observation_size, "parameters": learner.parameters, **result,
                        "ours/peer": None, "ours/peer cpu": None, "load": os.getloadavg()[0],
                    }
                    del learner
                if "ours" in measured and "peer" in measured:
                    for rate, ratio in (("frames/s", "ours/peer"), ("frames/cpu-s", "ours/peer cpu")):
                        measured["ours"][ratio] = measured["ours"][rate] / measured["peer"][rate]
                rows += [{column: row[column] for column in COLUMNS} for row in measured.values()]
    return rows


def format_rows(rows: list[dict]) -> str:
    """The table, then ours ÷ peer frames/s at each thread count and number of worlds."""
    lines = [format_table(rows, COLUMNS)]
    for row in rows:
        if row["ours/peer"] is not None:
            lines.append(f"ours ÷ peer frames/s at {row['threads']} thread(s), {row['worlds']} worlds: "
                         f"{row['ours/peer']:.2f} (per CPU-second: {row['ours/peer cpu']:.2f})")
    lines.append(f"OMP_WAIT_POLICY: {os.environ.get('OMP_WAIT_POLICY', 'not set (OpenMP default)')}")
    if importlib.util.find_spec("vmas") is None:
        lines.append("(no peer rows: VMAS is not installed; pip install 'sidewalk-problem[bench]')")
    return "\n".join(lines)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be ≥ 1")
    return value


def _non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} must be ≥ 0")
    return value


def parse_options(argv: Sequence[str]) -> dict[str, Any]:
    """``run``'s keyword arguments from the section's own flags (``--ma-steps``, ``--ma-iterations``,
    ``--ma-warmup``, ``--ma-learners``; ``runners/bench.py`` adds ``--num-envs`` and ``--threads``)."""
    parser = argparse.ArgumentParser(prog="runners/bench.py multiagent", description=__doc__.splitlines()[0])
    parser.add_argument("--ma-steps", type=_positive_int, default=STEPS,
                        help=f"steps of every world an iteration (default {STEPS}; IPPO's default batch: 16)")
    parser.add_argument("--ma-iterations", type=_positive_int, default=ITERATIONS,
                        help="timed iterations; the median is kept")
    parser.add_argument("--ma-warmup", type=_non_negative_int, default=WARMUP, help="untimed iterations first")
    parser.add_argument("--ma-learners", nargs="+", choices=LEARNERS, default=list(LEARNERS))
    args = parser.parse_args(list(argv))
    return {"steps": args.ma_steps, "iterations": args.ma_iterations, "warmup": args.ma_warmup,
            "learners": args.ma_learners}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=_positive_int, nargs="+", default=list(NUM_ENVS))
    parser.add_argument("--threads", type=_positive_int, nargs="+", default=list(THREADS))
    args, rest = parser.parse_known_args(argv)
    print(format_rows(run(num_envs=args.num_envs, threads=args.threads, **parse_options(rest))))


if __name__ == "__main__":
    main()
