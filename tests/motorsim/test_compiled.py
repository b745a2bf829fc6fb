"""The friction loop: the numba kernel and the Python loop give the same trajectory, and
simulate switches to the kernel only after enough Python intervals."""
import numpy as np

from motorsim import Motor, compiled, simulate
from motorsim.compiled import friction_run_python


def _stick_slip_run(n=20_000):
    # a slow sine that lets friction stop the motor every half period, on a jittered clock
    rng = np.random.default_rng(2)
    t = np.concatenate([[0.0], np.cumsum(0.005 * (1 + 0.1 * rng.uniform(-1, 1, n - 1)))])
    return t, 40 * np.sin(2.0 * t) + 5 * rng.standard_normal(n)


def test_simulate_with_friction_is_the_same_on_both_paths(kernel_path):
    # both paths against the Python loop run directly: 1e-12 of the largest value (the
    # compiled libm may round exp/log differently in the last bit)
    t, duty = _stick_slip_run()
    motor = Motor(25.0, 3.0, friction=60.0, bias=1.0)
    traj = simulate(motor, duty, t, initial_speed=0.5, initial_angle=2.0)
    speed, angle = np.empty(len(t)), np.empty(len(t))
    speed[0], angle[0] = 0.5, 2.0
    friction_run_python(25.0, 3.0 * duty[:-1] + 1.0, 60.0, np.diff(t), speed, angle, 60.0)
    assert np.sum(speed == 0.0) > 100                      # it does stick
    assert np.max(np.abs(traj.speed - speed)) <= 1e-12 * np.max(np.abs(speed))
    assert np.max(np.abs(traj.angle - angle)) <= 1e-12 * np.max(np.abs(angle))


def test_the_kernel_is_used_only_after_enough_python_intervals(monkeypatch):
    calls = []
    monkeypatch.setattr(compiled, "compiled_kernel", lambda: lambda *args: calls.append(len(args[3])))
    monkeypatch.setattr(compiled, "COMPILE_AFTER", 1500)
    monkeypatch.setitem(compiled.usage, "python_intervals", 0)
    t = np.arange(1000) * 0.005
    motor = Motor(25.0, 3.0, friction=10.0)
    simulate(motor, np.full(1000, 100.0), t)
    simulate(motor, np.full(1000, 100.0), t)
    assert calls == []                                     # 999 + 999 intervals in Python
    simulate(motor, np.full(1000, 100.0), t)
    assert calls == [999]
