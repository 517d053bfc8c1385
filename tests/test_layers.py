"""The import layers of pyproject.toml's import-linter contract hold: a new upward import fails here."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_imports_point_down_the_layers():
    command = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    done = subprocess.run([command, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=600,
                          check=False)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "1 kept, 0 broken" in done.stdout


def test_the_guide_draws_the_layers_the_contract_holds():
    """docs/guide/extending.md's drawing of the layers is pyproject.toml's contract, line for line."""
    import re
    import tomllib

    contract = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]
    guide = (ROOT / "docs" / "guide" / "extending.md").read_text()
    drawing = re.search(r"## The layers\n.*?```text\n(.*?)```", guide, re.DOTALL)
    assert drawing is not None, "docs/guide/extending.md has no drawing of the layers"
    assert drawing.group(1).splitlines() == contract["layers"]
