"""The friction loop: the numba kernel and the Python loop give the same trajectory, and
simulate switches to the kernel only after enough Python intervals."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motorsim import Motor, compiled, simulate
from motorsim.compiled import friction_run_python


def _stick_slip_run(n=20_000):
    # a slow sine that lets friction stop the motor every half period, on a jittered clock
    rng = np.random.default_rng(2)
    t = np.concatenate([[0.0], np.cumsum(0.005 * (1 + 0.1 * rng.uniform(-1, 1, n - 1)))])
    return t, 40 * np.sin(2.0 * t) + 5 * rng.standard_normal(n)


def test_simulate_with_friction_is_the_same_on_both_paths(kernel_path):
    # both paths against the Python loop run directly: 1e-12 of the largest value (the
    # compiled libm may round exp/log differently in the last bit)
    t, duty = _stick_slip_run()
    motor = Motor(25.0, 3.0, friction=60.0, bias=1.0)
    traj = simulate(motor, duty, t, initial_speed=0.5, initial_angle=2.0)
    speed, angle = np.empty(len(t)), np.empty(len(t))
    speed[0], angle[0] = 0.5, 2.0
    friction_run_python(25.0, 3.0 * duty[:-1] + 1.0, 60.0, np.diff(t), speed, angle, 60.0)
    assert np.sum(speed == 0.0) > 100                      # it does stick
    assert np.max(np.abs(traj.speed - speed)) <= 1e-12 * np.max(np.abs(speed))
    assert np.max(np.abs(traj.angle - angle)) <= 1e-12 * np.max(np.abs(angle))


def test_the_kernel_is_used_only_after_enough_python_intervals(monkeypatch):
    calls = []
    monkeypatch.setattr(compiled, "compiled_kernel", lambda: lambda *args: calls.append(len(args[3])))
    monkeypatch.setattr(compiled, "COMPILE_AFTER", 1500)
    monkeypatch.setitem(compiled.usage, "python_intervals", 0)
    t = np.arange(1000) * 0.005
    motor = Motor(25.0, 3.0, friction=10.0)
    simulate(motor, np.full(1000, 100.0), t)
    simulate(motor, np.full(1000, 100.0), t)
    assert calls == []                                     # 999 + 999 intervals in Python
    simulate(motor, np.full(1000, 100.0), t)
    assert calls == [999]


def test_no_compiled_loop_without_numba_or_with_the_switch_off(monkeypatch):
    # numba is a dependency only where it has wheels: an import failure and MOTORID_NUMBA=0 both mean
    # "run the Python paths", never an error
    monkeypatch.setenv("MOTORID_NUMBA", "0")
    assert compiled.numba_jit() is None
    monkeypatch.delenv("MOTORID_NUMBA")
    monkeypatch.setitem(sys.modules, "numba", None)        # `import numba` raises ImportError
    assert compiled.numba_jit() is None


def test_the_install_requires_numba_where_it_has_wheels():
    # the speed goals hold in the install a user makes: `pip install motorid` brings numba on CPython
    from importlib.metadata import requires
    numba = [r for r in requires("motorid") or () if r.startswith("numba") and "extra ==" not in r]
    assert len(numba) == 1 and "platform_python_implementation == \"CPython\"" in numba[0], numba


FALLBACK_FIT = """
import sys
sys.modules["numba"] = None                                 # as where numba cannot install
import numpy as np
from identify import fit
from motorsim import Encoder, Experiment, Motor, Multisine, SimRig
from motorsim.compiled import numba_jit
assert numba_jit() is None
rig = SimRig(Motor(25.0, 3.0, friction=40.0), Encoder(2000), rng=np.random.default_rng(3))
rec = rig.run(Experiment(Multisine((5.0, 17.0, 41.0), (80, 60, 50), (0, 1, 2)), 0.002, 4.0))
est = fit(rec)
print(repr(est.a), repr(est.b), est.selection.chosen.label)
"""


@pytest.mark.slow
def test_a_process_without_numba_gives_the_same_default_fit():
    # the whole default (friction simulation, friction fits, their responses) on the pure paths, in a process
    # where numba cannot be imported, against this process's compiled paths: the same candidate and the same
    # a, b to 1e-7 (the two responses agree to ~1e-13; the fits' conditioning amplifies that far below 1e-7)
    import numpy as np

    from identify import fit
    from motorsim import Encoder, Experiment, Multisine, SimRig
    proc = subprocess.run([sys.executable, "-c", FALLBACK_FIT], capture_output=True, text=True, timeout=600,
                          cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 0, proc.stderr
    a, b, label = proc.stdout.split(maxsplit=2)
    rig = SimRig(Motor(25.0, 3.0, friction=40.0), Encoder(2000), rng=np.random.default_rng(3))
    rec = rig.run(Experiment(Multisine((5.0, 17.0, 41.0), (80, 60, 50), (0, 1, 2)), 0.002, 4.0))
    est = fit(rec)
    assert label.strip() == est.selection.chosen.label
    assert float(a) == pytest.approx(est.a, rel=1e-7) and float(b) == pytest.approx(est.b, rel=1e-7)
