"""Static friction in the simulator: the exact per-interval solution against an independent fine-step
integration, no change without it, the knob's checks, and the knob through the rig, the CLI and fake://."""
import numpy as np
import pytest

from hardware.fake_device import parse_fake_url
from motorid.cli import main
from motorsim import Encoder, Experiment, Motor, SimRig, Sine, read_recording, simulate
from motorsim.checks import ParameterError
from motorsim.compiled import friction_run_python

A, B, C = 25.0, 3.0, 60.0


def _fine_step(duty, h, static, sub, bias=0.0):
    """Angle and speed by explicit Euler on ``sub`` steps per sample, written independently of the simulator:
    at rest the shaft stays while ``|b u + d| <= static``; a step that would carry the speed through zero while
    ``|b u + d| <= static`` stops it there."""
    angle, speed = np.zeros(len(duty)), np.zeros(len(duty))
    th = w = 0.0
    dt = h / sub
    for k in range(len(duty) - 1):
        drive = B * duty[k] + bias
        for _ in range(sub):
            if w == 0.0:
                if abs(drive) <= static:
                    continue
                acc = drive - C * np.sign(drive)
            else:
                acc = -A * w + drive - C * np.sign(w)
            nw = w + dt * acc
            if w != 0.0 and np.sign(nw) != np.sign(w) and abs(drive) <= static:
                nw = 0.0
            th += dt * 0.5 * (w + nw)
            w = nw
        angle[k + 1], speed[k + 1] = th, w
    return angle, speed


@pytest.mark.parametrize("ratio", [1.6, 2.0], ids=["1.6x", "2x"])
def test_stiction_matches_a_fine_step_integration(ratio, kernel_path):
    # a slow sine that stops the shaft every half period; the Euler reference's error is first order in its
    # step, so its distance to the exact solution must halve as the step halves, and be small at the finer one
    h = 0.005
    t = np.arange(400) * h
    duty = np.round(200 * np.sin(5.0 * t))
    traj = simulate(Motor(A, B, friction=C, static_friction=ratio * C, bias=1.0), duty, t)
    gaps = []
    for sub in (200, 400):
        angle, speed = _fine_step(duty, h, ratio * C, sub, bias=1.0)
        gaps.append(np.max(np.abs(traj.angle - angle)))
    assert np.sum(traj.speed == 0.0) > 10                       # it does stick
    assert gaps[1] < 0.7 * gaps[0]                                # converging on the simulator's solution
    assert gaps[1] < 1e-3 * np.max(np.abs(traj.angle))


def test_stiction_holds_the_shaft_longer_than_friction_alone():
    t = np.arange(600) * 0.005
    duty = np.round(200 * np.sin(5.0 * t))
    plain = simulate(Motor(A, B, friction=C), duty, t)
    sticky = simulate(Motor(A, B, friction=C, static_friction=2 * C), duty, t)
    assert np.sum(sticky.speed == 0.0) >= 2 * np.sum(plain.speed == 0.0) + 10   # 30 against 10 samples


def test_no_stiction_is_the_friction_model_unchanged(kernel_path):
    # static_friction 0 (none) and static_friction = friction are the Coulomb model, and the Python loop with
    # the break-away at the friction level gives the same run (1e-12 of the largest value: the compiled libm
    # may round exp/log differently in the last bit)
    rng = np.random.default_rng(3)
    t = np.arange(3000) * 0.005
    duty = 40 * np.sin(2.0 * t) + 5 * rng.standard_normal(len(t))
    none = simulate(Motor(A, B, friction=C, bias=1.0), duty, t, initial_speed=0.5)
    equal = simulate(Motor(A, B, friction=C, bias=1.0, static_friction=C), duty, t, initial_speed=0.5)
    speed, angle = np.empty(len(t)), np.empty(len(t))
    speed[0], angle[0] = 0.5, 0.0
    friction_run_python(A, B * duty[:-1] + 1.0, C, np.diff(t), speed, angle, C)
    for traj in (none, equal):
        assert np.max(np.abs(traj.speed - speed)) <= 1e-12 * np.max(np.abs(speed))
        assert np.max(np.abs(traj.angle - angle)) <= 1e-12 * np.max(np.abs(angle))


def test_stiction_without_sliding_friction_sticks_only_at_rest():
    # friction 0, static 50: the linear motor once moving, held at rest while |b u| <= 50
    t = np.arange(200) * 0.005
    duty = np.where(t < 0.5, 10.0, 30.0)                          # 30 rad/s^2 first: stuck; then 90: moves
    traj = simulate(Motor(A, B, static_friction=50.0), duty, t)
    assert np.all(traj.speed[:100] == 0.0) and np.all(traj.speed[101:] > 0)
    linear = simulate(Motor(A, B), np.where(t < 0.5, 0.0, 30.0), t)
    assert np.max(np.abs(traj.speed - linear.speed)) <= 1e-12 * np.max(linear.speed)


@pytest.mark.parametrize("kwargs, match", [
    ({"friction": C, "static_friction": 30.0}, r"static_friction must be 0 \(none\) or >= friction"),
    ({"static_friction": -1.0}, "static_friction"),
    ({"static_friction": 10.0, "electrical_time_constant": 0.01}, "electrical_time_constant must be 0"),
], ids=["below-friction", "negative", "with-a-lag"])
def test_bad_static_friction_is_refused_by_name(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        Motor(A, B, **kwargs)


def test_the_knob_reaches_the_rig_the_cli_and_fake_urls(tmp_path):
    motor = Motor(A, B, friction=C, static_friction=1.6 * C)
    assert not motor.is_linear and motor.breakaway == 1.6 * C
    rec = SimRig(motor, Encoder(counts_per_rev=1000)).run(Experiment(Sine(5.0, 200), 0.005, 3.0))
    assert rec.metadata["true_static_friction"] == repr(1.6 * C)
    out = tmp_path / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--friction", "60", "--static-friction", "96",
                 "--duration", "3", "--sine", "5,200", "--counts-per-rev", "1000", "--out", str(out)]) == 0
    from_cli = read_recording(out)
    assert from_cli.metadata["true_static_friction"] == "96.0"
    np.testing.assert_array_equal(from_cli.counts, rec.counts)
    assert parse_fake_url("fake://?friction=60&static_friction=96").motor.static_friction == 96.0
