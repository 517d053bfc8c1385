"""``device=cuda`` end to end: the envs' specs, every kind of learner's run (lone and as a group of replicas, which
maps its networks with ``torch.vmap`` on an accelerator) and the promise that the same seed, replicas and device give
the same numbers. Skipped where torch sees no GPU (CI); run where one is lent (docs/guide/benchmarks.md)."""

from pathlib import Path

import pandas as pd
import pytest
import torch
from omegaconf import OmegaConf
from torchrl.envs.utils import check_env_specs

from sidewalk.compose import compose
from sidewalk.config import validate
from sidewalk.envs.grid import DiscreteSidewalkEnv
from sidewalk.envs.unicycle import ContinuousSidewalkEnv
from sidewalk.experiment import Trial
from sidewalk.run_folder import read_torch_file

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device: torch.cuda.is_available() is False")

WALL_CLOCK = ["time_s", "frames_per_s"]
RUN = ["device=cuda", "num_envs=64", "eval_episodes=32", "eval_every=4", "checkpoint_every=4", "logger=none",
       "plots=false"]
SETUPS = {
    "dqn_grid": ["iterations=12", "algo.learning_starts=0", "algo.frames_per_batch=64", "algo.batch_size=32"],
    "trpo_continuous": ["env=continuous", "algo=trpo", "opponent=prm", "iterations=4"],
    "ppo_continuous": ["env=continuous", "algo=ppo", "opponent=prm", "iterations=4"],
    "ppo_lagrangian_continuous": ["+experiment=safe_continuous", "algo=ppo_lagrangian", "iterations=4"],
    "ippo_selfplay_grid": ["+experiment=selfplay_discrete", "algo=ippo", "iterations=4"],
    "mappo_selfplay_continuous": ["+experiment=selfplay_continuous", "algo=mappo", "iterations=4"],
    "iql_selfplay_grid": ["+experiment=selfplay_discrete", "algo=iql", "iterations=12", "algo.learning_starts=0"],
    "qmix_selfplay_grid": ["+experiment=selfplay_discrete", "algo=qmix", "iterations=12", "algo.learning_starts=0"],
}


def train(folder: Path, overrides: list[str]) -> Path:
    cfg = compose(RUN + overrides)
    Trial(validate(cfg), folder, OmegaConf.to_container(cfg, resolve=True)).run(progress=False)
    return folder


def metrics(folder: Path) -> pd.DataFrame:
    files = sorted(folder.glob("seed*/metrics.csv")) or [folder / "metrics.csv"]
    return pd.concat([pd.read_csv(path).drop(columns=WALL_CLOCK) for path in files])


@pytest.mark.parametrize("core", [DiscreteSidewalkEnv, ContinuousSidewalkEnv])
def test_env_specs_on_cuda(core):
    env = core(num_envs=16, seed=0, noise=0.1, device="cuda")
    check_env_specs(env, seed=None)
    assert env.reset().get(("agents", "observation")).device.type == "cuda"


@pytest.mark.parametrize("setup", list(SETUPS))
@pytest.mark.parametrize("replicas", [1, 2])
def test_run_on_cuda_repeats_and_reads_back_on_cpu(tmp_path, setup, replicas):
    overrides = [*SETUPS[setup], f"replicas={replicas}", "seed=3"]
    first = train(tmp_path / "first", overrides)
    second = train(tmp_path / "second", overrides)
    pd.testing.assert_frame_equal(metrics(first), metrics(second))  # same seed, replicas and device
    rates = metrics(first)["eval/team/success_rate"].dropna()
    assert len(rates) and rates.between(0, 1).all()
    policy = min(first.glob("**/policy.pt"))
    state = read_torch_file(policy, map_location="cpu")
    assert state  # the policy a CPU machine reads back
