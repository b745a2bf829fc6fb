"""The model an Estimate gives back: transfer functions with their delay, the full nonlinear
system, JSON round trip, and readable text."""
import json
import math

import control
import numpy as np
import pytest

from identify import Estimate
from motorid.cli import main
from motorsim import Motor, simulate

H = 0.005


def estimate(**extra):
    return Estimate(method="oe-friction", a=25.0, b=3.0, n_samples=1000, sample_period=H, residual_rms=0.01,
                    fit_percent=99.0, covariance=np.diag([0.04, 0.0009]), extra=extra)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_discrete_transfer_function_is_the_zoh_model_with_its_delay(delay):
    tf = estimate(input_delay=delay).transfer_function("discrete")
    zoh = control.sample_system(control.tf([3.0], [1.0, 25.0]), H, method="zoh")
    expected = zoh * control.tf([1.0], [1.0, *([0.0] * delay)], H)
    assert tf.dt == H and tf.input_labels == ["duty"] and tf.output_labels == ["speed"]
    t = np.arange(40) * H
    u = np.where(t > 0.02, 100.0, 0.0)
    y = control.forced_response(tf, t, u).outputs
    np.testing.assert_allclose(y, control.forced_response(expected, t, u).outputs, rtol=1e-12, atol=1e-12)
    # and the discrete model is motorid's own simulation of the delayed motor, sample for sample
    np.testing.assert_allclose(y, simulate(Motor(25.0, 3.0, input_delay=delay), u, t).speed, rtol=1e-9, atol=1e-12)


def test_continuous_form_refuses_to_drop_a_delay_and_takes_pade_on_request():
    est = estimate(input_delay=2)
    with pytest.raises(ValueError, match=r"input delay of 2 samples \(0.01 s\).*'discrete'.*delay='pade'"):
        est.transfer_function()
    tf = est.transfer_function(delay="pade", pade_order=4)
    assert control.dcgain(tf) == pytest.approx(3.0 / 25.0, rel=1e-12)
    assert tf.den[0][0].size - 1 == 5 and tf.input_labels == ["duty"]          # pole a + 4 Padé poles
    plain = estimate().transfer_function()
    assert plain.num[0][0].tolist() == [3.0] and plain.den[0][0].tolist() == [1.0, 25.0]
    with pytest.raises(ValueError, match="form must be"):
        est.transfer_function("z")


@pytest.mark.parametrize("extra", [
    {}, {"input_delay": 2}, {"friction": 300.0, "bias": -5.0}, {"friction": 300.0, "dead_zone": 12.0, "input_delay": 3},
], ids=["linear", "delay", "friction-bias", "friction-deadzone-delay"])
def test_io_system_reproduces_motorsim_simulate(extra):
    """Same intervals integrated the same way: agreement to rounding, checked at 1e-9 relative."""
    est = estimate(**extra)
    t = np.arange(600) * H
    u = np.round(200 * np.sin(8 * t))                   # reverses: friction sticks and crosses zero
    sys = est.io_system()
    x0 = [0.1, 2.0, *([30.0] * est.input_delay)]      # duty before the run: 30
    res = control.input_output_response(sys, t, u, x0)
    ref = simulate(est.motor(), u, t, initial_speed=2.0, initial_angle=0.1, duty_before=30.0)
    scale = np.max(np.abs(ref.speed))
    np.testing.assert_allclose(res.outputs[0], ref.speed, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(res.outputs[1], ref.angle, rtol=1e-9, atol=1e-9 * np.max(np.abs(ref.angle)))
    assert sys.dt == H and sys.input_labels == ["duty"] and sys.output_labels == ["speed", "angle"]
    if "friction" in extra:
        assert np.any(ref.speed == 0.0)                 # the run does stick: the friction path is exercised


def test_json_round_trip_keeps_everything(tmp_path):
    est = estimate(input_delay=1, friction=2.5, bias=-0.5, dead_zone=0.0)
    est = Estimate(**{**est.__dict__, "covariance": np.diag([0.04, 0.0009, math.nan, 0.01, 0.02]),
                      "param_names": ("a", "b", "friction", "bias", "dead_zone"), "input_unit": "V",
                      "data_files": (("run.csv", "ab" * 32),)})
    back = Estimate.from_json(est.to_json())
    for field in ("method", "a", "b", "n_samples", "sample_period", "residual_rms", "fit_percent",
                  "param_names", "extra", "residual_unit", "input_unit", "data_files"):
        assert getattr(back, field) == getattr(est, field), field
    np.testing.assert_array_equal(back.covariance, est.covariance)    # nan survives as JSON null
    assert isinstance(back.input_delay, int)
    path = tmp_path / "m.json"
    path.write_text(est.to_json())
    assert Estimate.from_json(str(path)).a == 25.0
    with pytest.raises(ValueError, match="format 'motorid estimate v2'.*got None"):
        Estimate.from_json('{"a": 1}')


def test_identify_save_writes_a_model_that_rebuilds_the_estimate(tmp_path, capsys):
    run = tmp_path / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--sine", "10,200", "--input-delay", "1",
                 "--out", str(run)]) == 0
    model = tmp_path / "model.json"
    capsys.readouterr()
    assert main(["identify", str(run), "--input-delay", "auto", "--save", str(model), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    doc = json.loads(model.read_text())
    import hashlib
    assert doc["data_files"] == [{"path": str(run), "sha256": hashlib.sha256(run.read_bytes()).hexdigest()}]
    est = Estimate.from_json(model.read_text())
    assert est.a == printed["a"] and est.b == printed["b"] and est.input_delay == 1 == printed["input_delay"]
    assert est.sample_period == 0.005 and doc["units"]["sample_period"] == "s"


def test_str_and_repr_are_readable():
    est = estimate(input_delay=1)
    text, rep = str(est), repr(est)
    assert "array" not in rep + text and "np.float64" not in rep + text and "\n" not in rep
    assert rep.startswith("Estimate(method='oe-friction', a=25, b=3, input_delay=1")
    assert "95 % CI [24.608, 25.392]" in text and "input_delay 1 samples (0.005 s)" in text
    assert all(type(x) is float for pair in est.confidence_interval().values() for x in pair)
