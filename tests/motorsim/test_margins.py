"""Margins of a sampled loop from its polynomials, against python-control's ``stability_margins``."""
import math

import control
import numpy as np
import pytest

from motorsim.checks import ParameterError
from motorsim.margins import discrete_margins


def _integrator_with_delay(gain, delay):
    """``gain / (z^delay (z - 1))``: the loop of an integral controller on a delayed sampled integrator."""
    return np.array([gain]), np.polymul(np.r_[1.0, np.zeros(delay)], [1.0, -1.0])


@pytest.mark.parametrize("gain", [0.05, 0.2, 0.5])
@pytest.mark.parametrize("delay", [0, 1, 3])
def test_margins_equal_python_control_on_delayed_integrators(gain, delay):
    num, den = _integrator_with_delay(gain, delay)
    m = discrete_margins(num, den, 0.01)
    gm, pm, _, _, wgc, _ = control.stability_margins(control.tf(num, den, 0.01), method="frd")
    assert m.phase_margin == pytest.approx(pm, rel=1e-6)
    assert m.crossover == pytest.approx(wgc, rel=1e-6)
    assert m.gain_margin == pytest.approx(gm, rel=1e-6) or (math.isinf(gm) and math.isinf(m.gain_margin))
    assert m.delay_margin == pytest.approx(max(0.0, math.radians(pm) / wgc), rel=1e-6)   # none when unstable
    poles = control.feedback(control.tf(num, den, 0.01), 1).poles()
    assert m.stable == bool(np.all(np.abs(poles) < 1.0))


def test_a_loop_that_gains_too_much_is_unstable_and_its_margins_say_so():
    num, den = _integrator_with_delay(1.5, 2)     # gain margin below 1: the closed loop rings up
    m = discrete_margins(num, den, 0.01)
    assert not m.stable and m.gain_margin < 1 and m.phase_margin < 0 and m.delay_margin == 0
    assert m.describe().endswith("(UNSTABLE)")


def test_a_loop_without_gain_has_infinite_margins():
    m = discrete_margins([0.0], [1.0, -0.5], 0.01)
    assert math.isinf(m.gain_margin) and math.isinf(m.phase_margin) and m.stable


@pytest.mark.parametrize("num, den, period, match", [
    ([1.0], [0.0, 0.0], 0.01, "den not all 0"),
    ([np.nan], [1.0, -1.0], 0.01, "finite"),
    ([1.0], [1.0, -1.0], 0.0, "sample_period"),
], ids=["zero-den", "nan", "period"])
def test_bad_loops_are_refused_with_the_rule(num, den, period, match):
    with pytest.raises(ParameterError, match=match):
        discrete_margins(num, den, period)
