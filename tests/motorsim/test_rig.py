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
