"""motorsim.batch: many repetitions simulated at once, against python-control and the one-run simulator."""
import control
import numpy as np
import pytest

from motorsim import Encoder, Motor, Sine, simulate
from motorsim.batch import encoder_counts_batch, simulate_batch

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
