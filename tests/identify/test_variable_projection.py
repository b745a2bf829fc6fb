"""The separable (variable projection in ``a``) output-error fit equals the general Levenberg–Marquardt one."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from identify.checks.uncertainty import covariance_from_jacobian
from identify.data import as_recordings, prepare_segments
from identify.fits.output_error import OutputErrorProblem, select_delay
from identify.fits.start import initial_guess
from identify.fits.variable_projection import (
    is_separable,
    separable_residual_sum,
    solve_separable,
    static_gain_ceiling,
)
from motorsim.excitation import Sine
from motorsim.plant import Motor
from motorsim.rig import Experiment, SimRig
from motorsim.sensors import Encoder

# Both minimise the same residual; LM stops at xtol = 1e-12 and the separable iteration
# after a relative step of 1e-8 (quadratic convergence: error ~1e-16), so a and b agree to
# 1e-9 relative; the covariance is the same J^T J formed differently (1e-7 relative).
SAME = 1e-9


def _recordings(kind):
    if kind == "one":
        rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(3))
        return [rig.run(Experiment(Sine(10.0, 200), 0.005, 5.0))]
    if kind == "dropped":  # one recording cut into segments at the lost samples
        rig = SimRig(Motor(25.0, 3.0), drop_rate=0.002, rng=np.random.default_rng(4))
        return [rig.run(Experiment(Sine(10.0, 200), 0.005, 10.0))]
    # pooled recordings of different lengths and drives
    rig = SimRig(Motor(4.0, 0.5), Encoder(angle_noise=1e-4), rng=np.random.default_rng(5))
    return [rig.run(Experiment(Sine(2.0, 150), 0.001, 3.0)), rig.run(Experiment(Sine(7.0, 90), 0.001, 4.0))]


def _levenberg_marquardt(segments, x0):
    problem = OutputErrorProblem(segments, False)
    res = least_squares(problem.residuals, x0, jac=problem.jacobian, method="lm", x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return problem, res


@pytest.mark.parametrize("kind", ["one", "dropped", "pooled"])
def test_separable_fit_equals_levenberg_marquardt(kind):
    recs = as_recordings(_recordings(kind))
    segments = prepare_segments(recs, 0)
    assert is_separable(segments, with_bias=False)
    assert (len(segments) > 1) == (kind != "one")
    a0, b0 = initial_guess(recs, segments)
    sol = solve_separable(segments, a0)
    problem, res = _levenberg_marquardt(segments, np.array([a0, b0]))
    assert sol.a == pytest.approx(res.x[0], rel=SAME)
    assert sol.b == pytest.approx(res.x[1], rel=SAME)
    # residuals: the model angle agrees to SAME of the largest angle (its a and b do)
    scale = max(np.max(np.abs(s.output)) for s in segments)
    np.testing.assert_allclose(sol.residuals, res.fun, rtol=0, atol=SAME * scale)
    np.testing.assert_allclose(sol.initial_speeds, problem.initial_speeds(res.x), rtol=1e-7, atol=1e-9)
    cov = covariance_from_jacobian(problem.jacobian(res.x), 1.0, 2)
    np.testing.assert_allclose(sol.covariance(1.0), cov, rtol=1e-7)


def test_bias_speed_and_jittered_data_are_not_separable():
    rig = SimRig(Motor(25.0, 3.0), jitter=0.1, rng=np.random.default_rng(6))
    jittered = prepare_segments(as_recordings(rig.run(Experiment(Sine(10.0, 200), 0.005, 2.0))), 0)
    uniform = prepare_segments(as_recordings(SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 2.0))), 0)
    assert not is_separable(jittered, with_bias=False)
    assert not is_separable(uniform, with_bias=True)
    assert is_separable(uniform, with_bias=False)


def _wrong_delay_segments():
    """A short sine run fitted with 8 samples of delay too many: the rows prefer no lag at all."""
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 2.0))
    return [rec], prepare_segments([rec], 8, skip=10)


def test_a_fit_running_off_to_a_static_gain_stops_at_the_ceiling_with_the_limits_residual():
    recs, segments = _wrong_delay_segments()
    start = initial_guess(recs, segments)[0]
    assert solve_separable(segments, start) is None           # unbounded a: no minimum to return
    ceiling = static_gain_ceiling(segments)
    stopped = solve_separable(segments, start, ceiling=ceiling)
    assert stopped is not None and stopped.a == ceiling
    # the general fit follows a far up too (to ~1e12 1/s, where the lag left is ~1e-10 of the
    # gain's); its residual sum agrees with the limit's to that order
    problem, res = _levenberg_marquardt(segments, [start, 3.0])
    assert res.x[0] * 0.005 > 1e6
    rss_limit = float(stopped.residuals @ stopped.residuals)
    assert rss_limit <= float(res.fun @ res.fun) * (1 + 1e-6)
    assert rss_limit == pytest.approx(float(res.fun @ res.fun), rel=1e-6)


def test_delay_selection_needs_no_general_fit_for_candidates_that_run_off(monkeypatch):
    import scipy.optimize

    def refuse(*args, **kwargs):
        raise AssertionError("a candidate delay fell back to least_squares")
    monkeypatch.setattr(scipy.optimize, "least_squares", refuse)
    rig = SimRig(Motor(25.0, 3.0, input_delay=2), Encoder(4096), rng=np.random.default_rng(8))
    assert select_delay(rig.run(Experiment(Sine(10.0, 200), 0.005, 2.0))) == 2


@pytest.mark.parametrize("kind", ["one", "dropped"])
def test_residual_sum_with_a_bias_equals_levenberg_marquardt_on_the_bias_model(kind):
    # a bias drifts the angle by (bias/a) (tau - W): one more shared linear column, the ramp
    rig = SimRig(Motor(25.0, 3.0, bias=8.0), Encoder(4096), drop_rate=0.002 if kind == "dropped" else 0.0,
                 rng=np.random.default_rng(9))
    recs = [rig.run(Experiment(Sine(10.0, 200), 0.005, 10.0))]
    segments = prepare_segments(as_recordings(recs), 0)
    assert len(segments) > 1 if kind == "dropped" else len(segments) == 1
    start = initial_guess(recs, segments)[0]
    problem = OutputErrorProblem(segments, True)
    res = least_squares(problem.residuals, [start, 3.0, 0.0], jac=problem.jacobian, method="lm", x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12)
    with_bias = separable_residual_sum(segments, start, with_bias=True)
    without = separable_residual_sum(segments, start)
    # both minimise the same residual (LM to xtol 1e-12): the sums agree to 1e-9 relative
    assert with_bias == pytest.approx(float(res.fun @ res.fun), rel=1e-9)
    assert without > 10 * with_bias                       # the ramp matters on this run
    assert res.x[2] == pytest.approx(8.0, rel=0.01)


def test_friction_fit_finds_the_delay_of_a_plant_with_friction_and_a_bias():
    # ranking delays with the linear model without a bias chose 0 here (a off by -26 %)
    from identify import fit
    from motorsim.excitation import Multisine
    rig = SimRig(Motor(25.0, 3.0, friction=60.0, bias=5.0, input_delay=2), Encoder(4096),
                 rng=np.random.default_rng(2))
    rec = rig.run(Experiment(Multisine((7.5, 25.0, 50.0), (90, 90, 90), (0.0, 0.7, 1.4)), 0.005, 10.0))
    est = fit(rec, method="oe-friction", input_delay="auto")
    assert est.input_delay == 2
    assert est.a == pytest.approx(25.0, rel=1e-3) and est.b == pytest.approx(3.0, rel=1e-3)
    assert est.extra["bias"] == pytest.approx(5.0, rel=0.02)


@pytest.mark.parametrize("with_bias", [False, True])
def test_shared_work_resumes_the_coarse_steps_and_changes_no_number(monkeypatch, with_bias):
    """Within ``shared_work`` a coarse candidate and the full fit of the same candidate (what the default's refine
    makes) give the numbers each gives alone, bit for bit, and the full fit makes no coarse step again."""
    from identify.fits import variable_projection as vp
    from identify.fits.output_error import linear_candidate
    from motorsim.excitation import Multisine
    rec = SimRig(Motor(25.0, 3.0), Encoder(16667, angle_noise=1e-4), rng=np.random.default_rng(3)).run(
        Experiment(Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3)), 0.005, 30.0))
    segs = prepare_segments([rec], 1, skip=2)
    alone = [linear_candidate([rec], segs, 1, with_bias, refine=refine) for refine in (False, True)]
    coarse_rows = []
    evaluate = vp._evaluate
    monkeypatch.setattr(vp, "_evaluate", lambda s, a, direction=True, **kept: coarse_rows.append(s[0].n) or evaluate(
        s, a, direction, **kept))
    with vp.shared_work():
        first = linear_candidate([rec], segs, 1, with_bias, refine=False)
        made = len(coarse_rows)
        full = linear_candidate([rec], segs, 1, with_bias, refine=True)
    assert not first.refined and full.refined
    for got, want in zip((first, full), alone):
        assert got.candidate.a == want.candidate.a and got.candidate.b == want.candidate.b
        assert got.bias == want.bias and np.array_equal(got.residuals, want.residuals)
    # the coarse steps run on the first rows (1000 of the run's 5999): the full fit's evaluations are all on every row
    assert 0 < sum(n < 2000 for n in coarse_rows[:made]) and not any(n < 2000 for n in coarse_rows[made:])
    assert vp._SHARED is None                       # forgotten on exit


def test_shared_work_reuses_the_columns_made_on_the_same_rows_and_changes_no_number(monkeypatch):
    """Within ``shared_work`` the ``linear`` and ``bias`` candidates of a delay take their first step's columns from
    one another (the same start on the same rows): every number as each candidate gives it alone, bit for bit, with
    fewer filter passes."""
    from identify.fits import variable_projection as vp
    from identify.fits.output_error import linear_candidate
    from motorsim.excitation import Multisine
    rec = SimRig(Motor(25.0, 3.0, bias=2.0), Encoder(16667, angle_noise=1e-4), rng=np.random.default_rng(4)).run(
        Experiment(Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3)), 0.005, 30.0))
    segs = prepare_segments([rec], 1, skip=2)
    order = [(False, False), (True, False), (False, True), (True, True)]        # (with_bias, refine)
    alone = [linear_candidate([rec], segs, 1, bias, refine=refine) for bias, refine in order]
    passes = []
    filter_pass = vp.first_order_filter
    monkeypatch.setattr(vp, "first_order_filter", lambda *a, **k: passes.append(1) or filter_pass(*a, **k))
    for bias, refine in order:
        linear_candidate([rec], segs, 1, bias, refine=refine)
    apart = len(passes)
    passes.clear()
    with vp.shared_work():
        shared = [linear_candidate([rec], segs, 1, bias, refine=refine) for bias, refine in order]
    for got, want in zip(shared, alone):
        assert got.candidate.a == want.candidate.a and got.candidate.b == want.candidate.b
        assert got.bias == want.bias and np.array_equal(got.residuals, want.residuals)
    # the coarse steps resumed save 16 passes (two full fits, four evaluations of F and G each); the bias candidate's
    # first step, its F and G taken as the linear candidate made them, 2 more
    assert len(passes) <= apart - 18
