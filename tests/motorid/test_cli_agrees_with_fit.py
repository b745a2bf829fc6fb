"""``identify.fit(rec, method)`` and ``motorid identify --method`` give the same answer for the same request.

The input delay's default is decided once (``identify.data.DEFAULT_INPUT_DELAY``); before, the command
line searched the delay while ``identify.fit`` fitted at 0 (a run with a 2-sample delay: delay 0 and
``a`` = 19.71 from Python, delay 2 and ``a`` = 25.00 from the command line).  Every method on every
recording of ``tests/data`` and on delayed simulated runs; the same code on the same numbers, so the
answers are equal to the last bit that JSON carries.
"""
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from identify import available_methods, fit, option_declarations, structures
from identify.data import DEFAULT_INPUT_DELAY
from motorid.cli import main
from motorsim import Motor
from motorsim.columns import import_recording
from motorsim.excitation import PRBS, Sine
from motorsim.rig import Experiment, SimRig
from motorsim.writing import write_recording

DATA = Path(__file__).parents[1] / "data" / "undcmotor"
#: Every recording of tests/data with the column flags that read it (t in s, u in V, y in deg/s).
LAB = {name: ["--time", "t:s", "--input", "u:V", "--speed", "y:deg/s"]
       for name in ("DCmotor_prbs_open_exp.csv", "DCmotor_step_open_exp.csv")}
#: Every open-loop method, the estimators of structures the default does not consider (a two-mass plant's
#: generic fit, bounded, on recordings it does not describe) among them.
METHODS = available_methods(open_loop=True)


def _cli(capsys, path, method, flags=()):
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main(["identify", str(path), "--method", method, "--json", *flags])
    captured = capsys.readouterr()
    if code != 0:
        return "refused"
    data = json.loads(captured.out)
    return data["input_delay"], data["a"], data["b"]


def _api(rec, method):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            est = fit(rec, method)
        except ValueError:
            return "refused"
    return est.input_delay, est.a, est.b


@pytest.fixture(scope="module")
def delayed(tmp_path_factory):
    """Simulated runs with an input delay: a sine through 2 samples, a PRBS through 3, with encoder noise."""
    d = tmp_path_factory.mktemp("delayed")
    runs = {}
    for name, delay, excitation, dt in (("sine-delay-2", 2, Sine(10.0, 200), 0.005),
                                        ("prbs-delay-3", 3, PRBS(200, -200, 8, 2), 0.002)):
        rec = SimRig(Motor(25.0, 3.0, input_delay=delay), rng=np.random.default_rng(delay)).run(
            Experiment(excitation, dt, 3.0))
        write_recording(rec, d / f"{name}.csv")
        runs[name] = d / f"{name}.csv"
    return runs


def test_the_input_delay_default_is_the_declared_one_for_every_method_that_searches_it():
    for method in METHODS:
        for o in option_declarations(method):
            if o.name == "input_delay" and "auto" in o.kind:
                assert o.default == DEFAULT_INPUT_DELAY == "auto"


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["sine-delay-2", "prbs-delay-3"])
def test_python_and_the_command_line_agree_on_delayed_runs(delayed, capsys, name, method):
    from motorsim.reading import read_recording
    path = delayed[name]
    api = _api(read_recording(path), method)
    assert api == _cli(capsys, path, method)
    if method in ("oe", "oe-friction", "iv"):           # the methods that search it find the delay
        assert api[0] == int(name[-1])


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(LAB))
def test_python_and_the_command_line_agree_on_every_recording_in_tests_data(capsys, name, method):
    flags = LAB[name]
    rec = import_recording(str(DATA / name), time=flags[1], input=flags[3], speed=flags[5])
    assert _api(rec, method) == _cli(capsys, DATA / name, method, flags)


def test_every_registered_structure_s_estimator_is_compared():
    """The structures the default does not consider (two-mass) are compared too: their fit is bounded."""
    assert {s.method for s in structures().values()} <= set(METHODS)
