"""kS, kV, kA from an estimate: the defining relation to a, b, friction and bias, and the delta-method errors."""
import dataclasses
import json

import numpy as np
import pytest

from identify import Estimate, feedforward_constants


def _estimate(**kw):
    base = dict(method="oe-friction", a=25.0, b=3.0, n_samples=1000, sample_period=0.005, residual_rms=1e-4,
                fit_percent=99.9, param_names=("a", "b", "friction", "bias"),
                covariance=np.diag([0.04, 1e-4, 0.09, 0.01]), extra={"friction": 6.0, "bias": -1.5})
    return Estimate(**{**base, **kw})


def test_constants_reproduce_the_model_input_for_any_speed_and_acceleration():
    est = _estimate()
    ff = feedforward_constants(est)
    rng = np.random.default_rng(0)
    for omega, alpha in rng.normal(0, 20, (10, 2)):
        u = ff.ks * np.sign(omega) + ff.kv * omega + ff.ka * alpha + ff.k0
        # the model's acceleration under that input is alpha
        assert -25.0 * omega + 3.0 * u - 1.5 - 6.0 * np.sign(omega) == pytest.approx(alpha, abs=1e-9)


def test_standard_errors_match_a_monte_carlo_of_the_covariance():
    est = _estimate()
    ff = feedforward_constants(est)
    draws = np.random.default_rng(1).multivariate_normal([25.0, 3.0, 6.0, -1.5], est.covariance, 200_000)
    a, b, c, d = draws.T
    for name, values in {"kv": a / b, "ka": 1 / b, "ks": c / b, "k0": -d / b}.items():
        assert ff.stderr[name] == pytest.approx(np.std(values), rel=0.02), name


def test_constants_without_fitted_friction_have_no_interval_and_reach_the_json():
    est = _estimate(method="oe", param_names=("a", "b"), covariance=np.diag([0.04, 1e-4]), extra={})
    ff = feedforward_constants(est)
    assert ff.ks == 0 and np.isnan(ff.stderr["ks"]) and not np.isnan(ff.stderr["kv"])
    doc = json.loads(est.to_json())
    assert doc["feedforward"]["kv"]["value"] == pytest.approx(25.0 / 3.0)
    assert doc["feedforward"]["ka"]["unit"] == "duty/(rad/s^2)"
    assert Estimate.from_json(est.to_json()).a == 25.0
    assert "feedforward kS 0 duty, kV 8.333 [" in ff.describe()


def test_the_constants_intervals_widen_with_a_and_b_where_the_selection_widened_them():
    # before: kA [0.014972, 0.014994] missed the true 0.015 while b's widened interval held 1/0.015
    est = Estimate(method="oe", a=8.0, b=66.9, n_samples=4000, sample_period=0.005, residual_rms=0.05,
                   fit_percent=99.9, covariance=np.diag([1e-6, 1e-4]), input_unit="V",
                   model_range={"a": (7.9, 8.1), "b": (66.0, 67.0)})
    ff = feedforward_constants(est)
    ci = ff.confidence_interval(0.95)
    b_low, b_high = est.confidence_interval(0.95)["b"]
    assert ci["ka"][0] <= 1 / b_high and ci["ka"][1] >= 1 / b_low        # kA = 1/b over b's interval, exactly
    assert ci["ka"][0] <= 0.015 <= ci["ka"][1]
    a_low, a_high = est.confidence_interval(0.95)["a"]
    assert ci["kv"][0] <= a_low / b_high and ci["kv"][1] >= a_high / b_low
    # no widening: the delta method's interval as before
    plain = feedforward_constants(dataclasses.replace(est, model_range={}))
    assert plain.ranges == {} and plain.confidence_interval()["ka"][1] < 1 / 66.7


def test_the_printed_constants_have_digits_enough_to_tell_the_interval_from_the_value():
    from identify.feedforward import apart
    assert apart(0.12, 0.11999, 0.12001) == ("0.12", "0.11999", "0.12001")
    assert apart(0.3549, 0.2792, 0.4322) == ("0.3549", "0.2792", "0.4322")     # four digits where they suffice
    est = Estimate(method="oe", a=8.0, b=66.6667, n_samples=4000, sample_period=0.005, residual_rms=0.05,
                   fit_percent=99.9, covariance=np.diag([1e-6, 1e-6]), input_unit="V")
    line = feedforward_constants(est).describe()
    kv = line.split("kV ")[1].split(" V/")[0]
    value, low, high = kv.replace("[", "").replace("]", "").replace(",", "").split()
    assert low != value != high                                               # not 'kV 0.12 [0.12, 0.12]'
