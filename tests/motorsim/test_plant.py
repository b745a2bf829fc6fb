"""The plant against references we did not write: python-control, scipy's expm, closed forms."""
import math

import control
import numpy as np
import pytest
from scipy.linalg import expm

from motorsim import Motor, Sine, simulate
from motorsim.excitation import PRBS
from motorsim.plant import zoh_matrices

RTOL = 1e-9  # noise-free: the exact ZOH solution is reproduced to rounding error


def test_transfer_function_is_b_over_s_plus_a():
    tf = Motor(25.0, 3.0).transfer_function()
    np.testing.assert_allclose(tf.num[0][0], [3.0])
    np.testing.assert_allclose(tf.den[0][0], [1.0, 25.0])


def test_discretise_uses_control_sample_system_zoh():
    motor = Motor(25.0, 3.0)
    sysd = motor.discretise(0.005)
    ref = control.sample_system(motor.state_space(), 0.005, method="zoh")
    np.testing.assert_allclose(sysd.A, ref.A, rtol=RTOL)
    np.testing.assert_allclose(sysd.B, ref.B, rtol=RTOL)
    assert sysd.dt == 0.005


@pytest.mark.parametrize("excitation", [Sine(10.0), Sine(40.0, 255, 0.3), PRBS(200, -150, 9, 3)],
                         ids=["sine10", "sine40", "prbs"])
def test_simulation_equals_forced_response_of_zoh_model(excitation):
    motor, dt, n = Motor(25.0, 3.0), 0.005, 2000
    duty = excitation.duty(n, dt).astype(float)
    ours = simulate(motor, duty, np.arange(n) * dt, initial_speed=1.5, initial_angle=0.25)
    ref = control.forced_response(motor.discretise(dt), U=duty, X0=[0.25, 1.5])
    np.testing.assert_allclose(ours.angle, ref.outputs[0], rtol=RTOL, atol=RTOL * np.abs(ours.angle).max())
    np.testing.assert_allclose(ours.speed, ref.outputs[1], rtol=RTOL, atol=RTOL * np.abs(ours.speed).max())


def test_nonuniform_time_equals_matrix_exponential_per_interval():
    rng = np.random.default_rng(1)
    motor = Motor(12.0, -2.0)
    t = np.cumsum(rng.uniform(0.002, 0.008, 300))
    duty = rng.integers(-255, 256, 300).astype(float)
    ours = simulate(motor, duty, t)
    # reference: augmented-matrix exponential of [[A, B], [0, 0]] over each interval
    A = np.array([[0.0, 1.0], [0.0, -12.0]])
    B = np.array([[0.0], [-2.0]])
    M = np.zeros((3, 3))
    M[:2, :2], M[:2, 2:] = A, B
    x = np.zeros(2)
    for k in range(299):
        E = expm(M * (t[k + 1] - t[k]))
        x = E[:2, :2] @ x + E[:2, 2] * duty[k]
        np.testing.assert_allclose([ours.angle[k + 1], ours.speed[k + 1]], x, rtol=1e-9, atol=1e-9)


def test_input_delay_shifts_the_duty():
    dt, n = 0.01, 400
    duty = Sine(5.0).duty(n, dt)
    t = np.arange(n) * dt
    delayed = simulate(Motor(8.0, 1.0, input_delay=3), duty, t, duty_before=7.0)
    shifted = np.concatenate([[7.0] * 3, duty[:-3]])
    plain = simulate(Motor(8.0, 1.0), shifted, t)
    np.testing.assert_array_equal(delayed.speed, plain.speed)


def test_dead_zone_removes_small_duty_and_shifts_the_rest():
    motor = Motor(8.0, 1.0, dead_zone=30.0)
    np.testing.assert_array_equal(motor.drive([-100, -30, 0, 29.5, 30, 31, 200]), [-70, 0, 0, 0, 0, 1, 170])


@pytest.mark.usefixtures("kernel_path")
class TestCoulombFriction:
    """Closed forms of w' = -a w + b u - c sign(w)."""

    a, b, c = 10.0, 2.0, 50.0

    def test_constant_drive_from_rest(self):
        u, t = 100.0, np.linspace(0, 1, 201)
        traj = simulate(Motor(self.a, self.b, friction=self.c), np.full_like(t, u), t)
        w_inf = (self.b * u - self.c) / self.a
        np.testing.assert_allclose(traj.speed, w_inf * -np.expm1(-self.a * t), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(traj.angle, w_inf * (t + np.expm1(-self.a * t) / self.a), rtol=1e-12, atol=1e-12)

    def test_sticks_when_drive_does_not_overcome_friction(self):
        t = np.linspace(0, 1, 101)
        traj = simulate(Motor(self.a, self.b, friction=self.c), np.full_like(t, 25.0), t)  # b u = c
        assert np.all(traj.speed == 0) and np.all(traj.angle == 0)

    def test_coasts_to_a_stop_and_stays(self):
        w0, t = 20.0, np.linspace(0, 0.5, 501)
        traj = simulate(Motor(self.a, self.b, friction=self.c), np.zeros_like(t), t, initial_speed=w0)
        r = self.c / self.a
        t_stop = math.log(1 + w0 / r) / self.a
        expected = np.where(t < t_stop, (w0 + r) * np.exp(-self.a * t) - r, 0.0)
        np.testing.assert_allclose(traj.speed, expected, atol=1e-12)
        final_angle = (w0 + r) / self.a * (1 - math.exp(-self.a * t_stop)) - r * t_stop
        np.testing.assert_allclose(traj.angle[t > t_stop], final_angle, rtol=1e-12)

    def test_reverses_through_zero(self):
        # moving forward, strong reverse drive: must pass through rest and settle at the reverse equilibrium
        t = np.linspace(0, 2, 401)
        traj = simulate(Motor(self.a, self.b, friction=self.c), np.full_like(t, -200.0), t, initial_speed=30.0)
        np.testing.assert_allclose(traj.speed[-1], (-400.0 + self.c) / self.a, rtol=1e-6)
        assert np.all(np.diff(traj.speed) <= 1e-12)  # monotone: no chatter at zero


@pytest.mark.parametrize("kwargs, match", [
    (dict(a=0.0, b=1.0), "a must be > 0"),
    (dict(a=1.0, b=0.0), "b must be nonzero"),
    (dict(a=1.0, b=1.0, friction=-1.0), "friction must be >= 0"),
    (dict(a=float("nan"), b=1.0), "a must be finite"),
    (dict(a="1", b=1.0), "a must be a real number"),
    (dict(a=1.0, b=1.0, input_delay=1.5), "input_delay must be an integer"),
], ids=["a0", "b0", "friction", "nan", "str", "delay"])
def test_motor_rejects_bad_parameters(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        Motor(**kwargs)


def test_simulate_rejects_time_not_increasing():
    with pytest.raises(ValueError, match="time must be strictly increasing"):
        simulate(Motor(1.0, 1.0), [0, 0, 0], [0.0, 0.1, 0.1])



def _speed_loop(motor, duty, t, initial_speed):
    """The exact recursion, one interval at a time (the reference)."""
    e, g, _, _ = zoh_matrices(motor.a, motor.b, np.diff(t))
    out = np.empty(len(t))
    out[0] = x = initial_speed
    for k in range(len(t) - 1):
        x = e[k] * x + g[k] * duty[k]
        out[k + 1] = x
    return out


def _state_loop(motor, duty, t, initial_speed, initial_angle):
    """Speed and angle by the exact per-interval recursion, bias included (the reference)."""
    e, g, p, q = zoh_matrices(motor.a, motor.b, np.diff(t))
    drive = duty + motor.bias / motor.b
    speed, angle = np.empty(len(t)), np.empty(len(t))
    speed[0], angle[0] = initial_speed, initial_angle
    for k in range(len(t) - 1):
        speed[k + 1] = e[k] * speed[k] + g[k] * drive[k]
        angle[k + 1] = angle[k] + p[k] * speed[k] + q[k] * drive[k]
    return speed, angle


@pytest.mark.parametrize("spread", [0.0, 1e-12, 3e-10], ids=["bit-equal", "1e-12", "3e-10"])
def test_nearly_uniform_intervals_equal_the_exact_loop_in_speed_and_angle(spread):
    # intervals within RECURSION_RTOL of each other take the constant-coefficient path with
    # first-order corrections: speed and angle agree with the loop to rounding (1e-12 of the largest)
    rng = np.random.default_rng(3)
    n = 20_000
    t = np.concatenate([[0.0], np.cumsum(0.005 * (1 + spread * rng.uniform(-1, 1, n - 1)))])
    duty = Sine(10.0, 200).duty(n, 0.005).astype(float)
    motor = Motor(25.0, 3.0, bias=-4.0)
    speed, angle = _state_loop(motor, duty, t, 0.7, -1.5)
    out = simulate(motor, duty, t, initial_speed=0.7, initial_angle=-1.5)
    assert np.max(np.abs(out.speed - speed)) <= 1e-12 * np.max(np.abs(speed))
    assert np.max(np.abs(out.angle - angle)) <= 1e-12 * np.max(np.abs(angle))


@pytest.mark.parametrize("a, dt", [(25.0, 0.005), (0.05, 0.001), (200.0, 0.01)], ids=["article", "slow", "fast"])
def test_float_time_grid_equals_the_exact_per_interval_loop(a, dt):
    # k * dt has intervals that differ by rounding (the fast path with its correction pass):
    # it must agree with the per-interval loop to rounding, 1e-12 of the largest speed
    n = 200_000
    t = np.arange(n) * dt
    assert len(np.unique(np.diff(t))) > 1
    duty = Sine(10.0, 200).duty(n, dt).astype(float)
    motor = Motor(a, 3.0)
    exact = _speed_loop(motor, duty, t, 0.7)
    speed = simulate(motor, duty, t, initial_speed=0.7).speed
    assert np.max(np.abs(speed - exact)) <= 1e-12 * np.max(np.abs(exact))


@pytest.mark.parametrize("jitter", [1e-6, 1e-3, 0.3], ids=["1e-6", "1e-3", "0.3-per-sample-loop"])
def test_jittered_time_grid_equals_the_exact_per_interval_loop(jitter):
    # a real clock, outside RECURSION_RTOL: fixed-point passes with the midrange factor
    # (rho = 1e-3 at 1e-3 jitter) or, for wild jitter, the per-sample loop; the loop's
    # answer to rounding, 1e-12 of the largest speed
    rng = np.random.default_rng(5)
    t = np.concatenate([[0.0], np.cumsum(0.005 * (1 + jitter * rng.uniform(-1, 1, 999)))])
    duty = rng.standard_normal(1000)
    motor = Motor(25.0, 3.0)
    exact = _speed_loop(motor, duty, t, 0.3)
    speed = simulate(motor, duty, t, initial_speed=0.3).speed
    assert np.max(np.abs(speed - exact)) <= 1e-12 * np.max(np.abs(exact))


@pytest.mark.parametrize("dt, start", [(0.005, 1000.0), (0.25, 0.0)], ids=["float-grid", "bit-equal-intervals"])
def test_a_long_run_in_blocks_has_the_bits_of_one_pass(monkeypatch, dt, start):
    # the blocks carry each filter pass and the sum across: every sample sees the same operations in the
    # same order, so the answer is the one-pass answer to the bit (not merely to rounding)
    import motorsim.plant as plant
    n = 4 * plant.ZOH_BLOCK + 1234
    t = start + np.arange(n) * dt
    duty = PRBS(seed=2).duty(n, dt).astype(float)
    motor = Motor(25.0, 3.0, bias=-4.0)
    blocked = simulate(motor, duty, t, initial_speed=0.7, initial_angle=-1.5)
    monkeypatch.setattr(plant, "ZOH_BLOCK", 10 * n)
    whole = simulate(motor, duty, t, initial_speed=0.7, initial_angle=-1.5)
    assert np.array_equal(blocked.speed, whole.speed)
    assert np.array_equal(blocked.angle, whole.angle)


def test_simulate_tells_a_large_finite_duty_from_a_non_finite_one():
    # the finiteness check sums the duty first: a sum that overflows is checked value by value
    t = np.arange(4) * 0.01
    out = simulate(Motor(25.0, 1e-10), np.full(4, 1e308), t)      # the duty's sum overflows, the run does not
    assert np.all(np.isfinite(out.speed)) and out.speed[-1] > 0
    with pytest.raises(ValueError, match="finite"):
        simulate(Motor(25.0, 3.0), [0.0, np.nan, 0.0, 0.0], t)
