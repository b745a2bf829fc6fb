"""A speed that turns under a constant recorded input: a torque of the angle is no log that misses its input.

The constant-input screen (:func:`identify.data.check_constant_input_runs`) refuses a file whose speed rises and
falls while the logged input stays flat: a motor whose torque depends on its speed alone cannot do that, so the
log misses the input the motor received.  An arm under gravity does it under any constant input; the screen
asks :func:`identify.checks.angle_turns.angle_torque_explains` first, which learns a torque of the angle outside
the turning runs and predicts them with it.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import identify.checks.angle_turns as angle_turns
from identify import fit
from identify.data import ConstantInputTurnWarning, check_constant_input_runs, run_turns
from identify.errors import NotIdentifiableError
from motorid.bench.misfits import _integrate, _record
from motorsim import Motor, Recording
from motorsim.plant import simulate

A, B, LEVEL = 36.0, 4.9, 195


def _arm(seed: int, weight_share: float = 0.3, hold: float = 0.1) -> Recording:
    """An arm whose weight pulls with ``weight_share`` of the drive's torque, under a binary PRBS of +-LEVEL held
    ``hold`` s; 5 ms, 2048 counts, 12 s."""
    rng = np.random.default_rng(seed)
    h, n = 0.005, 2400
    levels = LEVEL * rng.choice([-1, 1], int(n * h / hold) + 2)
    duty = levels[(np.arange(n) * h / hold).astype(int)].astype(np.int64)
    weight = weight_share * B * LEVEL
    theta, _ = _integrate(lambda t, th, w, u: -A * w + B * u - weight * math.sin(th), duty, h)
    return _record(np.arange(n) * h, duty, theta, seed, 2048)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_arm_under_gravity_is_not_refused_as_a_log_that_misses_its_input(seed, monkeypatch):
    rec = _arm(seed)
    with monkeypatch.context() as m:       # without the angle's torque the screen refuses it: the test can fail
        m.setattr(angle_turns, "angle_torque_explains", lambda *args, **kwargs: False)
        with pytest.raises(NotIdentifiableError, match="stays at"):
            check_constant_input_runs(rec, "arm")
    with pytest.warns(ConstantInputTurnWarning, match="a torque of the angle .* explains it"):
        check_constant_input_runs(rec, "arm")


def test_the_default_answers_an_arm_under_gravity_honestly():
    # the default has no structure with gravity: its answer must cover the built motor or not be clear
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fit(_arm(0))
    ci = est.confidence_interval()
    covers = ci["a"][0] <= A <= ci["a"][1] and ci["b"][0] <= B <= ci["b"][1]
    assert covers or not est.selection.clear


@pytest.mark.parametrize("clip", [40, 60, 90])
def test_a_log_clipped_below_the_input_is_still_refused(clip):
    # outside the clipped runs the logged input is the applied one and no torque of the angle is found
    t = np.arange(800) * 0.005
    applied = 200 * np.sin(10.0 * t)
    speed = simulate(Motor(25.0, 3.0), applied, t).speed
    rec = Recording(time=t, duty=np.clip(np.round(applied), -clip, clip), sample_period=0.005, speed=speed)
    with pytest.raises(NotIdentifiableError, match="stays at"):
        check_constant_input_runs(rec, "clipped")


def test_too_few_rows_outside_the_turns_explain_nothing():
    # one constant input over the whole run: nothing outside it to learn a torque from
    rec = _arm(0)
    assert angle_turns.angle_torque_explains(rec, [(3, len(rec), 1.0)], 0, run_turns) is False
