"""The batch engine against python-control's simulation and the one-run estimators it replaces."""
import control
import numpy as np
import pytest

from identify import NotIdentifiableError, fit_euler_ls, fit_zoh_ls
from motorsim import Constant, Encoder, Experiment, Motor, Recording, SimRig, Sine, simulate
from scenarios.batch import BATCHED_METHODS, MethodOutcome, encoder_counts_batch, fit_batch, simulate_batch, speed_batch

# Noise-free comparisons of the same arithmetic done two ways: agreement to 1e-9 relative
# (the bound asserted below); observed differences are ~1e-13.
RTOL = 1e-9


def _duties(n, dt, phases, freq=10.0, amp=200):
    return np.stack([Sine(freq, amp, ph).duty(n, dt) for ph in phases]).astype(float)


@pytest.mark.parametrize("a, b, dt, w0", [(25.0, 3.0, 0.005, 0.0), (4.0, 0.5, 0.001, 7.0), (90.0, -2.0, 0.02, -3.0)],
                         ids=["article", "slow-fine", "fast-negative-gain"])
def test_simulate_batch_equals_python_control_forced_response(a, b, dt, w0):
    duty = _duties(3000, dt, [0.0, 1.0, 2.5])
    angle, speed = simulate_batch(Motor(a, b), duty, dt, initial_speed=w0)
    sysd = Motor(a, b).discretise(dt)
    for r in range(len(duty)):
        ref = control.forced_response(sysd, U=duty[r], X0=[0.0, w0]).outputs
        np.testing.assert_allclose(angle[r], ref[0], rtol=0, atol=RTOL * np.max(np.abs(ref[0])))
        np.testing.assert_allclose(speed[r], ref[1], rtol=0, atol=RTOL * np.max(np.abs(ref[1])))


def test_simulate_batch_applies_dead_zone_and_delay_like_motorsim_simulate():
    motor = Motor(25.0, 3.0, dead_zone=15.0, input_delay=2)
    dt, n = 0.005, 1500
    duty = _duties(n, dt, [0.0, 0.7])
    angle, speed = simulate_batch(motor, duty, dt)
    for r in range(2):
        ref = simulate(motor, duty[r], np.arange(n) * dt)
        np.testing.assert_allclose(angle[r], ref.angle, rtol=0, atol=RTOL * np.max(np.abs(ref.angle)))
        np.testing.assert_allclose(speed[r], ref.speed, rtol=0, atol=RTOL * np.max(np.abs(ref.speed)))


def test_simulate_batch_refuses_friction_naming_the_rule():
    with pytest.raises(ValueError, match="friction"):
        simulate_batch(Motor(25.0, 3.0, friction=5.0), np.zeros((2, 10)), 0.005)
    with pytest.raises(ValueError, match="duty must have shape"):
        simulate_batch(Motor(25.0, 3.0), np.zeros((2, 3, 4)), 0.005)


def test_encoder_rows_equal_encoder_counts_with_the_same_generators():
    angle = np.cumsum(np.full((3, 500), 0.01), axis=1)
    enc = Encoder(4096, angle_noise=3e-4)
    ours = encoder_counts_batch(angle, 4096, 3e-4, [np.random.default_rng(s) for s in (1, 2, 3)])
    for r, s in enumerate((1, 2, 3)):
        # integer counts from the same draws: exactly equal
        np.testing.assert_array_equal(ours[r], enc.counts(angle[r], np.random.default_rng(s)))
    with pytest.raises(ValueError, match="rngs"):
        encoder_counts_batch(angle, 4096, 3e-4, None)


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
        assert f.n_failed == 2
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


def test_failure_reasons_group_by_the_message_with_its_numbers_masked():
    # each repetition's message carries its own figure; grouped verbatim, every group had one member
    failures = ("singular: cond 3.1e+08 after 12 steps", "singular: cond 2.7e+08 after 9 steps", "",
                "recording is too short: 1 regression rows", "singular: cond -4e+07 after 3 steps")
    outcome = MethodOutcome("oe", np.zeros(5), np.zeros(5), failures)
    assert outcome.failure_summary() == ("singular: cond 3.1e+08 after 12 steps (3) | "
                                         "recording is too short: 1 regression rows (1)")
