"""The report package imports one way: each module of ``sidewalk/report/`` only from the modules below it in
``LAYERS``, at module level or inside a function, so no import cycle can hide in it; and it imports in a fresh
interpreter with the names its users import."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "sidewalk" / "report"
# Bottom to top: a module may import from the modules before it, never from itself or those after it.
LAYERS = ("runs", "conditions", "tables", "checkpoints", "figures", "aggregates", "crossplay", "claims", "who_yields",
          "marl_eval", "document")


def report_imports(path: Path) -> list[tuple[int, str]]:
    """(line, layer) of every import in ``path`` that loads a module of ``sidewalk.report``, wherever it stands
    (module level or inside a function); ``"__init__"`` where it loads the package itself, which loads them all."""
    package = "sidewalk.report"
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative to sidewalk.report, the package of every file here
                parent = ".".join(package.split(".")[: 3 - node.level])
                base = f"{parent}.{base}" if base else parent
            # "from sidewalk.report import runs" loads a module; "from sidewalk.report import Settings", the package.
            modules = [f"{base}.{alias.name}" for alias in node.names] if base == package else [base]
        else:
            continue
        for module in modules:
            if module.startswith(f"{package}."):
                name = module.split(".")[2]
                found.append((node.lineno, name if name in LAYERS else "__init__"))
            elif module == package:
                found.append((node.lineno, "__init__"))
    return found


def test_every_module_of_the_report_package_has_a_layer():
    modules = {path.stem for path in PACKAGE.glob("*.py")} - {"__init__"}
    assert modules == set(LAYERS), "place a new module of sidewalk/report/ in LAYERS"


@pytest.mark.parametrize("layer", LAYERS)
def test_report_modules_import_only_from_the_layers_below(layer):
    path = PACKAGE / f"{layer}.py"
    upward = [
        f"{path.relative_to(ROOT)}:{line} imports sidewalk.report{'' if target == '__init__' else '.' + target}"
        for line, target in report_imports(path)
        if target == "__init__" or LAYERS.index(target) >= LAYERS.index(layer)
    ]
    assert not upward, f"imports against the layer order {' ← '.join(LAYERS)}: {upward}"


def test_the_layer_check_sees_imports_inside_functions(tmp_path):
    source = tmp_path / "runs.py"
    source.write_text(
        "from sidewalk.report.tables import fmt\n"
        "def f():\n"
        "    from .document import write_report\n"
        "    from . import figures\n"
        "    import sidewalk.report.claims\n"
        "    from sidewalk.report import Settings\n"
        "    from sidewalk.stats import iqm\n"
    )
    assert report_imports(source) == [
        (1, "tables"),
        (3, "document"),
        (4, "figures"),
        (5, "claims"),
        (6, "__init__"),
    ]


def test_report_package_imports_in_a_fresh_interpreter():
    code = (
        "from sidewalk.report.checkpoints import load_experiment, load_policy\n"
        "from sidewalk.report.claims import check_claims\n"
        "from sidewalk.report.document import write_report\n"
        "from sidewalk.report.tables import X_AXES, Settings\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0, result.stderr
