"""Every Python example of the Markdown documents runs as written, or scaled down, or says why not.

The ``python`` code blocks of the README and of the docs site's pages run in a fresh namespace in a
temporary folder that sees the repository's ``tests/``. One that needs a device or a server runs
against the software stand-ins the documents describe (:data:`SCALED`: each replacement is a
documented URL or flag), and one that cannot run here has its reason in :data:`NOT_RUN`. The
gallery's scripts (``docs/examples``) run in ``make docs``.
"""
from __future__ import annotations

import warnings

import pytest

from tests.test_documented_commands import DOCS, ROOT

#: text in an example -> what it is replaced by here (documented stand-ins)
SCALED = {
    # fake:// is the emulated Arduino on a pseudo-terminal; speed=0 runs it as fast as the host reads
    'SerialRig("/dev/ttyACM0", 250_000)': 'SerialRig("fake://?a=25&b=3&speed=0", 250_000)',
}

#: text in an example -> why the example is not run here
NOT_RUN = {
    'Client("tcp://scheduler:8786")': "needs a running Dask scheduler (tests/scenarios run sweeps on a local "
                                      "Dask executor)",
    'backlash: float = knob(': "one line to add inside a dataclass of the bench (tests/test_names.py checks every "
                               "knob declared that way)",
}


def _python_blocks(text: str):
    fence, start, lines = None, 0, []
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if fence is None and stripped.startswith("```") and stripped[3:].strip() == "python":
            fence, start, lines = stripped, number, []
        elif fence is not None and stripped.startswith("```"):
            yield start, "\n".join(lines)
            fence = None
        elif fence is not None:
            lines.append(line)


EXAMPLES = [(f"{doc.relative_to(ROOT)}:{n}", code) for doc in DOCS
            for n, code in _python_blocks(doc.read_text(encoding="utf-8"))]


def test_the_documents_show_python_examples():
    assert len(EXAMPLES) >= 3, [w for w, _ in EXAMPLES]


def _reason(code: str) -> str | None:
    return next((why for key, why in NOT_RUN.items() if key in code), None)


@pytest.mark.parametrize("where,code", [(w, c) for w, c in EXAMPLES if not _reason(c)], ids=lambda x: x[:40])
def test_python_example_runs(where, code, tmp_path, monkeypatch):
    (tmp_path / "tests").symlink_to(ROOT / "tests")
    monkeypatch.chdir(tmp_path)
    for old, new in SCALED.items():
        code = code.replace(old, new)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        exec(compile(code, where, "exec"), {"__name__": "__documented__"})


def test_every_skip_matches_an_example():
    for key in (*SCALED, *NOT_RUN):
        assert any(key in code for _, code in EXAMPLES), key
