"""The firmware's controllers under simavr (``avr-sim://``): duty for duty the Python reference step.

The firmware computes each duty in its sample interrupt from the counts it has just read,
in integer arithmetic (``motorid_bench.ino``, ``control_step``).  Here the Python reference,
:class:`motorsim.fixed_point.ControlLoop`, is run afterwards on the counts the firmware recorded:
every duty must be the same, and the loop must track as the model predicts.
"""
from __future__ import annotations

from urllib.parse import urlencode

import numpy as np
import pytest

from hardware import protocol as P
from hardware.serial_rig import SerialRig
from hardware.sim.launcher import build, missing_tools, open_avr_sim
from motorsim.control import (
    ClosedLoopExperiment,
    Feedforward,
    LQRPosition,
    LQRSpeed,
    LQRSpeedIntegral,
    OneStepMPC,
    PISpeed,
    PlantModel,
    PositionPD,
    parse_reference,
    tracking_error,
)

pytestmark = pytest.mark.firmware

#: designed for the device's one-sample delay (it applies each duty at the next tick)
MODEL = PlantModel(25.0, 3.0, 0.005, 16667, input_delay=P.DEVICE_INPUT_DELAY)
CASES = [(OneStepMPC(MODEL), "sine:10,10"), (PISpeed(MODEL), "sine:10,10"),
         (PISpeed(MODEL, 0.05, feedforward=True), "trapezoid:15,0.3,0.5,0.1"),
         (PositionPD(MODEL), "step:1,0.1"), (Feedforward(MODEL), "multisine:10,5;30,3"),
         (LQRSpeed(MODEL), "sine:10,10"), (LQRPosition(MODEL), "trapezoid:3,0.3,0.5,0.1"),
         (LQRSpeedIntegral(MODEL), "sine:10,10"),
         (LQRSpeedIntegral(MODEL), "step:5,0.7,40")]   # 40 rad/s needs 333 duty: the sum stops at the limit
IDS = ["mpc", "pi", "pi-ff", "position", "feedforward", "lqr", "lqr-position", "lqr-integral", "lqr-integral-limit"]


@pytest.fixture(scope="module")
def runs():
    """Each controller for 1.5 s on the emulated firmware (one harness, in lock-step, as fast as it goes)."""
    missing = missing_tools()
    if missing:
        pytest.skip(f"the AVR toolchain is missing: {', '.join(missing)} (make firmware-deps installs it)")
    build()
    url = "avr-sim://?" + urlencode({"a": 25.0, "b": 3.0, "counts_per_rev": 16667, "speed": 0})
    out = []
    with open_avr_sim(url, 250000, 0.02) as port, SerialRig(port, 250000, counts_per_rev=16667,
                                                            watchdog_ms=200) as rig:
        assert rig.device.version == P.PROTOCOL_VERSION == 6
        for controller, spec in CASES:
            exp = ClosedLoopExperiment(controller, parse_reference(spec), 1.5)
            out.append((controller, spec, exp, rig.run(exp)))
    return out


@pytest.mark.parametrize("case", range(len(CASES)), ids=IDS)
def test_firmware_duty_equals_the_python_reference_step(runs, case):
    controller, _, exp, rec = runs[case]
    assert not rec.has_gaps and len(rec) == exp.n_samples
    loop = controller.start(exp.reference_samples(), exp.duty_limit)
    reference = [loop.step(k, int(c)) for k, c in enumerate(rec.counts)]
    np.testing.assert_array_equal(rec.duty, reference)
    assert rec.metadata["device_tick_overruns"] == "0"
    assert len(set(rec.duty.tolist())) > 20   # the controller really moved the duty


@pytest.mark.parametrize("case", [0, 1, 5, 6, 7], ids=["mpc", "pi", "lqr", "lqr-position", "lqr-integral"])
def test_firmware_loop_tracks_within_10_percent_of_the_prediction(runs, case):
    controller, spec, exp, rec = runs[case]
    predicted = controller.predict(parse_reference(spec), exp.duration).tracking_rms
    measured = float(np.sqrt(np.mean(tracking_error(rec) ** 2)))
    # the device applies each duty exactly one tick later, as the design assumes; what is left
    # is the encoder's quantisation
    assert measured == pytest.approx(predicted, rel=0.10)


@pytest.mark.parametrize("case", range(len(CASES)), ids=IDS)
def test_oe_identifies_the_on_board_closed_loop_recordings(runs, case):
    from identify import fit
    _, _, _, rec = runs[case]
    est = fit(rec, method="oe", input_delay=int(rec.metadata["input_delay_samples"]))
    # The device applies each duty exactly at the tick after the one that computed it (an exact
    # ZOH with one sample of delay), so the fit's model is the device's.  Measured: see
    # hardware/firmware/README.md ("Identification of closed-loop runs"); 0.1 % is the goal.
    assert est.a == pytest.approx(25.0, rel=1e-3) and est.b == pytest.approx(3.0, rel=1e-3)
