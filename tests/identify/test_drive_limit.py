"""A driver that clips the duty it is sent: the ``drive-limit`` structure, ``oe-drive-limit``, and why the default does
not apply it."""
import numpy as np
import pytest

import identify
from identify import fit
from identify.default.evidence import DRIVE_LIMIT, RULES
from motorid.bench.misfits import clipped_duty
from motorsim import Recording
from motorsim.checks import ParameterError

SHAPE = identify.structure("drive-limit")
TRUTH = {"a": 25.0, "b": 3.0, "drive_limit": 150.0, "bias": -2.0}
DT = 0.005
#: Noise-free: the same model computed two ways, and a fit of exact data, agree to 1e-9 relative (observed ~1e-12).
RTOL = 1e-9


def _duty(n, phase=0.3):
    t = np.arange(n) * DT
    return np.round(170 * np.sin(10 * t + phase) + 30 * np.sin(53 * t)).astype(np.int64)


def test_its_simulation_is_python_controls_motor_on_the_clipped_duty():
    import control
    n, delay = 1200, 2
    t = np.arange(n) * DT
    duty = _duty(n)
    ours = SHAPE.response(TRUTH, duty, t, input_delay=delay, initial_speed=-1.0)
    sys = control.ss([[0, 1], [0, -TRUTH["a"]]], [[0, 0], [TRUTH["b"], TRUTH["bias"]]], np.eye(2), np.zeros((2, 2)))
    late = np.concatenate([np.zeros(delay), duty[:-delay]]).astype(float)
    u = np.vstack([np.clip(late, -150, 150), np.ones(n)])
    ref = control.forced_response(control.sample_system(sys, DT, "zoh"), t, u, X0=[0.0, -1.0])
    np.testing.assert_allclose(ours.angle, ref.outputs[0], rtol=0, atol=RTOL * np.max(np.abs(ref.outputs[0])))
    np.testing.assert_allclose(ours.speed, ref.outputs[1], rtol=0, atol=RTOL * np.max(np.abs(ref.outputs[1])))


@pytest.mark.parametrize("delay", [0, 2])
def test_oe_drive_limit_recovers_the_limit_from_exact_data(delay):
    n = 3000
    t = np.arange(n) * DT
    duty = _duty(n)
    angle = SHAPE.response(TRUTH, duty, t, input_delay=delay, initial_speed=3.0).angle + 1.0
    est = fit(Recording(time=t, duty=duty, sample_period=DT, angle=angle), "oe-drive-limit", input_delay=delay)
    assert est.structure == "drive-limit" and est.input_delay == delay
    for name, value in TRUTH.items():
        assert est.value(name) == pytest.approx(value, rel=RTOL)
    with pytest.raises(ParameterError, match="no drive limit.*--input-limit 150"):
        est.motor()


def test_the_default_leaves_the_clipped_driver_unclear_and_the_rule_would_make_it_clear():
    # the drive limit is not among the default's rules: the clipped duty stays an honest "not clear"
    assert DRIVE_LIMIT not in RULES
    est = fit(clipped_duty(0))
    assert not est.selection.clear and est.structure != "drive-limit"
    # the rule itself, given the same answer, finds the limit (right to well within 1e-3 here: 4096 counts)
    from identify.data import as_recordings
    from identify.default.evidence import on_evidence
    from identify.default.selection import _check_parts
    recs = as_recordings([clipped_duty(0)])
    start = fit(recs, "oe", input_delay=0)
    from identify.comparison import Candidate, Selection
    chosen = Candidate("linear", 0, start.a, start.b, 1.0, 0.0, True)
    selection = Selection((chosen,), chosen, chosen, None)
    after = _check_parts(recs, start, selection, open_loop=True)
    assert not after[1].clear
    new, chosen_selection, _ = on_evidence(recs, (start, selection), after, _check_parts, rules=(DRIVE_LIMIT,))
    assert new.structure == "drive-limit" and chosen_selection.clear
    assert new.a == pytest.approx(25.0, rel=1e-3) and new.b == pytest.approx(3.0, rel=1e-3)
    assert new.extra["drive_limit"] == pytest.approx(150.0, rel=1e-3)
