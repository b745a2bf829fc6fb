"""The frequency-domain fit of the ``second-order`` structure, and its frequency response as the structure gives it."""
import math

import control
import numpy as np
import pytest

from identify import Estimate, structures
from identify.frequency.frequency_estimate import frequency_response
from identify.frequency.frequency_fit import fit_frequency_response
from motorsim import Encoder, Experiment, Motor, OddMultisine, SimRig
from motorsim.checks import ParameterError

A, B, TAU, DT = 25.0, 3.0, 0.004, 0.001
SECOND = structures()["second-order"]


def _run(seed, tau=TAU):
    """6 periods of an odd multisine (512 samples at 1 ms, lines 2 ... 780 rad/s) on the lag motor."""
    rig = SimRig(Motor(A, B, electrical_time_constant=tau), Encoder(angle_noise=2e-3), rng=np.random.default_rng(seed))
    return rig.run(Experiment(OddMultisine(512, 127, 15, seed=seed), sample_period=DT, duration=512 * DT * 6))


@pytest.mark.parametrize("output", ["angle", "speed"])
@pytest.mark.parametrize("tau,delay", [(TAU, 0), (TAU, 2), (1e-5, 1)], ids=["4ms", "4ms-delay2", "10us-delay1"])
def test_the_structures_response_is_python_controls_sampled_motor(tau, delay, output):
    values = {"a": A, "b": B, "electrical_time_constant": tau, "bias": 0.7}     # a bias has no response
    omega = np.geomspace(0.5, 0.999 * math.pi / DT, 40)
    mine = SECOND.frequency_response(values, DT, omega, output=output, input_delay=delay)
    ss = control.sample_system(Motor(A, B, electrical_time_constant=tau).state_space(), DT, method="zoh")
    z = np.exp(1j * omega * DT)
    angle, speed = (np.array([(ss.C[i] @ np.linalg.solve(zz * np.eye(3) - ss.A, ss.B))[0] for zz in z])
                    for i in (0, 1))
    # the angle's response is the mean speed over the interval the input is held: (z - 1) angle / dt
    ref = (speed if output == "speed" else (z - 1) * angle / DT) * z ** -delay
    assert np.max(np.abs(mine - ref) / np.abs(ref)) < 1e-9      # both exact ZOH: rounding only


@pytest.mark.parametrize("seed", [1, 2, 3], ids=["seed1", "seed2", "seed3"])
def test_the_fit_recovers_a_b_and_tau_e_within_four_standard_errors(seed):
    """4 standard errors: the Gauss-Newton covariance is, if anything, conservative on this run (over
    seeds 1 ... 12 the RMS of (estimate - truth) / stderr measured 0.60, 0.63 and 0.70 for a, b, tau_e:
    the chi-square inflation and the bounds' few degrees of freedom), so a check fails by chance with
    probability below 6e-5; the first-order fit on the same lines misses by far more (its standardised
    residual RMS measured 3.7 ... 7.1, its a 12 ... 18 % low)."""
    frf = frequency_response(_run(seed))
    est = fit_frequency_response(frf, structure="second-order")
    assert est.structure == "second-order" and est.param_names == ("a", "b", "electrical_time_constant")
    se = est.stderr()
    truth = {"a": A, "b": B, "electrical_time_constant": TAU}
    for name, value in truth.items():
        assert abs(est.values()[name] - value) < 4 * se[name], name
    assert se["electrical_time_constant"] < 0.05 * TAU and se["a"] < 0.02 * A
    assert 0.7 < est.residual_rms < 1.4                      # the model fits within the bounds
    linear = fit_frequency_response(frf)
    assert linear.structure == "linear" and linear.residual_rms > 3     # the lag is outside its bounds
    assert abs(linear.a - A) > 4 * linear.stderr()["a"]


def test_the_default_is_unchanged_and_the_electrical_pole_is_the_faster_one():
    frf = frequency_response(_run(4))
    default, linear = fit_frequency_response(frf), fit_frequency_response(frf, structure=structures()["linear"])
    assert (default.a, default.b, default.structure) == (linear.a, linear.b, "linear")
    assert np.array_equal(default.covariance, linear.covariance)
    est = fit_frequency_response(frf, structure="second-order")
    tau = est.extra["electrical_time_constant"]
    assert est.a * tau < 1.0
    # the twin (the poles swapped, b rescaled) has the same response: the fit names them one way
    twin = {"a": 1 / tau, "b": est.b / (est.a * tau), "electrical_time_constant": 1 / est.a}
    assert SECOND.frequency_response(twin, DT, frf.omega) == pytest.approx(
        SECOND.frequency_response(est.values(), DT, frf.omega), rel=1e-9)


@pytest.mark.parametrize("name, message", [("friction", "must be linear"), ("bias", "use structure 'linear'"),
                                           ("cubic", "structure must be one of")], ids=["friction", "bias", "unknown"])
def test_a_structure_without_a_response_of_its_own_is_refused(name, message):
    frf = frequency_response(_run(5))
    with pytest.raises(ParameterError, match=message):
        fit_frequency_response(frf, structure=name)


def test_model_of_draws_the_full_model_with_its_three_parameter_band():
    frf = frequency_response(_run(6))
    est = Estimate("oe-electrical", A, B, 1000, DT, 1e-3, 99.0, np.diag([0.01, 1e-4, 1e-8, 1e-4]),
                   ("a", "b", "electrical_time_constant", "bias"), {"electrical_time_constant": TAU, "bias": 0.3},
                   structure="second-order")
    model = frf.model_of(est)
    assert np.array_equal(model.response, SECOND.frequency_response(est.values(), DT, frf.omega))
    first = frf.model_response(A, B)
    assert np.max(np.abs(model.response - first) / np.abs(first)) > 0.5      # tau_e is not dropped
    # the band: J C J^H over a, b, tau_e (bias has no response), against a direct sum of the three terms
    var = np.zeros(len(frf))
    for name, v in (("a", 0.01), ("b", 1e-4), ("electrical_time_constant", 1e-8)):
        h = 1e-6 * est.values()[name]
        up = SECOND.frequency_response({**est.values(), name: est.values()[name] + h}, DT, frf.omega)
        down = SECOND.frequency_response({**est.values(), name: est.values()[name] - h}, DT, frf.omega)
        var += v * np.abs((up - down) / (2 * h)) ** 2
    assert model.variance == pytest.approx(var, rel=1e-9)
    assert frf.covers(model.response).mean() > 0.9


def test_the_fitted_estimate_is_a_model_of_its_structure():
    est = fit_frequency_response(frequency_response(_run(7)), structure="second-order", input_delay=1)
    assert est.input_delay == 1 and est.motor().electrical_time_constant == est.extra["electrical_time_constant"]
    tf = est.transfer_function("discrete")
    omega = np.geomspace(1.0, 2000.0, 10)
    speed = SECOND.frequency_response(est.values(), DT, omega, output="speed", input_delay=1)
    assert tf(np.exp(1j * omega * DT)) == pytest.approx(speed, rel=1e-9)
