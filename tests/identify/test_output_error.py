"""Output error (``oe``): exact on noise-free data from independent integrators, honest on noisy data."""

import numpy as np
import pytest

from identify import NotIdentifiableError, cramer_rao_bound, fit
from identify.checks.validation import model_output
from identify.fits.output_error import fit_output_error, select_delay
from motorsim.recording import Recording

# Noise-free data from expm / python-control agree with the closed-form ZOH model to ~1e-13;
# the fit stops at xtol = 1e-12, so a and b come back to well within 1e-8 relative.
EXACT = 1e-8


def _sine(t, freq, amp=200.0, phase=0.3):
    return np.round(amp * np.sin(freq * t + phase))


def _angle_recording(angle, duty, t, dt, **kw):
    return Recording(time=t, duty=duty, sample_period=dt, angle=angle, **kw)


@pytest.mark.parametrize("a, b, dt, freq, jitter", [
    (25.0, 3.0, 0.005, 10.0, 0.0), (4.0, 0.5, 0.001, 2.0, 0.0), (90.0, 2.0, 0.02, 60.0, 0.0),
    (25.0, 3.0, 0.005, 10.0, 0.1),
], ids=["article", "slow-pole-1ms", "fast-pole-20ms", "jitter-10%"])
def test_noise_free_angle_gives_the_truth(reference, a, b, dt, freq, jitter):
    rng = np.random.default_rng(1)
    n = 1500
    t = np.arange(n) * dt + (rng.uniform(-0.5, 0.5, n) * jitter * dt if jitter else 0.0)
    duty = _sine(t, freq)
    if jitter:
        angle, _ = reference.expm_trajectory(a, b, duty, t, initial_speed=5.0)
    else:
        angle, _ = reference.control_trajectory(a, b, duty, dt, initial_speed=5.0)
    est = fit_output_error(_angle_recording(angle + 0.7, duty, t, dt))
    assert est.a == pytest.approx(a, rel=EXACT)
    assert est.b == pytest.approx(b, rel=EXACT)
    assert est.method == "oe" and est.input_delay == 0.0
    assert est.fit_percent > 99.999999


def test_analytic_and_finite_difference_jacobians_reach_the_same_fit(reference):
    dt, n = 0.005, 2000
    t = np.arange(n) * dt
    duty = _sine(t, 10.0)
    angle, _ = reference.control_trajectory(25.0, 3.0, duty, dt)
    rec = reference.quantised_recording(angle, duty, t, dt, 1200)
    an = fit_output_error(rec)
    fd = fit_output_error(rec, jac="2-point")
    # same minimum of the same cost; finite differences limit the agreement to ~1e-7
    assert an.a == pytest.approx(fd.a, rel=1e-6) and an.b == pytest.approx(fd.b, rel=1e-6)
    np.testing.assert_allclose(an.covariance, fd.covariance, rtol=1e-3)


def test_dropped_samples_split_the_run_without_inventing_the_duty(reference):
    rng = np.random.default_rng(2)
    dt, n = 0.005, 3000
    t = np.arange(n) * dt
    duty = _sine(t, 12.0)
    angle, _ = reference.control_trajectory(25.0, 3.0, duty, dt, initial_speed=-4.0)
    keep = np.ones(n, bool)
    keep[1:] = rng.random(n - 1) > 0.02
    seq = np.flatnonzero(keep)
    # the duty of a dropped row is never seen; poison it to prove the fit does not use it
    rec = Recording(time=t[keep], duty=duty[keep], sample_period=dt, angle=angle[keep] + 3.0, seq=seq)
    assert rec.has_gaps
    est = fit_output_error(rec)
    assert est.a == pytest.approx(25.0, rel=EXACT) and est.b == pytest.approx(3.0, rel=EXACT)


def test_four_sines_pool_into_one_estimate(reference):
    dt, n = 0.005, 800
    t = np.arange(n) * dt
    recs, singles = [], []
    for i, freq in enumerate((10.0, 20.0, 30.0, 40.0)):
        duty = _sine(t, freq, phase=0.0)
        angle, _ = reference.control_trajectory(25.0, 3.0, duty, dt, initial_speed=10.0 * i)
        recs.append(reference.quantised_recording(angle, duty, t, dt, 4096, offset=100 * i))
        singles.append(fit_output_error(recs[-1]))
    pooled = fit(recs)  # the default method is oe
    # pooled: four times the data, so its standard error beats every single run's
    assert pooled.stderr()["a"] < min(s.stderr()["a"] for s in singles)
    assert abs(pooled.a - 25.0) < 4 * pooled.stderr()["a"]  # 4 sigma: fails by chance < 1e-4
    assert abs(pooled.b - 3.0) < 4 * pooled.stderr()["b"]


def test_speed_only_recording_is_fitted_against_speed(reference):
    dt, n = 0.01, 1000
    t = np.arange(n) * dt
    duty = _sine(t, 15.0)
    _, speed = reference.control_trajectory(20.0, 2.0, duty, dt, initial_speed=8.0)
    est = fit_output_error(Recording(time=t, duty=duty, sample_period=dt, speed=speed))
    assert est.a == pytest.approx(20.0, rel=EXACT) and est.b == pytest.approx(2.0, rel=EXACT)
    assert est.residual_unit == "rad/s"


def test_bias_variant_recovers_a_constant_acceleration(reference):
    dt, n = 0.01, 1500
    t = np.arange(n) * dt
    duty = 100 + _sine(t, 8.0, amp=60)
    _, speed = (reference.expm_trajectory(15.0, 1.5, duty, t, initial_speed=5.0, bias=-40.0))
    est = fit_output_error(Recording(time=t, duty=duty, sample_period=dt, speed=speed), fit_bias=True)
    assert est.a == pytest.approx(15.0, rel=EXACT) and est.b == pytest.approx(1.5, rel=EXACT)
    assert est.extra["bias"] == pytest.approx(-40.0, rel=EXACT)
    assert est.param_names == ("a", "b", "bias") and est.covariance.shape == (3, 3)
    assert est.method == "oe" and est.input_delay == 0


def test_quantised_counts_land_within_their_standard_errors_near_the_bound(reference):
    dt, n = 0.005, 4000
    t = np.arange(n) * dt
    duty = _sine(t, 25.0)
    angle, _ = reference.control_trajectory(25.0, 3.0, duty, dt)
    rec = reference.quantised_recording(angle, duty, t, dt, 1200)
    est = fit_output_error(rec)
    se = est.stderr()
    # quantisation error is deterministic here, so allow 4 standard errors
    assert abs(est.a - 25.0) < 4 * se["a"] and abs(est.b - 3.0) < 4 * se["b"]
    crb = cramer_rao_bound(25.0, 3.0, duty, dt, counts_per_rev=1200).stderr()
    # the reported standard error estimates the residual variance; it should sit near the bound
    assert 0.7 < se["a"] / crb["a"] < 1.4 and 0.7 < se["b"] / crb["b"] < 1.4
    d = est.to_dict()
    assert d["a_ci95"][0] < 25.0 < d["a_ci95"][1] or abs(est.a - 25.0) < 4 * se["a"]
    assert {"a_stderr", "b_stderr", "a_ci95", "b_ci95"} <= set(d)


@pytest.mark.parametrize("true_delay", [1, 3])
def test_delay_auto_finds_the_input_delay(reference, true_delay):
    dt, n = 0.005, 1500
    t = np.arange(n) * dt
    duty = _sine(t, 20.0) + np.round(80 * np.sign(np.sin(3.1 * t)))
    applied = np.concatenate([np.zeros(true_delay), duty[:-true_delay]])
    angle, _ = reference.control_trajectory(25.0, 3.0, applied, dt)
    rec = _angle_recording(angle, duty, t, dt)
    assert select_delay(rec) == true_delay
    est = fit_output_error(rec, input_delay="auto")
    assert est.input_delay == true_delay
    assert est.a == pytest.approx(25.0, rel=EXACT) and est.b == pytest.approx(3.0, rel=EXACT)


def test_model_output_reproduces_held_out_data(reference):
    dt, n = 0.005, 1000
    t = np.arange(n) * dt
    train_duty, test_duty = _sine(t, 10.0), _sine(t, 33.0, phase=1.0)
    tr, _ = reference.control_trajectory(25.0, 3.0, train_duty, dt)
    te, _ = reference.control_trajectory(25.0, 3.0, test_duty, dt, initial_speed=30.0)
    est = fit_output_error(_angle_recording(tr, train_duty, t, dt))
    meas, sim = model_output(est, _angle_recording(te + 5.0, test_duty, t, dt))
    ok = np.isfinite(meas)
    assert ok.sum() == n - 1
    np.testing.assert_allclose(sim[ok], meas[ok], atol=1e-6 * np.max(np.abs(meas[ok])))


def _rec(duty, angle, dt=0.005, **kw):
    n = len(duty)
    return Recording(time=np.arange(n) * dt, duty=duty, sample_period=dt, angle=angle, **kw)


@pytest.mark.parametrize("make, match", [
    (lambda: _rec(np.ones(5), np.arange(5.0)), "too short"),
    (lambda: _rec(np.zeros(500), np.arange(500.0)), "zero throughout.*persistently exciting"),
    (lambda: _rec(np.full(500, 120.0), np.arange(500.0)), "constant.*persistently exciting"),
    (lambda: _rec(np.round(200 * np.sin(np.arange(500) * 0.05)), np.full(500, 2.0)), "never changes.*stuck"),
], ids=["too-short", "zero-input", "constant-input", "stuck-encoder"])
def test_unidentifiable_data_says_why(make, match):
    with pytest.raises(NotIdentifiableError, match=match):
        fit_output_error(make())


def test_unstable_data_is_refused_with_theta1(reference):
    dt, n = 0.005, 400
    t = np.arange(n) * dt
    duty = _sine(t, 10.0)
    angle, _ = reference.expm_trajectory(-3.0, 3.0, duty, t)
    with pytest.raises(NotIdentifiableError, match=r"theta1 = exp\(-a dt\)"):
        fit_output_error(_angle_recording(angle, duty, t, dt))


def test_saturated_duty_warns(reference):
    dt, n = 0.005, 1000
    t = np.arange(n) * dt
    duty = np.clip(_sine(t, 10.0, amp=2000), -255, 255)
    angle, _ = reference.control_trajectory(25.0, 3.0, duty, dt)
    with pytest.warns(UserWarning, match="duty sits at its limit"):
        est = fit_output_error(_angle_recording(angle, duty, t, dt))
    assert est.a == pytest.approx(25.0, rel=EXACT)


@pytest.mark.parametrize("kwargs, match", [(dict(input_delay=-1), "input_delay"),
                                           (dict(input_delay="soon"), "input_delay"), (dict(jac="exact"), "jac")],
                         ids=["negative", "word", "jac"])
def test_bad_options_name_the_parameter(reference, kwargs, match):
    with pytest.raises(ValueError, match=match):
        fit_output_error(_rec(_sine(np.arange(100) * 0.005, 10.0), np.arange(100.0)), **kwargs)


def test_the_default_chooses_among_models_and_oe_can_be_forced():
    from identify import DEFAULT_METHOD, available_methods
    assert DEFAULT_METHOD == "auto" and "oe" in available_methods() and "auto" not in available_methods()


@pytest.mark.parametrize("kind", ["angle", "speed"])
def test_one_scan_over_all_segments_equals_segment_by_segment(reference, kind):
    from identify.data import prepare_segments
    from identify.fits.output_error import OutputErrorProblem
    rng = np.random.default_rng(5)
    dt, n = 0.005, 2000
    t = np.arange(n) * dt + rng.uniform(-0.05, 0.05, n) * dt
    duty = _sine(t, 12.0)
    angle, speed = reference.expm_trajectory(25.0, 3.0, duty, t, initial_speed=2.0)
    keep = np.ones(n, bool)
    keep[1:] = rng.random(n - 1) > 0.03
    column = dict(angle=angle[keep]) if kind == "angle" else dict(speed=speed[keep])
    rec = Recording(time=t[keep], duty=duty[keep], sample_period=dt, seq=np.flatnonzero(keep), **column)
    segments = prepare_segments([rec])
    batched, looped = OutputErrorProblem(segments, True), OutputErrorProblem(segments, True)
    looped.batched = False
    assert batched.batched and len(segments) > 20
    x = np.array([22.0, 3.3, 4.0])  # away from the optimum, so residuals are large
    for got, want in zip(batched.evaluate(x), looped.evaluate(x)):
        # the carried-in state is projected out exactly; only rounding differs
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.max(np.abs(want)))
