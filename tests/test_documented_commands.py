"""Every command the Markdown files show runs as written (or, for a synopsis, names real flags).

The shell lines are taken from the code blocks (indented or fenced without a language, or
``sh``/``console``) of every ``.md`` file of the repository, the docs site's pages and their
``{motorid-output}`` blocks (run by ``make docs``) included: lines that start with ``motorid``
or ``make`` (a ``$ `` prompt is dropped, ``#`` comments are cut, ``;`` separates commands).

- A **synopsis** (``[optional]`` parts, ``a|b`` choices or placeholders such as ``FILE.csv``)
  cannot run as written: its command must exist and every ``--flag`` it names must be a flag
  of that command.
- A **concrete** command runs through ``motorid``'s entry point in a temporary folder that sees
  the repository's ``tests/`` (so ``tests/data/...`` paths work), the commands of one file in
  order (``import`` writes what ``identify`` reads), and must exit with status 0.  Long ones are
  scaled down by :data:`SCALED`, with flags the documents describe.
- ``make`` targets and the emulated-firmware commands are not run here, each for the reason
  in :data:`NOT_RUN` (the firmware ones run under the ``firmware`` marker in
  ``tests/motorid/test_live.py``).
"""
from __future__ import annotations

import re
import shlex
import warnings
from pathlib import Path

import pytest

from motorid.cli import main

ROOT = Path(__file__).resolve().parent.parent
DOCS = sorted(p for p in ROOT.rglob("*.md")
              if not {".venv", "build", "_build", "auto_examples", "generated"} & set(p.parts))

#: a command as documented -> the same command scaled down (documented flags or URL keys only)
SCALED = {
    # fake:// key speed: device time per wall-clock time, 0 = as fast as the host reads (README)
    "motorid live --port 'fake://?a=25&b=3' --duration 10 --json":
        "motorid live --port 'fake://?a=25&b=3&speed=0' --duration 10 --json",
    "motorid live --port 'fake://?a=2&b=0.3' --until 1":
        "motorid live --port 'fake://?a=2&b=0.3&speed=0' --until 1",
    # --samples and --repeats: the benchmark's own flags (motorid bench simulate --help)
    "motorid bench simulate": "motorid bench simulate --samples 2000 --repeats 1",
}

#: a command (prefix) -> why it is not run by this test
NOT_RUN = {
    "make test": "the whole suite, this test included (CI runs it)",
    "make test-fast": "a subset of this suite",
    "make lint": "ruff and mypy, run by CI",
    "make docs": "builds the documentation site, its {motorid-output} commands and examples included (CI runs it)",
    "make demo": "creates .venv and runs motorid demo (tests/motorid/test_demo.py runs the demo)",
    "make venv": "creates .venv and installs motorid into it (every make target does)",
    "make firmware": "installs the AVR toolchain with apt-get and builds the firmware (make test does)",
    "make avr-sim": "installs simavr with apt-get and builds the harness (make test does)",
    "make bench-check": "a new virtual environment and the speed gate, minutes of timings on the machine's load",
    # benchmarks whose output a page shows ({motorid-output} :any-status:): make docs runs them in CI;
    # their goals depend on the machine's load, and they start processes or run in real time
    "motorid bench --check": "the speed gate: every goal's benchmark at full size, minutes of timings on the "
                             "machine's load (docs/develop.md: run before a change lands)",
    "motorid bench startup": "starts each command as a subprocess, repeatedly (make docs runs it)",
    "motorid bench parse": "reads a large file in fresh processes, twice per reader (make docs runs it)",
    "motorid bench serial --frames": "a real-time run through a pty (make docs runs it)",
    "motorid bench sweep --repetitions": "a python-control loop per run as its baseline (make docs runs it)",
    "motorid bench firmware": "needs the firmware built with the AVR toolchain (tests/hardware/"
                              "test_firmware_emulation.py measures the same under the firmware marker)",
    "motorid live --port 'avr-sim://": "needs the firmware built with the AVR toolchain: the firmware-marked "
                                       "test_live_on_the_emulated_firmware_holds_a_and_b_in_its_intervals runs it",
}

_PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*(\.[a-z0-9]+)?$|^[A-Z]+\.[a-z]+$")


def _blocks(text: str):
    """(line number, line) of every line in a shell code block."""
    fence, lang, in_indented = None, "", False
    previous_blank = True
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if stripped.startswith("```"):
            if fence is None:
                fence, lang = stripped, stripped[3:].strip()
            else:
                fence = None
            continue
        if fence is not None:
            if lang in ("", "sh", "bash", "shell", "console", "{motorid-output}"):
                yield number, stripped
            continue
        in_indented = line.startswith("    ") and (in_indented or previous_blank)
        if in_indented:
            yield number, stripped
        previous_blank = not stripped


def documented_commands() -> list[tuple[str, str]]:
    """``(where, command)`` for every command line of every Markdown file."""
    found = []
    for doc in DOCS:
        for number, line in _blocks(doc.read_text(encoding="utf-8")):
            line = line[2:] if line.startswith("$ ") else line
            line = line.removeprefix(".venv/bin/")          # the README's tour, runnable as pasted in a clone
            if not line.startswith(("motorid ", "make ")):
                continue
            code = re.split(r"\s+#\s", line, maxsplit=1)[0]
            for part in code.split(";"):
                if part.strip():
                    found.append((f"{doc.relative_to(ROOT)}:{number}", part.strip()))
    return found


COMMANDS = documented_commands()


def _is_synopsis(words: list[str]) -> bool:
    return any("[" in w or ("|" in w and "://" not in w) or _PLACEHOLDER.match(w) for w in words[1:])


def _not_run(command: str) -> str | None:
    return next((why for prefix, why in NOT_RUN.items() if command.startswith(prefix)), None)


def test_the_documents_show_commands():
    assert len(COMMANDS) >= 25, COMMANDS          # the extraction finds the README's command lines
    assert any(c == "motorid live --port 'fake://?a=25&b=3' --duration 10 --json" for _, c in COMMANDS)


@pytest.mark.parametrize("where,command", [(w, c) for w, c in COMMANDS
                                           if not _not_run(c) and _is_synopsis(shlex.split(c))],
                         ids=lambda x: x)
def test_synopsis_names_real_flags(where, command, motorid_commands):
    words = shlex.split(command)
    path = max((p for p in motorid_commands if tuple(words[1:1 + len(p)]) == p), key=len)
    assert path, f"{where}: no command {words[1]!r}"
    offered = {s for action in motorid_commands[path]._actions for s in action.option_strings}
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", command))
    assert named <= offered, f"{where}: motorid {' '.join(path)} has no {sorted(named - offered)}"


CONCRETE = [(w, c) for w, c in COMMANDS if not _not_run(c) and not _is_synopsis(shlex.split(c))]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    path = tmp_path_factory.mktemp("documented")
    (path / "tests").symlink_to(ROOT / "tests")
    return path


@pytest.mark.parametrize("where,command", CONCRETE, ids=lambda x: x)
def test_concrete_command_runs(where, command, workdir, monkeypatch, capsys):
    monkeypatch.chdir(workdir)
    argv = shlex.split(SCALED.get(command, command))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)     # what a user is told (e.g. friction merged into bias)
        status = main(argv[1:])
    captured = capsys.readouterr()
    assert status == 0, f"{where}: {command}\n{captured.err[-2000:]}"


def test_every_skip_has_a_reason_and_matches_a_command():
    for prefix, why in NOT_RUN.items():
        assert why and any(c.startswith(prefix) for _, c in COMMANDS), prefix
    assert set(SCALED) <= {c for _, c in COMMANDS}
