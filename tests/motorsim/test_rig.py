"""SimRig honours the Rig protocol and applies exactly the experiment's duty."""
import numpy as np
import pytest

from motorsim import PRBS, Encoder, Experiment, Motor, Rig, SimRig, Sine, simulate


def test_simrig_is_a_rig_and_applies_the_experiment_duty():
    exp = Experiment(PRBS(150, -150, 8, 2), 0.002, 1.0)
    rig = SimRig(Motor(30.0, 2.0))
    assert isinstance(rig, Rig)
    rec = rig.run(exp)
    assert len(rec) == exp.n_samples == 500
    np.testing.assert_array_equal(rec.duty, exp.duty())
    traj = simulate(Motor(30.0, 2.0), exp.duty(), np.arange(500) * 0.002)
    np.testing.assert_array_equal(rec.counts, Encoder().counts(traj.angle))
    assert rec.metadata["excitation"] == "prbs:150,-150,8,2,1" and rec.metadata["true_a"] == "30.0"


def test_same_seed_same_recording_and_different_seed_differs():
    def run(seed):
        return SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), jitter=0.1, drop_rate=0.02,
                      rng=np.random.default_rng(seed)).run(Experiment(Sine(10.0), 0.005, 2.0))
    a, b, c = run(1), run(1), run(2)
    np.testing.assert_array_equal(a.counts, b.counts)
    np.testing.assert_array_equal(a.time, b.time)
    assert not np.array_equal(a.seq, c.seq)


def test_drops_leave_gaps_and_jitter_bounds_the_intervals():
    rec = SimRig(Motor(25.0, 3.0), jitter=0.2, drop_rate=0.1, rng=np.random.default_rng(0)).run(
        Experiment(Sine(10.0), 0.005, 10.0))
    missing = 2000 - len(rec)
    # binomial(1999, 0.1): mean 200, sd 13.4; 4 sd either way
    assert abs(missing - 199.9) < 4 * 13.4
    gaps = np.diff(rec.seq)
    steps = np.diff(rec.time)[gaps == 1]
    assert steps.min() >= 0.005 * 0.8 - 1e-12 and steps.max() <= 0.005 * 1.2 + 1e-12


def test_simrig_needs_an_rng_for_randomness():
    with pytest.raises(TypeError, match="rng must be a numpy.random.Generator"):
        SimRig(Motor(1.0, 1.0), jitter=0.1)


@pytest.mark.parametrize("kwargs, match", [
    (dict(excitation="sine"), "excitation must be an Excitation"),
    (dict(excitation=Sine(10.0), duration=0.005), "at least 2 samples"),
    (dict(excitation=Sine(10.0), duty_limit=300), r"duty_limit must be in 0\.\.\.255"),
    (dict(excitation=Sine(10.0), sample_period=0.5), "Nyquist"),
], ids=["type", "short", "limit", "nyquist"])
def test_experiment_validates(kwargs, match):
    with pytest.raises((TypeError, ValueError), match=match):
        Experiment(**kwargs)


def _disturbance(seed, n, dt, rms, time_constant):
    """The AR(1) torque SimRig draws first from its rng (no angle noise, jitter or drops)."""
    from scipy.signal import lfilter
    r = np.exp(-dt / time_constant)
    e = np.random.default_rng(seed).standard_normal(n) * rms * np.sqrt(1 - r * r)
    e[0] = 0.0
    return lfilter([1.0], [1.0, -r], e)


def test_a_disturbance_enters_the_motor_as_its_bias_does():
    # linear motor: the run with the torque minus the run without is the motor's response to
    # d / b added to the duty, exactly (superposition); rtol 1e-9 is rounding of the two paths
    exp, motor = Experiment(Sine(10.0, 150), 0.002, 2.0), Motor(25.0, 3.0)
    n = exp.n_samples
    rig = SimRig(motor, record_speed=True, disturbance=20.0, disturbance_time=0.05, rng=np.random.default_rng(4))
    with_torque = rig.run(exp)
    d = _disturbance(4, n, 0.002, 20.0, 0.05)
    expected = simulate(motor, exp.duty() + d / 3.0, np.arange(n) * 0.002)
    np.testing.assert_allclose(with_torque.speed, expected.speed, rtol=1e-9, atol=1e-9)
    assert with_torque.metadata["disturbance"] == "20.0" and with_torque.metadata["disturbance_time"] == "0.05"


def test_the_disturbance_has_its_rms_and_correlation_time():
    # 190 correlation times: the sample RMS within 20 % of 30 and the autocorrelation at one
    # correlation time (50 samples of 2 ms = 0.1 s) near exp(-1) = 0.37, within 0.15 (standard
    # errors of about 10 % and 0.07 over about 190 independent stretches)
    d = _disturbance(0, 10000, 0.002, 30.0, 0.1)
    assert np.sqrt(np.mean(d[500:] ** 2)) == pytest.approx(30.0, rel=0.2)
    x = d[500:] - d[500:].mean()
    assert np.dot(x[:-50], x[50:]) / np.dot(x, x) == pytest.approx(np.exp(-1.0), abs=0.15)


def test_a_position_loop_feeds_the_disturbance_back():
    # zero reference: without a torque the loop holds the shaft still (duty 0 throughout); with
    # one, the duty answers it, against its sign (the duty opposes the torque's drift)
    from motorsim.control import ClosedLoopExperiment, PlantModel, PositionPD, Reference
    pd = PositionPD(PlantModel(25.0, 3.0, 0.001, 2000), time_constant=0.05)
    exp = ClosedLoopExperiment(pd, Reference("constant", level=0.0), 5.0)
    still = SimRig(Motor(25.0, 3.0), Encoder(2000)).run(exp)
    assert not np.any(still.duty)
    pushed = SimRig(Motor(25.0, 3.0), Encoder(2000), disturbance=30.0, rng=np.random.default_rng(2)).run(exp)
    d = _disturbance(2, exp.n_samples, 0.001, 30.0, 0.1)
    assert np.corrcoef(pushed.duty[1:], d[:-1])[0, 1] < -0.5


@pytest.mark.parametrize("kwargs, match", [
    ({"disturbance": -1.0}, "disturbance"),
    ({"disturbance": 1.0, "disturbance_time": 0.0}, "disturbance_time"),
], ids=["negative", "zero time"])
def test_a_bad_disturbance_is_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SimRig(Motor(25.0, 3.0), rng=np.random.default_rng(0), **kwargs)


def test_a_disturbance_needs_an_rng():
    with pytest.raises(TypeError, match="rng"):
        SimRig(Motor(25.0, 3.0), disturbance=1.0)


def test_a_disturbance_acts_behind_an_electrical_lag_on_the_shaft():
    # The torque enters the mechanical equation, not through the lag: by superposition the run with it
    # minus the run without is 1/(s + a) driven by the torque itself (b = 1), exactly; 1e-9 is rounding.
    # (The per-sample loop is the plant's own step, so the lag no longer refuses a disturbance.)
    exp, motor = Experiment(Sine(10.0, 150), 0.002, 2.0), Motor(25.0, 3.0, electrical_time_constant=0.004)
    n = exp.n_samples
    rig = SimRig(motor, record_speed=True, disturbance=20.0, disturbance_time=0.05, rng=np.random.default_rng(4))
    with_torque = rig.run(exp)
    without = simulate(motor, exp.duty(), np.arange(n) * 0.002)
    torque_alone = simulate(Motor(25.0, 1.0), _disturbance(4, n, 0.002, 20.0, 0.05), np.arange(n) * 0.002)
    np.testing.assert_allclose(with_torque.speed - without.speed, torque_alone.speed, rtol=0,
                               atol=1e-9 * np.max(np.abs(without.speed)))
