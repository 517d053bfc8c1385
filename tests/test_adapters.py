"""sidewalk's adapters over other libraries' internals (``_hydra``, ``_omegaconf``, ``_minari``) still do their jobs on
the installed versions: a failure here means the library moved what the adapter relies on, and the message names the
library's version and what moved."""

from __future__ import annotations

import dataclasses
import inspect
import sys

import gymnasium
import hydra
import numpy as np
import omegaconf
import pytest
from omegaconf import OmegaConf

from sidewalk._hydra import BASIC_SWEEPER, SPLIT_ARGUMENTS_PARAMETERS, basic_sweeper, basic_sweeper_points
from sidewalk._omegaconf import node_key

# ---- Hydra: the basic sweeper's split of a sweep into jobs -----------------------------------------------------------


def test_hydra_s_basic_sweeper_is_where_the_adapter_imports_it_and_splits_as_it_calls_it():
    sweeper = basic_sweeper()  # raises naming the Hydra version when the class or its split_arguments moved
    assert f"{sweeper.__module__}.{sweeper.__qualname__}" == BASIC_SWEEPER, (
        f"Hydra {hydra.__version__} moved its basic sweeper to {sweeper.__module__}; update sidewalk/_hydra.py")
    parameters = tuple(inspect.signature(sweeper.split_arguments).parameters)
    assert parameters == SPLIT_ARGUMENTS_PARAMETERS, (
        f"Hydra {hydra.__version__}: BasicSweeper.split_arguments takes {parameters}; update sidewalk/_hydra.py")


def test_a_config_s_default_sweeper_is_the_one_the_adapter_names():
    from sidewalk.compose import compose

    target = compose([], hydra_config=True).hydra.sweeper._target_
    assert target == BASIC_SWEEPER, (
        f"Hydra {hydra.__version__} names its default sweeper {target}; sidewalk/_hydra.py names {BASIC_SWEEPER}")


def test_the_basic_sweeper_crosses_params_with_the_command_line_the_command_line_winning():
    points = basic_sweeper_points({"a": "1,2", "b": "x"}, ["c=range(0,2)", "a=3"])
    assert points == [["a=3", "b=x", "c=0"], ["a=3", "b=x", "c=1"]], (
        f"Hydra {hydra.__version__}'s basic sweeper splits a sweep otherwise; check sidewalk/_hydra.py")
    assert basic_sweeper_points(None) == [[]]
    assert basic_sweeper_points({"noise": "0.0,0.5", "shield": "false,true"}) == [
        ["noise=0.0", "shield=False"], ["noise=0.0", "shield=True"],
        ["noise=0.5", "shield=False"], ["noise=0.5", "shield=True"],
    ]


def test_a_moved_split_is_named_with_the_hydra_version(monkeypatch):
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

    monkeypatch.setattr(BasicSweeper, "split_arguments", staticmethod(lambda overrides: []))
    with pytest.raises(RuntimeError, match=rf"Hydra {hydra.__version__}: BasicSweeper.split_arguments takes"):
        basic_sweeper_points({"a": "1,2"})


# ---- OmegaConf: the key a resolver resolves --------------------------------------------------------------------------


@pytest.fixture
def key_resolver():
    OmegaConf.register_new_resolver("test_adapters.key", lambda *, _node_: node_key(_node_))
    yield "test_adapters.key"
    OmegaConf.clear_resolver("test_adapters.key")


def test_a_resolver_learns_the_key_it_resolves(key_resolver):
    cfg = OmegaConf.create({"env": {"width_m": f"${{{key_resolver}:}}", "rows": [f"${{{key_resolver}:}}"]}})
    assert (cfg.env.width_m, cfg.env.rows[0]) == ("width_m", 0), (
        f"OmegaConf {omegaconf.__version__}: a resolver's _node_._key() no longer returns its key; "
        "update sidewalk/_omegaconf.py")


def test_a_node_without_its_key_is_named_with_the_omegaconf_version():
    with pytest.raises(RuntimeError, match=rf"OmegaConf {omegaconf.__version__}: object has no _key\(\)"):
        node_key(object())


# ---- Minari: a collector that records without jax --------------------------------------------------------------------

class Walk(gymnasium.Env):
    """A walker on a line with a dict observation; an episode ends after three steps."""

    observation_space = gymnasium.spaces.Dict({"position": gymnasium.spaces.Box(-10, 10, (1,), np.float32)})
    action_space = gymnasium.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.steps = 0
        return {"position": np.zeros(1, np.float32)}, {"flags": {"done": False}}

    def step(self, action):
        self.steps += 1
        observation = {"position": np.full(1, self.steps, np.float32)}
        return observation, 1.0, self.steps >= 3, False, {"flags": {"done": self.steps >= 3}}


def test_minari_s_episode_buffer_has_the_fields_the_adapter_copies():
    minari = pytest.importorskip("minari")  # an extra: sidewalk-problem[data]
    from minari.data_collector.episode_buffer import EpisodeBuffer

    from sidewalk._minari import EPISODE_BUFFER_FIELDS

    fields = tuple(field.name for field in dataclasses.fields(EpisodeBuffer))
    assert fields == EPISODE_BUFFER_FIELDS, (
        f"Minari {minari.__version__}: EpisodeBuffer's fields are {fields}; update sidewalk/_minari.py")


@pytest.mark.filterwarnings("ignore::UserWarning:minari.utils")  # the test dataset's missing description and specs
def test_the_collector_keeps_every_buffer_jax_free_and_records_every_step(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    from sidewalk._minari import jax_free_collector_class

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    monkeypatch.setitem(sys.modules, "jax", None)  # importing jax fails: only the adapter's buffer can record
    collector = jax_free_collector_class()(Walk(), record_infos=True)
    moved = f"Minari {minari.__version__} no longer keeps its episode buffer in DataCollector._buffer"
    try:
        collector.reset(seed=0)
        assert type(collector._buffer).__name__ == "NumpyEpisodeBuffer", moved
        for _ in range(4):  # one episode's end opens a new buffer, which must be re-typed too
            collector.step(1)
            assert type(collector._buffer).__name__ == "NumpyEpisodeBuffer", moved
        dataset = collector.create_dataset("test/walk-v0", algorithm_name="none", author="test",
                                           author_email="test@example.com", code_permalink="none")
        episode = next(dataset.iterate_episodes())
        assert episode.observations["position"].ravel().tolist() == [0, 1, 2, 3]
        assert episode.infos["flags"]["done"].tolist() == [False, False, False, True]
    finally:
        collector.close()


def test_tree_map_maps_dicts_tuples_and_lists_leaf_by_leaf():
    from sidewalk._minari import tree_map

    tree = {"a": (1, [2, 3]), "b": None}
    assert tree_map(lambda leaf, other: leaf + other, tree, {"a": (10, [20, 30]), "b": None}) == {
        "a": (11, [22, 33]), "b": None}
