"""What we ship cannot starve a learner of gradient steps: every preset (each learner its sweep names) and every job
of a committed reference gives its learner at least as many gradient steps a frame as the learner's own defaults in
that domain. Grid PPO at minibatches of 512 (the safe reference's job before issue "Who yields, learned") had an
eighth of its default's steps and walked its start row; at its own 64 it found its goal row
(results/who-yields/README.md)."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import pytest
from omegaconf import DictConfig

from sidewalk.compose import compose

ROOT = Path(__file__).resolve().parents[1]
PRESETS = sorted(path.stem for path in (ROOT / "conf" / "experiment").glob("*.yaml"))
REFERENCE_JOBS = {
    f"{meta.parent.relative_to(ROOT)}:{name}": overrides
    for meta in sorted((ROOT / "results" / "reference").rglob("reference.json"))
    for name, overrides in json.loads(meta.read_text())["jobs"].items()
}


def steps_per_frame(cfg: DictConfig) -> float | None:
    """Gradient steps a collected frame buys: PPO's epochs × minibatches a batch, the Q learners' updates a batch;
    None for a learner with neither (TRPO: one natural-gradient step a batch)."""
    algo = cfg.algo
    frames = math.ceil(algo.frames_per_batch / cfg.num_envs) * cfg.num_envs  # a batch is whole steps of every world
    if "minibatch_size" in algo and "epochs" in algo:
        return algo.epochs * math.ceil(frames / algo.minibatch_size) / frames
    if "updates_per_batch" in algo:
        return algo.updates_per_batch / frames
    return None


@functools.cache
def own_steps_per_frame(domain: str, algo: str) -> float | None:
    return steps_per_frame(compose([f"env={domain}", f"algo={algo}"]))


def learners_of(preset: str) -> list[list[str]]:
    """A preset's runs, one per learner its sweep names (its own default learner if it sweeps none)."""
    cfg = compose([f"+experiment={preset}"], hydra_config=True)
    algos = cfg.hydra.sweeper.get("params", {}).get("algo")
    return [[f"+experiment={preset}", *([f"algo={algo}"] if algos else [])] for algo in (algos or "").split(",")]


def assert_not_starved(overrides: list[str]) -> None:
    cfg = compose(overrides)
    shipped = steps_per_frame(cfg)
    if shipped is None:
        return
    own = own_steps_per_frame(cfg.env.domain, cfg.algo.name)
    assert shipped >= own, (
        f"{' '.join(overrides)}: {cfg.algo.name} gets {shipped:.3g} gradient steps a frame, fewer than its own "
        f"defaults' {own:.3g} in env={cfg.env.domain}"
    )


@pytest.mark.parametrize("preset", PRESETS)
def test_every_preset_gives_its_learners_their_gradient_steps(preset):
    for overrides in learners_of(preset):
        assert_not_starved(overrides)


@pytest.mark.parametrize("job", sorted(REFERENCE_JOBS))
def test_every_reference_job_gives_its_learner_its_gradient_steps(job):
    assert_not_starved(list(REFERENCE_JOBS[job]))


def test_the_guard_catches_the_starved_setting():
    """The safe reference's grid PPO-Lagrangian job as it was: minibatches of 512, an eighth of the steps."""
    with pytest.raises(AssertionError, match="fewer than its own defaults'"):
        assert_not_starved(["+experiment=safe_discrete", "algo=ppo_lagrangian", "algo.minibatch_size=512"])
