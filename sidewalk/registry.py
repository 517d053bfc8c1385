"""One registry for each kind of plug-in: opponents, layouts (scenarios) and learners.

A plug-in declares itself once, where it is written: an ``Opponent`` or ``Algorithm`` subclass with a ``name``
registers itself when its class is created, a layout module registers its ``Scenario``. The built-in ones are the
modules of their package (imported the first time a registry is read); another package adds its own through
Python entry points, the mechanism Gymnasium and pytest use::

    [project.entry-points."sidewalk.opponents"]
    shy = "my_package.shy:ShyOpponent"

(groups ``sidewalk.opponents``, ``sidewalk.layouts``, ``sidewalk.learners``; the value is the class, or the
layout's ``Scenario``), and its YAML through Hydra's search path (``docs/guide/extending.md``). What a plug-in
supports (domains, multi-agent, ...) is read from the plug-in itself, so the config checks need no list of names.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import pkgutil
from collections.abc import Callable, Iterator, Mapping
from typing import Any


class UnknownName(KeyError, ValueError):
    """A name no plug-in has (a ``KeyError`` for mapping code, a ``ValueError`` for the config checks)."""

    def __str__(self) -> str:
        return str(self.args[0])


class Registry(Mapping[str, Any]):
    """Name → plug-in of one ``kind``, filled by the built-in modules of ``packages`` and the entry points of
    ``group``, both read on first use. A name asked for but missing raises ``UnknownName`` naming the valid ones."""

    def __init__(self, kind: str, packages: tuple[str, ...], group: str) -> None:
        self.kind = kind
        self.packages = packages
        self.group = group
        self._entries: dict[str, Any] = {}
        self._broken: dict[str, str] = {}  # plug-ins whose entry point failed to load, with the error
        self._loaded = False
        self._loading = False

    def register(self, name: str, entry: Any) -> None:
        """Add ``entry`` under ``name``; a second, different entry under one name is an error."""
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"{self.kind} name {name!r} must be an identifier (it is a config choice)")
        known = self._entries.get(name)
        if known is not None and _qualname(known) != _qualname(entry):
            raise ValueError(f"two {self.kind}s are named {name!r}: {_qualname(known)} and {_qualname(entry)}")
        self._entries[name] = entry

    def load(self) -> None:
        """Import the built-in modules and the installed plug-ins (once)."""
        if self._loaded or self._loading:
            return
        self._loading = True
        try:
            for name in self.packages:
                package = importlib.import_module(name)
                for module in pkgutil.iter_modules(package.__path__):
                    importlib.import_module(f"{name}.{module.name}")
            for point in importlib.metadata.entry_points(group=self.group):
                self._load_entry_point(point)
            self._loaded = True
        finally:
            self._loading = False

    def _load_entry_point(self, point: importlib.metadata.EntryPoint) -> None:
        try:
            entry = point.load()  # importing the module may register the entry itself
        except Exception as error:  # noqa: BLE001  # one broken plug-in does not take the others down; naming it does
            self._broken[point.name] = f"{point.value}: {type(error).__name__}: {error}"
            return
        self.register(point.name, entry)

    def __getitem__(self, name: str) -> Any:
        self.load()
        if name in self._entries:
            return self._entries[name]
        if name in self._broken:
            raise UnknownName(f"{self.kind} {name!r} (entry point group {self.group}) failed to load: "
                              f"{self._broken[name]}")
        raise UnknownName(f"{self.kind}={name!r} is not valid; valid: {', '.join(map(repr, self))}")

    def __contains__(self, name: object) -> bool:
        self.load()
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        self.load()
        return iter(sorted(self._entries))

    def __len__(self) -> int:
        self.load()
        return len(self._entries)

    def names(self, where: Callable[[Any], bool] = lambda entry: True) -> list[str]:
        """The registered names whose entry satisfies ``where`` (e.g. plays a domain)."""
        return [name for name in self if where(self._entries[name])]


def _qualname(entry: Any) -> str:
    return f"{getattr(entry, '__module__', '?')}.{getattr(entry, '__qualname__', repr(entry))}"


# Scripted opponents live below the views, the partners made of a saved run or a dataset above the learners: one name
# space of choices for ``opponent=``.
OPPONENTS = Registry("opponent", ("sidewalk.opponents", "sidewalk.partners"), "sidewalk.opponents")
LAYOUTS = Registry("layout", ("sidewalk.envs.layouts",), "sidewalk.layouts")
LEARNERS = Registry("algo", ("sidewalk.algos",), "sidewalk.learners")
