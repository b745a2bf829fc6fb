"""Pole-placement designs (PI, position P/PD) keep their phase margin on the model with its input delay.

The poles are placed on a model without the delay; a time constant whose loop on the exact model
(differenced counts, input delay) keeps less than ``min_phase_margin`` is lengthened to the shortest
that keeps it.  python-control's ``stability_margins`` on the same loop is the independent check, and
SimRig runs the designs on a motor with the delay.
"""
import dataclasses
import math
import warnings

import control
import numpy as np
import pytest

from motorsim import Encoder, Motor, SimRig
from motorsim.checks import ParameterError
from motorsim.control import (
    MIN_PHASE_MARGIN,
    ClosedLoopExperiment,
    DesignLimitWarning,
    PISpeed,
    PlantModel,
    PositionPD,
    parse_reference,
)
from motorsim.fixed_point import SPEED_REFERENCE_LSB, quantise_gain
from motorsim.robustness import robust_design


def _model(delay):
    return PlantModel(25.0, 3.0, 0.005, 16667, input_delay=delay)


def _python_control_margins(controller):
    """``(gain margin, phase margin, stable)`` of ``L = -Cy P`` by python-control, the independent reference."""
    loop = -(controller.plant() * controller.laws()[1])
    gm, pm, *_ = control.stability_margins(loop, method="frd")
    return gm, pm, bool(np.all(np.abs(control.feedback(loop, 1).poles()) < 1.0))


def _design(cls, model, time_constant, **settings):
    """The design, and the warning it gave (None when it kept the time constant asked for)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        controller = cls(model, time_constant, **settings)
    assert all(w.category is DesignLimitWarning for w in caught) and len(caught) <= 1
    return controller, (str(caught[0].message) if caught else None)


@pytest.mark.parametrize("delay", [0, 1, 2])
@pytest.mark.parametrize("time_constant", [0.005, 0.01, 0.02, 0.05])
@pytest.mark.parametrize("cls", [PISpeed, PositionPD], ids=["pi", "position"])
def test_every_design_keeps_the_phase_margin_by_python_control_and_the_shortest_time_constant(cls, time_constant,
                                                                                              delay):
    model = _model(delay)
    controller, warning = _design(cls, model, time_constant)
    gm, pm, stable = _python_control_margins(controller)
    assert stable and pm >= MIN_PHASE_MARGIN and gm > 2.0     # and more than 6 dB of gain margin
    raw = cls(model, time_constant, min_phase_margin=0.0)
    _, raw_pm, raw_stable = _python_control_margins(raw)
    if raw_stable and raw_pm >= MIN_PHASE_MARGIN:              # kept as asked: the same gains
        assert warning is None and controller.time_constant == time_constant
        assert controller.gains() == raw.gains()
        return
    # lengthened to the shortest time constant that keeps the margin, to 3 significant digits
    assert warning is not None and controller.time_constant > time_constant
    assert f"time_constant {time_constant!r} s" in warning
    assert f"designed with time_constant {controller.time_constant!r} s" in warning
    step = 10.0 ** (math.floor(math.log10(controller.time_constant)) - 2)
    shorter = dataclasses.replace(controller, time_constant=controller.time_constant - step, min_phase_margin=0.0)
    _, shorter_pm, shorter_stable = _python_control_margins(shorter)
    assert not (shorter_stable and shorter_pm >= MIN_PHASE_MARGIN)


def test_pi_gains_are_still_the_pole_placement_of_the_time_constant_designed_with():
    pi = PISpeed(_model(0), 0.05)
    e, g, _, _ = pi.model.speed_coefficients()
    p = math.exp(-0.005 / 0.05)
    assert pi.gains() == {"kp": quantise_gain((e - p * p) / g * SPEED_REFERENCE_LSB),
                          "ki": quantise_gain((1 - p) ** 2 / g * SPEED_REFERENCE_LSB)} == {"kp": 1397, "ki": 198}


def test_a_pi_asked_for_10_ms_with_one_sample_of_delay_is_slowed_and_tracks_a_step_without_ringing():
    # Asked as it is: 6 degrees of phase margin, the step overshoots by 107 % and still rings after
    # 0.45 s; designed with the margin: 26 ms, 60 degrees, 6 %, settled.  On SimRig as predicted (a
    # 2 rad/s step keeps both duties below the limit; one count per sample is 0.075 rad/s).
    model, reference = _model(1), parse_reference("step:2,0.05")
    with pytest.warns(DesignLimitWarning, match=r"leaves a phase margin of 6\.05 deg .* designed with "
                                                r"time_constant 0\.026 s"):
        designed = PISpeed(model, 0.01)
    asked = PISpeed(model, 0.01, min_phase_margin=0.0)
    rig = SimRig(Motor(25.0, 3.0, input_delay=1), Encoder(counts_per_rev=16667))
    overshoot, settled = {}, {}
    for name, pi in (("designed", designed), ("asked", asked)):
        rec = rig.run(ClosedLoopExperiment(pi, reference, 0.5))
        speed = rec.measured_speed()[1:]
        overshoot[name] = speed.max() / 2.0 - 1.0
        settled[name] = np.abs(speed[-20:] - 2.0).max()
        predicted = pi.predict(reference, 0.5)
        assert np.abs(predicted.duty).max() < 255
        assert overshoot[name] == pytest.approx(predicted.output.max() / 2.0 - 1.0, abs=0.04)
    assert overshoot["designed"] < 0.10 and settled["designed"] < 0.1
    assert overshoot["asked"] > 0.8 and settled["asked"] > 0.2


def test_the_margin_can_be_chosen_or_turned_off_and_bad_values_are_refused():
    model = _model(1)
    with pytest.warns(DesignLimitWarning):
        loose = PISpeed(model, 0.01, min_phase_margin=45.0)
    assert loose.time_constant == pytest.approx(0.0194) and loose.margins().phase_margin >= 45.0
    assert PISpeed(model, 0.01, min_phase_margin=0.0).time_constant == 0.01
    for bad, match in ((-1.0, "min_phase_margin must be in 0...180 deg, got -1.0"), (180.0, "0...180"),
                       (True, "min_phase_margin must be a")):
        with pytest.raises(ParameterError, match=match):
            PISpeed(model, 0.05, min_phase_margin=bad)
    with pytest.raises(TypeError):
        PISpeed(model, 0.05, False, 45.0)        # keyword only: the positional order is unchanged


def test_a_margin_no_time_constant_can_keep_is_refused_by_name():
    with pytest.raises(ParameterError, match="min_phase_margin 179 deg cannot be kept by a pi design"):
        PISpeed(_model(1), 0.05, min_phase_margin=179.0)


def test_robust_design_tries_the_limit_once_and_keeps_the_margin_without_warning():
    covariance = np.array([[4.0, 0.3], [0.3, 0.09]])
    controller, r = robust_design("pi", _model(1), covariance, parse_reference("sine:10,10"), 1.0, n_draws=40,
                                  rng=np.random.default_rng(0), time_constant=0.01)
    assert controller.time_constant >= 0.026 and r.point.phase_margin >= MIN_PHASE_MARGIN and r.unstable == 0
