"""Closed loop on the emulated device (protocol v2): the controller runs on the device, the host checks it."""
from __future__ import annotations

import numpy as np
import pytest

from hardware import protocol as P
from hardware.fake_device import FakeDevice, FaultPlan
from hardware.serial_rig import SerialRig
from motorsim import Encoder, Experiment, Motor, SimRig, Sine
from motorsim.control import (
    ClosedLoopExperiment,
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

#: designed for the device's one-sample delay (it applies each duty at the next tick)
MODEL = PlantModel(25.0, 3.0, 0.005, 16667, input_delay=P.DEVICE_INPUT_DELAY)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.mark.parametrize("controller, spec", [
    (OneStepMPC(MODEL), "sine:10,10"), (PISpeed(MODEL), "sine:10,10"), (PositionPD(MODEL), "step:1,0.1"),
    (LQRSpeed(MODEL), "sine:10,10"), (LQRSpeedIntegral(MODEL), "sine:10,10"),
    (LQRPosition(MODEL), "trapezoid:3,0.3,0.5,0.1"),
], ids=["mpc", "pi", "position", "lqr", "lqr-integral", "lqr-position"])
def test_fake_device_tracks_as_predicted_and_as_simrig_duty_for_duty(controller, spec):
    exp = ClosedLoopExperiment(controller, parse_reference(spec), 2.0)
    with SerialRig("fake://?a=25&b=3&speed=0") as rig:
        rec = rig.run(exp)
    # the host re-ran the integer step on every count received and found the device's duty
    assert rec.metadata["host_duty_mismatches"] == "0" and rec.metadata["host_unverified_duties"] == "0"
    # same motor, same integer step: the simulated rig gives the same duties and counts
    sim = SimRig(Motor(25.0, 3.0, input_delay=P.DEVICE_INPUT_DELAY)).run(exp)
    np.testing.assert_array_equal(rec.duty, sim.duty)
    np.testing.assert_array_equal(rec.counts - rec.counts[0], sim.counts - sim.counts[0])
    predicted = controller.predict(parse_reference(spec), 2.0).tracking_rms
    assert _rms(tracking_error(rec)) == pytest.approx(predicted, rel=0.10)
    np.testing.assert_array_equal(rec.reference, exp.reference_values())


def test_lost_samples_stop_the_host_check_but_not_the_run():
    exp = ClosedLoopExperiment(OneStepMPC(MODEL), parse_reference("sine:10,10"), 2.0)
    dev = FakeDevice(Motor(25.0, 3.0), Encoder(), FaultPlan(drop_rate=0.05), speed=0.0,
                     rng=np.random.default_rng(3))
    with dev, SerialRig(dev.port_name) as rig:
        rec = rig.run(exp)
    first_gap = int(np.flatnonzero(np.diff(rec.seq) != 1)[0]) + 1
    assert rec.has_gaps and int(rec.metadata["host_unverified_duties"]) == len(rec) - first_gap
    assert rec.metadata["host_duty_mismatches"] == "0"


def test_counts_per_rev_comes_from_the_device_and_a_contradiction_is_an_error():
    with SerialRig("fake://?a=25&b=3&speed=0&counts_per_rev=1200") as rig:
        assert rig.device.counts_per_rev == 1200 and rig.counts_per_rev == 1200
        rec = rig.run(Experiment(Sine(10), 0.005, 0.2))
        assert rec.counts_per_rev == 1200
        with pytest.raises(ValueError, match="designed for 16667 counts per revolution, the rig .* has 1200"):
            rig.run(ClosedLoopExperiment(OneStepMPC(MODEL), parse_reference("sine:10,10"), 1.0))
    with pytest.raises(ValueError, match="counts_per_rev 16667 was given but the device .* reports 1200"):
        SerialRig("fake://?a=25&b=3&speed=0&counts_per_rev=1200", counts_per_rev=16667).open()


def test_bad_control_and_reference_are_refused_and_config_returns_to_open_loop():
    assert "takes at least 5 gains" in P.control_problems(P.Control(P.ControllerKind.MPC, 1, (1, 2, 3)))[0]
    assert P.control_problems(P.Control(9, 0, (1,)))
    assert "takes at least 4 gains" in P.control_problems(P.Control(P.ControllerKind.LQR_POSITION, 1, (1, 2, 3)))[0]
    short = P.Control(P.ControllerKind.LQR_INTEGRAL, 1, (1, 2, 3, 4, 5))
    assert "takes at least 6 gains" in P.control_problems(short)[0]
    lqr = ClosedLoopExperiment(LQRPosition(MODEL), parse_reference("constant:1"))
    assert not P.control_problems(P.control_for(lqr))
    assert P.reference_problems(P.ReferenceWords("constant", 70000))
    assert not P.control_problems(P.control_for(ClosedLoopExperiment(OneStepMPC(MODEL), parse_reference("constant:1"))))
    with SerialRig("fake://?a=25&b=3&speed=0") as rig:
        rig.run(ClosedLoopExperiment(PISpeed(MODEL), parse_reference("constant:5"), 0.2))
        rec = rig.run(Experiment(Sine(10), 0.005, 0.2))     # CONFIG cleared the controller
        np.testing.assert_array_equal(rec.duty, Experiment(Sine(10), 0.005, 0.2).duty())
        assert rec.reference is None
