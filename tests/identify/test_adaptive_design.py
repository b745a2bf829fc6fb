"""The fixed experiments of the loop's family designed for a known motor, and the loop's PRBS blocks."""
from __future__ import annotations

import math

import numpy as np
import pytest

from identify.adaptive import (
    SIMULTANEOUS,
    _blocks,
    _profiled,
    _two_tone,
    _variances,
    design_fixed,
    fixed_design_time,
    information,
)
from motorsim import PRBS, Sine
from motorsim.checks import ParameterError

DT = 0.005
NOISE = 1e-2 ** 2 + (2 * math.pi / 1000) ** 2 / 12       # 10 mrad of angle noise and 1000 counts' rounding


def _worst(a, b, ex, seconds, **kw):
    """The larger relative Cramér-Rao variance of a and b, the lag free."""
    n = int(round(seconds / DT))
    var = _variances(_profiled(information(a, b, ex.duty(n, DT, 253), DT, lag=True, **kw)))
    return float(np.max(var / np.square([a, b])))


@pytest.mark.parametrize("a, b", [(20.4, 2.2), (117.0, 16.0), (2.9, 0.3)])
def test_the_fixed_design_is_the_best_of_the_family_by_the_bound_it_reports(a, b):
    d = design_fixed(a, b, DT, 2.0, duty_limit=253, angle_noise=1e-2, counts_per_rev=1000)
    # its reach is the bound's, widened for both at once (1.96 the normal quantile)
    var = _variances(_profiled(information(a, b, d.excitation.duty(400, DT, 253), DT, lag=True)))
    for k, v, x in zip(("a", "b"), var, (a, b)):
        assert d.reach[k] == pytest.approx(100 * 1.959964 * SIMULTANEOUS * math.sqrt(NOISE * v) / x, rel=1e-5)
    # no member of the family on a coarser grid does better (the grid's own points are among the candidates)
    mine = _worst(a, b, d.excitation, 2.0)
    grid = np.geomspace(2 * 2 * math.pi / 2.0, 0.8 * math.pi / DT, 9)
    for f in grid:
        assert mine <= _worst(a, b, _two_tone(float(f"{f:.4g}"), 251, 0.8 * math.pi / DT, 3, 1 / 3), 2.0) * (1 + 1e-9)
    # the loop's blocks are two lines, and a PRBS alone is not of the family (one duty magnitude does not tell
    # the gain from a dead zone); with sines, a single line is a candidate too
    assert len(d.excitation.frequencies) == 2 and not isinstance(d.excitation, PRBS)
    with_sines = design_fixed(a, b, DT, 2.0, duty_limit=253, angle_noise=1e-2, counts_per_rev=1000, sines=True)
    best = _worst(a, b, with_sines.excitation, 2.0)
    assert best <= mine * (1 + 1e-9)
    for f in grid:
        assert best <= _worst(a, b, Sine(float(f"{f:.4g}"), 251), 2.0) * (1 + 1e-9)


def test_the_fixed_design_time_is_the_shortest_predicted_to_reach_the_target():
    d = fixed_design_time(20.4, 2.2, DT, 1.0, 60.0, duty_limit=253, angle_noise=1e-2, counts_per_rev=1000)
    assert max(d.reach.values()) <= 1.0
    # 5 % shorter (the bisection stops within 3 %), redesigned for that length: short of the target
    shorter = design_fixed(20.4, 2.2, DT, d.duration / 1.05, duty_limit=253, angle_noise=1e-2, counts_per_rev=1000)
    assert max(shorter.reach.values()) > 1.0


def test_a_bad_fixed_design_is_refused_naming_the_parameter():
    with pytest.raises(ParameterError, match="b must be nonzero"):
        design_fixed(20.0, 0.0, DT, 1.0)
    with pytest.raises(ParameterError, match="duration"):
        design_fixed(20.0, 2.0, DT, -1.0)


def test_a_prbs_pins_a_and_b_with_the_lag_free_sooner_than_two_lines():
    # a = 117 1/s: the best two lines at half the duty each against the PRBS of the full duty, 8 s
    a, b = 117.0, 16.0
    lines = min(_worst(a, b, ex, 8.0) for ex, _, _ in _blocks(a, b, 2.0, DT, 255, None, None, 0.25, 60.0, None,
                                                             prbs=False))
    prbs = min(_worst(a, b, ex, 8.0) for ex, _, _ in _blocks(a, b, 2.0, DT, 255, None, None, 0.25, 60.0, None)
               if isinstance(ex, PRBS))
    assert lines / prbs > 3          # measured 4.6: the time to a reach scales with the variance


def test_the_prbs_blocks_keep_the_budgets_and_wait_for_a_run_of_more_than_one_magnitude():
    def prbs(**kw):
        args = dict(max_speed=None, max_travel=None, breakaway=None)
        args.update(kw)
        return [ex for ex, _, _ in _blocks(20.0, 2.0, 2.0, DT, 255, args["max_speed"], args["max_travel"], 0.25,
                                           60.0, args["breakaway"], prbs=kw.get("prbs", True))
                if isinstance(ex, PRBS)]
    assert prbs() and all(ex.high == 253 and ex.low == -253 for ex in prbs())
    # the steady speed b L / a within a speed budget of 50 rad/s: L = 500 / 2 = 500 -> the duty limit; 20 rad/s: 200
    assert {ex.high for ex in prbs(max_speed=20.0)} == {200}
    assert prbs(max_travel=3.0) == [] and prbs(prbs=False) == []
    assert prbs(breakaway=253.0) == []


@pytest.mark.slow
def test_after_a_run_of_two_lines_the_loop_runs_a_prbs_and_its_intervals_hold_the_motor():
    import warnings

    from identify.adaptive import run_until
    from motorsim import Encoder, Motor, SimRig
    rig = SimRig(Motor(117.0, 27.0), Encoder(1000, angle_noise=1e-2), rng=np.random.default_rng(3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_until(rig, 0.5, max_time=60.0)
    kinds = [r.excitation.split(":")[0] for r in result.rounds if r.phase == "design"]
    # measured: two lines (3 s), then a PRBS held 3 samples (4.7 s), 8.7 s in all
    assert kinds[0] == "multisine" and "prbs" in kinds[1:]
    assert result.reached
    ci = result.estimate.confidence_interval(0.95)
    assert ci["a"][0] <= 117.0 <= ci["a"][1] and ci["b"][0] <= 27.0 <= ci["b"][1]
