"""identify.fits.recursive: RLS against batch least squares, and the running estimators against the truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from identify import fit_zoh_ls
from identify.fits.recursive import RecursiveLeastSquares, RunningEstimator
from motorsim import PRBS, Encoder, Experiment, Motor, SimRig, Sine


def _feed(est, rec):
    for s, t, u, c in zip(rec.seq, rec.time, rec.duty, rec.counts):
        est.add(int(s), float(t), float(u), int(c))
    return est.estimate()


def test_rls_equals_batch_least_squares_on_random_rows():
    # With lambda = 1 and P0 = 1e8 I, RLS solves min ||A x - y||^2 + 1e-8 ||x||^2; on 500 rows with
    # A^T A ~ 500 I the regularisation moves x by ~1e-11 relative, so 1e-8 leaves room for rounding.
    rng = np.random.default_rng(5)
    A = rng.normal(size=(500, 3))
    y = A @ np.array([0.9, -2.0, 0.5]) + rng.normal(scale=0.1, size=500)
    rls = RecursiveLeastSquares(3)
    for row, target in zip(A, y):
        rls.update(row, target)
    np.testing.assert_allclose(rls.theta, np.linalg.lstsq(A, y, rcond=None)[0], rtol=1e-8)
    assert rls.n_updates == 500


def test_rls_with_forgetting_tracks_a_parameter_change():
    # lambda = 0.95 remembers ~20 rows: 300 rows after the jump the old value has weight 0.95^300 ~ 2e-7.
    rng = np.random.default_rng(6)
    rls = RecursiveLeastSquares(1, forgetting=0.95)
    for k in range(600):
        x = rng.normal()
        rls.update([x], (1.0 if k < 300 else 3.0) * x)
    assert rls.theta[0] == pytest.approx(3.0, rel=1e-6)


@pytest.mark.parametrize("excitation", [Sine(10.0), PRBS(200, -200, 9, 3)], ids=["sine", "prbs"])
def test_running_zoh_ls_reproduces_the_batch_zoh_ls_estimate(excitation):
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(excitation, 0.005, 10.0))
    run, batch = _feed(RunningEstimator(0.005, rec.counts_per_rev, model="zoh-ls"), rec), fit_zoh_ls(rec)
    # same rows, same mapping; RLS differs from QR least squares only by rounding and the 1e-8 prior
    assert run.a == pytest.approx(batch.a, rel=1e-6) and run.b == pytest.approx(batch.b, rel=1e-6)
    assert run.n_rows == batch.n_samples


def test_running_zoh_avg_is_exact_on_a_fine_encoder():
    # With 2^31 - 1 counts per revolution the quantisation is ~3e-9 rad: the exact model of the
    # differenced speed recovers a and b to ~1e-6 (what is left is quantisation through the regression).
    rec = SimRig(Motor(25.0, 3.0), Encoder(2**31 - 1)).run(Experiment(PRBS(200, -200, 9, 3), 0.005, 5.0))
    est = _feed(RunningEstimator(0.005, 2**31 - 1), rec)
    assert est.a == pytest.approx(25.0, rel=1e-5) and est.b == pytest.approx(3.0, rel=1e-5)


@pytest.mark.parametrize("excitation", [Sine(10.0), Sine(40.0), PRBS(200, -200, 9, 3)],
                         ids=["sine10", "sine40", "prbs"])
def test_running_zoh_avg_reaches_the_truth_on_the_articles_encoder(excitation):
    # 16 667 counts/rev at 5 ms quantise the speed to 0.075 rad/s; fitted in (a, b) the exact
    # averaged-speed model is left with a quantisation bias of 0.01-0.03 % here (the same as a batch
    # nonlinear least-squares fit of that model); 0.2 % bounds it with room, where zoh-ls is off by 6-20 %.
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(excitation, 0.005, 10.0))
    est = _feed(RunningEstimator(0.005, rec.counts_per_rev), rec)
    assert est.a == pytest.approx(25.0, rel=2e-3) and est.b == pytest.approx(3.0, rel=2e-3)


def test_running_estimate_never_pairs_across_a_gap():
    rec = SimRig(Motor(25.0, 3.0), drop_rate=0.1, rng=np.random.default_rng(2)).run(
        Experiment(PRBS(200, -200, 9, 3), 0.005, 4.0))
    est = _feed(RunningEstimator(0.005, rec.counts_per_rev, model="zoh-ls"), rec)
    d = np.diff(rec.seq)
    assert est.n_rows == int(np.sum((d[:-1] == 1) & (d[1:] == 1)))   # three consecutive indices per row
    batch = fit_zoh_ls(rec)
    assert est.a == pytest.approx(batch.a, rel=1e-6)


def test_running_estimate_is_nan_until_identifiable():
    est = RunningEstimator(0.005, 1000)
    est.add(0, 0.0, 100, 0)
    e = est.estimate()
    assert not e.ready and math.isnan(e.a) and e.to_dict()["a"] is None


@pytest.mark.parametrize("kwargs, name", [({"sample_period": 0.0}, "sample_period"),
                                          ({"counts_per_rev": 0}, "counts_per_rev"), ({"model": "x"}, "model"),
                                          ({"forgetting": 0.0}, "forgetting")],
                         ids=["dt", "cpr", "model", "forgetting"])
def test_running_estimator_rejects_bad_arguments(kwargs, name):
    args = {"sample_period": 0.005, "counts_per_rev": 1000, **kwargs}
    with pytest.raises(ValueError, match=name):
        RunningEstimator(**args)
