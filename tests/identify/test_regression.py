"""euler-ls and zoh-ls against their closed forms on noise-free sampled speed."""
import math

import numpy as np
import pytest

from identify import NotIdentifiableError, fit, fit_euler_ls, fit_zoh_ls
from identify.fits.regression import solve_least_squares
from motorsim import PRBS, Constant, Experiment, Motor, Recording, SimRig, Sine, simulate

RTOL = 1e-9  # noise-free: both regressions are exact up to rounding


def _sampled_speed_recording(a, b, dt, excitation, n=2000, w0=0.0):
    t = np.arange(n) * dt
    u = excitation.duty(n, dt)
    return Recording(time=t, duty=u, sample_period=dt, speed=simulate(Motor(a, b), u, t, initial_speed=w0).speed)


CASES = [(25.0, 3.0, 0.005, Sine(10.0)), (4.0, 0.5, 0.02, Sine(3.0, 255, 1.0)),
         (90.0, 12.0, 0.001, PRBS(200, -100, 11)), (40.0, -2.0, 0.01, Sine(30.0, 150))]
IDS = ["article", "slow", "fast-prbs", "negative-b"]


@pytest.mark.parametrize("a, b, dt, ex", CASES, ids=IDS)
def test_zoh_ls_recovers_the_truth(a, b, dt, ex):
    est = fit_zoh_ls(_sampled_speed_recording(a, b, dt, ex, w0=1.0))
    assert est.a == pytest.approx(a, rel=RTOL) and est.b == pytest.approx(b, rel=RTOL)
    assert est.residual_rms < 1e-9 * 255 * abs(b) / a
    assert est.fit_percent == pytest.approx(100.0, abs=1e-6)


@pytest.mark.parametrize("a, b, dt, ex", CASES, ids=IDS)
def test_euler_ls_equals_its_closed_form(a, b, dt, ex):
    est = fit_euler_ls(_sampled_speed_recording(a, b, dt, ex, w0=1.0))
    a_e = (1.0 - math.exp(-a * dt)) / dt
    assert est.a == pytest.approx(a_e, rel=RTOL) and est.b == pytest.approx(b * a_e / a, rel=RTOL)


def test_articles_eq26_by_hand():
    """[a, b] = C((A^T A)^{-1} A^T b - d), C = diag(-1, 1)/dt, d = [1, 0] — literally."""
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(20.0), 0.005, 2.0))
    w = rec.measured_speed()
    A = np.column_stack([w[1:-1], rec.duty[1:-1]])
    bvec = w[2:]
    x = np.linalg.inv(A.T @ A) @ A.T @ bvec
    ab = np.diag([-1.0, 1.0]) / 0.005 @ (x - [1.0, 0.0])
    est = fit_euler_ls(rec)
    assert est.a == pytest.approx(ab[0], rel=1e-9) and est.b == pytest.approx(ab[1], rel=1e-9)
    assert est.n_samples == len(bvec)


def test_pooled_fit_equals_the_stacked_regression():
    rig = SimRig(Motor(25.0, 3.0))
    recs = [rig.run(Experiment(Sine(f), 0.005, 1.0)) for f in (10, 20, 30, 40)]
    pooled = fit_zoh_ls(recs)
    # the stacked problem solved independently: normal equations summed over recordings
    AtA, Atb = np.zeros((2, 2)), np.zeros(2)
    for r in recs:
        w = r.measured_speed()
        A = np.column_stack([w[1:-1], r.duty[1:-1]])
        AtA += A.T @ A
        Atb += A.T @ w[2:]
    t1, t2 = np.linalg.solve(AtA, Atb)
    a = -math.log(t1) / 0.005
    assert pooled.a == pytest.approx(a, rel=1e-9)
    assert pooled.b == pytest.approx(a * t2 / (1 - t1), rel=1e-9)
    assert pooled.n_samples == sum(len(r) - 2 for r in recs)


def test_gaps_are_never_bridged():
    rec = SimRig(Motor(25.0, 3.0), drop_rate=0.05, rng=np.random.default_rng(3)).run(Experiment(Sine(10.0), 0.005, 2.0))
    est = fit_zoh_ls(rec)
    # each segment of length L contributes L - 2 rows (one for the first difference, one for the target)
    assert est.n_samples == sum(max(len(s) - 2, 0) for s in rec.segments())


@pytest.mark.parametrize("method", ["euler-ls", "zoh-ls"])
def test_covariance_is_the_delta_method_of_the_ols_covariance(method):
    rng = np.random.default_rng(0)
    rec = _sampled_speed_recording(25.0, 3.0, 0.005, PRBS(200, -200, 10))
    noisy = Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period,
                      speed=rec.speed + rng.normal(0, 0.5, len(rec)))
    est = fit(noisy, method=method)
    # finite-difference Jacobian of the mapping (theta1, theta2) -> (a, b) around the LS solution
    from identify.fits.regression import regression_rows
    A, y = regression_rows([noisy])
    x, cov_x, _ = solve_least_squares(A, y)
    dt = 0.005

    def mapping(t):
        if method == "euler-ls":
            return np.array([(1 - t[0]) / dt, t[1] / dt])
        a = -math.log(t[0]) / dt
        return np.array([a, a * t[1] / (1 - t[0])])
    J = np.column_stack([(mapping(x + h) - mapping(x - h)) / (2e-7) for h in np.eye(2) * 1e-7])
    np.testing.assert_allclose(est.covariance, J @ cov_x @ J.T, rtol=1e-5)
    lo, hi = est.confidence_interval(0.95)["a"]
    assert lo < est.a < hi and hi - lo == pytest.approx(2 * 1.959964 * est.stderr()["a"], rel=1e-6)


def test_ols_covariance_matches_the_textbook_formula():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(200, 2))
    y = A @ [0.9, 0.1] + rng.normal(0, 0.1, 200)
    x, cov, rms = solve_least_squares(A, y)
    r = y - A @ x
    np.testing.assert_allclose(cov, (r @ r) / 198 * np.linalg.inv(A.T @ A), rtol=1e-10)
    assert rms == pytest.approx(math.sqrt(r @ r / 200))


def test_zero_input_is_not_identifiable():
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Constant(0), 0.005, 1.0))
    with pytest.raises(NotIdentifiableError, match="not persistently exciting"):
        fit_zoh_ls(rec)


def test_constant_input_at_steady_state_is_not_identifiable():
    rec = _sampled_speed_recording(25.0, 3.0, 0.005, Constant(100), w0=12.0)  # 12 = b u / a: steady state
    with pytest.raises(NotIdentifiableError, match="not persistently exciting"):
        fit_zoh_ls(rec)


def test_theta1_outside_unit_interval_is_explained():
    t = np.arange(200) * 0.01
    u = Sine(5.0).duty(200, 0.01)
    unstable = simulate(Motor(1.0, 1.0), u, t).speed * np.exp(2.0 * t)  # a growing mode: theta1 > 1
    rec = Recording(time=t, duty=u, sample_period=0.01, speed=unstable)
    with pytest.raises(NotIdentifiableError, match=r"theta1 = .* is not in \(0, 1\)"):
        fit_zoh_ls(rec)


def test_too_short_and_mixed_recordings():
    rec = _sampled_speed_recording(25.0, 3.0, 0.005, Sine(10.0), n=3)
    with pytest.raises(NotIdentifiableError, match="too short"):
        fit_zoh_ls(rec)
    a = _sampled_speed_recording(25.0, 3.0, 0.005, Sine(10.0))
    b = _sampled_speed_recording(25.0, 3.0, 0.01, Sine(10.0))
    with pytest.raises(ValueError, match="share one sample_period"):
        fit_zoh_ls([a, b])
    with pytest.raises(ValueError, match="method must be one of"):
        fit(a, method="magic")
    with pytest.raises(TypeError, match=r"recordings\[0\] must be a Recording"):
        fit_zoh_ls(["run.csv"])
