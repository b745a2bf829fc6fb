"""Identification from closed-loop recordings: oe holds, iv is biased, iv-reference is consistent."""
import numpy as np
import pytest

from identify import NotIdentifiableError, fit, fit_reference_iv
from motorsim import Encoder, Experiment, Motor, SimRig, Sine
from motorsim.control import ClosedLoopExperiment, OneStepMPC, PISpeed, PlantModel, PositionPD, parse_reference

MODEL = PlantModel(25.0, 3.0, 0.005, 16667)
LOOPS = [(OneStepMPC(MODEL), "sine:10,10"), (OneStepMPC(MODEL, 1e-3), "multisine:10,10;31,4"),
         (PISpeed(MODEL), "multisine:10,10;31,4"), (PISpeed(MODEL, 0.03, feedforward=True), "trapezoid:15,0.5,1"),
         (PositionPD(MODEL), "sine:5,1")]
IDS = ["mpc-sine", "mpc-multisine", "pi", "pi-ff", "position"]


def _closed(controller, spec, noise=0.0, seed=0):
    rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=noise), rng=np.random.default_rng(seed))
    return rig.run(ClosedLoopExperiment(controller, parse_reference(spec), 10.0))


@pytest.mark.parametrize("noise", [0.0, 1e-3], ids=["quantised", "noisy"])
@pytest.mark.parametrize("controller, spec", LOOPS, ids=IDS)
def test_oe_identifies_closed_loop_recordings_within_0_1_percent(controller, spec, noise):
    est = fit(_closed(controller, spec, noise), method="oe")
    # measured: worst 0.011 % over these loops and seeds; 0.1 % is the stated goal
    assert est.a == pytest.approx(25.0, rel=1e-3) and est.b == pytest.approx(3.0, rel=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_iv_is_biased_in_closed_loop_and_iv_reference_is_not(seed):
    rec = _closed(OneStepMPC(MODEL, 1e-3), "multisine:10,10;31,4", 1e-3, seed)
    iv = fit(rec, method="iv")
    ivr = fit_reference_iv(rec)
    # iv's instruments come from the measured duty, correlated with the noise through the loop:
    # +14 % on a here; the reference is set beforehand.  iv-reference scatters by about 0.1 %
    # (3 seeds: +0.04, +0.08, +0.05 %), so 0.5 % is several of its standard deviations.
    assert iv.a / 25.0 - 1 > 0.05
    assert ivr.a == pytest.approx(25.0, rel=5e-3) and ivr.b == pytest.approx(3.0, rel=5e-3)
    assert ivr.method == "iv-reference"


def test_iv_reference_refuses_open_loop_and_constant_references():
    with pytest.raises(NotIdentifiableError, match="reference column"):
        fit_reference_iv(SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10), 0.005, 2.0)))
    with pytest.raises(NotIdentifiableError, match="constant"):
        fit_reference_iv(_closed(PISpeed(MODEL), "constant:10"))
