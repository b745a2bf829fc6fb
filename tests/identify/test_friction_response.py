"""The friction response (vectorised, and compiled in one pass) equals the event-by-event simulation, and its
sensitivities are exact."""
import numpy as np
import pytest

from identify.fits import friction_response as response_module
from identify.fits.friction_kernel import compiled_response
from identify.fits.friction_response import friction_response
from motorsim.plant import Motor, simulate


@pytest.fixture(autouse=True, params=["vectorised", "compiled"])
def response_path(request, monkeypatch):
    """Every test runs on the vectorised path (numpy) and on the compiled one-pass kernel (numba)."""
    if request.param == "compiled":
        if compiled_response() is None:
            pytest.skip("numba is not installed or MOTORID_NUMBA=0")
        monkeypatch.setattr(response_module, "kernel_for", lambda rows: compiled_response())
    else:
        monkeypatch.setattr(response_module, "kernel_for", lambda rows: None)
    return request.param

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


@pytest.mark.parametrize("change", [1.0, 1.01, 1.3])
@pytest.mark.parametrize("warm", [False, True], ids=["cold", "warm"])
def test_the_vectorised_path_finds_the_modes_in_one_scan(monkeypatch, change, warm):
    # a two-sine drive through heavy friction: 33 events and 506 stuck intervals in 3000.  From the linear
    # response's modes (cold) the fixed-point iteration this replaced took 17 scans; from the modes of a fit's
    # previous evaluation (warm, b and c 30 % away) 2.  Now the wrong modes are walked one interval at a time
    # until the walk and the scan are both at rest: one scan warm, two cold (a walk there goes past WALK_LIMIT);
    # the response is the simulator's (rounding only)
    monkeypatch.setattr(response_module, "kernel_for", lambda rows: None)
    u, t = _inputs(False)
    k = np.arange(len(t))
    u = np.round(70 * np.sin(3.0 * k * 0.005) + 40 * np.sin(17.0 * k * 0.005))
    b, c = 3.0 * change, 75.0 * change
    modes = friction_response(25.0, 3.0, 75.0, 0.0, 0.0, u, t).modes if warm else None
    resp = friction_response(25.0, b, c, 0.0, 0.0, u, t, modes=modes)
    assert resp.passes == (1 if warm else 2)
    ref = simulate(Motor(25.0, b, friction=c), u, t)
    np.testing.assert_allclose(resp.speed, ref.speed, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.angle, ref.angle - ref.angle[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jitter"])
@pytest.mark.parametrize("params", CASES, ids=["friction", "all", "slow"])
def test_the_two_paths_agree_to_rounding(params, jitter, monkeypatch):
    if compiled_response() is None:
        pytest.skip("numba is not installed or MOTORID_NUMBA=0")
    u, t = _inputs(jitter)
    monkeypatch.setattr(response_module, "kernel_for", lambda rows: compiled_response())
    fast = friction_response(*params, u, t, 0.3)
    monkeypatch.setattr(response_module, "kernel_for", lambda rows: None)
    slow = friction_response(*params, u, t, 0.3)
    np.testing.assert_array_equal(fast.modes, slow.modes)
    # the same formulas in another order: rounding only (speeds ~ 20 rad/s, angles ~ 100 rad)
    np.testing.assert_allclose(fast.speed, slow.speed, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fast.angle, slow.angle, rtol=0, atol=1e-10)
    for f, s in ((fast.angle_sensitivity, slow.angle_sensitivity), (fast.speed_sensitivity, slow.speed_sensitivity)):
        assert f is not None and s is not None
        for j in range(s.shape[1]):
            np.testing.assert_allclose(f[:, j], s[:, j], rtol=0, atol=1e-10 * np.max(np.abs(s[:, j])))
    assert fast.passes == 1          # one pass: no mode iteration


def test_short_runs_take_the_kernel_only_once_it_is_loaded(monkeypatch):
    from identify.fits import friction_kernel
    if compiled_response() is None:
        pytest.skip("numba is not installed or MOTORID_NUMBA=0")
    monkeypatch.undo()                               # the real kernel_for, not the fixture's
    assert friction_kernel.kernel_for(friction_kernel.KERNEL_MIN_ROWS - 1) is compiled_response()   # loaded above
    monkeypatch.setattr(friction_kernel, "compiled_response", _unloaded(friction_kernel.compiled_response))
    assert friction_kernel.kernel_for(friction_kernel.KERNEL_MIN_ROWS - 1) is None
    assert friction_kernel.kernel_for(friction_kernel.KERNEL_MIN_ROWS) is not None


def _unloaded(cached):
    """A stand-in for the cached loader that says nothing is loaded yet and loads on call."""
    import functools

    @functools.cache
    def loader():
        return cached()
    return loader


@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jitter"])
@pytest.mark.parametrize("static", [1.6 * 75.0, 2.0 * 75.0], ids=["1.6x", "2x"])
def test_stiction_response_equals_the_simulation_and_its_sensitivities_are_exact(static, jitter):
    # the static level moves only the decisions to stick: the response is the simulator's (rounding only), and
    # the other parameters' sensitivities stay exact (central differences, as above)
    _, t = _inputs(jitter)
    u = np.round(70 * np.sin(3.0 * np.arange(len(t)) * 0.005))     # forces up to 215 rad/s^2: the shaft stops often
    ref = simulate(Motor(25.0, 3.0, friction=75.0, bias=5.0, static_friction=static), u, t, initial_speed=0.3)
    x = np.array([25.0, 3.0, 75.0, 5.0, 0.0, 0.3])
    resp = friction_response(*x[:5], u, t, x[5], static_friction=static)
    plain = friction_response(*x[:5], u, t, x[5])
    assert np.sum(resp.modes == 0) > np.sum(plain.modes == 0) + 50       # it sticks longer than friction alone
    np.testing.assert_allclose(resp.speed, ref.speed, rtol=0, atol=1e-9)
    np.testing.assert_allclose(resp.angle, ref.angle - ref.angle[0], rtol=0, atol=1e-9)
    for j in (0, 1, 2, 3, 5):
        step = 1e-6 * max(abs(x[j]), 1.0)
        hi, lo = x.copy(), x.copy()
        hi[j] += step
        lo[j] -= step
        fd = (friction_response(*hi[:5], u, t, hi[5], sensitivities=False, static_friction=static).angle
              - friction_response(*lo[:5], u, t, lo[5], sensitivities=False, static_friction=static).angle) / (2 * step)
        assert np.max(np.abs(resp.angle_sensitivity[:, j] - fd)) <= 1e-5 * np.max(np.abs(fd)), f"column {j}"


def test_a_static_level_at_or_below_the_friction_changes_nothing():
    u, t = _inputs(False)
    plain = friction_response(25.0, 3.0, 75.0, 5.0, 0.0, u, t, 0.3)
    for static in (0.0, 40.0, 75.0):
        same = friction_response(25.0, 3.0, 75.0, 5.0, 0.0, u, t, 0.3, static_friction=static)
        np.testing.assert_array_equal(same.modes, plain.modes)
        np.testing.assert_array_equal(same.angle, plain.angle)
        np.testing.assert_array_equal(same.angle_sensitivity, plain.angle_sensitivity)
