"""Heavy dependencies load only where they are used: not for ``motorid --help``, nor on importing the packages,
nor to identify a short recording (its first-order filter passes are numpy's, ``motorsim.recursion``).

Checked in a fresh interpreter (``sys.modules`` after the import), not by timing; the times
are ``motorid bench startup``'s.
"""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("control", "matplotlib", "scipy.signal", "scipy.stats", "serial")

CASES = {
    "motorid --help": "import motorid.cli, contextlib, io\n"
                      "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
                      "    motorid.cli.main(['--help'])",
    "motorid identify --help": "import motorid.cli, contextlib, io\n"
                               "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
                               "    motorid.cli.main(['identify', '--help'])",
    "import identify": "import identify\nfrom identify import fit, available_methods, Estimate",
    "import motorsim": "import motorsim\nfrom motorsim.columns import import_recording",
    # what `motorid bench startup` times: a 400-sample run, identified with the command's defaults
    # (oe, automatic input delay, outlier screening, robust covariance) and printed
    "motorid identify short.csv": "import contextlib, io, os, tempfile\n"
                                  "from motorsim import Experiment, Motor, SimRig, Sine, write_recording\n"
                                  "import motorid.cli\n"
                                  "folder = tempfile.mkdtemp()\n"
                                  "path = write_recording(SimRig(Motor(25.0, 3.0)).run(\n"
                                  "    Experiment(Sine(10.0, 200), 0.005, 2.0)), os.path.join(folder, 'short.csv'))\n"
                                  "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
                                  "    code = motorid.cli.main(['identify', str(path)])\n"
                                  "assert code == 0 and 'method      oe' in out.getvalue(), (code, out.getvalue())",
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_no_heavy_import(case):
    code = CASES[case] + f"\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"{case} imported {proc.stdout.strip()}"


def test_the_default_on_a_linear_multisine_does_not_import_numba():
    # numba and its compiler hold about 130 MB: a linear recording's fit (the default's check of its friction
    # screen included) runs friction's few Python passes rather than import them (identify FILE's memory goal)
    code = ("import warnings\nwarnings.simplefilter('ignore')\n"
            "from motorid.bench.selection import _multisine\nfrom identify import fit\n"
            "est = fit(_multisine(10000))\nassert abs(est.a / 25 - 1) < 1e-3, est.a\n"
            "import sys\nprint('numba' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False"
