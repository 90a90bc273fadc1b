"""Sphinx configuration of the documentation site (``make docs``; ``make docs-check`` fails on any warning).

Laid out as Stable-Baselines3's docs/conf.py: Markdown pages through myst-parser, the API reference through
autodoc and autosummary, SB3's Read the Docs theme. Sphinx rather than mkdocs: SB3's site is Sphinx, and our
docstrings are reST like SB3's.
"""

import ast
import datetime
import importlib
import os
import re
import sys
import warnings
from pathlib import Path

from docutils.utils import new_document
from sphinx.util.docutils import SphinxDirective

# The packages, as the editable install lays them out (sb3_emmarl/ and envs/wildlife_reserve/), for a checkout
# that was not installed; autodoc imports every module, so keep the threads of torch and numba to one.
ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path[:0] = [ROOT, os.path.join(ROOT, "envs")]
os.environ.setdefault("OMP_NUM_THREADS", "1")

from sb3_emmarl.version import __version__  # noqa: E402

# The API pages walk every module, the reserve's former name too (wildlife_reserve.reserve_v0, an alias that warns
# users who import it): its warning says nothing to a reader of the build.
warnings.filterwarnings("ignore", message="wildlife_reserve.reserve_v0 is the reserve's former name", category=FutureWarning)

# -- Project information -----------------------------------------------------------------------------------------------

project = "sb3-emmarl"
author = "sb3-emmarl contributors"
_year = datetime.date.today().year
copyright = f"2026-{_year}, {author}" if _year > 2026 else f"2026, {author}"
version = __version__
release = __version__

# -- General configuration ---------------------------------------------------------------------------------------------

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
language = "en"
exclude_patterns = ["_build", "_templates", "Thumbs.db", ".DS_Store"]
pygments_style = "sphinx"

# -- API reference -----------------------------------------------------------------------------------------------------

# Our docstrings are reST with ``:param:`` fields, which Sphinx's autodoc reads natively (no napoleon), as SB3's are.
autosummary_generate = True  # docs/api/_autosummary/ is written at build time, never checked in
autosummary_ignore_module_all = True  # a package's __all__ re-exports; each object is documented where it is defined
autodoc_default_options = {
    "members": True,
    "undoc-members": True,
    "show-inheritance": True,
    "ignore-module-all": True,
}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_preserve_defaults = True  # default arguments as written in the source (e.g. ``ENV_ID``), not their values
# Our own docstrings only: an override without one would otherwise show its base's, which for gymnasium and
# PettingZoo is Google style (their ``Args:`` blocks are not reST).
autodoc_inherit_docstrings = False

# -- Markdown (myst-parser) --------------------------------------------------------------------------------------------

# GitHub's anchors (e.g. results.md#how-much-knowing-the-mode-pays) on every heading level, so the links between
# pages work on GitHub and on the site alike.
myst_heading_anchors = 6
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath", "fieldlist"]

# -- HTML output -------------------------------------------------------------------------------------------------------

html_theme = "sphinx_rtd_theme"
html_title = f"sb3-emmarl {release}"
html_theme_options = {"navigation_depth": 3, "collapse_navigation": True}
html_show_sourcelink = False
html_static_path = ["_static"]
html_css_files = ["custom.css"]


# -- Environment cards ---------------------------------------------------------------------------------------------------

# An environment module's docstring is its PettingZoo card, written in Markdown as PettingZoo's are (a "# Title", a
# table, "### Observations" ...): it is parsed as Markdown, its title kept as the first paragraph (autosummary's
# one-line summary) and its other headings as rubrics under the module's own title.
_HEADING = re.compile(r"^#{1,6} +(.*?) *#*$")


def _markdown_card(app, what, name, obj, options, lines) -> None:
    start = next((i for i, line in enumerate(lines) if line.strip()), 0)
    if what != "module" or not lines or not lines[start].startswith("# "):
        return
    title = _HEADING.match(lines[start]).group(1)
    body = [f"   {line}" if line.strip() else "" for line in lines[start + 1:]]
    lines[:] = [f"**{title}**", "", ".. markdown-card::", "", *body]


class MarkdownCard(SphinxDirective):
    """The content, Markdown, parsed by myst-parser; headings become rubrics."""

    has_content = True

    def run(self) -> list:
        from myst_parser.parsers.sphinx_ import MystParser

        text = "\n".join(
            f"```{{rubric}} {match.group(1)}\n```" if (match := _HEADING.match(line)) else line for line in self.content
        )
        document = new_document(self.get_source_info()[0], self.state.document.settings)
        MystParser().parse(text, document)
        return list(document.children)


# -- Annotations named under TYPE_CHECKING ------------------------------------------------------------------------------

def _type_checking_imports(path: Path) -> list[str]:
    """The import statements under ``if TYPE_CHECKING:`` in a source file."""
    return [
        ast.unparse(statement)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        if isinstance(node, ast.If) and ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
        for statement in node.body
        if isinstance(statement, (ast.Import, ast.ImportFrom))
    ]


def _import_type_checking_names(app) -> None:
    """Run each module's ``if TYPE_CHECKING:`` imports in that module, for the docs build only.

    Without them ``typing.get_type_hints`` fails on an object whose annotations name such a class, and autodoc falls
    back to bare text (``policy: MlpPolicy``), which then resolves to whichever ``MlpPolicy`` Sphinx finds
    (sphinx-autodoc-typehints resolves them the same way). SB3's aliases (``GymEnv``, ``MaybeCallback``) hold
    forward references to its own TYPE_CHECKING names, which are evaluated in the module that uses the alias:
    every module gets those names too, where it has none of its own.
    """
    import stable_baselines3.common.type_aliases as sb3_aliases

    shared = _type_checking_imports(Path(sb3_aliases.__file__))
    for folder, package in (("sb3_emmarl", "sb3_emmarl"), ("envs/wildlife_reserve", "wildlife_reserve")):
        for path in sorted(Path(ROOT, folder).rglob("*.py")):
            parts = path.relative_to(Path(ROOT, folder)).with_suffix("").parts
            module = importlib.import_module(".".join((package, *(parts[:-1] if parts[-1] == "__init__" else parts))))
            for statement in (*_type_checking_imports(path), *shared):
                names: dict = {}
                try:
                    exec(statement, names)
                except ImportError:  # e.g. _typeshed, which exists for type checkers only
                    continue
                for name, value in names.items():
                    if name != "__builtins__":
                        module.__dict__.setdefault(name, value)


def setup(app) -> None:
    app.add_directive("markdown-card", MarkdownCard)
    app.connect("autodoc-process-docstring", _markdown_card)
    app.connect("builder-inited", _import_type_checking_names)
