"""Cramér–Rao bound: checked against python-control's own simulation and against Monte Carlo."""
import math

import control
import numpy as np
import pytest

from identify import cramer_rao_bound
from identify.checks.uncertainty import quantisation_variance


def _duty(n, dt, freq=10.0):
    return np.round(200 * np.sin(freq * np.arange(n) * dt))


def _reference_bound(a, b, duty, dt, w0, variance):
    """Fisher information from python-control's forced_response and central differences."""
    def angle(pa, pb, pw):
        sys = control.sample_system(control.ss([[0, 1], [0, -pa]], [[0], [pb]], [[1, 0]], [[0]]), dt, "zoh")
        return control.forced_response(sys, U=duty, X0=[0.0, pw]).outputs
    cols = []
    for i, step in enumerate((1e-5 * a, 1e-5 * abs(b), 1e-3)):
        d = np.zeros(3)
        d[i] = step
        cols.append((angle(a + d[0], b + d[1], w0 + d[2]) - angle(a - d[0], b - d[1], w0 - d[2])) / (2 * step))
    J = np.column_stack([*cols, np.ones(len(duty))])
    return variance * np.linalg.inv(J.T @ J)[:2, :2]


@pytest.mark.parametrize("a, b, dt, w0", [(25.0, 3.0, 0.005, 0.0), (4.0, 0.5, 0.001, 7.0), (90.0, 2.0, 0.02, -3.0)],
                         ids=["article", "slow-fast-sampling", "fast-pole-slow-sampling"])
def test_bound_matches_python_control_sensitivities(a, b, dt, w0):
    duty = _duty(2000, dt, freq=0.7 * a)
    crb = cramer_rao_bound(a, b, duty, dt, counts_per_rev=4096, angle_noise=1e-3, initial_speed=w0)
    ref = _reference_bound(a, b, duty, dt, w0, 1e-6 + quantisation_variance(4096))
    # central differences with relative step 1e-5 are accurate to ~1e-8; inversion amplifies by cond(J^T J)
    np.testing.assert_allclose(crb.covariance, ref, rtol=1e-4)
    assert crb.n_samples == 2000 and crb.param_names == ("a", "b")
    assert crb.stderr()["a"] == pytest.approx(math.sqrt(ref[0, 0]), rel=1e-4)


def test_bound_scales_with_noise_variance_and_record_length():
    duty = _duty(4000, 0.005)
    one = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=None, angle_noise=1e-3)
    two = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=None, angle_noise=2e-3)
    np.testing.assert_allclose(two.covariance, 4 * one.covariance, rtol=1e-12)  # exactly linear in sigma^2
    long = cramer_rao_bound(25.0, 3.0, np.tile(duty, 4), 0.005, counts_per_rev=None, angle_noise=1e-3)
    # 4x the data of a periodic input: variance ~ 1/4 (not exact: transient and nuisance parameters)
    ratio = long.covariance[0, 0] / one.covariance[0, 0]
    assert 0.2 < ratio < 0.3


def test_jittered_time_gives_a_nearby_bound():
    rng = np.random.default_rng(0)
    dt, n = 0.005, 3000
    duty = _duty(n, dt)
    t = np.arange(n) * dt + rng.uniform(-0.05, 0.05, n) * dt
    base = cramer_rao_bound(25.0, 3.0, duty, dt)
    jit = cramer_rao_bound(25.0, 3.0, duty, dt, time=t)
    # +-5 % jitter changes the information by a few percent at most
    np.testing.assert_allclose(jit.stderr()["a"], base.stderr()["a"], rtol=0.05)


def test_input_that_does_not_excite_gives_no_finite_bound():
    # at steady state under a constant duty only b/a shows: a and b cannot be separated
    steady = cramer_rao_bound(25.0, 3.0, np.full(500, 100.0), 0.005, initial_speed=3.0 * 100 / 25)
    assert not math.isfinite(steady.stderr()["a"]) or steady.relative_stderr()["a"] > 1e3
    # a zero duty from rest: the angle does not depend on a or b at all
    assert not math.isfinite(cramer_rao_bound(25.0, 3.0, np.zeros(500), 0.005).stderr()["b"])
    # whereas a step from rest does identify both
    assert cramer_rao_bound(25.0, 3.0, np.full(500, 100.0), 0.005).relative_stderr()["a"] < 1e-3


@pytest.mark.parametrize("kwargs, match", [
    (dict(a=-1.0), "a must"), (dict(b=0.0), "b must"), (dict(sample_period=0.0), "sample_period"),
    (dict(counts_per_rev=0), "counts_per_rev"), (dict(angle_noise=-1.0), "angle_noise"),
    (dict(counts_per_rev=None), "noise-free"), (dict(duty=[1.0, 2.0]), "duty"),
    (dict(time=np.zeros(100)), "time"),
], ids=["a", "b", "sample_period", "counts_per_rev", "angle_noise", "zero-noise", "short", "time"])
def test_bad_arguments_name_the_parameter(kwargs, match):
    args = dict(a=25.0, b=3.0, duty=_duty(100, 0.005), sample_period=0.005)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        cramer_rao_bound(args.pop("a"), args.pop("b"), args.pop("duty"), args.pop("sample_period"), **args)


def test_newey_west_without_lags_is_the_white_sandwich():
    # L = 0: (J^T J)^-1 (sum r_t^2 J_t J_t^T) (J^T J)^-1, exactly (to rounding)
    from identify.checks.uncertainty import newey_west_covariance
    rng = np.random.default_rng(3)
    J = rng.normal(size=(500, 3)) * [1.0, 100.0, 0.01]
    r = rng.normal(size=500)
    bread = np.linalg.inv(J.T @ J)
    direct = bread @ ((J * r[:, None] ** 2).T @ J) @ bread
    np.testing.assert_allclose(newey_west_covariance(J, r, 3, 0), direct, rtol=1e-9)


def test_correlated_residuals_switch_to_newey_west_and_widen_the_interval():
    # AR(1) residuals with coefficient 0.9: the variance of a mean is about (1 + 0.9)/(1 - 0.9) = 19 times
    # the white formula's; Newey-West must see most of that (> 5 x) while Gauss-Newton cannot
    from identify.checks.uncertainty import robust_covariance
    rng = np.random.default_rng(4)
    e = rng.normal(size=4000)
    r = np.empty_like(e)
    r[0] = e[0]
    for k in range(1, len(e)):
        r[k] = 0.9 * r[k - 1] + e[k]
    J = np.ones((len(r), 1))
    white, how_white = robust_covariance(J, rng.normal(size=len(r)), 1.0, 1)
    cov, how = robust_covariance(J, r, float(r @ r) / len(r), 1)
    assert how_white == "gauss-newton" and how == "newey-west"
    assert cov[0, 0] > 5 * float(r @ r) / len(r) / len(r)


def test_bound_with_a_known_delay_is_the_bound_of_the_delayed_duty():
    # the delay shifts the duty (zeros before the run): exactly the bound of the shifted duty
    from identify import cramer_rao_bound
    t = np.arange(2000) * 0.005
    duty = np.round(150 * np.sin(25 * t) + 60 * np.sin(60 * t + 1))
    shifted = np.concatenate([np.zeros(2), duty[:-2]])
    delayed = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=1200, input_delay=2).covariance
    np.testing.assert_allclose(delayed, cramer_rao_bound(25.0, 3.0, shifted, 0.005, counts_per_rev=1200).covariance,
                               rtol=1e-12)


def test_friction_bound_is_at_least_the_linear_one():
    # with friction the bound estimates c and d alongside, so it cannot be below the bound of the same
    # experiment on a linear plant of equal a, b and fewer nuisance parameters by much; and it is finite
    from identify import cramer_rao_bound
    t = np.arange(2000) * 0.005
    duty = np.round(150 * np.sin(25 * t) + 60 * np.sin(60 * t + 1))
    fr = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=4096, friction=1e-6).stderr()
    lin = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=4096).stderr()
    # a vanishing friction leaves the angle's sensitivities to a and b those of the linear plant; the extra
    # columns for c and d can only raise the bound (Schur complement)
    assert fr["a"] >= lin["a"] * (1 - 1e-9) and fr["b"] >= lin["b"] * (1 - 1e-9)
    assert np.isfinite(fr["a"]) and np.isfinite(fr["b"])


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.995])
def test_correlation_length_and_ljung_box_match_a_direct_reference(phi):
    # reference: the autocorrelation by np.correlate and the Ljung-Box statistic written out; phi = 0.995
    # is correlated past the dot-product lags, so the FFT path is checked too
    from scipy.stats import chi2

    from identify.checks.uncertainty import _DIRECT_AUTOCORRELATION_LAGS, _correlation_length
    rng = np.random.default_rng(7)
    e = rng.normal(size=3000)
    r = np.empty_like(e)
    r[0] = e[0]
    for k in range(1, len(e)):
        r[k] = phi * r[k - 1] + e[k]
    x = r - r.mean()
    ac = np.correlate(x, x, "full")[len(x) - 1:] / float(x @ x)
    limit = 300
    inside = np.flatnonzero(np.abs(ac[1:limit + 1]) < 1.96 / math.sqrt(len(x)))
    expected_length = int(inside[0]) + 1 if len(inside) else limit
    n, m = len(x), 20
    q = n * (n + 2) * sum(ac[k] ** 2 / (n - k) for k in range(1, m + 1))
    length, p = _correlation_length(r, limit)
    assert length == expected_length
    assert p == pytest.approx(float(chi2.sf(q, m)), rel=1e-9, abs=1e-300)
    if phi > 0.99:
        assert length > _DIRECT_AUTOCORRELATION_LAGS
