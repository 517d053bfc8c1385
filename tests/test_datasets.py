"""Episodes as Minari datasets (sidewalk.datasets): record through the Gymnasium face, save, append, load."""

from __future__ import annotations

import dataclasses
import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pytest

pytest.importorskip("minari")
pytest.importorskip("h5py")
import minari

import sidewalk  # registers the Gymnasium ids
from sidewalk import datasets

GRID = ("sidewalk/Discrete-v0", {"opponent": "dijkstra", "max_steps": 60}, "dijkstra", {})
CONTINUOUS = ("sidewalk/Continuous-v0", {"opponent": "prm", "max_steps": 80}, "convention", {"style": "keep_right"})


@pytest.fixture
def root(tmp_path, monkeypatch):
    """A datasets root of its own, also for plain minari calls (never the user's ~/.minari)."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
    return tmp_path / "datasets"


def walk(env, driver, episodes: int, first_seed: int = 0) -> list[int]:
    """Drive the recorded agent with ``driver`` for ``episodes`` episodes; their step counts."""
    lengths = []
    for episode in range(episodes):
        _, info = env.reset(seed=first_seed + episode)
        driver.reset()
        steps, done = 0, False
        while not done:
            _, _, terminated, truncated, info = env.step(driver(info))
            steps += 1
            done = terminated or truncated
        lengths.append(steps)
    return lengths


@pytest.mark.parametrize("case", [GRID, CONTINUOUS], ids=["grid", "continuous"])
def test_record_save_append_load(root, case):
    env_id, env_config, walker, walker_kwargs = case
    env = datasets.record(gymnasium.make(env_id, **env_config))
    driver = datasets.ScriptedDriver(env, walker, **walker_kwargs)
    lengths = walk(env, driver, 2)
    saved = datasets.save(env, "sidewalk/walks-v0", env_config=env_config, author="tests", description="a walker")
    assert (saved.total_episodes, saved.total_steps) == (2, sum(lengths))

    lengths += walk(env, driver, 1, first_seed=10)
    appended = datasets.save(env, "sidewalk/walks-v0", env_config=env_config)
    assert (appended.total_episodes, appended.total_steps) == (3, sum(lengths))

    plain = minari.load_dataset("sidewalk/walks-v0")  # Minari alone, from MINARI_DATASETS_PATH
    episodes = list(plain.iterate_episodes())
    assert [len(episode.actions) for episode in episodes] == lengths
    assert [len(episode.observations) for episode in episodes] == [n + 1 for n in lengths]
    last = episodes[-1]
    assert last.infos["is_success"].shape == (lengths[-1] + 1,)
    assert last.infos["state"].shape[:2] == (lengths[-1] + 1, 2)
    assert set(last.infos["agents"]) == {"reached_goal", "collided_agent", "collided_wall", "timed_out", "reward",
                                         "cost"}
    assert bool(last.infos["is_success"][-1]) == bool(last.terminations[-1])
    assert np.array_equal(np.asarray(last.observations[0]), env.reset(seed=10)[0])  # raw, not JPEG

    pins = datasets.pins_of(plain)
    assert pins["env_id"] == env_id and pins["env_version"] == 0
    assert pins["sidewalk_version"] == sidewalk.__version__
    config = pins["env_config"]
    assert config["opponent"] == env_config["opponent"] and config["ego"] == 0
    assert config["max_steps"] == env_config["max_steps"]
    core_keywords = {field.name for field in dataclasses.fields(env.unwrapped.view.core.Params)}
    assert {"noise", "rewards", "layout", "max_steps"} <= core_keywords <= set(config)
    assert {"opponent_kwargs", "end_on_ego_done", "shield", "domain"} <= set(config)
    card = (root / "sidewalk" / "walks-v0" / datasets.CARD_NAME).read_text()
    assert "episodes: 3" in card and f"steps: {sum(lengths)}" in card and "agent 0" in card
    assert f"`{env_config['opponent']}`" in card


def recorded_grid(root, dataset_id="sidewalk/grid-v0"):
    env = datasets.record(gymnasium.make("sidewalk/Discrete-v0", opponent="dijkstra", max_steps=40))
    walk(env, datasets.ScriptedDriver(env, "dijkstra"), 1)
    return datasets.save(env, dataset_id, env_config={"opponent": "dijkstra", "max_steps": 40})


def test_load_warns_naming_what_differs(root, monkeypatch, recwarn):
    dataset = recorded_grid(root)
    datasets.load("sidewalk/grid-v0")
    assert not [w for w in recwarn if issubclass(w.category, datasets.DatasetEnvMismatchWarning)]

    # A dataset of an older package: another noise default, a key since gone, an older env version.
    pins = datasets.pins_of(dataset)
    pins["env_config"]["noise"] = 0.25
    pins["env_config"]["old_knob"] = 3
    pins["env_version"] = 7
    dataset.storage.update_metadata({datasets.METADATA_KEY: json.dumps(pins)})
    monkeypatch.setattr(datasets, "__version__", "99.0")
    with pytest.warns(datasets.DatasetEnvMismatchWarning) as caught:
        loaded = datasets.load("sidewalk/grid-v0")
    message = str(caught[0].message)
    for named in ("noise 0.25 (now 0.0)", "'old_knob'", "env_version 7 (now 0)", "sidewalk_version"):
        assert named in message
    assert loaded.total_steps == dataset.total_steps


def test_save_refuses_another_env_and_bad_input(root):
    recorded_grid(root)
    env = datasets.record(gymnasium.make("sidewalk/Discrete-v0", opponent="dijkstra", max_steps=50))
    walk(env, datasets.ScriptedDriver(env, "dijkstra"), 1)
    with pytest.raises(ValueError, match="max_steps 40"):
        datasets.save(env, "sidewalk/grid-v0", env_config={"opponent": "dijkstra", "max_steps": 50})
    with pytest.raises(ValueError, match="noise=0.3"):
        datasets.save(env, "sidewalk/other-v0", env_config={"noise": 0.3})
    with pytest.raises(ValueError, match="nonsense"):
        datasets.save(env, "sidewalk/other-v0", env_config={"nonsense": 1})
    for bad in ("walks", "sidewalk/walks", "walks-v0", "sidewalk/walks v0-v1", "s/walks-v0", 3):
        with pytest.raises(ValueError, match="namespace/name-vN"):
            datasets.save(env, bad, env_config={})
        with pytest.raises(ValueError, match="namespace/name-vN"):
            datasets.load(bad)
    with pytest.raises(FileNotFoundError, match="sidewalk/missing-v0"):
        datasets.load("sidewalk/missing-v0")
    with pytest.raises(TypeError, match="sidewalk Gymnasium env"):
        datasets.record(gymnasium.make("CartPole-v1"))


def test_data_path_selects_the_root(tmp_path, monkeypatch):
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))  # a stray default would land here, not in the user's home
    here = tmp_path / "elsewhere"
    env = datasets.record(gymnasium.make("sidewalk/Discrete-v0", opponent="dijkstra", max_steps=30), data_path=here)
    walk(env, datasets.ScriptedDriver(env, "dijkstra"), 1)
    datasets.save(env, "people/walks-v2", env_config={"opponent": "dijkstra", "max_steps": 30}, data_path=here)
    assert (here / "people" / "walks-v2" / "data").is_dir()
    assert datasets.load("people/walks-v2", data_path=here).total_episodes == 1
    assert not (tmp_path / "home").exists()
    assert "MINARI_DATASETS_PATH" not in __import__("os").environ


def test_a_missing_dataset_is_one_line_naming_the_root_what_is_there_and_both_ways_to_another(root):
    with pytest.raises(FileNotFoundError) as missing:
        datasets.check_dataset("sidewalk/grid-walks-v0")
    message = str(missing.value)
    assert f"no dataset 'sidewalk/grid-walks-v0' under {root} (none there)" in message and "\n" not in message
    assert "opponent.params.data_path=DIR" in message and "MINARI_DATASETS_PATH=DIR" in message
    recorded_grid(root)
    recorded_grid(root, "people/alice/walks-v3")
    with pytest.raises(FileNotFoundError, match=r"\(datasets there: people/alice/walks-v3, sidewalk/grid-v0\)"):
        datasets.load("sidewalk/grid-walks-v0")  # load's own check is this one
    assert datasets.check_dataset("sidewalk/grid-v0") == root / "sidewalk" / "grid-v0"
    assert datasets.check_dataset("sidewalk/grid-v0", data_path=root) == root / "sidewalk" / "grid-v0"
    with pytest.raises(ValueError, match="namespace/name-vN"):
        datasets.check_dataset("grid-v0")


ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide" / "datasets.md"


def test_the_guide_s_proxy_command_finds_what_its_recording_snippet_saved(tmp_path, monkeypatch):
    from sidewalk.compose import compose

    monkeypatch.chdir(tmp_path)  # where a user runs both, as the guide's root is relative
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))  # Minari's default root: not the user's
    text = GUIDE.read_text()
    recording = text.split("```python\n", 1)[1].split("```", 1)[0]
    subprocess.run([sys.executable, "-c", recording], cwd=tmp_path, check=True)  # in the environment set above
    line = next(line for line in text.splitlines() if line.startswith("python runners/main.py opponent=proxy"))
    params = compose(shlex.split(line)[2:]).opponent.params
    assert datasets.check_dataset(params.dataset, params.data_path) == Path("datasets").resolve() / params.dataset
    if shutil.which("git") and (ROOT / ".git").exists():  # a recording under the clone must not make runs -dirty
        ignored = subprocess.run(["git", "check-ignore", "-q", f"datasets/{params.dataset}/data/main_data.hdf5"],
                                 cwd=ROOT, check=False)
        assert ignored.returncode == 0, "datasets/ is not in .gitignore"
