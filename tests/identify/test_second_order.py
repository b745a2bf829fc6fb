"""The motor behind an electrical lag, b/((s + a)(tau_e s + 1)): simulated exactly, fitted exactly,
chosen by the default only where the data show the second pole, and long delays searched."""
from __future__ import annotations

import json

import control
import numpy as np
import pytest

from identify import Estimate, fit
from identify.fits.electrical import fit_output_error_electrical
from identify.model_structures import structure
from motorsim import Encoder, Experiment, Motor, Multisine, Recording, SimRig
from motorsim.checks import ParameterError
from motorsim.excitation import PRBS
from motorsim.plant import simulate

MULTISINE = Multisine((3.0, 17.0, 70.0, 200.0), (60, 50, 40, 40), (0, 1, 2, 3))


def _reference(a, b, tau, bias, u, t, w0=0.0):
    """python-control's own ZOH simulation of the three-state model (angle, speed, current)."""
    A = [[0, 1, 0], [0, -a, b], [0, 0, -1 / tau]]
    B = [[0, 0], [0, 1], [1 / tau, 0]]
    sysd = control.sample_system(control.ss(A, B, np.eye(3), np.zeros((3, 2))), t[1] - t[0], method="zoh")
    return control.forced_response(sysd, t, np.vstack([u, np.full_like(u, bias)]), X0=[0.0, w0, 0.0]).outputs


@pytest.mark.parametrize("tau", [0.004, 1 / 25.0, 1 / 25.0 * (1 + 1e-9)], ids=["4 ms", "a = c", "a ~ c"])
def test_the_simulation_is_python_control_s_zero_order_hold(tau):
    # the closed form's quotients keep their limit at a = c (1e-9: rounding of ~3000 steps)
    t = np.arange(3000) * 0.001
    u = np.round(150 * np.sin(12 * t) + 60 * np.sin(90 * t))
    run = simulate(Motor(25.0, 3.0, bias=2.0, electrical_time_constant=tau), u, t, initial_speed=1.5)
    ref = _reference(25.0, 3.0, tau, 2.0, u, t, w0=1.5)
    np.testing.assert_allclose(run.speed, ref[1], rtol=0, atol=1e-9 * np.max(np.abs(ref[1])))
    np.testing.assert_allclose(run.angle, ref[0], rtol=0, atol=1e-9 * np.max(np.abs(ref[0])))


def test_a_lag_with_coulomb_friction_is_refused_by_name():
    with pytest.raises(ParameterError, match="electrical_time_constant must be 0 when friction is set"):
        Motor(25.0, 3.0, friction=10.0, electrical_time_constant=0.004)


def test_the_structure_s_transfer_function_and_json():
    s = structure("second-order")
    values = {"a": 25.0, "b": 3.0, "electrical_time_constant": 0.004, "bias": 0.0}
    tf = s.transfer_function(values, 0.001, 2, "discrete")
    ref = control.sample_system(control.tf([3.0], [0.004, 1.1, 25.0]), 0.001, method="zoh") * control.tf(
        [1], [1, 0, 0], 0.001)
    z = np.exp(1j * np.linspace(1.0, 2000.0, 17) * 0.001)
    np.testing.assert_allclose(tf(z), ref(z), rtol=1e-9)
    est = Estimate(method="oe-electrical", a=25.0, b=3.0, n_samples=100, sample_period=0.001, residual_rms=0.0,
                   fit_percent=100.0, param_names=("a", "b", "electrical_time_constant", "bias"),
                   extra={"electrical_time_constant": 0.004, "bias": 0.0}, input_delay=2)
    assert est.structure == "second-order" and est.motor().electrical_time_constant == 0.004
    doc = json.loads(est.to_json())
    assert doc["structure"] == "second-order" and doc["electrical_time_constant"] == 0.004
    assert Estimate.from_json(est.to_json()).values() == est.values()


@pytest.mark.parametrize("kind", ["angle", "speed"])
def test_oe_electrical_is_exact_on_noise_free_data(kind):
    # noise-free samples of the exact model: a, b, tau_e to 1e-7 relative (the search's tolerance, 1e-10 in
    # the logarithms of the poles, with the conditioning of a 4 s run)
    t = np.arange(4000) * 0.001
    u = MULTISINE.duty(len(t), 0.001).astype(float)
    run = simulate(Motor(25.0, 3.0, electrical_time_constant=0.004, input_delay=1), u, t)
    rec = Recording(time=t, duty=u, sample_period=0.001, **({"angle": run.angle} if kind == "angle"
                                                           else {"speed": run.speed}))
    est = fit_output_error_electrical(rec, input_delay=1)
    assert est.a == pytest.approx(25.0, rel=1e-7) and est.b == pytest.approx(3.0, rel=1e-7)
    assert est.extra["electrical_time_constant"] == pytest.approx(0.004, rel=1e-7)


@pytest.mark.parametrize("tau", [0.002, 0.004, 0.008])
@pytest.mark.parametrize("seed", [1, 2])
def test_the_default_finds_a_driver_s_lag_on_a_fine_encoder(tau, seed):
    # the class the first-order family absorbed as a delay of 2-5 samples, "clear", intervals without the truth
    rig = SimRig(Motor(25.0, 3.0, electrical_time_constant=tau), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(seed))
    est = fit(rig.run(Experiment(MULTISINE, 0.001, 8.0)))
    se = est.stderr()
    assert est.structure == "second-order" and est.input_delay == 0
    assert abs(est.a / 25.0 - 1) < 0.01 and abs(est.b / 3.0 - 1) < 0.01          # within 1 % of the truth
    # and the truth within 4 standard errors (fixed seeds; a 95 % interval misses 1 run in 20 by design,
    # the coverage over 100 seeds is motorid bench coverage's)
    for name, truth in (("a", 25.0), ("b", 3.0), ("electrical_time_constant", tau)):
        assert abs(est.value(name) - truth) <= 4 * se[name], name


def test_a_lag_too_fast_for_the_sample_period_keeps_the_first_order_answer_and_says_so():
    rig = SimRig(Motor(25.0, 3.0, electrical_time_constant=0.0001), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(3))
    est = fit(rig.run(Experiment(MULTISINE, 0.005, 10.0)))
    assert est.structure in ("linear", "bias")
    assert any("second-order not a candidate" in n for n in est.notes)
    ci = est.confidence_interval(0.95)
    assert ci["a"][0] <= 25.0 <= ci["a"][1] or abs(est.a / 25 - 1) < 0.01


@pytest.mark.parametrize("delay", [13, 16, 20])
def test_a_delay_past_ten_samples_is_searched_and_found(delay):
    rig = SimRig(Motor(25.0, 3.0, input_delay=delay), Encoder(angle_noise=1e-4), rng=np.random.default_rng(delay))
    est = fit(rig.run(Experiment(MULTISINE, 0.001, 8.0)))
    assert est.input_delay == delay and est.structure == "linear"
    assert abs(est.a / 25.0 - 1) < 0.001 and abs(est.b / 3.0 - 1) < 0.001
    assert any("input delays searched up to" in n for n in est.notes)


def test_a_twenty_sample_delay_on_a_prbs_is_found():
    # was a = 9.0 [8.3, 9.7], "a clear choice"
    rig = SimRig(Motor(25.0, 3.0, input_delay=20), Encoder(angle_noise=1e-4), rng=np.random.default_rng(5))
    est = fit(rig.run(Experiment(PRBS(hold=20), 0.001, 8.0)))
    ci = est.confidence_interval(0.95)
    assert est.input_delay == 20 and ci["a"][0] <= 25.0 <= ci["a"][1]


def test_a_delay_at_the_edge_of_what_the_data_allow_is_never_clear():
    rig = SimRig(Motor(25.0, 3.0, input_delay=12), Encoder(angle_noise=1e-4), rng=np.random.default_rng(2))
    rec = rig.run(Experiment(MULTISINE, 0.005, 1.2))            # 240 rows: delays up to 12 only
    est = fit(rec)
    if est.input_delay == 12:
        assert not est.selection.clear and "longest searched" in est.selection.doubt


@pytest.mark.parametrize("counts_per_rev, sample_period", [(360, 0.002), (1000, 0.005), (360, 0.005)])
def test_a_speed_column_that_differences_counts_is_fitted_as_the_counts(counts_per_rev, sample_period):
    # the class that was honest but imprecise (a 2-6 % low, wide intervals): now the counts' own answer
    rig = SimRig(Motor(25.0, 3.0), Encoder(counts_per_rev), rng=np.random.default_rng(1))
    rec = rig.run(Experiment(Multisine((2.0, 7.0, 23.0, 60.0), (60, 60, 50, 40), (0, 1, 2, 3)), sample_period, 10.0))
    speed = rec.measured_speed()
    speed[0] = 0.0
    only_speed = Recording(time=rec.time, duty=rec.duty, sample_period=sample_period, speed=np.round(speed, 9))
    est, truth = fit(only_speed), fit(rec)
    assert est.a == pytest.approx(truth.a, rel=1e-9) and est.b == pytest.approx(truth.b, rel=1e-9)
    assert any(f"one count of {counts_per_rev} per revolution" in n for n in est.notes)
    assert est.counts_per_rev == truth.counts_per_rev == counts_per_rev      # the model names its encoder


def test_a_tachometer_speed_is_not_taken_for_differenced_counts():
    from identify.data import counts_behind_speed
    t = np.arange(2000) * 0.005
    speed = 10 * np.sin(3 * t) + 0.01 * np.random.default_rng(0).standard_normal(2000)
    assert counts_behind_speed(Recording(time=t, duty=np.zeros(2000), sample_period=0.005, speed=speed)) is None
    printed = np.round(speed, 3)            # a file's printed resolution is no encoder's grid
    assert counts_behind_speed(Recording(time=t, duty=np.zeros(2000), sample_period=0.005, speed=printed)) is None


def test_a_speed_column_averaged_over_each_interval_is_not_a_clear_second_pole():
    # a difference of positions lags the speed by half a sample, which a second pole fits: the file does not
    # say which the column is, so both readings are covered and the choice is not clear
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Multisine((2.0, 7.0, 23.0, 60.0), (60, 60, 50, 40),
                                                             (0, 1, 2, 3)), 0.005, 8.0))
    speed = rec.measured_speed()
    speed[0] = 0.0
    noisy = speed + 1e-3 * np.random.default_rng(0).standard_normal(len(speed))   # off any counts grid
    est = fit(Recording(time=rec.time, duty=rec.duty, sample_period=0.005, speed=noisy))
    ci = est.confidence_interval(0.95)
    assert ci["a"][0] <= 25.0 <= ci["a"][1] and ci["b"][0] <= 3.0 <= ci["b"][1]
    if est.structure == "second-order":
        assert not est.selection.clear and "average speed over each interval" in est.selection.doubt


@pytest.mark.parametrize("delay", [2, 5])
def test_a_slow_lag_behind_a_delay_is_found_with_its_own_delay(delay):
    # a 10-sample lag stands in for about 9 samples of delay: the first-order best (delay 11-14) was more than
    # eight delays above the true one, and the second pole, fitted only that far down, came out one sample
    # late, a = 24.78 [24.76, 24.80], "a clear choice"
    rig = SimRig(Motor(25.0, 3.0, electrical_time_constant=0.01, input_delay=delay), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(delay))
    est = fit(rig.run(Experiment(MULTISINE, 0.001, 4.0)))
    assert est.structure == "second-order" and est.input_delay == delay
    assert abs(est.a / 25.0 - 1) < 0.01 and abs(est.b / 3.0 - 1) < 0.01
    se = est.stderr()     # the truth within 4 standard errors, as above
    for name, truth in (("a", 25.0), ("b", 3.0), ("electrical_time_constant", 0.01)):
        assert abs(est.value(name) - truth) <= 4 * se[name], name


@pytest.mark.parametrize("tau, sample_period, omega", [(0.003, 0.001, 20.0), (0.005, 0.005, 10.0)],
                         ids=["3 ms lag at 1 ms", "5 ms lag at 5 ms"])
def test_one_sine_through_a_lag_is_covered_by_the_intervals(tau, sample_period, omega):
    # one sine cannot tell a lag from a delay: the first-order model with its delay fits as well as the second
    # pole and was chosen, clear, its interval 30 times narrower than the second pole's own and around its own
    # value (3 ms: a = 25.0039 [25.0004, 25.0042], b = 2.9949 for 25 and 3); the intervals now hold the second
    # pole's own too
    from motorsim import Sine
    rig = SimRig(Motor(25.0, 3.0, electrical_time_constant=tau), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(0))
    est = fit(rig.run(Experiment(Sine(omega, 200), sample_period, 6.0)))
    ci = est.confidence_interval(0.95)
    assert abs(est.a / 25.0 - 1) < 0.01 and abs(est.b / 3.0 - 1) < 0.01
    assert ci["a"][0] <= 25.0 <= ci["a"][1] and ci["b"][0] <= 3.0 <= ci["b"][1]
    assert (ci["a"][1] - ci["a"][0]) < 0.01 * 25.0                # and still narrow: 0.1 % at most


def test_a_prbs_behind_a_delay_finds_the_lag_from_a_poor_first_order_start():
    # a PRBS through a 6 ms lag behind 3 samples: the first-order start pole is 4.6 for 25, and the search from the
    # best start on the lag's grid slid to tau_e at its lower bound, a = 21.5 [20.9, 22.2], which the default
    # returned as a clear choice after its own candidate had found 25; a search ending at that bound now tries the
    # next starts
    rig = SimRig(Motor(25.0, 3.0, electrical_time_constant=0.006, input_delay=3), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(0))
    rec = rig.run(Experiment(PRBS(hold=5), 0.001, 6.0))
    est = fit_output_error_electrical(rec, input_delay=3)
    assert abs(est.a / 25.0 - 1) < 0.001 and abs(est.b / 3.0 - 1) < 0.001
    assert abs(est.extra["electrical_time_constant"] / 0.006 - 1) < 0.01
