"""a and b from a frequency response: the truth within the covariance, on periodic and broadband data."""
import numpy as np
import pytest

from identify import fit
from identify.errors import NotIdentifiableError
from identify.frequency.frequency_estimate import FrequencyResponse, frequency_response
from identify.frequency.frequency_fit import fit_frequency_response
from motorsim import PRBS, Encoder, Experiment, Motor, OddMultisine, SimRig

A, B, DT = 25.0, 3.0, 0.005


@pytest.mark.parametrize("seed", [1, 2, 3], ids=["seed1", "seed2", "seed3"])
def test_fit_lands_within_its_intervals_and_agrees_with_oe(seed):
    rig = SimRig(Motor(A, B), Encoder(angle_noise=2e-3), rng=np.random.default_rng(seed))
    rec = rig.run(Experiment(OddMultisine(1024, 63, 20, seed=seed), sample_period=DT, duration=1024 * DT * 6))
    est = fit_frequency_response(frequency_response(rec))
    ci = est.confidence_interval(0.99)
    assert ci["a"][0] < A < ci["a"][1] and ci["b"][0] < B < ci["b"][1]
    assert 0.7 < est.residual_rms < 1.3   # the model fits within the bounds
    se = est.stderr()
    assert se["a"] < 0.01 * A
    oe = fit(rec, method="oe")
    assert abs(oe.a - est.a) < 4 * np.hypot(se["a"], oe.stderr()["a"])


def test_fit_on_a_broadband_welch_response():
    rig = SimRig(Motor(A, B), Encoder(angle_noise=1e-3), rng=np.random.default_rng(5))
    rec = rig.run(Experiment(PRBS(200, -200, 16, 1, seed=3), sample_period=DT, duration=60.0))
    est = fit_frequency_response(frequency_response(rec, segment=512))
    assert est.a == pytest.approx(A, rel=0.02) and est.b == pytest.approx(B, rel=0.02)


def test_fit_needs_two_lines():
    frf = FrequencyResponse([1.0], [0.1], [1e-6], [10.0], [1.0], DT)
    with pytest.raises(NotIdentifiableError, match="at least 2 frequencies"):
        fit_frequency_response(frf)
    with pytest.raises(TypeError, match="frf must be a FrequencyResponse"):
        fit_frequency_response([1.0])
