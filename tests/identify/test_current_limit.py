"""A driver that limits its current: the ``current-limit`` structure, ``oe-current-limit``, and the default choosing
it on evidence."""
import math

import numpy as np
import pytest

import identify
from identify import fit
from identify.default.evidence import CURRENT_LIMIT, RULES
from identify.fits.limit_response import (
    _compiled,
    _compiled_sensitivity,
    limit_response,
    limit_run_python,
    limit_sensitivities,
    limit_sensitivity_run_python,
)
from motorid.bench.misfits import current_limit
from motorsim import Recording
from motorsim.checks import ParameterError

SHAPE = identify.structure("current-limit")
TRUTH = {"a": 25.0, "b": 3.0, "current_limit": 400.0, "emf_share": 0.8, "bias": -2.0}
DT = 0.002
#: Noise-free: the same model computed two ways, and a fit of exact data, agree to 1e-9 relative (observed ~1e-12).
RTOL = 1e-9


def _steps(n, levels=(180, -150, 60, 200, -30, -200), hold=150):
    return np.repeat(np.array(levels * (n // (hold * len(levels)) + 1)), hold)[:n].astype(np.int64)


def test_below_its_limit_it_is_python_controls_motor():
    import control
    n, delay = 1200, 2
    t = np.arange(n) * DT
    duty = np.round(170 * np.sin(10 * t + 0.3) + 30 * np.sin(53 * t)).astype(np.int64)
    values = dict(TRUTH, current_limit=1e9)
    ours = SHAPE.response(values, duty, t, input_delay=delay, initial_speed=-1.0)
    sys = control.ss([[0, 1], [0, -TRUTH["a"]]], [[0, 0], [TRUTH["b"], TRUTH["bias"]]], np.eye(2), np.zeros((2, 2)))
    late = np.concatenate([np.zeros(delay), duty[:-delay]]).astype(float)
    ref = control.forced_response(control.sample_system(sys, DT, "zoh"), t, np.vstack([late, np.ones(n)]),
                                  X0=[0.0, -1.0])
    np.testing.assert_allclose(ours.angle, ref.outputs[0], rtol=0, atol=RTOL * np.max(np.abs(ref.outputs[0])))
    np.testing.assert_allclose(ours.speed, ref.outputs[1], rtol=0, atol=RTOL * np.max(np.abs(ref.outputs[1])))


@pytest.mark.parametrize("share", [0.8, 1.0])
def test_a_step_from_rest_follows_the_closed_form_through_the_limit(share):
    # from rest under a step u: the torque is held at L (w' = L - am w) until b u - ae w falls to L, at w* =
    # (b u - L)/ae, then the linear motor takes the speed on to b u / a
    a, b, limit, u = 25.0, 3.0, 400.0, 200.0
    ae, am = share * a, (1 - share) * a
    t = np.arange(400) * 0.0005
    w_star = (b * u - limit) / ae
    if am > 0:
        t_star = -math.log(1 - am * w_star / limit) / am
        sat_w = limit / am * -np.expm1(-am * t)
        sat_th = limit / am * (t + np.expm1(-am * t) / am)
        th_star = limit / am * (t_star + math.expm1(-am * t_star) / am)
    else:
        t_star = w_star / limit
        sat_w, sat_th, th_star = limit * t, limit * t ** 2 / 2, limit * t_star ** 2 / 2
    assert 0.01 < t_star < 0.15      # the limit acts over part of the run, not all of it
    ss, late = b * u / a, t - t_star
    lin_w = ss + (w_star - ss) * np.exp(-a * late)
    lin_th = th_star + ss * late + (w_star - ss) * -np.expm1(-a * late) / a
    speed = np.where(t <= t_star, sat_w, lin_w)
    angle = np.where(t <= t_star, sat_th, lin_th)
    ours = SHAPE.response({"a": a, "b": b, "current_limit": limit, "emf_share": share}, np.full(len(t), u), t)
    np.testing.assert_allclose(ours.speed, speed, rtol=0, atol=RTOL * np.max(speed))
    np.testing.assert_allclose(ours.angle, angle, rtol=0, atol=RTOL * np.max(angle))


def test_the_compiled_loop_and_the_python_loop_agree():
    kernel = _compiled()
    if kernel is None:
        pytest.skip("numba is not installed here")
    rng = np.random.default_rng(1)
    n = 2000
    bu = 3.0 * _steps(n).astype(float)
    h = DT * (1 + 0.2 * rng.uniform(-1, 1, n - 1))
    out = []
    for run in (limit_run_python, kernel):
        speed, angle = np.zeros(n), np.zeros(n)
        speed[0] = 4.0
        run(20.0, 5.0, bu, 400.0, -2.0, h, speed, angle)
        out.append((speed, angle))
    np.testing.assert_allclose(out[0][0], out[1][0], rtol=0, atol=1e-12 * np.max(np.abs(out[0][0])))
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=0, atol=1e-12 * np.max(np.abs(out[0][1])))


@pytest.mark.parametrize("share", [0.8, 1.0])
def test_the_sensitivities_are_the_responses_own_derivatives(share):
    # central differences of the response at steps of 1e-5 of each value: their own error (truncation ~ step^2,
    # rounding ~ 1e-16 / step) is below 1e-8 of the largest sensitivity; 1e-6 leaves a margin of 100.  The share at
    # its bound 1 is differenced one-sided, at a step of 1e-8 (truncation ~ 1e-8, rounding ~ 1e-8)
    rng = np.random.default_rng(4)
    n = 2500
    t = np.cumsum(np.r_[0.0, DT * (1 + 0.2 * rng.uniform(-1, 1, n - 1))])
    duty = _steps(n) + rng.integers(-20, 21, n)
    x = np.array([25.0, 3.0, 400.0, share, -2.0, 1.5])
    angle, speed, d_angle, d_speed = limit_sensitivities(*x[:5], duty, t, x[5])
    exact = limit_response(*x[:5], duty, t, x[5])
    assert np.array_equal(angle, exact[0]) and np.array_equal(speed, exact[1])
    asked = np.abs(x[1] * duty[:-1] - x[3] * x[0] * speed[:-1])
    assert 0.05 < np.mean(asked > x[2]) < 0.5        # the limit acts on part of the run: both regions differentiated
    for i in range(6):
        step = 1e-5 * abs(x[i])
        up, down = x.copy(), x.copy()
        up[i] += step
        down[i] -= step
        if i == 3 and up[i] > 1.0:
            up[i], down[i], step = x[i], x[i] - 1e-8, 0.5e-8
        a_up, w_up = limit_response(*up[:5], duty, t, up[5])
        a_down, w_down = limit_response(*down[:5], duty, t, down[5])
        for ours, diff in ((d_angle[:, i], (a_up - a_down) / (2 * step)),
                           (d_speed[:, i], (w_up - w_down) / (2 * step))):
            assert np.max(np.abs(ours - diff)) <= 1e-6 * np.max(np.abs(diff)), i


def test_the_compiled_sensitivities_are_the_python_loops():
    kernel = _compiled_sensitivity()
    if kernel is None:
        pytest.skip("numba is not installed here")
    n = 1500
    h = np.full(n - 1, DT)
    u = _steps(n).astype(float)[:-1]
    out = []
    for run in (limit_sensitivity_run_python, kernel):
        speed, angle, sw, sth = np.zeros(n), np.zeros(n), np.zeros((n, 6)), np.zeros((n, 6))
        speed[0], sw[0, 5] = 4.0, 1.0
        run(25.0, 0.8, u, 3.0, 400.0, -2.0, h, speed, angle, sw, sth)
        out.append(np.column_stack([speed, angle, sw, sth]))
    np.testing.assert_allclose(out[0], out[1], rtol=0, atol=1e-12 * np.max(np.abs(out[0])))


def test_a_loose_pole_on_a_coarse_speed_column_is_fitted_to_its_minimum():
    # a 48-count speed column at 1 ms (steps of 131 rad/s) leaves a loose along b / a; the fit must still end where
    # no Gauss-Newton step lowers the cost: each parameter's step under 1e-5 of its value (the solver's tolerance
    # on the cost is 1e-14, on a of this flat valley that is ~1e-7)
    from identify.data import prepare_segments
    from identify.fits.current_limit import _residual_jacobian, _residuals
    from identify.fits.limit_response import initial_speed_fit
    rng = np.random.default_rng(1)
    h, n = 0.001, 6000
    t = np.arange(n) * h
    duty = np.repeat(rng.choice([-200, -150, -60, 60, 150, 200], n // 300 + 1), 300)[:n]
    angle = SHAPE.response(TRUTH, duty, t).angle
    counts = np.floor(angle * 48 / (2 * np.pi) + rng.uniform(0, 1)).astype(np.int64)
    speed = np.round(np.r_[0.0, np.diff(counts)] * 2 * np.pi / 48 / h, 2)
    rec = Recording(time=t, duty=duty, sample_period=h, speed=speed)
    est = fit(rec, "oe-current-limit", input_delay=0)
    segments = prepare_segments([rec], 0)
    theta = np.array([est.value(n) for n in ("a", "b", "current_limit", "emf_share", "bias")])
    x = np.concatenate([theta, [initial_speed_fit(theta, seg) for seg in segments]])
    step = np.linalg.lstsq(_residual_jacobian(x, segments), -_residuals(x, segments), rcond=None)[0]
    assert np.all(np.abs(step[:5]) <= 1e-5 * np.abs(theta)), step[:5] / theta


@pytest.mark.parametrize("delay", [0, 2])
def test_oe_current_limit_recovers_the_limit_from_exact_data(delay):
    n = 3000
    t = np.arange(n) * DT
    duty = _steps(n)
    angle = SHAPE.response(TRUTH, duty, t, input_delay=delay, initial_speed=3.0).angle + 1.0
    est = fit(Recording(time=t, duty=duty, sample_period=DT, angle=angle), "oe-current-limit", input_delay=delay)
    assert est.structure == "current-limit" and est.input_delay == delay
    for name, value in TRUTH.items():
        assert est.value(name) == pytest.approx(value, rel=RTOL, abs=RTOL)
    with pytest.raises(ParameterError, match="no current limit.*400"):
        est.motor()


def test_its_fit_of_the_bench_current_limit_holds_the_truth():
    # the bench integrates b u - 0.8 a w clipped at 700 rad/s^2, less 0.2 a w (RK4, 2048 counts): the structure's
    # own form, so its fit's intervals hold every value (3 standard errors: a fixed seed, two-sided)
    est = fit(current_limit(0), "oe-current-limit")
    se = est.stderr()
    for name, value in {"a": 25.0, "b": 3.0, "current_limit": 700.0, "emf_share": 0.8}.items():
        assert abs(est.value(name) - value) < 3 * se[name], name
    assert se["a"] < 0.01 and se["b"] < 0.001


def test_the_default_chooses_it_where_the_gain_is_lower_at_high_drive():
    assert CURRENT_LIMIT in RULES
    est = fit(current_limit(1))
    assert est.structure == "current-limit" and est.selection.clear
    ci = est.confidence_interval(0.95)
    assert ci["a"][0] <= 25.0 <= ci["a"][1] and ci["b"][0] <= 3.0 <= ci["b"][1]
    assert any("limits the motor's current" in n for n in est.notes)
    assert any(c.split == "low / high drive" for c in est.selection.checks)
