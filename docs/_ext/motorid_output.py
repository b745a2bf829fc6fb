"""The ``motorid-output`` directive: a ``motorid`` command run while the docs are built, its output shown.

A figure the docs quote comes from the command that prints it, run by ``make docs``::

    ```{motorid-output}
    motorid demo --no-plots --no-control
    ```

The command is shown, then what it printed on stdout (``:stderr:`` adds stderr). The commands of
one page run in order in one temporary folder that sees the repository's ``tests/`` (so
``tests/data/...`` paths work and ``simulate`` writes what ``identify`` reads), as the
documented-commands test runs them. A command that exits with another status than ``:status:``
(default 0) fails the build; ``:any-status:`` shows a benchmark's figures whatever it says of its
goals (a benchmark exits 1 when this machine missed one). ``:figures: A.png B/C.png`` shows the
figures the page's commands wrote, by their paths in that folder, below the output (copied into
``docs/_figures``, which ``make docs`` clears; a figure missing fails the build).
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import shutil
import tempfile
import warnings
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import Directive, directives

ROOT = Path(__file__).resolve().parent.parent.parent
#: Where the figures of ``:figures:`` are copied, in the docs' source folder (cleared by ``make docs``).
FIGURES = ROOT / "docs" / "_figures"


def _workdir(env) -> Path:
    folders = env.temp_data.setdefault("motorid_output_dirs", {})
    if env.docname not in folders:
        path = Path(tempfile.mkdtemp(prefix="motorid-docs-"))
        (path / "tests").symlink_to(ROOT / "tests")
        folders[env.docname] = path
    return folders[env.docname]


def run_documented(command: str, cwd: Path, *, stderr: bool = False) -> tuple[int, str]:
    """Run ``motorid ...`` through its entry point in ``cwd``: (status, what it printed)."""
    from motorid.cli import main
    words = shlex.split(command)
    if words[:1] != ["motorid"]:
        raise ValueError(f"a documented command starts with motorid, got {command!r}")
    out, err = io.StringIO(), io.StringIO()
    previous = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            try:
                status = main(words[1:])
            except SystemExit as stop:
                status = int(stop.code or 0)
    finally:
        os.chdir(previous)
    text = out.getvalue() + (err.getvalue() if stderr else "")
    return status, text


class MotoridOutput(Directive):
    has_content = True
    option_spec = {"stderr": directives.flag, "status": directives.nonnegative_int, "hide-command": directives.flag,
                   "any-status": directives.flag, "figures": directives.unchanged}

    def run(self):
        env = self.state.document.settings.env
        blocks = []
        for command in (line.strip() for line in self.content if line.strip()):
            status, text = run_documented(command, _workdir(env), stderr="stderr" in self.options)
            expected = self.options.get("status", 0)
            if status != expected and "any-status" not in self.options:
                raise self.error(f"{command!r} exited with status {status} (expected {expected}):\n{text[-2000:]}")
            shown = text.rstrip() if "hide-command" in self.options else f"$ {command}\n{text.rstrip()}"
            block = nodes.literal_block(shown, shown)
            block["language"] = "text"
            blocks.append(block)
        for name in self.options.get("figures", "").split():
            blocks.append(self._figure(env, name))
        return blocks

    def _figure(self, env, name: str) -> nodes.Node:
        """The figure ``name`` a command of this page wrote, as an image node (fails the build when missing)."""
        source = _workdir(env) / name
        if not source.is_file():
            raise self.error(f"figure {name!r} was not written by the commands above (looked in {source.parent})")
        FIGURES.mkdir(exist_ok=True)
        target = f"{re.sub(r'[^A-Za-z0-9]+', '-', env.docname)}-{re.sub(r'[^A-Za-z0-9.]+', '-', name)}"
        shutil.copyfile(source, FIGURES / target)
        figure = nodes.figure()
        figure += nodes.image(uri=f"/_figures/{target}", alt=name)
        figure += nodes.caption(name, name)
        return figure


def figure_scraper(block, block_vars, gallery_conf):
    """sphinx-gallery scraper for the figures of ``motorid.plots``.

    The plots build ``matplotlib.figure.Figure`` objects without pyplot (so the core needs no
    display), which the default scraper does not see: each new figure among the example's
    variables is saved to the gallery's next image path.
    """
    from matplotlib.figure import Figure
    from sphinx_gallery.scrapers import figure_rst
    seen = block_vars.setdefault("motorid_figures_seen", set())
    paths = []
    for value in list(block_vars["example_globals"].values()):
        if isinstance(value, Figure) and id(value) not in seen:
            seen.add(id(value))
            path = next(block_vars["image_path_iterator"])
            value.savefig(path, dpi=90)
            paths.append(path)
    return figure_rst(paths, gallery_conf["src_dir"])


def setup(app):
    app.add_directive("motorid-output", MotoridOutput)
    return {"parallel_read_safe": False, "parallel_write_safe": True}
