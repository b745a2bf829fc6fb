"""The accuracy benchmark's data generators are accurate, and a small run meets the criteria."""
import numpy as np
import pytest

from motorid.bench.accuracy import bench_accuracy, rk4_angle, rk4_friction_angle
from motorsim.plant import Motor, simulate


@pytest.mark.parametrize("a, dt, jitter", [(4.0, 0.001, 0.0), (90.0, 0.02, 0.1)], ids=["slow", "fast-jittered"])
def test_rk4_generator_agrees_with_the_exact_solution(a, dt, jitter):
    rng = np.random.default_rng(0)
    n = 800
    t = np.arange(n) * dt + rng.uniform(-0.5, 0.5, n) * jitter * dt
    duty = np.round(200 * np.sin(0.7 * a * t))
    exact = simulate(Motor(a, 0.12 * a), duty, t).angle
    # RK4 with a delta <= 0.02: global error ~1e-10 of the angle's scale
    np.testing.assert_allclose(rk4_angle(a, 0.12 * a, duty, t), exact, atol=1e-8 * np.max(np.abs(exact)))


def test_friction_generator_agrees_with_the_event_based_solution():
    dt, n = 0.005, 400
    t = np.arange(n) * dt
    duty = np.round(200 * np.sin(25 * t))
    exact = simulate(Motor(25.0, 3.0, friction=75.0, dead_zone=10.0), duty, t).angle
    ours = rk4_friction_angle(25.0, 3.0, 75.0, 0.0, duty, t, dead_zone=10.0)
    # zero crossings located by linear interpolation inside h/64 sub-steps: ~1e-6 rad
    np.testing.assert_allclose(ours, exact, atol=2e-5)


def test_a_small_benchmark_run_meets_the_criteria(capsys):
    rc = bench_accuracy(["--only", "sines", "--sample-periods", "0.005", "--counts", "4096", "--poles", "25",
                         "--ratios", "1", "--samples", "3000"])
    out = capsys.readouterr().out
    assert rc == 0 and "all criteria hold" in out and "worst |oe error|" in out


@pytest.mark.parametrize("label, method", [("white angle noise", "oe"), ("timing jitter 10 %", "oe"),
                                           ("44 counts/rev", "oe"), ("44 counts/rev", "iv"),
                                           ("timing jitter 10 %", "iv")])
def test_intervals_cover_the_truth_in_a_reduced_fixed_seed_run(label, method):
    # 60 runs of 1000 samples: if the 95 % intervals covered 95 % of the time, fewer than 51 covering
    # runs (85 %) has binomial probability below 1e-3; jitter is the regime that needs Newey-West, 44
    # counts/rev the one that needs the encoder bootstrap (Gauss-Newton / Newey-West covered 36-46 % there)
    from motorid.bench.accuracy import COVERAGE_REGIMES, coverage_run
    from motorsim.excitation import Multisine
    regime = next(r for r in COVERAGE_REGIMES if r[:2] == (label, method))
    duty = Multisine((7.5, 25.0, 50.0), (90, 90, 90), (0.0, 0.7, 1.4)).duty(1000, 0.005).astype(float)
    rows = [coverage_run(regime, duty, 0.005, np.random.default_rng(child))
            for child in np.random.SeedSequence(11).spawn(60)]
    rows = [r for r in rows if r is not None]
    assert len(rows) == 60
    assert sum(r[0] for r in rows) >= 51 and sum(r[1] for r in rows) >= 51
    expected = {("timing jitter 10 %", "oe"): "newey-west", ("44 counts/rev", "oe"): "encoder-bootstrap"}.get(
        (label, method))
    if expected:
        assert sum(r[2] == expected for r in rows) > 30


def test_closed_loop_section_holds_oe_and_reports_iv_reference_on_every_loop(capsys):
    rc = bench_accuracy(["--only", "closedloop"])
    out = capsys.readouterr().out
    rows = [line.partition(" iv-reference ") for line in out.splitlines() if " iv-reference " in line]
    # oe within 0.1 % on every run is the section's criterion; the five loops each get an iv-reference row
    assert rc == 0 and "all criteria hold" in out
    assert [r[0].strip() for r in rows] == ["P position, floored", "PI speed, differenced",
                                               "one-step MPC, SimRig", "PI speed, SimRig", "PD position, SimRig"]
    assert all(np.isfinite(float(r[2].split()[0])) for r in rows)


@pytest.mark.parametrize("rng, kind", [(None, "a numpy.random.Generator"), (42, "a numpy.random.Generator")],
                         ids=["missing", "an int"])
def test_make_recording_without_a_generator_raises_our_type_error_naming_rng(rng, kind):
    from motorid.bench.accuracy import make_recording
    from motorsim.checks import ParameterTypeError
    t = np.arange(50) * 0.01
    with pytest.raises(ParameterTypeError, match=f"rng must be {kind} when angle_noise or drop_rate is set, got"):
        make_recording(np.sin(t), np.zeros(50), t, 0.01, 400, rng=rng, angle_noise=1e-3)
