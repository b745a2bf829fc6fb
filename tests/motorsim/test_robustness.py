"""Margins of the designed loops against python-control, and the seeded Monte Carlo over the covariance."""
import contextlib
import dataclasses
import signal

import control
import numpy as np
import pytest

from motorsim import Encoder, Motor, SimRig
from motorsim.checks import ParameterError
from motorsim.control import (
    ClosedLoopExperiment,
    Feedforward,
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
from motorsim.robustness import ModelDraws, analyse_robustness, draw_models, loop_margins, robust_design

MODELS = [PlantModel(25.0, 3.0, 0.005, 16667), PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1)]
#: ``pi-fast`` keeps the time constant asked for (no phase margin required): 6 degrees with the delay
DESIGNS = [OneStepMPC, PISpeed, PositionPD, lambda m: PISpeed(m, 0.01, min_phase_margin=0.0),
           lambda m: OneStepMPC(m, 1e-3), LQRSpeed, LQRPosition, LQRSpeedIntegral]


@pytest.mark.parametrize("model", MODELS, ids=["delay0", "delay1"])
@pytest.mark.parametrize("design", DESIGNS, ids=["mpc", "pi", "position", "pi-fast", "mpc-weighted", "lqr",
                                                 "lqr-position", "lqr-integral"])
def test_margins_equal_python_control_stability_margins_on_the_same_loop(model, design):
    controller = design(model)
    _, cy = controller.laws()
    gm, pm, _, _, wgc, _ = control.stability_margins(-(controller.plant() * cy))
    m = loop_margins(controller)
    assert m.gain_margin == pytest.approx(gm, rel=1e-6)
    assert m.phase_margin == pytest.approx(pm, rel=1e-6)
    assert m.crossover == pytest.approx(wgc, rel=1e-6, nan_ok=True) and m.stable
    if np.isinf(pm):                     # the loop gain never reaches 1 (a heavily weighted MPC)
        assert np.isinf(m.delay_margin)
    else:
        assert m.delay_margin == pytest.approx(np.radians(pm) / wgc, rel=1e-6)


@pytest.mark.parametrize("design", [PISpeed, PositionPD, OneStepMPC, LQRSpeed, LQRPosition, LQRSpeedIntegral],
                         ids=["pi", "position", "mpc", "lqr", "lqr-position", "lqr-integral"])
def test_delay_margin_separates_the_stable_from_the_unstable_extra_delays(design):
    controller = design(MODELS[0])
    samples = loop_margins(controller).delay_margin / controller.model.sample_period
    below, above = int(np.floor(samples)), int(np.ceil(samples))
    assert below < samples < above
    slower = [dataclasses.replace(controller.model, input_delay=d) for d in (below, above)]
    assert loop_margins(controller, slower[0]).stable and not loop_margins(controller, slower[1]).stable


def test_a_loop_without_feedback_has_infinite_margins():
    m = loop_margins(Feedforward(MODELS[1]))
    assert np.isinf(m.gain_margin) and np.isinf(m.phase_margin) and m.stable


COVARIANCE = np.array([[4.0, 0.3], [0.3, 0.09]])     # a +- 2 1/s, b +- 0.3, correlated


def test_analysis_is_seeded_and_its_worst_case_bounds_its_percentile():
    pi = PISpeed(MODELS[1])
    ref = parse_reference("sine:10,10")
    one = analyse_robustness(pi, COVARIANCE, ref, 1.0, n_draws=40, rng=np.random.default_rng(3))
    two = analyse_robustness(pi, COVARIANCE, ref, 1.0, n_draws=40, rng=np.random.default_rng(3))
    assert one == two and one.n_draws == 40 and "Monte Carlo" in one.method
    assert one.worst_rms >= one.percentile_rms >= 0 and one.worst_phase_margin <= one.point.phase_margin
    assert one.unstable == 0 and not one.warnings()


def test_a_fragile_design_is_warned_about():
    # gain margin 0.93 dB at the point: b 10 % higher destabilises it (kept so: no phase margin required)
    fast = PISpeed(MODELS[1], 0.01, min_phase_margin=0.0)
    r = analyse_robustness(fast, COVARIANCE, parse_reference("sine:10,10"), 1.0, n_draws=60,
                           rng=np.random.default_rng(0))
    assert r.point.stable and 0 < r.unstable < 1 and np.isinf(r.worst_rms)
    assert any("unstable" in w for w in r.warnings())


def test_robust_design_measured_rms_stays_within_its_predicted_worst_case():
    # The robust design, run on SimRig against plants drawn from the same covariance
    # with another seed (a Monte Carlo of the truth), tracks no worse than its predicted worst case.
    # Measured: time constant 0.01 -> 0.02 s; measured RMS 0.73-0.86 x the predicted worst case 1.14 rad/s.
    model, ref = MODELS[1], parse_reference("sine:10,10")
    controller, r = robust_design("pi", model, COVARIANCE, ref, 1.0, n_draws=60, rng=np.random.default_rng(0),
                                  time_constant=0.01, min_phase_margin=0.0)
    assert r.unstable == 0 and controller.time_constant > 0.01
    for truth in draw_models(model, COVARIANCE, 4, np.random.default_rng(99)):
        rig = SimRig(Motor(truth.a, truth.b, input_delay=1), Encoder(counts_per_rev=16667))
        rec = rig.run(ClosedLoopExperiment(controller, ref, 1.0))
        measured = float(np.sqrt(np.mean(tracking_error(rec)[1:] ** 2)))
        assert measured <= r.worst_rms * 1.02


def test_robust_design_refuses_a_controller_without_a_knob_and_a_bad_covariance():
    with pytest.raises(ParameterError, match="kind"):
        robust_design("feedforward", MODELS[0], COVARIANCE, parse_reference("sine:10,10"), 1.0,
                      rng=np.random.default_rng(0))
    with pytest.raises(ParameterError, match="covariance"):
        draw_models(MODELS[0], np.eye(3), 5, np.random.default_rng(0))
    # not numbers, or not finite: the parameter and what it got, not numpy's own error
    with pytest.raises(ParameterError, match="covariance must be .* got 'x'"):
        draw_models(MODELS[0], "x", 5, np.random.default_rng(0))
    with pytest.raises(ParameterError, match="covariance must be .* got non-finite entries"):
        draw_models(MODELS[0], np.full((2, 2), np.nan), 5, np.random.default_rng(0))


class _StillRunning(Exception):
    pass


@contextlib.contextmanager
def _fails_instead_of_hanging(seconds: int = 60):
    """Turn an endless loop into a failure (the draw used to redraw forever); not a speed check."""
    def stop(signum, frame):
        raise _StillRunning
    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    except _StillRunning:
        pytest.fail(f"still running after {seconds} s: an endless loop", pytrace=False)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


BACKWARDS = PlantModel(25.0, -3.0, 0.005, 16667)        # a motor wired backwards, identified correctly


@pytest.mark.parametrize("kind", ["pi", "lqr", "mpc"])
def test_a_motor_wired_backwards_is_analysed_and_designed_robustly(kind):
    with _fails_instead_of_hanging():
        draws = draw_models(BACKWARDS, COVARIANCE, 30, np.random.default_rng(0))
        controller, r = robust_design(kind, BACKWARDS, COVARIANCE, parse_reference("sine:10,10"), 1.0, n_draws=30,
                                      rng=np.random.default_rng(0))
    assert len(draws) == 30 and draws.n_rejected == draws.n_other_sign == 0 and all(m.b < 0 for m in draws)
    assert controller.model.b == -3.0 and r.point.stable and r.unstable == 0 and r.other_sign == 0
    assert not r.warnings()


#: b = 3 with a standard deviation of 9.8: P(b <= 0) = Phi(-3 / 9.8) = 0.380
ACROSS_ZERO = [[0.25, 0.0], [0.0, 96.0]]


def test_draws_across_b_zero_are_analysed_as_the_plants_they_are_counted_and_warned_of():
    n = 2000
    draws = draw_models(MODELS[0], ACROSS_ZERO, n, np.random.default_rng(0))
    # binomial share: 4 standard deviations, sqrt(0.38 * 0.62 / 2000) = 0.011 each
    assert len(draws) == n and draws.n_other_sign / n == pytest.approx(0.380, abs=0.044)
    pi = PISpeed(MODELS[0])
    r = analyse_robustness(pi, ACROSS_ZERO, parse_reference("sine:10,10"), 0.5, rng=np.random.default_rng(0),
                           models=draws[:200])
    # a PI whose plant turned the other way integrates its error away from the reference: unstable
    assert r.other_sign == pytest.approx(sum(m.b < 0 for m in draws[:200]) / 200)
    assert r.unstable >= r.other_sign > 0.25 and np.isinf(r.worst_rms)
    assert any("b of the other sign" in w and "not know which way" in w for w in r.warnings())


def test_draws_with_a_at_or_below_zero_are_left_out_counted_and_warned_of():
    model = PlantModel(0.5, 3.0, 0.005, 16667)
    n = 2000
    draws = draw_models(model, [[1.0, 0.0], [0.0, 0.01]], n, np.random.default_rng(0))
    # P(a <= 0) = Phi(-0.5) = 0.309; 4 binomial standard deviations, 0.010 each
    assert len(draws) + draws.n_rejected == n and draws.n_rejected / n == pytest.approx(0.309, abs=0.041)
    assert all(m.a > 0 for m in draws)
    few = ModelDraws(draws.models[:40], n_rejected=10)
    r = analyse_robustness(PISpeed(model), None, parse_reference("sine:10,10"), 0.5, rng=np.random.default_rng(0),
                           models=few)
    assert r.n_draws == 40 and r.n_rejected == 10 and r.rejected == 0.2 and "10 more with a <= 0 left out" in r.method
    assert any("20 % of the plants drawn (10 of 50) have a <= 0" in w for w in r.warnings())
    with pytest.raises(ParameterError, match="all 7 plants drawn from the covariance have a <= 0"):
        analyse_robustness(PISpeed(model), None, parse_reference("sine:10,10"), 0.5, rng=np.random.default_rng(0),
                           models=ModelDraws((), n_rejected=7))


TAU_MODEL = PlantModel(25.0, 3.0, 0.001, 16667, input_delay=1, electrical_time_constant=0.004)


def test_the_electrical_time_constant_is_drawn_with_a_and_b_from_a_three_by_three_covariance():
    n = 4000
    cov = np.diag([0.04, 1e-4, 1e-6])                       # tau_e 4 ms +- 1 ms
    cov[0, 2] = cov[2, 0] = 0.5 * np.sqrt(0.04 * 1e-6)      # a and tau_e correlated, 0.5
    draws = draw_models(TAU_MODEL, cov, n, np.random.default_rng(1))
    taus = np.array([m.electrical_time_constant for m in draws])
    a = np.array([m.a for m in draws])
    # P(tau_e < 0) = Phi(-4) = 3e-5, 0.13 draws expected (more than 3: 1e-5); mean and spread within 4 standard
    # errors of theirs
    assert draws.n_rejected <= 3 and len(draws) + draws.n_rejected == n
    assert abs(taus.mean() - 0.004) <= 4 * 1e-3 / np.sqrt(n)
    assert abs(taus.std() / 1e-3 - 1) <= 4 / np.sqrt(2 * n)
    assert abs(np.corrcoef(a, taus)[0, 1] - 0.5) <= 4 * (1 - 0.25) / np.sqrt(n)
    # a 2 x 2 covariance keeps the model's tau_e in every plant
    kept = draw_models(TAU_MODEL, cov[:2, :2], 10, np.random.default_rng(1))
    assert {m.electrical_time_constant for m in kept} == {0.004}


def test_draws_with_a_negative_electrical_time_constant_are_left_out_and_counted():
    n = 2000
    draws = draw_models(TAU_MODEL, np.diag([0.04, 1e-4, 0.004 ** 2]), n, np.random.default_rng(0))
    # tau_e 4 ms +- 4 ms: P(tau_e < 0) = Phi(-1) = 0.159; 4 binomial standard deviations, 0.008 each
    assert draws.n_rejected / n == pytest.approx(0.159, abs=0.033)
    assert all(m.electrical_time_constant >= 0 for m in draws)


def test_a_three_by_three_covariance_needs_a_model_with_an_electrical_time_constant():
    with pytest.raises(ParameterError, match="no electrical time constant to draw around"):
        draw_models(PlantModel(25.0, 3.0, 0.001, 16667), np.eye(3) * 1e-6, 5, np.random.default_rng(0))


def test_an_uncertain_electrical_time_constant_widens_the_margins_a_design_can_count_on():
    # PI on a 4 ms lag at 1 ms: the lag costs phase; drawn with +-1.5 ms, the worst phase margin over 100 plants
    # is lower than with the lag fixed at its estimate
    pi = PISpeed(TAU_MODEL, time_constant=0.03)
    ab = np.diag([0.01, 1e-6])
    fixed = analyse_robustness(pi, ab, parse_reference("sine:10,10"), 0.5, n_draws=100, rng=np.random.default_rng(0))
    full = np.zeros((3, 3))
    full[:2, :2], full[2, 2] = ab, 0.0015 ** 2
    drawn = analyse_robustness(pi, full, parse_reference("sine:10,10"), 0.5, n_draws=100, rng=np.random.default_rng(0))
    assert "(a, b, tau_e) drawn" in drawn.method and "kept in every plant" in fixed.method
    # a and b barely move (0.4 % and 0.03 %): the spread of the margins is the lag's
    assert drawn.worst_phase_margin < fixed.worst_phase_margin - 3.0
