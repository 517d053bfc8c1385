"""Replicas: the update of R seeds of one learner, R lone learners one after another (``algo.update`` in a loop)
or one learner with a replica axis (``replicas=R``, ``sidewalk.algos.replicas``) on the same batches laid out
(R, worlds, time), in ms per iteration (all R updates), one torch thread.

Each replica is the learner at its defaults on the continuous sidewalk's ego view against the random opponent
(``default_num_envs`` worlds, seed r), with one collector batch of its own (``frames_per_batch`` frames: 2048 from
128 worlds for TRPO and PPO). Both ways update on the same batches, each iteration's time the median of ``repeats``
after one untimed warm-up iteration (the first creates Adam's state).

With ``--units`` it times instead the replicated units themselves, the choice ``replicate_`` makes: the paper's
conv stack on grid ego images and a 2x32 tanh MLP on the continuous ego observation, forward and forward+backward,
mapped with ``torch.vmap``, looped over the replicas' slices (the conv stack's CPU path), as R lone units, and for
the MLP as batched matmuls (its path).

    python -m sidewalk.bench.replica_updates                        # TRPO and PPO, R = 5
    python -m sidewalk.bench.replica_updates --replicas 3 --learners trpo --repeats 5
    python -m sidewalk.bench.replica_updates --units --repeats 20  # vmap against the loop, per unit
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.modules import MLP, ConvNet

from sidewalk.algos.base import Algorithm
from sidewalk.algos.networks import PAPER_CONV
from sidewalk.algos.replicas import replicate_
from sidewalk.bench.common import torch_threads
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.registry import LEARNERS
from sidewalk.views import make_view

LEARNER_NAMES = ("trpo", "ppo")


def replica_learners(name: str, replicas: int) -> tuple[list[Algorithm], list[EnvBase]]:
    """``replicas`` learners ``name`` at their defaults, replica r built on its own world (seed r) after
    ``torch.manual_seed(r)``: calling it twice gives two identical sets (a deep copy of a PPO learner would not
    be one: its optimiser keeps the original's parameters)."""
    cls = LEARNERS[name]
    config = cls.Config()
    learners, envs = [], []
    for seed in range(replicas):
        env = make_view("ego", ContinuousSidewalkEnv(num_envs=config.default_num_envs, seed=seed), opponent="random")
        torch.manual_seed(seed)
        learners.append(cls(config, env))
        envs.append(env)
    return learners, envs


def collect_batches(learners: Sequence[Algorithm], envs: Sequence[EnvBase]) -> list[TensorDictBase]:
    """One collector batch (``frames_per_batch`` frames) per learner, collected by its own policy in its own env."""
    batches = []
    for learner, env in zip(learners, envs):
        collector = Collector(env, learner.collection_policy(), frames_per_batch=learner.config.frames_per_batch,
                              total_frames=-1, auto_register_policy_transforms=False)
        batches.append(next(iter(collector)).clone())
        collector.shutdown()
    return batches


def _median_ms(iteration: Callable[[], object], repeats: int) -> float:
    iteration()  # warm-up: the first update creates the optimisers' state
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        iteration()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def time_learner(name: str, replicas: int, repeats: int) -> dict[str, Any]:
    """ms per iteration of ``replicas`` updates of learner ``name``: R lone learners looped, and one learner with a
    replica axis."""
    looped, envs = replica_learners(name, replicas)
    batches = collect_batches(looped, envs)
    cls = LEARNERS[name]
    torch.manual_seed(0)
    replicated = cls(cls.Config(), envs[0], replicas=replicas)
    stacked = torch.stack(batches)  # (R, worlds, time): each replica's batch on the replica axis

    def loop() -> None:
        for algo, batch in zip(looped, batches):
            algo.update(batch.clone())

    def together() -> None:
        replicated.update(stacked.clone())

    loop_ms, replicated_ms = _median_ms(loop, repeats), _median_ms(together, repeats)
    return {"learner": name, "replicas": replicas, "looped_ms": loop_ms, "replicated_ms": replicated_ms,
            "speedup": loop_ms / replicated_ms}


def time_replica_updates(replicas: int = 5, repeats: int = 3, learners: Sequence[str] = LEARNER_NAMES
                         ) -> list[dict[str, Any]]:
    """ms per iteration of ``replicas`` updates, looped and with a replica axis, for each learner, one torch thread;
    prints one line each and returns the rows."""
    rows = []
    with torch_threads(1):
        for name in learners:
            row = time_learner(name, replicas, repeats)
            rows.append(row)
            print(f"{name}: {replicas} replicas, looped {row['looped_ms']:.1f} ms, replica axis {row['replicated_ms']:.1f} ms "
                  f"per iteration ({row['speedup']:.2f}x)", flush=True)
    return rows


def _units(replicas: int) -> list[tuple[str, Callable[[], nn.Module], torch.Tensor]]:
    """(name, a lone unit's builder, one replica's input) for each timed unit."""
    image_shape = make_view("ego", DiscreteSidewalkEnv(num_envs=1), opponent="random").observation_spec[
        "observation"].shape[-3:]
    vector_size = make_view("ego", ContinuousSidewalkEnv(num_envs=1), opponent="random").observation_spec[
        "observation"].shape[-1]

    def conv() -> nn.Module:
        return ConvNet(in_features=image_shape[0], activation_class=nn.ReLU, **PAPER_CONV)

    def mlp() -> nn.Module:
        return MLP(in_features=vector_size, out_features=1, num_cells=[32, 32], activation_class=nn.Tanh)

    return [("conv stack, 128 grid images", conv, torch.rand(128, *image_shape)),
            ("2x32 tanh MLP, 2048 samples", mlp, torch.randn(2048, vector_size)),
            ("2x32 tanh MLP, 128 samples", mlp, torch.randn(128, vector_size))]


def _unit_ms(replicated: nn.Module, lone: Sequence[nn.Module], inputs: torch.Tensor, backward: bool,
             repeats: int) -> dict[str, float]:
    forwards = {"vmap": lambda: replicated.forward_vmapped(inputs),
                "loop": lambda: replicated.forward_looped(inputs),
                "lone": lambda: torch.stack([unit(x) for unit, x in zip(lone, inputs)])}
    if replicated.__dict__.get("linear_only"):  # an MLP: its linear layers as batched matmuls, the path it takes
        forwards["batched"] = lambda: replicated.forward_batched(inputs)

    def iteration(forward: Callable[[], torch.Tensor]) -> None:
        output = forward()
        if backward:
            output.sum().backward()

    with torch.set_grad_enabled(backward):
        return {f"{way}_ms": _median_ms(lambda f=forward: iteration(f), repeats) for way, forward in forwards.items()}


def time_units(replicas: int = 5, repeats: int = 20) -> list[dict[str, Any]]:
    """ms of one replicated unit's forward (and forward+backward) over ``replicas`` replicas: under vmap, looped
    over the slices, and as ``replicas`` lone units; one torch thread, medians of ``repeats``. Prints a line each."""
    rows = []
    with torch_threads(1):
        for name, build, one_input in _units(replicas):
            torch.manual_seed(0)
            lone = [build() for _ in range(replicas)]
            replicated = replicate_(build(), replicas)
            inputs = one_input.expand(replicas, *one_input.shape).clone()
            for backward in (False, True):
                row = {"unit": name, "pass": "forward+backward" if backward else "forward", "replicas": replicas,
                       **_unit_ms(replicated, lone, inputs, backward, repeats)}
                rows.append(row)
                batched = f", batched matmuls {row['batched_ms']:.2f} ms" if "batched_ms" in row else ""
                print(f"{name}, {row['pass']}: vmap {row['vmap_ms']:.2f} ms, loop {row['loop_ms']:.2f} ms, "
                      f"{replicas} lone units {row['lone_ms']:.2f} ms{batched}", flush=True)
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replicas", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--learners", nargs="+", choices=LEARNER_NAMES, default=list(LEARNER_NAMES))
    parser.add_argument("--units", action="store_true", help="time the replicated units (vmap, loop, lone) instead")
    args = parser.parse_args(argv)
    if args.units:
        time_units(args.replicas, args.repeats)
        return
    time_replica_updates(args.replicas, args.repeats, args.learners)


if __name__ == "__main__":
    main()
