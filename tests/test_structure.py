"""The package stays readable: short functions, modules that hold one thing, and other libraries' internals reached
only through the ``_``-named adapters (``_torchrl.py``, ``_hydra.py``, ``_omegaconf.py``, ``_minari.py``), so a
release that changes them fails in one place, loudly (tests/test_adapters.py, tests/test_torchrl_adapter.py)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sidewalk"
SOURCES = sorted(PACKAGE.rglob("*.py"))
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = {"experiment.py": 400, **{f"views/{p.name}": 400 for p in (PACKAGE / "views").glob("*.py")}}
ADAPTER = PACKAGE / "_torchrl.py"
ADAPTERS = [path for path in sorted(PACKAGE.glob("_*.py")) if path.name not in ("__init__.py", "_checks.py")]
# Private names of other libraries that are theirs to offer to subclasses: Stable-Baselines3's VecEnv._get_indices
# (for VecEnv subclasses) and NamedTuple's public _replace.
OFFERED = {"_get_indices", "_replace"}


def parsed(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def test_no_function_is_longer_than_80_lines():
    long = [
        f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for path in SOURCES for node in ast.walk(parsed(path))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES
    ]
    assert not long, "split into named parts: " + "; ".join(long)


@pytest.mark.parametrize("module, limit", sorted(MAX_MODULE_LINES.items()))
def test_the_experiment_and_the_views_stay_short(module, limit):
    assert len((PACKAGE / module).read_text().splitlines()) < limit


def own_names() -> set[str]:
    """Every name sidewalk defines or imports: a private attribute with one of these names is our own."""
    names: set[str] = set()
    for path in SOURCES:
        if path in ADAPTERS:
            continue
        for node in ast.walk(parsed(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names.add(node.target.id)
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                names.update((alias.asname or alias.name).split(".")[-1] for alias in node.names)
    return names


def test_private_attributes_of_other_libraries_are_reached_only_through_the_adapters():
    ours = own_names() | OFFERED
    reached = sorted(
        f"{path.relative_to(PACKAGE)}:{node.lineno} .{node.attr}"
        for path in SOURCES if path not in ADAPTERS
        for node in ast.walk(parsed(path))
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
        and node.attr not in ours
    )
    assert not reached, "go through an adapter (sidewalk/_torchrl.py, _hydra.py, ...): " + "; ".join(reached)


def test_private_modules_of_other_libraries_are_imported_only_by_the_adapters():
    """``hydra._internal``, ``minari.data_collector.episode_buffer``'s privates and kin: imported in an adapter."""
    imported = sorted(
        f"{path.relative_to(PACKAGE)}:{node.lineno} {module}"
        for path in SOURCES if path not in ADAPTERS
        for node in ast.walk(parsed(path))
        for module in ([node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                       else [alias.name for alias in node.names] if isinstance(node, ast.Import) else [])
        if not module.startswith("sidewalk") and module != "__future__"
        and any(part.startswith("_") for part in module.split("."))
    )
    assert not imported, "go through an adapter: " + "; ".join(imported)


def test_the_adapters_are_the_bottom_layer():
    """An adapter imports its library and the standard library, nothing of sidewalk's but ``_checks``."""
    for path in ADAPTERS:
        for node in ast.walk(parsed(path)):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sidewalk"):
                assert node.module == "sidewalk._checks", f"{path.name} imports {node.module}"


def test_the_adapter_names_every_private_attribute_it_touches():
    """The attributes the adapter reaches are listed where its checks read them, so a TorchRL change is named."""
    source = ADAPTER.read_text()
    for attribute in ("_carrier", "_frames", "_iter", "_low", "_high", "_batch_size"):
        assert f'"{attribute}"' in source, attribute
