"""The vectorised friction response equals the event-by-event simulation, and its sensitivities are exact."""
import numpy as np
import pytest

from identify.friction_response import friction_response
from motorsim.plant import Motor, simulate

CASES = [(25.0, 3.0, 75.0, 0.0, 0.0), (25.0, 3.0, 75.0, 5.0, 10.5), (10.0, 1.2, 30.0, -3.0, 10.5)]


def _inputs(jitter: bool):
    dt, n = 0.005, 3000
    t = np.arange(n) * dt
    if jitter:
        t = t + np.random.default_rng(1).uniform(-0.1, 0.1, n) * dt
    u = np.round(200 * np.sin(10.0 * np.arange(n) * dt + 0.3))
    return u, t


@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jitter"])
@pytest.mark.parametrize("params", CASES, ids=["friction", "all", "slow"])
def test_response_equals_the_event_by_event_simulation(params, jitter):
    a, b, c, d, z = params
    u, t = _inputs(jitter)
    ref = simulate(Motor(a, b, friction=c, bias=d, dead_zone=z), u, t, initial_speed=0.3)
    resp = friction_response(a, b, c, d, z, u, t, 0.3)
    assert np.sum(np.abs(resp.modes) == 2) > 20          # the run has many zero crossings
    # both exact: they differ by rounding only (speeds ~ 20 rad/s, angles ~ 100 rad)
    np.testing.assert_allclose(resp.speed, ref.speed, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.angle, ref.angle - ref.angle[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jitter"])
@pytest.mark.parametrize("params", CASES, ids=["friction", "all", "slow"])
def test_sensitivities_match_central_differences(params, jitter):
    u, t = _inputs(jitter)
    x = np.array([*params, 0.3])
    resp = friction_response(*x[:5], u, t, x[5])
    assert resp.angle_sensitivity is not None
    for j in range(6):
        step = 1e-6 * max(abs(x[j]), 1.0)
        hi, lo = x.copy(), x.copy()
        hi[j] += step
        lo[j] -= step
        fd = (friction_response(*hi[:5], u, t, hi[5], sensitivities=False).angle
              - friction_response(*lo[:5], u, t, lo[5], sensitivities=False).angle) / (2 * step)
        # central differences carry ~ step^2 truncation and 1e-16/step rounding: ~1e-7 relative
        scale = np.max(np.abs(fd))
        assert np.max(np.abs(resp.angle_sensitivity[:, j] - fd)) <= 1e-5 * scale, f"column {j}"


def test_warm_started_modes_give_the_same_response():
    u, t = _inputs(False)
    first = friction_response(25.0, 3.0, 75.0, 0.0, 0.0, u, t)
    again = friction_response(25.0, 3.003, 75.0, 0.0, 0.0, u, t, modes=first.modes)
    cold = friction_response(25.0, 3.003, 75.0, 0.0, 0.0, u, t)
    np.testing.assert_array_equal(again.modes, cold.modes)
    np.testing.assert_allclose(again.angle, cold.angle, rtol=0, atol=1e-12)
