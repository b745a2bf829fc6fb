"""Property-based tests, one per input surface: any input gives a result or one of our errors, never another.

Our errors subclass ``ValueError``/``TypeError`` and name what broke (``motorsim.checks.ParameterError``,
``RecordingFormatError``, ``ScenarioError``, ``NotIdentifiableError``); a plain ``ValueError``,
``IndexError``, ``RecursionError``, ``OverflowError`` or a hang is a bug.  Kept small, a few seconds in all.
"""
from __future__ import annotations

import io
import json
import string

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from identify.errors import NotIdentifiableError
from motorsim.checks import ParameterError
from motorsim.recording import RecordingFormatError
from scenarios.scenario import ScenarioError

OURS = (ParameterError, RecordingFormatError, ScenarioError, NotIdentifiableError)
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

HEADER = "# motorid recording v1\n# sample_period: 0.005\n# counts_per_rev: 1000\nseq,time_s,duty,counts\n"
GOOD_ROWS = [f"{k},{k * 0.005!r},{int(200 * np.sin(10 * k * 0.005))},{k * 3}" for k in range(60)]
CELL = st.one_of(st.integers(-2 ** 70, 2 ** 70).map(str), st.floats(allow_nan=True).map(repr),
                 st.text(alphabet=string.printable + "٠١٢٣٤٥٦٧٨٩\u00a0", max_size=8))


def _ours(call) -> None:
    try:
        call()
    except OURS:
        pass


@FUZZ
@given(row=st.integers(0, 59), column=st.integers(0, 3), cell=CELL, extra=st.sampled_from(
    ["", "# counts_per_rev: 1000\n", "# ppr: 999\n", "# dt: 0.004\n", "# sample_period: 1e-300\n", "#\n"]))
def test_recording_text(tmp_path, row, column, cell, extra):
    from motorsim.reading import read_recording
    rows = list(GOOD_ROWS)
    cells = rows[row].split(",")
    cells[column] = cell.replace(",", "").replace("\n", "")
    rows[row] = ",".join(cells)
    path = tmp_path / "fuzz.csv"
    path.write_text(HEADER.replace("seq,", extra + "seq,") + "\n".join(rows) + "\n", encoding="utf-8")
    _ours(lambda: read_recording(path))


@pytest.fixture(scope="module")
def mat_bytes() -> bytes:
    from scipy import io as sio
    buffer = io.BytesIO()
    sio.savemat(buffer, {"t": np.arange(50) * 0.005, "u": np.ones(50), "y": np.arange(50.0)})
    return buffer.getvalue()


@FUZZ
@given(data=st.data())
def test_mat_files(tmp_path, mat_bytes, data):
    from motorsim.columns import read_table
    raw = bytearray(mat_bytes)
    cut = data.draw(st.integers(0, len(raw)))
    for _ in range(data.draw(st.integers(0, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path / "fuzz.mat"
    path.write_bytes(bytes(raw[:cut]))
    _ours(lambda: read_table(path))


JSON = st.recursive(st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
                    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner,
                                                                                  max_size=3), max_leaves=8)
FIELDS = ["method", "a", "b", "extra", "param_names", "covariance", "sample_period", "units", "n_samples",
          "fit_percent", "residual_rms", "data_files"]


@FUZZ
@given(field=st.sampled_from(FIELDS), value=JSON)
def test_model_json(field, value):
    from identify.estimate import Estimate
    doc = json.loads(Estimate(method="oe", a=25.0, b=3.0, n_samples=10, sample_period=0.005, residual_rms=0.1,
                              fit_percent=99.0, covariance=np.eye(2)).to_json())
    doc[field] = value
    _ours(lambda: Estimate.from_json(json.dumps(doc)))


TOML_VALUE = st.one_of(st.integers(-10 ** 20, 10 ** 20), st.floats(allow_nan=False), st.text(max_size=6),
                       st.lists(st.one_of(st.integers(-1000, 10 ** 9), st.floats(allow_nan=False)), max_size=4),
                       st.booleans())


@FUZZ
@given(key=st.sampled_from(["repetitions", "duration", "sample_period", "a", "b", "frequency", "amplitude",
                            "methods", "angle_noise", "counts_per_rev", "seed", "name", "grid"]), value=TOML_VALUE)
def test_scenario_toml(key, value):
    from scenarios.scenario import scenario_from_dict
    doc = {"name": "fuzz", "repetitions": 2, "duration": 1.0, "sample_period": 0.005, "methods": ["zoh-ls"],
           "motor": {"a": 25.0, "b": 3.0}, "excitation": {"frequency": 10.0, "amplitude": 200}}
    if key in ("a", "b"):
        doc["motor"][key] = value
    elif key in ("frequency", "amplitude"):
        doc["excitation"][key] = value
    else:
        doc[key] = value
    _ours(lambda: scenario_from_dict(doc, source="fuzz"))


SPEC = st.text(alphabet="sinemultchrpbcaodkfx:,;@.-+e0123456789 ", max_size=24)


@FUZZ
@given(spec=SPEC)
def test_excitation_specs(spec):
    from motorsim.excitation import parse_excitation
    _ours(lambda: parse_excitation(spec))


@FUZZ
@given(spec=SPEC.map(lambda s: s.replace("sine", "step").replace("multi", "trapezoid")))
def test_reference_specs(spec):
    from motorsim.control import parse_reference
    _ours(lambda: parse_reference(spec))


@FUZZ
@given(text=st.one_of(st.text(max_size=12), st.sampled_from(["inf", "-inf", "nan", "1e309", "٣", "1_0", " 5 ",
                                                             "0x10", "1e-320", "-0"])))
def test_cli_numbers(text):
    from motorsim.rig import bench_knobs
    for knob in bench_knobs():
        _ours(lambda knob=knob: knob.parse(text))
