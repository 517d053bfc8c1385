"""The documentation: the Sphinx site builds with warnings as errors, and the Python snippets of README.md
and of the user guide run, so that a snippet that rots fails the suite.

Every ```python block of a page runs, in order, in one fresh interpreter per page (cwd a temporary folder,
this checkout importable), so a block may use what an earlier block of its page defined. A block that must not
run is marked in its fence (```python no-run) or by a first line ``# not run: <why>``; bash blocks never run.
A snippet's traceback names the page and the line in it.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted((DOCS / "guide").glob("*.md"))]
FENCE = re.compile(
    r"^(?P<fence>`{3,})(?P<info>[^`\n]*)\n(?P<body>.*?)^(?P=fence)[ \t]*$", re.MULTILINE | re.DOTALL
)
SKIP_MARK = "# not run:"
TAIL_CHARS = 6000

# Runs each block compiled under its page's name, padded so that a traceback's line numbers are the page's.
RUNNER = """
import json, sys
namespace = {"__name__": "__main__"}
for page, line, code in json.load(open(sys.argv[1])):
    exec(compile("\\n" * (line - 1) + code, page, "exec"), namespace)
"""


def python_blocks(page: Path) -> list[tuple[str, int, str]]:
    """The runnable ```python blocks of ``page`` as (path, first line of code, code), in page order."""
    text = page.read_text()
    blocks = []
    for match in FENCE.finditer(text):
        words = match["info"].split()
        if not words or words[0] != "python" or "no-run" in words[1:]:
            continue
        if match["body"].lstrip().startswith(SKIP_MARK):
            continue
        first_line = text.count("\n", 0, match.start("body")) + 1
        blocks.append((str(page), first_line, match["body"]))
    return blocks


def tail(text: str) -> str:
    return text[-TAIL_CHARS:]


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.setdefault("MPLBACKEND", "Agg")
    return env


# The packages the extras install (pyproject's optional-dependencies) and BenchMARL (installed apart), by import name:
# the site must build without them, as it does from a plain `pip install` of the package and the docs tools.
OPTIONAL_IMPORTS = ("benchmarl", "pettingzoo", "vmas", "stable_baselines3", "sb3_contrib", "rliable", "tensorboard",
                    "wandb", "mlflow")
# Runs Sphinx with the packages named in argv[1] (comma-separated) not found, as where they are not installed.
SPHINX_WITHOUT = """
import importlib.machinery, sys
hidden, find = set(sys.argv[1].split(",")), importlib.machinery.PathFinder.find_spec
importlib.machinery.PathFinder.find_spec = lambda name, path=None, target=None: (
    None if name.partition(".")[0] in hidden else find(name, path, target))
from sphinx.cmd.build import main
sys.exit(main(sys.argv[2:]))
"""


def test_the_site_builds_without_warnings_or_optional_packages(tmp_path: Path) -> None:
    html = tmp_path / "html"
    out = subprocess.run(
        [sys.executable, "-c", SPHINX_WITHOUT, ",".join(OPTIONAL_IMPORTS), "-W", "--keep-going", "-b", "html",
         str(DOCS), str(html)],
        cwd=ROOT, env=child_env(), capture_output=True, text=True, timeout=600, check=False,
    )
    assert out.returncode == 0, f"sphinx failed ({out.returncode}):\n{tail(out.stdout + out.stderr)}"
    assert (html / "index.html").is_file()


@pytest.mark.parametrize("page", [page for page in PAGES if python_blocks(page)], ids=lambda p: p.name)
def test_the_python_snippets_of_a_page_run(page: Path, tmp_path: Path) -> None:
    blocks = tmp_path / "blocks.json"
    blocks.write_text(json.dumps(python_blocks(page)))
    out = subprocess.run(
        [sys.executable, "-c", RUNNER, str(blocks)],
        cwd=tmp_path, env=child_env(), capture_output=True, text=True, timeout=300, check=False,
    )
    name = page.relative_to(ROOT)
    assert out.returncode == 0, f"a snippet of {name} failed:\n{tail(out.stdout + out.stderr)}"


def test_the_readme_shows_the_three_faces() -> None:
    code = "\n".join(block for _, _, block in python_blocks(ROOT / "README.md"))
    for face in ("sidewalk.envs", "gymnasium.make", "parallel_env"):
        assert face in code, f"README.md has no runnable snippet using {face}"


def test_a_marked_block_is_not_run(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "```python\nx = 1\n```\n\n```python no-run\nraise SystemExit(1)\n```\n\n"
        "```python\n# not run: hours of training\nraise SystemExit(1)\n```\n\n"
        "````md\n```python\ny = 2\n```\n````\n```bash\nexit 1\n```\n"
    )
    assert [(line, code) for _, line, code in python_blocks(page)] == [(2, "x = 1\n")]


def test_the_readme_links_resolve() -> None:
    # The site's own build checks the links of docs/; README.md is not part of it.
    for target in re.findall(r"\]\((?![a-z][a-z0-9+.-]*:|#)([^)\s]+)\)", (ROOT / "README.md").read_text()):
        assert (ROOT / target.partition("#")[0]).exists(), f"README.md links to {target}: no such file"


def test_the_docs_stay_within_the_repository() -> None:
    for page in [ROOT / "README.md", *DOCS.rglob("*.md")]:
        assert "shared/" not in page.read_text(), f"{page.relative_to(ROOT)} points outside the repository"


def test_the_docs_and_the_reports_cite_only_what_ships() -> None:
    # The specification the developers work from does not ship: "SPEC §4" sends a reader nowhere. The paper's sections
    # and these pages do.
    texts = [ROOT / "README.md", *DOCS.rglob("*.md"), *(ROOT / "results" / "reference").rglob("*.md"),
             *(ROOT / "sidewalk" / "report").rglob("*.py")]
    for path in texts:
        cited = re.findall(r"\bSPEC\b[^\n]{0,20}", path.read_text())
        assert not cited, f"{path.relative_to(ROOT)} cites the unshipped SPEC: {cited}"


def test_the_gallery_reads_on_github_as_on_the_site() -> None:
    # GitHub shows a MyST directive as a literal block: the gallery links to the stills' page (a page of the site too).
    text = (DOCS / "gallery.md").read_text()
    assert "```{" not in text, "docs/gallery.md holds a MyST directive, which GitHub shows as a code block"
    targets = re.findall(r"\]\((?![a-z][a-z0-9+.-]*:|#)([^)\s]+)\)", text)
    assert "scenarios/README.md" in targets
    for target in targets:
        assert (DOCS / target).exists(), f"docs/gallery.md links to {target}: no such file"
