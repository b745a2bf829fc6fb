"""kS, kV, kA from an estimate: the defining relation to a, b, friction and bias, and the delta-method errors."""
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
