"""Sphinx configuration of the sidewalk documentation: MyST Markdown pages plus autodoc, built offline.

python -m sphinx -W --keep-going -b html docs build/docs     # as tests/test_docs.py builds it
"""

from __future__ import annotations

import enum
import importlib
import importlib.util
import os
import re
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # autodoc documents this checkout, whatever copy of the package is installed

project = "sidewalk"
author = "The sidewalk authors"
copyright = "2026, The sidewalk authors"
release = version = importlib.import_module("sidewalk.version").__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.viewcode",
]

source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "examples",  # scripts, linked from the guide
]

# MyST: anchors on headings down to ###, for [text](page.md#anchor) links.
myst_heading_anchors = 3

# autodoc: our docstrings only; inherited ones come from TorchRL and Gymnasium, written for their own sites.
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_inherit_docstrings = False
autodoc_typehints = "description"
autodoc_member_order = "bysource"
# The API page's modules that import an optional package: PettingZoo is an extra, BenchMARL is installed apart
# (docs/guide/benchmarl.md). Where one is missing, autodoc imports those modules against Sphinx's mocks of it.
autodoc_mock_imports = [name for name in ("benchmarl", "pettingzoo") if importlib.util.find_spec(name) is None]


def benchmarl_stand_in() -> None:
    """For a build without BenchMARL: the names ``sidewalk.interop.benchmarl`` iterates or assigns into at import
    (it registers its tasks), which Sphinx's mocks cannot stand in for: the task registry and the task bases,
    ``Task`` an Enum numbering its members as BenchMARL's does. Sphinx's mocks serve the rest of BenchMARL."""

    class Task(enum.Enum):
        def __new__(cls, *args):
            member = object.__new__(cls)
            member._value_ = len(cls.__members__) + 1
            return member

    class TaskClass:
        pass

    root, environments, common = (types.ModuleType(name) for name in
                                  ("benchmarl", "benchmarl.environments", "benchmarl.environments.common"))
    Task.__module__ = TaskClass.__module__ = common.__name__
    common.Task, common.TaskClass = Task, TaskClass
    environments.common, environments.tasks, environments.task_config_registry = common, [], {}
    root.environments, root.__path__ = environments, []  # a package: its other modules come from the mocks
    sys.modules.update({module.__name__: module for module in (root, environments, common)})


if "benchmarl" in autodoc_mock_imports:
    benchmarl_stand_in()

html_theme = "alabaster"
html_title = f"sidewalk {release}"
html_theme_options = {
    "description": "The Sidewalk Problem as batched TorchRL environments",
    "fixed_sidebar": True,
    "page_width": "1200px",
    "body_max_width": "none",
}


# Pages link to files of the repository as GitHub reads them: relative to themselves. Sphinx knows only the
# pages of docs/ as documents, so a link to another Markdown file (results/reference/report.md) becomes a file
# link (MyST's `path:`), and a Markdown file included from elsewhere (results/reference/**/README.md) has its links
# rebased onto the including page, which must sit at the top of docs/: MyST names only the including page's stem.
RELATIVE_TARGET = re.compile(r"\]\((?![a-z][a-z0-9+.-]*:|#|/)([^)\s]+)\)")


def file_links(app, text: str, written_in: Path, read_from: Path, rebase_all: bool) -> str:
    srcdir = Path(app.srcdir).resolve()

    def rebase(match: re.Match) -> str:
        target, _, anchor = match.group(1).partition("#")
        resolved = (written_in / target).resolve()
        relative = os.path.relpath(resolved, read_from)
        inside = resolved.is_relative_to(srcdir)
        docname = resolved.relative_to(srcdir).with_suffix("").as_posix() if inside else None
        if resolved.suffix == ".md" and docname not in app.env.found_docs:
            return f"](path:{relative})"
        if rebase_all:
            return f"]({relative}{'#' + anchor if anchor else ''})"
        return match.group(0)

    return RELATIVE_TARGET.sub(rebase, text)


def page_links(app, docname, source):
    page_dir = Path(app.srcdir, docname).parent.resolve()
    source[0] = file_links(app, source[0], page_dir, page_dir, rebase_all=False)


def included_links(app, relative_path, parent_docname, content):
    included_dir = Path(app.srcdir, relative_path).parent.resolve()
    content[0] = file_links(app, content[0], included_dir, Path(app.srcdir).resolve(), rebase_all=True)


def setup(app):
    app.connect("source-read", page_links)
    app.connect("include-read", included_links)
