"""Best linear approximation: a linear motor shows no distortion, friction and a dead zone do."""
import numpy as np
import pytest

from identify.errors import NotIdentifiableError
from identify.frequency.best_linear import best_linear_approximation
from motorsim import PRBS, Encoder, Experiment, Motor, OddMultisine, SimRig

A, B, DT, PERIOD = 25.0, 3.0, 0.005, 1024


def _runs(motor, realisations=4, periods=4, noise=1e-3):
    out = []
    for seed in range(1, realisations + 1):
        rig = SimRig(motor, Encoder(angle_noise=noise), rng=np.random.default_rng(seed))
        out.append(rig.run(Experiment(OddMultisine(PERIOD, 63, 20, seed=seed), sample_period=DT,
                                      duration=PERIOD * DT * (periods + 1))))
    return out


def _drive_rms():
    d = OddMultisine(PERIOD, 63, 20, seed=1).duty(PERIOD, DT).astype(float)
    return float(np.sqrt(np.mean(d**2)))


def test_a_linear_motor_shows_distortion_below_the_noise():
    bla = best_linear_approximation(_runs(Motor(A, B)))
    assert bla.is_linear() and bla.is_linear(kind="odd") and bla.is_linear(kind="even")
    assert len(bla.distorted_lines()) == 0
    assert bla.summary().startswith("linear to within")
    frf = bla.frequency_response
    assert frf.covers(frf.model_response(A, B)).mean() >= 0.9
    # the realisations vary by their noise only: distortion variance within the noise variance's spread
    assert np.median(bla.distortion_variance / bla.noise_variance) < 1.0


@pytest.mark.parametrize("motor", [Motor(A, B, friction=0.2 * B * _drive_rms()), Motor(A, B, dead_zone=20)],
                         ids=["friction-20-percent-of-drive", "dead-zone-20-duty"])
def test_friction_and_dead_zone_are_detected_as_odd_distortion(motor):
    bla = best_linear_approximation(_runs(motor))
    assert not bla.is_linear(kind="odd")
    assert bla.is_linear(kind="even")   # both are odd nonlinearities
    where = bla.distorted_lines(kind="odd")
    assert len(where) >= 5
    assert np.all(bla.distortion_db()[np.isin(bla.detection_omega, where)] > bla.noise_db()[
        np.isin(bla.detection_omega, where)] + 10)       # at least 10 dB above the noise there
    assert "odd-order distortion above the noise at" in bla.summary() and "oe-friction" in bla.summary()
    # stochastic distortion also shows at the excited lines as realisation-to-realisation spread
    assert np.median(bla.distortion_variance / bla.noise_variance) > 10


def test_one_realisation_gives_the_bla_with_its_noise_only():
    bla = best_linear_approximation(_runs(Motor(A, B), realisations=1))
    assert bla.realisations == 1 and np.all(np.isnan(bla.distortion_variance))
    assert bla.is_linear()
    assert set(bla.to_dict()) >= {"bla", "detection_omega", "distortion_db", "summary"}


def test_realisations_must_share_their_lines():
    runs = _runs(Motor(A, B), realisations=1)
    other = SimRig(Motor(A, B)).run(Experiment(OddMultisine(512, 63, 20), sample_period=DT, duration=512 * DT * 4))
    with pytest.raises(NotIdentifiableError, match="share the period and the lines"):
        best_linear_approximation([*runs, other])
    prbs = SimRig(Motor(A, B)).run(Experiment(PRBS(200, -200, 8), sample_period=DT, duration=5.0))
    with pytest.raises(NotIdentifiableError, match="needs odd-multisine runs"):
        best_linear_approximation(prbs)
