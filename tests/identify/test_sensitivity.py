"""The exact ZOH response and its analytic sensitivities (the basis of oe and the Cramér–Rao bound)."""
import numpy as np
import pytest

from identify.fits.sensitivity import zoh_response
from motorsim.plant import Motor, simulate


def _case(a, dt, jitter, n=1500, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt + (rng.uniform(-0.5, 0.5, n) * jitter * dt if jitter else 0.0)
    return t, np.round(200 * np.sin(0.7 * a * t + 0.3))


CASES = [(25.0, 0.005, 0.0), (4.0, 0.001, 0.1), (90.0, 0.02, 0.1), (1e-3, 0.005, 0.0)]
IDS = ["article", "slow-jittered", "fast-jittered", "a-near-zero"]


@pytest.mark.parametrize("a, dt, jitter", CASES, ids=IDS)
def test_response_matches_motorsim(a, dt, jitter):
    t, u = _case(a, dt, jitter)
    ours = zoh_response(a, 3.0, u, t, 4.0, bias=5.0)
    ref = simulate(Motor(a, 3.0, bias=5.0), u, t, initial_speed=4.0)
    # both exact: agreement to rounding over 1500 steps
    np.testing.assert_allclose(ours.angle, ref.angle, rtol=0, atol=1e-11 * np.max(np.abs(ref.angle)))
    np.testing.assert_allclose(ours.speed, ref.speed, rtol=0, atol=1e-11 * np.max(np.abs(ref.speed)))


@pytest.mark.parametrize("a, dt, jitter", CASES, ids=IDS)
def test_sensitivities_match_central_differences(a, dt, jitter):
    t, u = _case(a, dt, jitter)
    base = dict(a=a, b=3.0, initial_speed=4.0, bias=5.0)
    resp = zoh_response(a, 3.0, u, t, 4.0, bias=5.0)
    for col, (name, step) in enumerate((("a", 1e-6 * max(a, 1.0)), ("b", 3e-6), ("initial_speed", 1e-4),
                                        ("bias", 1e-3))):
        hi, lo = dict(base), dict(base)
        hi[name] += step
        lo[name] -= step
        r_hi = zoh_response(hi["a"], hi["b"], u, t, hi["initial_speed"], bias=hi["bias"])
        r_lo = zoh_response(lo["a"], lo["b"], u, t, lo["initial_speed"], bias=lo["bias"])
        fd = (r_hi.angle - r_lo.angle) / (2 * step)
        # central differences: truncation ~ step^2, rounding ~ 1e-16 / step; 1e-5 covers both
        np.testing.assert_allclose(resp.angle_sensitivity[:, col], fd, rtol=0, atol=1e-5 * np.max(np.abs(fd)))
        fd_w = (r_hi.speed - r_lo.speed) / (2 * step)
        np.testing.assert_allclose(resp.speed_sensitivity[:, col], fd_w, rtol=0, atol=1e-5 * np.max(np.abs(fd_w)))


def test_initial_speed_column_derivative_in_a():
    t, u = _case(25.0, 0.005, 0.1)
    step = 1e-5
    resp = zoh_response(25.0, 3.0, u, t, 0.0)
    fd = (zoh_response(25.0 + step, 3.0, u, t).angle_sensitivity[:, 2]
          - zoh_response(25.0 - step, 3.0, u, t).angle_sensitivity[:, 2]) / (2 * step)
    np.testing.assert_allclose(resp.angle_initial_speed_a, fd, rtol=0, atol=1e-6 * np.max(np.abs(fd)))


def test_residual_only_evaluation_gives_the_same_output():
    t, u = _case(25.0, 0.005, 0.1)
    full = zoh_response(25.0, 3.0, u, t, 2.0)
    lean = zoh_response(25.0, 3.0, u, t, 2.0, sensitivities=False)
    np.testing.assert_array_equal(lean.angle, full.angle)
    np.testing.assert_array_equal(lean.angle_initial_speed, full.angle_sensitivity[:, 2])
    np.testing.assert_array_equal(lean.speed_initial_speed, full.speed_sensitivity[:, 2])
    np.testing.assert_array_equal(full.speed_initial_speed, full.speed_sensitivity[:, 2])
    assert lean.angle_sensitivity.shape == (len(t), 1)        # the columns not computed are not stored
