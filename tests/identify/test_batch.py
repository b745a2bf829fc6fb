"""identify.fits.batch: the estimators on many repetitions at once against the one-run fits they replace."""
import math

import numpy as np
import pytest

from identify import (
    BATCHED_METHODS,
    NotIdentifiableError,
    fit,
    fit_batch,
    fit_euler_ls,
    fit_output_error_batch,
    fit_zoh_ls,
    output_error_batchable,
    structure,
)
from motorsim import Constant, Experiment, Motor, Recording, SimRig, Sine
from motorsim.batch import encoder_counts_batch, simulate_batch, speed_batch

# Noise-free comparisons of the same arithmetic done two ways: agreement to 1e-9 relative
# (the bound asserted below); observed differences are ~1e-13.
RTOL = 1e-9


def _duties(n, dt, phases, freq=10.0, amp=200):
    return np.stack([Sine(freq, amp, ph).duty(n, dt) for ph in phases]).astype(float)


@pytest.mark.parametrize("noise", [0.0, 2e-4], ids=["quantised", "noisy"])
def test_batched_regressions_equal_identify_fits_on_the_same_recordings(noise):
    dt, n, cpr = 0.005, 2000, 16667
    motor = Motor(25.0, 3.0)
    duty = _duties(n, dt, [0.0, 0.4, 1.3, 2.2], freq=20.0)
    angle, _ = simulate_batch(motor, duty, dt)
    rngs = [np.random.default_rng(10 + r) for r in range(len(duty))] if noise else None
    counts = encoder_counts_batch(angle, cpr, noise, rngs)
    fits = fit_batch(list(BATCHED_METHODS), speed_batch(counts, cpr, dt), duty, dt)
    for r in range(len(duty)):
        rec = Recording(time=np.arange(n) * dt, duty=duty[r], sample_period=dt, counts=counts[r].astype(np.int64),
                        counts_per_rev=cpr)
        for name, ref in (("euler-ls", fit_euler_ls(rec)), ("zoh-ls", fit_zoh_ls(rec))):
            assert fits[name].a[r] == pytest.approx(ref.a, rel=RTOL)
            assert fits[name].b[r] == pytest.approx(ref.b, rel=RTOL)
            assert fits[name].failure[r] == ""


def test_batch_reports_the_failures_identify_raises_for():
    # A zero input: identify.fit refuses it; the batch marks every row failed with the reason.
    dt, n, cpr = 0.005, 400, 16667
    duty = np.zeros((2, n))
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Constant(0), dt, n * dt))
    with pytest.raises(NotIdentifiableError, match="identically zero"):
        fit_euler_ls(rec)
    counts = encoder_counts_batch(simulate_batch(Motor(25.0, 3.0), duty, dt)[0], cpr)
    fits = fit_batch(["euler-ls", "zoh-ls"], speed_batch(counts, cpr, dt), duty, dt)
    for f in fits.values():
        assert sum(1 for reason in f.failure if reason) == 2
        assert all("identically zero" in reason for reason in f.failure)
        assert np.all(np.isnan(f.a)) and np.all(np.isnan(f.b))


def test_zoh_failure_when_theta1_leaves_the_unit_interval():
    # A speed that grows by 2 % per sample, unrelated to the input: theta1 ~ 1.02, which
    # identify's zoh-ls refuses; the batch records the same refusal, and euler-ls still maps.
    rng = np.random.default_rng(0)
    n, dt = 400, 0.01
    w = 1.02 ** np.arange(n) + rng.normal(0, 0.01, n)
    duty = rng.normal(0, 100, n)
    rec = Recording(time=np.arange(n) * dt, duty=duty, sample_period=dt, speed=w)
    with pytest.raises(NotIdentifiableError, match="theta1"):
        fit_zoh_ls(rec)
    w_batch = w[None, :].copy()
    w_batch[:, 0] = np.nan  # the batch expects backward-differenced speed: no value at k = 0
    fits = fit_batch(["euler-ls", "zoh-ls"], w_batch, duty, dt)
    assert fits["zoh-ls"].failure[0].startswith("zoh-ls: theta1")
    assert np.isnan(fits["zoh-ls"].a[0])
    assert fits["euler-ls"].failure[0] == "" and fits["euler-ls"].a[0] < 0


def test_fit_batch_rejects_unbatched_names():
    with pytest.raises(ValueError, match="batched methods"):
        fit_batch(["no-such-method"], np.zeros((1, 10)), np.zeros(10), 0.01)


def test_the_zoh_map_is_the_inverse_of_the_structures_discrete_model():
    # the batch maps the regression back through the linear structure: its discrete model of
    # (a, b) gives back (a, b), to rounding of exp and log (1e-12 relative)
    linear = structure("linear")
    dt = 0.005
    pairs = [(25.0, 3.0), (0.5, -2.0), (400.0, 1e-3)]
    num_den = [linear.discrete_linear_part({"a": a, "b": b}, dt) for a, b in pairs]
    pole = np.array([-den[1] for _, den in num_den])
    gain = np.array([num[0] for num, _ in num_den])
    a, b = linear.values_from_discrete(pole, gain, dt)
    np.testing.assert_allclose(a, [p[0] for p in pairs], rtol=1e-12)
    np.testing.assert_allclose(b, [p[1] for p in pairs], rtol=1e-12)
    a, b = linear.values_from_discrete(np.array([0.0, 1.0, 1.5]), np.ones(3), dt)
    assert np.all(np.isnan(a)) and np.all(np.isnan(b))


@pytest.mark.parametrize("frequency, noise", [(10.0, 3e-4), (120.0, 3e-4)], ids=["regression-start", "grid-start"])
def test_batched_oe_equals_identify_fit_on_each_row(frequency, noise):
    # every row of one duty, fitted at once, against identify.fit(method="oe") on that row's recording:
    # the same minimum (1e-9 relative: different starts, rounding apart); at 120 rad/s on 2000 counts
    # per revolution the regression gives no row a start (theta1 > 1), so all start from identify's grid
    dt, n, cpr = 0.005, 2000, 2000
    duty = Sine(frequency, 200).duty(n, dt).astype(float)
    angle, _ = simulate_batch(Motor(25.0, 3.0), duty, dt)
    counts = encoder_counts_batch(np.broadcast_to(angle, (4, n)), cpr, noise,
                                  [np.random.default_rng(r) for r in range(4)])
    recs = [Recording(time=np.arange(n) * dt, duty=duty, sample_period=dt, counts=row.astype(np.int64),
                      counts_per_rev=cpr) for row in counts]
    assert output_error_batchable(recs[0])
    a, b = fit_output_error_batch(counts, duty, dt, cpr)
    for r, rec in enumerate(recs):
        if math.isnan(a[r]):
            continue                                    # left to identify.fit by the caller
        ref = fit(rec, "oe", outliers="keep")
        assert a[r] == pytest.approx(ref.a, rel=1e-9) and b[r] == pytest.approx(ref.b, rel=1e-9)
    assert np.isfinite(a).sum() >= 3


def test_a_constant_duty_takes_no_batched_oe():
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Constant(100), 0.005, 1.0))
    assert not output_error_batchable(rec)
