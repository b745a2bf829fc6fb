"""``Stepper``: the plant's exact step, the one every per-sample loop runs, against the exact simulator."""
import numpy as np
import pytest

from motorsim import Motor, Sine, simulate
from motorsim.plant import Stepper, first_order_coefficients, zoh_matrices

# Noise-free comparisons of the same exact solution computed two ways (a step at a time against the
# simulator's filter passes): 1e-9 relative to the run's largest value (observed ~1e-13).
RTOL = 1e-9

PLANTS = {
    "linear": Motor(25.0, 3.0),
    "bias-dead-zone": Motor(25.0, 3.0, bias=4.0, dead_zone=12.0),
    "friction": Motor(25.0, 3.0, friction=30.0, bias=4.0),
    "stiction": Motor(25.0, 3.0, friction=30.0, static_friction=45.0, bias=4.0, dead_zone=5.0),
    "lag": Motor(25.0, 3.0, electrical_time_constant=0.004, bias=4.0, dead_zone=5.0),
}


@pytest.mark.parametrize("motor", PLANTS.values(), ids=PLANTS.keys())
@pytest.mark.parametrize("jitter", [0.0, 0.3], ids=["uniform", "jittered"])
def test_stepping_each_interval_is_the_simulators_run(motor, jitter):
    rng = np.random.default_rng(5)
    n, dt = 800, 0.002
    t = np.arange(n) * dt + (rng.uniform(-0.5, 0.5, n) * jitter * dt if jitter else 0.0)
    t -= t[0]
    duty = Sine(9.0, 120).duty(n, dt).astype(float)
    ref = simulate(motor, duty, t, initial_speed=1.5)
    stepper = Stepper(motor, np.diff(t))
    state, angle, speed = (0.0, 1.5, 0.0), [0.0], [1.5]
    for k in range(n - 1):
        state = stepper.step(k, state, duty[k])
        angle.append(state[0])
        speed.append(state[1])
    np.testing.assert_allclose(angle, ref.angle, rtol=0, atol=RTOL * np.max(np.abs(ref.angle)))
    np.testing.assert_allclose(speed, ref.speed, rtol=0, atol=RTOL * np.max(np.abs(ref.speed)))


def test_a_torque_adds_to_the_bias():
    # an added acceleration is the bias's: the same step as a plant with that much more bias
    for motor in PLANTS.values():
        more = Motor(motor.a, motor.b, friction=motor.friction, bias=motor.bias + 7.0, dead_zone=motor.dead_zone,
                     static_friction=motor.static_friction, electrical_time_constant=motor.electrical_time_constant)
        one, two = Stepper(motor, 0.002), Stepper(more, 0.002)
        state = (0.3, 4.0, 0.0)
        np.testing.assert_allclose(one.step(0, state, 80.0, torque=7.0), two.step(0, state, 80.0), rtol=1e-12)


def test_the_step_coefficients_are_the_array_forms():
    e, p, r = first_order_coefficients(25.0, 0.005)
    ze, zg, zp, zq = (float(x) for x in zoh_matrices(25.0, 3.0, 0.005))
    # the same quantities (numpy's and math's exp may differ in the last bit: 1e-15 relative)
    assert e == pytest.approx(ze, rel=1e-15) and p == pytest.approx(zp, rel=1e-15)
    assert 3.0 * p == pytest.approx(zg, rel=1e-15) and 3.0 * r == pytest.approx(zq, rel=1e-15)
