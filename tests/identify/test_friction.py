"""``oe-friction``: Coulomb friction, offset and dead zone recovered where the linear fit drifts."""
import numpy as np
import pytest

from identify import fit
from identify.fits.friction import fit_output_error_friction, speed_reverses
from motorsim.plant import Motor, simulate
from motorsim.recording import Recording

# The friction model is simulated exactly (event by event) with an analytic Jacobian; on noise-free
# angles the fit stops within ~1e-6 relative.
CLOSE = 1e-5


def _run(motor, freq=20.0, n=1200, dt=0.005, amp=200.0, offset=0.0):
    t = np.arange(n) * dt
    duty = offset + np.round(amp * np.sin(freq * t + 0.3))
    traj = simulate(motor, duty, t)
    return Recording(time=t, duty=duty, sample_period=dt, angle=traj.angle + 1.0)


def test_friction_and_offset_are_recovered_where_oe_drifts():
    motor = Motor(25.0, 3.0, friction=60.0, bias=-20.0)
    rec = _run(motor)
    est = fit_output_error_friction(rec, dead_zone=False)
    assert est.a == pytest.approx(25.0, rel=CLOSE) and est.b == pytest.approx(3.0, rel=CLOSE)
    assert est.extra["friction"] == pytest.approx(60.0, rel=CLOSE)
    assert est.extra["bias"] == pytest.approx(-20.0, rel=CLOSE)
    assert est.param_names == ("a", "b", "friction", "bias") and est.covariance.shape == (4, 4)
    linear = fit(rec, method="oe")
    assert abs(linear.a / 25.0 - 1) > 0.05  # the linear model is far off (measured ~ +20 %)


def test_dead_zone_is_recovered():
    motor = Motor(25.0, 3.0, friction=40.0, dead_zone=12.0)
    est = fit_output_error_friction(_run(motor, freq=25.0), fix_bias=True)
    assert est.a == pytest.approx(25.0, rel=CLOSE) and est.b == pytest.approx(3.0, rel=CLOSE)
    assert est.extra["dead_zone"] == pytest.approx(12.0, rel=CLOSE)
    assert est.param_names == ("a", "b", "friction", "dead_zone") and est.extra["bias"] == 0.0


def test_motor_that_never_reverses_reports_the_net_offset():
    motor = Motor(15.0, 1.5, friction=30.0, bias=10.0)
    rec = _run(motor, freq=8.0, amp=60.0, offset=150.0)
    assert not speed_reverses(rec)
    with pytest.warns(UserWarning, match="indistinguishable from the bias d"):
        est = fit_output_error_friction(rec)
    # with omega > 0 throughout, -c sign(omega) + d = d - c = -20 rad/s^2
    assert est.extra["friction"] == 0.0 and est.extra["bias"] == pytest.approx(-20.0, rel=1e-8)
    assert est.a == pytest.approx(15.0, rel=1e-8) and est.b == pytest.approx(1.5, rel=1e-8)
    assert est.method == "oe-friction" and est.param_names == ("a", "b", "bias")


def test_bad_options_name_the_parameter():
    rec = _run(Motor(25.0, 3.0))
    with pytest.raises(TypeError, match="fix_bias"):
        fit_output_error_friction(rec, fix_bias="yes")
    with pytest.raises(TypeError, match="dead_zone"):
        fit_output_error_friction(rec, dead_zone=1)


def test_intervals_cover_the_truth_while_the_shaft_sticks():
    # Coulomb friction 75 rad/s^2 against b u up to 810: the shaft sticks around each reversal and the
    # 4096-count encoder's rounding stays put there.  150 runs of 1000 samples, random encoder phase:
    # with 95 % coverage, fewer than 133 covering runs has binomial probability 5e-4 (Gauss-Newton /
    # Newey-West intervals covered 120 and 116 of these runs for a and b).
    import math

    from motorsim.excitation import Multisine
    n, dt, runs, cpr = 1000, 0.005, 150, 4096
    t = np.arange(n) * dt
    duty = Multisine((7.5, 25.0, 50.0), (90, 90, 90), (0.0, 0.7, 1.4)).duty(n, dt).astype(float)
    angle = simulate(Motor(25.0, 3.0, friction=75.0), duty, t).angle
    covered_a = covered_b = 0
    for child in np.random.SeedSequence(7).spawn(runs):
        phase = np.random.default_rng(child).uniform(0.0, 2 * math.pi / cpr)
        counts = np.floor((angle + phase) * cpr / (2 * math.pi)).astype(np.int64)
        est = fit(Recording(time=t, duty=duty, sample_period=dt, counts=counts, counts_per_rev=cpr),
                  method="oe-friction", dead_zone=False)
        assert est.covariance_method == "linearised-encoder-bootstrap"
        ci = est.confidence_interval(0.95)
        covered_a += ci["a"][0] <= 25.0 <= ci["a"][1]
        covered_b += ci["b"][0] <= 3.0 <= ci["b"][1]
    assert covered_a >= 133 and covered_b >= 133, (covered_a, covered_b)


def test_noise_beyond_the_rounding_keeps_the_residual_based_covariance():
    # angle noise 2e-3 rad against a 4096-count step of 1.5e-3 rad: the residual variance is ~20 times
    # the rounding's step^2/12, so the residuals, not the encoder, decide the covariance
    import math
    n, dt, cpr = 1000, 0.005, 4096
    t = np.arange(n) * dt
    duty = np.round(200 * np.sin(20.0 * t + 0.3))
    angle = simulate(Motor(25.0, 3.0, friction=75.0), duty, t).angle
    noisy = angle + np.random.default_rng(3).normal(0.0, 2e-3, n)
    counts = np.floor(noisy * cpr / (2 * math.pi)).astype(np.int64)
    est = fit(Recording(time=t, duty=duty, sample_period=dt, counts=counts, counts_per_rev=cpr),
              method="oe-friction", dead_zone=False)
    assert est.covariance_method in ("gauss-newton", "newey-west")



@pytest.mark.parametrize("phase", [0.0, 0.3, 0.6], ids=["phase0", "phase0.3", "phase0.6"])
def test_long_fit_is_as_good_as_iterating_on_all_rows_to_rounding(monkeypatch, phase):
    # 10 000 samples (the prefix stage runs) on a 4096-count encoder, friction and a dead zone: the
    # default fit against one that iterates on all rows from the start until the step promises less
    # than 1e-12 of the cost.  Stick/slip kinks give the cost nearby local minima a fraction of a
    # standard error apart, so the two may land on different ones (measured: up to 0.8 standard
    # errors apart, 0.63 residual variances higher in cost; at phase 0.3 the slow one lands on a poor
    # minimum, twice the residual rms).  So: never worse by more than one residual variance, and
    # within 3 standard errors of the truth.
    import math

    from identify.fits import friction, friction_solver
    from motorsim.excitation import Sine
    n, dt, cpr = 10_000, 0.005, 4096
    t = np.arange(n) * dt
    duty = Sine(10.0, 200, 0.3).duty(n, dt).astype(float)
    angle = simulate(Motor(25.0, 3.0, friction=75.0, dead_zone=10.0), duty, t).angle
    counts = np.floor(angle * cpr / (2 * math.pi) + phase).astype(np.int64)
    rec = Recording(time=t, duty=duty, sample_period=dt, counts=counts, counts_per_rev=cpr)
    assert n >= friction.PREFIX_MIN_ROWS
    fast = fit(rec, method="oe-friction")
    monkeypatch.setattr(friction, "PREFIX_MIN_ROWS", 10 * n)
    monkeypatch.setattr(friction_solver, "FINAL_STEP", 0.0)
    full = fit(rec, method="oe-friction")
    variance = full.residual_rms ** 2 * n / (n - 7)          # 5 shared parameters, initial speed, offset
    assert n * (fast.residual_rms ** 2 - full.residual_rms ** 2) <= variance
    truth = {"a": 25.0, "b": 3.0, "friction": 75.0, "bias": 0.0, "dead_zone": 10.0}
    values = {"a": fast.a, "b": fast.b, **fast.extra}
    for k, name in enumerate(fast.param_names):
        assert abs(values[name] - truth[name]) <= 3 * math.sqrt(fast.covariance[k, k]), name


def _count_runs(monkeypatch):
    """Record the rows of every Levenberg–Marquardt run oe-friction makes."""
    from identify.fits import friction
    runs = []
    original = friction.levenberg_marquardt

    def counted(problem, x0, *args, **kwargs):
        runs.append(problem.n_rows)
        return original(problem, x0, *args, **kwargs)
    monkeypatch.setattr(friction, "levenberg_marquardt", counted)
    return runs


def test_a_good_start_makes_one_run_on_all_rows(monkeypatch):
    runs = _count_runs(monkeypatch)
    est = fit_output_error_friction(_run(Motor(25.0, 3.0, friction=60.0, bias=-20.0)), dead_zone=False, input_delay=0)
    assert est.a == pytest.approx(25.0, rel=CLOSE)
    assert runs == [1200]          # the regression's start only: no restarts from the linear fit


def test_a_bad_regression_start_falls_back_to_the_linear_starts(monkeypatch):
    from identify.fits import friction
    runs = _count_runs(monkeypatch)
    # a start far from the linear fit's pole (a 50 times too large) is not trusted
    good = friction._regression_start
    monkeypatch.setattr(friction, "_regression_start", lambda problem: good(problem) * np.r_[50.0, np.ones(4)])
    est = fit_output_error_friction(_run(Motor(25.0, 3.0, friction=60.0, bias=-20.0)), dead_zone=False, input_delay=0)
    assert len(runs) == 3          # the regression's start and the linear fit's two
    assert est.a == pytest.approx(25.0, rel=CLOSE) and est.extra["friction"] == pytest.approx(60.0, rel=CLOSE)


def test_the_statistic_is_at_least_the_relative_excess_the_scan_bound_rests_on():
    from identify.comparison import statistic
    rng = np.random.default_rng(4)
    for _ in range(200):
        best = rng.normal(size=640) * rng.uniform(0.1, 10.0)
        delta = rng.normal(size=640) * rng.uniform(0.01, 1.0) + rng.uniform(-1, 1) * best
        excess = rng.uniform(0.0, 5.0) * float(best @ best)
        # batch means over blocks: V <= |delta|^2 |best|^2 (Cauchy-Schwarz), so T >= excess / |best|^2
        assert statistic(delta, excess, best) >= excess / float(best @ best) * (1 - 1e-12)


def test_a_candidate_that_cannot_come_near_the_best_stops_early_and_is_refitted_in_full():
    from identify.data import prepare_segments
    from identify.fits.friction import FrictionScan, friction_candidate
    rec = _run(Motor(25.0, 3.0, friction=60.0, bias=-20.0), n=2000)
    segs = prepare_segments([rec], 3)               # the wrong delay: far worse than delay 0
    best = friction_candidate([rec], prepare_segments([rec], 0), 0, "friction", False)
    stopped = friction_candidate([rec], segs, 3, "friction", False, scan=FrictionScan(best.candidate.residual_sum))
    full = friction_candidate([rec], segs, 3, "friction", False)
    assert not stopped.refined and full.refined
    # the stopped fit's residual sum bounds the full fit's from above, and both are far beyond the best's
    assert stopped.candidate.residual_sum >= full.candidate.residual_sum > 1000 * best.candidate.residual_sum


def test_a_long_candidate_far_from_the_best_stops_at_its_start_without_a_run(monkeypatch):
    # on data long enough for the prefix stage, the bound is tested at the start itself: a candidate that cannot
    # come near the best costs one evaluation there, no Levenberg-Marquardt run (not even the prefix's)
    from identify.data import prepare_segments
    from identify.fits import friction
    from identify.fits.friction import FrictionScan, friction_candidate
    rec = _run(Motor(25.0, 3.0, friction=60.0, bias=-20.0), n=10_000)
    assert len(rec.time) >= friction.PREFIX_MIN_ROWS
    best = friction_candidate([rec], prepare_segments([rec], 0), 0, "friction", False)
    runs = _count_runs(monkeypatch)
    stopped = friction_candidate([rec], prepare_segments([rec], 3), 3, "friction", False,
                                 scan=FrictionScan(best.candidate.residual_sum))
    assert runs == [] and not stopped.refined
    full = friction_candidate([rec], prepare_segments([rec], 3), 3, "friction", False)
    assert stopped.candidate.residual_sum >= full.candidate.residual_sum > 1000 * best.candidate.residual_sum


def test_neighbouring_delays_share_their_start():
    from identify.data import prepare_segments
    from identify.fits.friction import FrictionScan, friction_candidate
    rec = _run(Motor(25.0, 3.0, friction=60.0, bias=-20.0, input_delay=1), n=2000)
    scan = FrictionScan()
    first = friction_candidate([rec], prepare_segments([rec], 0, skip=2), 0, "dead-zone", False, scan=scan)
    next_rows = prepare_segments([rec], 1, skip=2)
    start = scan.start("friction", ("a", "b", "friction", "bias"), next_rows)
    assert first.refined and start is not None and not start[1]       # a start from other rows
    warm = friction_candidate([rec], next_rows, 1, "friction", False, scan=scan)
    cold = friction_candidate([rec], prepare_segments([rec], 1, skip=2), 1, "friction", False)
    # the same minimum from either start (noise-free: to the fit's stopping tolerance)
    assert warm.candidate.a == pytest.approx(cold.candidate.a, rel=CLOSE)
    assert warm.candidate.a == pytest.approx(25.0, rel=CLOSE)


def test_the_fit_is_the_same_without_the_compiled_kernel(monkeypatch):
    # without numba (MOTORID_NUMBA=0, or where it cannot install) the vectorised response: the same fit to rounding
    from identify.fits import friction_response as response_module
    rec = _run(Motor(25.0, 3.0, friction=40.0, dead_zone=12.0), freq=25.0)
    fast = fit_output_error_friction(rec)
    monkeypatch.setattr(response_module, "kernel_for", lambda rows: None)
    slow = fit_output_error_friction(rec)
    for name in ("a", "b", "friction", "bias", "dead_zone"):
        # the two responses agree to ~1e-13; the fit amplifies that by its conditioning, far below CLOSE
        assert slow.value(name) == pytest.approx(fast.value(name), rel=1e-7, abs=1e-9), name


def test_the_structures_at_one_delay_share_their_linear_fit(monkeypatch):
    # each scanned candidate that is fitted in full checks itself against the linear model on its rows; the
    # structures fitted at one delay (the same rows) share that fit, and it decides nothing differently from
    # a fit of its own
    from identify.data import prepare_segments
    from identify.fits import friction
    rec = _run(Motor(25.0, 3.0, friction=60.0, bias=-20.0, input_delay=1), n=2000)
    made = []
    linear_fit = friction._linear_fit
    monkeypatch.setattr(friction, "_linear_fit", lambda *args: made.append(args[2]) or linear_fit(*args))
    segs = prepare_segments([rec], 1, skip=2)
    fitted = {}
    for share in (True, False):
        scan = friction.FrictionScan()
        for structure in ("dead-zone", "friction"):
            if not share:
                scan.linear.clear()
            fitted[share, structure] = friction.friction_candidate([rec], segs, 1, structure, False, scan=scan)
    assert made == [1, 1, 1]                # once for both structures when shared, once for each when not
    for structure in ("dead-zone", "friction"):
        assert fitted[True, structure].refined
        assert fitted[True, structure].candidate == fitted[False, structure].candidate


def test_a_shaft_that_starts_at_rest_keeps_its_intervals_on_an_angle_column():
    # a sine from rest: friction holds the shaft, so the segment's initial speed, fitted at exactly 0, moves
    # no residual (its Jacobian column is zero).  That made the information matrix singular and every
    # interval infinite ("no interval for a, b, friction, bias") on a fit within 0.1 % of the truth; the idle
    # initial speed is now held where it is.  360 counts written as degrees, 1e-4 rad of noise, fixed seed.
    from motorsim import Encoder, Experiment, SimRig, Sine
    rig = SimRig(Motor(25.0, 3.0, friction=60.0), Encoder(360, angle_noise=1e-4), rng=np.random.default_rng(0))
    rec = rig.run(Experiment(Sine(10.0, 200), 0.005, 8.0))
    angle = Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, angle=rec.measured_angle())
    est = fit(angle, method="oe-friction", input_delay=0, dead_zone=False)
    se = est.stderr()
    for name, truth in (("a", 25.0), ("b", 3.0), ("friction", 60.0)):
        # finite, and the truth within 4 standard errors of a run whose answer is within 1 %
        assert np.isfinite(se[name]) and abs(est.value(name) - truth) <= 4 * se[name], name
        assert abs(est.value(name) / truth - 1) < 0.01, name
