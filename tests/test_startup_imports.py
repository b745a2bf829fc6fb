"""Heavy dependencies load only where they are used: not for ``motorid --help``, nor on importing the packages.

Checked in a fresh interpreter (``sys.modules`` after the import), not by timing; the times
are ``motorid bench startup``'s.
"""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("control", "matplotlib", "scipy.signal", "serial")

CASES = {
    "motorid --help": "import scenarios.cli, contextlib, io\n"
                      "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
                      "    scenarios.cli.main(['--help'])",
    "motorid identify --help": "import scenarios.cli, contextlib, io\n"
                               "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
                               "    scenarios.cli.main(['identify', '--help'])",
    "import identify": "import identify\nfrom identify import fit, available_methods, Estimate",
    "import motorsim": "import motorsim\nfrom motorsim.columns import import_recording",
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_no_heavy_import(case):
    code = CASES[case] + f"\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"{case} imported {proc.stdout.strip()}"
