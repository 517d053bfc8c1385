"""The one place where sidewalk touches Minari's internals: a ``minari.DataCollector`` that records without jax.

Minari 0.5's ``EpisodeBuffer.add_step_data`` imports jax (``minari[create]``, hundreds of MB) only for a tree map over
dicts of arrays. Its callbacks (``StepDataCallback``, ``EpisodeMetadataCallback``) shape what is recorded, not how the
buffer appends it, and the collector builds its ``EpisodeBuffer`` by name: no public hook swaps the buffer. So the
collector here re-types the buffer that ``reset`` and ``step`` leave in the private ``_buffer``, copying
``EpisodeBuffer``'s dataclass fields. Minari may change either in any release: the collector checks both and raises a
``RuntimeError`` naming the Minari version (as ``tests/test_adapters.py`` does). Checked against Minari 0.5.
Minari is imported only when a collector is first built: ``import sidewalk`` stays light.
"""

from __future__ import annotations

import dataclasses
from functools import cache
from typing import Any

# The fields of Minari's EpisodeBuffer that the jax-free buffer reads and appends to.
EPISODE_BUFFER_FIELDS = ("id", "seed", "options", "observations", "actions", "rewards", "terminations", "truncations",
                         "infos")


def tree_map(fn: Any, tree: Any, other: Any) -> Any:
    """``fn`` over the leaves of ``tree`` (dicts, tuples and lists are nodes; None stays None), with the matching
    part of ``other``: the little of ``jax.tree_util.tree_map`` that Minari's episode buffers use."""
    if tree is None:
        return None
    if isinstance(tree, dict):
        return {key: tree_map(fn, value, other[key]) for key, value in tree.items()}
    if isinstance(tree, (tuple, list)):
        return type(tree)(tree_map(fn, value, part) for value, part in zip(tree, other, strict=True))
    return fn(tree, other)


def _moved(what: str) -> RuntimeError:
    import minari

    return RuntimeError(
        f"Minari {minari.__version__}: {what}, which sidewalk uses to record episodes without jax; "
        "sidewalk/_minari.py needs updating for this Minari version"
    )


def _append(data: Any, buffer: Any) -> list:
    if isinstance(buffer, list):
        buffer.append(data)
        return buffer
    return [buffer, data]


def _numpy_episode_buffer_class() -> type:
    """Minari's ``EpisodeBuffer`` whose ``add_step_data`` appends with ``tree_map`` rather than jax's."""
    from minari.data_collector.episode_buffer import EpisodeBuffer

    fields = tuple(field.name for field in dataclasses.fields(EpisodeBuffer))
    if fields != EPISODE_BUFFER_FIELDS:
        raise _moved(f"EpisodeBuffer's fields are {fields}, not {EPISODE_BUFFER_FIELDS}")

    @dataclasses.dataclass(frozen=True)
    class NumpyEpisodeBuffer(EpisodeBuffer):
        def add_step_data(self, step_data: Any) -> NumpyEpisodeBuffer:
            def first(data: Any) -> Any:
                return tree_map(lambda leaf, _: [leaf], data, data)

            observations = step_data["observation"]
            if self.observations is not None:
                observations = tree_map(_append, step_data["observation"], self.observations)
            actions = first(step_data["action"]) if self.actions is None else tree_map(
                _append, step_data["action"], self.actions)
            infos = first(step_data["info"]) if self.infos is None else tree_map(_append, step_data["info"], self.infos)
            self.rewards.append(step_data["reward"])
            self.terminations.append(step_data["terminated"])
            self.truncations.append(step_data["truncated"])
            fields = {name: getattr(self, name) for name in EPISODE_BUFFER_FIELDS}
            return NumpyEpisodeBuffer(**{**fields, "observations": observations, "actions": actions, "infos": infos})

    return NumpyEpisodeBuffer


@cache
def jax_free_collector_class() -> type:
    """``minari.DataCollector`` whose episode buffers append without jax; built (and Minari imported) once."""
    import minari

    numpy_episode_buffer = _numpy_episode_buffer_class()

    class SidewalkDataCollector(minari.DataCollector):
        """A ``minari.DataCollector`` that records without jax (``sidewalk.datasets.record`` builds it)."""

        def _retype(self) -> None:
            if not hasattr(self, "_buffer"):
                raise _moved("DataCollector keeps no _buffer")
            buffer = self._buffer
            if buffer is not None and not isinstance(buffer, numpy_episode_buffer):
                self._buffer = numpy_episode_buffer(**{name: getattr(buffer, name) for name in EPISODE_BUFFER_FIELDS})

        def reset(self, *args: Any, **kwargs: Any):
            out = super().reset(*args, **kwargs)
            self._retype()
            return out

        def step(self, action: Any):
            out = super().step(action)
            self._retype()  # an episode's end opened a new buffer
            return out

    return SidewalkDataCollector
