"""Plug-ins from outside: a package of its own adds an opponent, a layout and a learner through entry points and
its YAMLs through Hydra's search path, and all three train together through runners/main.py with no file of ours
touched."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY = ["iterations=2", "num_envs=4", "eval_every=0", "eval_episodes=4", "logger=none", "checkpoint_every=0", "plots=false"]

# The worked example of docs/guide/extending.md, as its files.
PLUGIN = {
    "pyproject.toml": """
        [build-system]
        requires = ["setuptools>=68"]
        build-backend = "setuptools.build_meta"

        [project]
        name = "sidewalk-corridor"
        version = "0.1.0"
        dependencies = ["sidewalk-problem"]

        [project.entry-points."sidewalk.opponents"]
        shy = "sidewalk_corridor.shy:ShyOpponent"

        [project.entry-points."sidewalk.layouts"]
        corridor = "sidewalk_corridor.corridor:SCENARIO"

        [project.entry-points."sidewalk.learners"]
        greedy_dqn = "sidewalk_corridor.greedy_dqn:GreedyDQN"

        [project.entry-points."sidewalk.configs"]
        sidewalk_corridor = "sidewalk_corridor.conf"

        [tool.setuptools]
        packages = ["sidewalk_corridor", "sidewalk_corridor.conf"]

        [tool.setuptools.package-data]
        "sidewalk_corridor.conf" = ["*/*.yaml"]
    """,
    "sidewalk_corridor/__init__.py": '"""A corridor scenario, a shy opponent and a DQN that never explores."""\n',
    "sidewalk_corridor/conf/__init__.py": '"""Config groups that Hydra finds through the sidewalk.configs entry point."""\n',
    "sidewalk_corridor/shy.py": '''
        """An opponent that only ever steps back and forth across the sidewalk: it yields the way."""

        import torch

        from sidewalk.opponents import Opponent

        UP, DOWN = 0, 1


        class ShyOpponent(Opponent):
            name = "shy"
            domains = ("discrete",)

            def __init__(self, env, controlled=(1,), ego=0, step_back: bool = True):
                super().__init__(env, controlled=controlled, ego=ego)
                self.step_back = step_back

            def act(self, state, goal, done, present=None):
                coin = torch.randint(0, 2, (state.shape[0], len(self.controlled)), generator=self.env.generator,
                                     device=state.device)
                return torch.where(coin.bool(), UP, DOWN)
    ''',
    "sidewalk_corridor/corridor.py": '''
        """A corridor three cells wide with a pillar in the middle: the two agents must pick a side."""

        from sidewalk.envs.layouts.base import GridLayout, Scenario, check_agents


        def corridor_grid(rows, cols, n_agents=2, min_start_goal_cells=0):
            check_agents("corridor", n_agents, 2, 2)
            middle = rows // 2
            return GridLayout(rows=rows, cols=cols, starts=((middle, 0), (middle, cols - 1)),
                              goals=((middle, cols - 1), (middle, 0)), center_row=middle,
                              blocked=((middle, cols // 2),))


        SCENARIO = Scenario("corridor", grid=corridor_grid)
    ''',
    "sidewalk_corridor/greedy_dqn.py": '''
        """DQN without exploration: a learner of our own, built on sidewalk's DQN."""

        from dataclasses import dataclass

        from sidewalk.algos.dqn import DQN, DQNConfig


        @dataclass
        class GreedyDQNConfig(DQNConfig):
            name: str = "greedy_dqn"
            eps_start: float = 0.0
            eps_end: float = 0.0


        class GreedyDQN(DQN):
            name = "greedy_dqn"
            domains = ("discrete",)
            Config = GreedyDQNConfig
    ''',
    "sidewalk_corridor/conf/opponent/shy.yaml": """
        defaults:
          - /schema/opponent/opponent@_here_
          - _self_

        name: shy
        ego: 0
        end_on_ego_done: false
        params:
          step_back: true
    """,
    "sidewalk_corridor/conf/algo/greedy_dqn.yaml": """
        defaults:
          - /schema/algo/greedy_dqn@_here_
          - _self_

        name: greedy_dqn
        frames_per_batch: 64
        default_num_envs: 16
        default_iterations: 20
        default_eval_every: 5
        learning_starts: 32
    """,
}


def fingerprint(*folders: Path) -> dict[str, str]:
    return {
        str(path.relative_to(ROOT)): hashlib.sha256(path.read_bytes()).hexdigest()
        for folder in folders for path in sorted(folder.rglob("*")) if path.is_file() and "__pycache__" not in path.parts
    }


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory) -> Path:
    """The plug-in package written in a temporary folder and installed (``pip install --target``) into another."""
    source, site = tmp_path_factory.mktemp("sidewalk-corridor"), tmp_path_factory.mktemp("site")
    for name, text in PLUGIN.items():
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text(textwrap.dedent(text).lstrip())
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "-q", "--target", str(site),
         str(source)],
        check=True, capture_output=True, text=True, timeout=300,
    )
    return site


def train(site: Path, run_dir: Path, *overrides: str) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [sys.executable, "runners/main.py", *TINY, *overrides, f"hydra.run.dir={run_dir}"],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env=environment, check=False,
    )


def test_a_plugin_package_trains_through_the_runner(plugin_site, tmp_path):
    # Its opponent, layout and learner in one run: each is found through its own entry point and YAML.
    overrides = ("opponent=shy", "env.layout=corridor", "env.width_cells=3", "env.length_cells=9",
                 "env.observation=vector", "algo=greedy_dqn")
    before = fingerprint(ROOT / "sidewalk", ROOT / "conf")
    done = train(plugin_site, tmp_path / "run", *overrides)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "run" / "metrics.csv").read_text().count("\n") == 3  # a header and two iterations
    saved = (tmp_path / "run" / "config.yaml").read_text()
    assert all(override.split("=")[1] in saved for override in overrides)
    assert fingerprint(ROOT / "sidewalk", ROOT / "conf") == before


def test_the_plugins_join_the_registries_and_the_config_checks(plugin_site, tmp_path):
    probe = """
from sidewalk.registry import LAYOUTS, LEARNERS, OPPONENTS
from sidewalk.config import opponent_domains
print(OPPONENTS["shy"].__name__, LAYOUTS["corridor"].domains, LEARNERS["greedy_dqn"].__name__,
      opponent_domains()["shy"])
"""
    environment = {**os.environ, "PYTHONPATH": str(plugin_site)}
    done = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True,
                          env=environment, check=False, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["ShyOpponent", "('discrete',)", "GreedyDQN", "('discrete',)"]
    # A plug-in's domain is checked like ours: the shy opponent does not play the continuous world.
    refused = train(plugin_site, tmp_path / "refused", "env=continuous", "opponent=shy")
    assert refused.returncode == 2
    assert "opponent=shy does not play env=continuous" in refused.stderr
