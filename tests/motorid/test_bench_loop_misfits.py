"""``motorid bench coverage``'s plants past the structures inside a loop (``motorid.bench.loop_misfits``)."""
import math

import numpy as np
import pytest

from identify.default.feedback import feedback_evidence
from motorid.bench import loop_misfits
from motorid.bench.coverage import CLASSES, TRUTH
from motorsim.plant import first_order_coefficients


@pytest.mark.slow          # 2.5 s: a 15 000-sample loop integrated by RK4 in Python
def test_the_loop_integrates_the_motor_exactly(monkeypatch):
    # without the random torque, a linear motor under the loop: the counts are the exact ZOH motor's for the duty the
    # loop logged (the closed form), to the encoder's noise of 1e-4 rad (0.03 of a count): at most one count apart,
    # where the angle sits within the noise of a count's edge
    monkeypatch.setattr(loop_misfits, "TORQUE", 0.0)
    a, b = loop_misfits.A, loop_misfits.B
    rec = loop_misfits._loop(lambda t, th, w, u: -a * w + b * u, 0, "position")
    e, p, q = first_order_coefficients(a, loop_misfits.H)
    theta, w = np.zeros(len(rec)), 0.0
    for k in range(len(rec) - 1):
        theta[k + 1] = theta[k] + p * w + q * b * rec.duty[k]
        w = e * w + p * b * rec.duty[k]
    exact = np.floor(theta * loop_misfits.COUNTS / (2 * math.pi)).astype(np.int64)
    apart = np.abs(rec.counts - exact)
    assert apart.max() <= 1 and np.mean(apart == 0) > 0.95
    assert np.ptp(rec.counts) > 1000 and np.max(np.abs(rec.duty)) == 255     # it moves, and the loop saturates


@pytest.mark.slow          # 2.3 s each: two 15 000-sample loops integrated by RK4 in Python
@pytest.mark.parametrize("name", sorted(loop_misfits.LOOP_MISFITS))
def test_each_loop_class_is_found_to_be_a_loop_and_follows_its_seed(name):
    rec = CLASSES[f"past: {name}"](0)
    assert len(rec) == loop_misfits.SAMPLES and rec.sample_period == loop_misfits.H
    assert feedback_evidence(rec)          # the duty answers the output: found in the data, as in a user's file
    np.testing.assert_array_equal(rec.duty, CLASSES[f"past: {name}"](0).duty)


def test_the_loop_classes_truth_spans_the_plants_values():
    (a, b) = TRUTH["past: forward gain 15 % above reverse, position loop"]
    assert a == (25.0, 25.0) and b == pytest.approx((3.0, 3.45), rel=1e-12)          # 1.15 x 3 in floats
    (a, b) = TRUTH["past: gain sagging with the duty, speed loop"]
    assert a == (25.0, 25.0) and b == pytest.approx((2.25, 3.0), rel=1e-12)
    assert "past: Stribeck friction, position loop" not in TRUTH      # a = 25, b = 3


@pytest.mark.slow          # 10 s: two 15 000-sample loops integrated by RK4 in Python, and the default on each
def test_a_warming_motor_and_an_asymmetric_gain_are_never_clear_with_an_interval_that_misses_them():
    # both were "a clear choice" missing the plant's range: warming (a 25 -> 23, b 3 -> 2.76), seed 8, a [23.49,
    # 26.07] b [2.892, 3.193]: its end part gave a 21.3, b 2.56 (early / late, p = 0.16, within the checks' level);
    # a forward gain 15 % above the reverse one, seed 16, a 22.2 [21.3, 24.2]: five checks had a part outside it
    import warnings

    from identify import fit
    for name, seed in (("motor warming, position loop", 8), ("forward gain 15 % above reverse, position loop", 16)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = fit(CLASSES[f"past: {name}"](seed))
        (a_lo, a_hi), (b_lo, b_hi) = TRUTH[f"past: {name}"]
        ci = est.confidence_interval(0.95)
        covered = ci["a"][0] <= a_lo and a_hi <= ci["a"][1] and ci["b"][0] <= b_lo and b_hi <= ci["b"][1]
        assert covered or not est.selection.clear, (name, ci)
        assert any("outside its interval" in note for note in est.notes)
