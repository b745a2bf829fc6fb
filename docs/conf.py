"""Sphinx configuration of the motorid documentation (``make docs``: warnings are errors)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))
os.environ.setdefault("MPLBACKEND", "Agg")

import motorid  # noqa: E402  (after the path is set)

project = "motorid"
author = "the motorid authors"
copyright = "the motorid authors, MIT licence"
release = motorid.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",   # MathJax 3 copied into _static: the pages render math with no network
    "numpydoc",
    "myst_parser",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
    "motorid_output",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "examples/README.rst"]
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath"]
suppress_warnings = ["myst.header"]

autosummary_generate = True
autodoc_default_options = {"members": True}
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_validation_checks: set[str] = set()
numpydoc_xref_param_type = False


sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("motorid_output.figure_scraper",),
    "write_computation_times": False,   # a page of this machine's timings, and one that loads scripts from CDNs
}

html_theme = "pydata_sphinx_theme"
html_title = "motorid"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
}
html_static_path: list[str] = []
nitpicky = False


def _check_pages(app, exc):
    """Fail the build when a page loads a script or style from another host (the site must work offline), or
    when a guide page's section navigation (the left sidebar) lists no page."""
    if exc is not None or app.builder.format != "html":
        return
    import re
    remote = re.compile(r"""<(?:script|link)[^>]+(?:src|href)=["'](?:https?:)?//""")
    for page in Path(app.outdir).rglob("*.html"):
        text = page.read_text(encoding="utf-8", errors="replace")
        if remote.search(text):
            raise RuntimeError(f"{page.relative_to(app.outdir)} loads a script or style from the network; the "
                               "docs must render offline")
        nav = text.partition('class="bd-links__title"')[2].partition("</nav>")[0]
        if page.parent.name == "guide" and "<a" not in nav:
            raise RuntimeError(f"{page.relative_to(app.outdir)}: its section navigation lists no page")


def setup(app):
    app.connect("build-finished", _check_pages)
