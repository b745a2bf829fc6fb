"""The Python API's user errors are ours: ValueError/TypeError subclasses that name the parameter, rule and value."""
from __future__ import annotations

import json

import numpy as np
import pytest

from identify import fit
from identify.errors import NotIdentifiableError
from identify.estimate import Estimate
from motorsim import Recording
from motorsim.checks import ParameterError, ParameterTypeError

OURS = (ParameterError, NotIdentifiableError)


def _estimate() -> Estimate:
    return Estimate(method="oe", a=25.0, b=3.0, n_samples=1000, sample_period=0.005, residual_rms=1e-4,
                    fit_percent=99.0, covariance=np.diag([0.01, 1e-4]), extra={"input_delay": 1})


def _v1(**change) -> str:
    """A document of the first format (parameters and the delay nested under ``extra``)."""
    doc = {"format": "motorid estimate v1", "method": "oe", "a": 25.0, "b": 3.0, "extra": {"input_delay": 1},
           "param_names": ["a", "b"], "covariance": [[0.01, 0.0], [0.0, 1e-4]], "sample_period": 0.005,
           "n_samples": 1000, "fit_percent": 99.0, "residual_rms": 1e-4}
    doc.update(change)
    return json.dumps(doc)


def _doc(**change) -> str:
    doc = json.loads(_estimate().to_json())
    doc.update(change)
    return json.dumps(doc)


@pytest.mark.parametrize("text, match", [
    (_doc().replace('"a": 25.0', '"a": NaN'), "finite"),
    ("[" * 100_000 + "]" * 100_000, "nested too deep"),
    ('{"format": ' * 100_000, "nested too deep|at most"),
    (_doc(a=True), "'a' must be a number"),
    (_doc(a="25"), "'a' must be a number"),
    (_v1(extra={"input_delay": 1.5}), "input_delay"),
    (_v1(extra=[1, 2]), "'extra' must be an object"),
    (_doc(input_delay=1.5), "input_delay"),
    (_doc(input_delay=-1), "input_delay"),
    (_doc(structure="third-order"), "structure must be one of"),
    (_doc(structure="friction", friction="x"), "'friction' must be a number"),
    (_doc(units=[1]), "'units' must be an object"),
    (_doc(units={"input": 7}), "units.input"),
    (_doc(covariance=[[1.0]]), "covariance"),
    (_doc(covariance="x"), "covariance"),
    (_doc(param_names=[1, 2]), "param_names"),
    (_doc(data_files=[{"path": 1}]), "data_files"),
    (_doc(sample_period=-1), "sample_period"),
    (_doc(n_samples="many"), "n_samples"),
    (json.dumps({k: v for k, v in json.loads(_doc()).items() if k != "method"}), "method"),
], ids=["NaN", "nested list bomb", "nested object bomb", "a true", "a string", "v1 delay 1.5", "v1 extra list",
        "delay 1.5", "negative delay", "unknown structure", "friction string",
        "units list", "unit number", "covariance shape", "covariance string", "names numbers", "data files",
        "negative sample period", "n_samples string", "no method"])
def test_a_hostile_saved_model_raises_our_errors_naming_the_field(text, match):
    with pytest.raises(OURS, match=match):
        Estimate.from_json(text)


def test_binary_text_and_wrong_argument_types_are_our_errors(tmp_path):
    path = tmp_path / "model.json"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    with pytest.raises(ParameterError, match="binary"):
        Estimate.from_json(str(path))
    with pytest.raises(ParameterTypeError, match="text"):
        Estimate.from_json(42)          # type: ignore[arg-type]


def test_a_saved_model_round_trips():
    assert Estimate.from_json(_estimate().to_json()).input_delay == 1


def test_a_model_of_the_first_format_is_read_and_migrated():
    est = Estimate.from_json(_v1())
    assert (est.structure, est.input_delay, est.a, est.b) == ("linear", 1, 25.0, 3.0)
    assert json.loads(est.to_json())["format"] == "motorid estimate v2"


T = np.arange(1000) * 0.005
U = np.round(200 * np.sin(10 * T))


@pytest.mark.parametrize("kw, match", [
    (dict(speed=np.where(np.arange(1000) == 5, np.nan, 1.0)), "speed must be finite"),
    (dict(speed=1e300 * np.sin(T)), "speed must be within"),
    (dict(angle=1e15 * T), "angle must be within"),
], ids=["NaN speed", "speed 1e300", "angle 1e15"])
def test_a_recording_that_no_motor_gives_is_refused_by_the_constructor(kw, match):
    with pytest.raises(ParameterError, match=match):
        Recording(T, U, 0.005, **kw)


def test_a_time_base_scaled_by_1e_300_is_refused_not_fitted_to_a_1e299():
    with pytest.raises(ParameterError, match="sample_period must be in"):
        Recording(T * 1e-300, U, 0.005e-300, speed=np.sin(T))


def test_counts_offset_by_2_62_give_the_same_fit_as_without():
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rec = SimRig(Motor(25.0, 3.0), Encoder(16667)).run(Experiment(Sine(10.0), 0.005, 3.0))
    shifted = Recording(rec.time, rec.duty, rec.sample_period, counts=rec.counts + 2 ** 62,
                        counts_per_rev=rec.counts_per_rev)
    assert fit(shifted).a == pytest.approx(fit(rec).a, rel=1e-9)


def test_an_input_delay_the_data_cannot_hold_is_refused_by_name():
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rec = SimRig(Motor(25.0, 3.0), Encoder(16667)).run(Experiment(Sine(10.0), 0.005, 5.0))
    for delay in (500, 5000):
        with pytest.raises(NotIdentifiableError, match="input_delay"):
            fit(rec, method="oe", input_delay=delay)


@pytest.mark.parametrize("make, match", [
    (lambda c: c.PlantModel(25.0, 0.0, 0.005, 1000), "b must be nonzero"),
    (lambda c: c.design_controller("pi", c.PlantModel(25.0, 3.0, 0.005, 1000), time_constant=0.05)
     .predict(c.parse_reference("step:1e308"), 1.0), "reference"),
    (lambda c: c.design_controller("pi", c.PlantModel(25.0, 3.0, 1e-9, 1000), time_constant=0.05)
     .predict(c.parse_reference("step:10"), 2.0), "samples"),
], ids=["b = 0", "step 1e308", "sample period 1e-9"])
def test_controllers_refuse_what_cannot_be_designed_or_predicted(make, match):
    from motorsim import control
    with pytest.raises(ParameterError, match=match):
        make(control)


@pytest.mark.parametrize("max_lag", [3, 40, 900])
def test_newey_west_lag_sums_by_fft_equal_the_direct_sums(max_lag):
    from identify.checks.uncertainty import _weighted_lag_products
    rng = np.random.default_rng(3)
    g = rng.standard_normal((3000, 3))
    g[:, 1] += np.convolve(g[:, 0], np.ones(25) / 25, "same")
    direct = np.zeros((3, 3))
    for lag in range(1, max_lag + 1):
        gamma = g[lag:].T @ g[:-lag]
        direct += (1 - lag / (max_lag + 1)) * (gamma + gamma.T)
    np.testing.assert_allclose(_weighted_lag_products(g, max_lag), direct, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("call", [
    lambda: __import__("identify").frequency_response([]),
    lambda: __import__("scenarios").run_sweep(42, "out"),
    lambda: __import__("identify.default.selection", fromlist=["x"]).select_model([], level=0.9),
], ids=["frequency_response", "run_sweep", "select_model"])
def test_library_entry_points_raise_our_error_types(call):
    from motorsim.checks import ParameterError
    with pytest.raises(ParameterError):
        call()
