"""The one place where sidewalk touches Hydra's internals: how its basic sweeper splits a sweep into job points.

Hydra has no public function that lists a multirun's jobs before it launches them; the basic sweeper's static
``split_arguments``, on a class under ``hydra._internal``, does that split. Hydra may move or change it in any
release: ``basic_sweeper_points`` checks the class and the method's signature before it calls them and raises a
``RuntimeError`` naming the Hydra version and what moved (as ``tests/test_adapters.py`` does), never a silently
different list of jobs. Checked against Hydra 1.3.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping, Sequence
from typing import Any

import hydra

# The ``_target_`` of Hydra's basic sweeper (``hydra/sweeper=basic``, Hydra's default), as a config names it.
BASIC_SWEEPER = "hydra._internal.core_plugins.basic_sweeper.BasicSweeper"
# The parameters of ``BasicSweeper.split_arguments`` that sidewalk passes.
SPLIT_ARGUMENTS_PARAMETERS = ("overrides", "max_batch_size")


def _moved(what: str) -> RuntimeError:
    return RuntimeError(
        f"Hydra {hydra.__version__}: {what}, which sidewalk uses to list a sweep's jobs before they start; "
        "sidewalk/_hydra.py needs updating for this Hydra version"
    )


def basic_sweeper() -> type:
    """Hydra's ``BasicSweeper`` class, once its ``split_arguments`` takes ``SPLIT_ARGUMENTS_PARAMETERS``."""
    module_name, _, class_name = BASIC_SWEEPER.rpartition(".")
    try:
        from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    except ImportError as error:
        raise _moved(f"no {class_name} in {module_name} ({error})") from None
    split = getattr(BasicSweeper, "split_arguments", None)
    if split is None:
        raise _moved(f"{class_name} has no split_arguments")
    parameters = tuple(inspect.signature(split).parameters)
    if parameters != SPLIT_ARGUMENTS_PARAMETERS:
        raise _moved(f"{class_name}.split_arguments takes {parameters}, not {SPLIT_ARGUMENTS_PARAMETERS}")
    return BasicSweeper


def basic_sweeper_points(
    params: Mapping[str, Any] | None, arguments: Sequence[str] = (), config_loader: Any = None
) -> list[list[str]]:
    """The overrides of every job Hydra's basic sweeper launches for its ``params`` (``hydra.sweeper.params``) and
    the command line's ``arguments``, in its order: each key's values (``a=1,2``, ``range(1,4)``) crossed with the
    other keys', a key of ``params`` given again on the command line taking the command line's values. Each job's
    list holds one ``key=value`` per key, values written as Hydra writes them. ``config_loader`` is Hydra's (for
    ``glob`` over config groups), as the sweeper passes it."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    sweeper = basic_sweeper()
    # The sweeper's own order (BasicSweeper.sweep): its params first, then the command line.
    arguments = [*(f"{key}={value}" for key, value in (params or {}).items()), *arguments]
    overrides = OverridesParser.create(config_loader=config_loader).parse_overrides(arguments)
    return sweeper.split_arguments(overrides, max_batch_size=None)[0]
