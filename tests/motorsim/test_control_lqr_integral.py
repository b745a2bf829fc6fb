"""Speed LQR with integral action: python-control's dlqr on the augmented model, no steady error on SimRig."""
import numpy as np
import pytest

from motorsim import Encoder, Motor, SimRig
from motorsim.checks import ParameterError
from motorsim.control import (
    INTEGRAL_WEIGHT,
    ClosedLoopExperiment,
    LQRSpeed,
    LQRSpeedIntegral,
    PlantModel,
    design_controller,
    parse_reference,
    tracking_error,
)
from motorsim.fixed_point import SPEED_REFERENCE_BITS, ControlLoop, gains_from_wire


def _model(delay, **kw):
    return PlantModel(25.0, 3.0, 0.005, 16667, input_delay=delay, **kw)


def _augmented(model):
    """The model with the input delay and the speed error's sum in the state, written out again here.

    ``x = [y, u(k-1) ... u(k-D-1), s]``: ``y(k+1) = e y + beta1 u(k-D) + beta2 u(k-D-1)``, the
    duties shifted along, ``s(k+1) = s(k) - y(k)`` (the sum of ``r - y`` with ``r = 0``).
    """
    e, _, b1, b2 = model.speed_coefficients()
    d = model.input_delay
    n = d + 3
    a, b = np.zeros((n, n)), np.zeros((n, 1))
    a[0, 0], a[0, d + 1], b[1, 0] = e, b2, 1.0
    if d:
        a[0, d] += b1
    else:
        b[0, 0] = b1
    for m in range(2, d + 2):
        a[m, m - 1] = 1.0
    a[-1, 0], a[-1, -1] = -1.0, 1.0
    return a, b


@pytest.mark.parametrize("delay", [0, 1, 3])
@pytest.mark.parametrize("duty_weight, integral_weight", [(1e-3, INTEGRAL_WEIGHT), (1e-2, 1000.0), (1e-4, 10.0)])
def test_gain_is_python_controls_dlqr_on_the_model_augmented_with_the_error_sum(delay, duty_weight, integral_weight):
    import control
    lqr = LQRSpeedIntegral(_model(delay), duty_weight, integral_weight)
    a, b = _augmented(lqr.model)
    scale, h = lqr.model.speed_scale, lqr.model.sample_period
    q = np.zeros_like(a)
    q[0, 0] = 1.0 / scale ** 2                     # omega^2 with omega = y / scale
    q[-1, -1] = integral_weight * (h / scale) ** 2  # theta^2 with theta = h s / scale
    k, _, _ = control.dlqr(a, b, q, duty_weight)
    np.testing.assert_allclose(lqr.state_gain(), k.ravel(), rtol=1e-9, atol=1e-9 * np.abs(k).max())
    # the step's laws close the loop of the quantised state feedback u = -Kq x: the same poles
    gains = {name: value / 2 ** 16 for name, value in lqr.gains().items()}
    kq = np.array([-gains["ky"], *(-gains[f"ku{j}"] for j in range(1, delay + 2)),
                   -gains["ki"] * 2 ** SPEED_REFERENCE_BITS])
    wanted = np.linalg.eigvals(a - b @ kq[None, :])
    loop = control.feedback(-(lqr.plant() * lqr.laws()[1]), 1).poles()
    np.testing.assert_allclose(np.sort_complex(loop[np.abs(loop) > 1e-3]),
                               np.sort_complex(wanted[np.abs(wanted) > 1e-3]), atol=1e-6)
    assert np.all(np.abs(loop[np.abs(loop) <= 1e-3]) < 1e-3) and lqr.is_stable() and lqr.preview == delay + 1
    assert list(lqr.gains())[:5] == ["kr", "ky", "ki", "k0", "kf"] and lqr.gains()["ki"] > 0


@pytest.mark.parametrize("delay", [0, 1, 2])
@pytest.mark.parametrize("spec", ["constant:10", "constant:-5", "step:8,0.5,2"])
def test_no_steady_error_under_a_bias_friction_and_gain_the_model_lacks(delay, spec):
    # The design knows a = 25, b = 3 and nothing else; the motor has b 20 % higher, a bias and
    # Coulomb friction.  Over the last second, the integral's mean error is within 0.01 rad/s
    # (measured: at most 0.0034; one count per sample is 0.075 rad/s); the plain LQR keeps
    # 0.06 ... 0.61 rad/s.
    motor = Motor(25.0, 3.6, friction=15.0, bias=-20.0, input_delay=delay)
    errors = {}
    for controller in (LQRSpeedIntegral(_model(delay)), LQRSpeed(_model(delay))):
        rig = SimRig(motor, Encoder(counts_per_rev=16667, angle_noise=1e-3), rng=np.random.default_rng(delay))
        rec = rig.run(ClosedLoopExperiment(controller, parse_reference(spec), 3.0))
        errors[controller.kind] = float(np.mean(tracking_error(rec)[-200:]))
    assert abs(errors["lqr-integral"]) < 0.01
    assert abs(errors["lqr"]) > 0.05


def test_the_error_sum_is_what_the_step_integrates_and_it_stops_at_the_duty_limit():
    # 40 rad/s, which the motor cannot reach at duty 40 (it needs 333), then 3 rad/s (25): the
    # duty sits at the limit and the sum stops growing there (conditional integration), so the
    # loop leaves the limit as soon as the reference comes back within reach.
    lqr, spec = LQRSpeedIntegral(_model(1)), "step:3,1.0,40"
    reference = parse_reference(spec).samples(401 + lqr.preview, 0.005, lqr.reference_scale)
    loop = lqr.start(reference, duty_limit=40)
    rec = SimRig(Motor(25.0, 3.0, input_delay=1), Encoder(counts_per_rev=16667)).run(
        ClosedLoopExperiment(lqr, parse_reference(spec), 2.0, duty_limit=40))
    sums = []
    for k, c in enumerate(rec.counts[:400]):
        loop.step(k, int(c))
        sums.append(loop.integral)
    assert np.all(rec.duty[20:195] == 40)                               # at the limit before the step
    assert np.ptp(sums[20:195]) < 40 * (1 << SPEED_REFERENCE_BITS)      # and the sum did not wind up
    assert abs(np.mean(tracking_error(rec)[-100:])) < 0.01              # after it, no steady error


def test_wire_order_and_the_step_agree_with_the_design():
    lqr = LQRSpeedIntegral(_model(2))
    gains = lqr.gains()
    assert gains_from_wire("lqr-integral", list(gains.values())) == gains
    with pytest.raises(ParameterError, match="at least 6 gains"):
        gains_from_wire("lqr-integral", [1, 2, 3, 4, 5])
    loop = ControlLoop("lqr-integral", gains, lqr.preview, [160] * 10)
    assert loop.step(0, 0) == (gains["kr"] * 160 + gains["k0"] + gains["kf"] + (1 << 15)) >> 16
    assert loop.integral == 160                                        # r(0) - 16 y(0), after the duty


def test_design_by_name_settings_and_bad_weights():
    lqr = design_controller("lqr-integral", _model(1), duty_weight=2e-3, integral_weight=50.0)
    assert isinstance(lqr, LQRSpeedIntegral) and lqr.settings() == {"duty_weight": 2e-3, "integral_weight": 50.0}
    assert lqr.metadata()["controller"] == "lqr-integral" and "ki=" in lqr.metadata()["controller_gains"]
    for bad in (0.0, -1.0, float("inf")):
        with pytest.raises(ParameterError, match="integral_weight"):
            LQRSpeedIntegral(_model(0), integral_weight=bad)
    with pytest.raises(ParameterError, match="integral_weight"):
        design_controller("lqr", _model(0), integral_weight=10.0)      # the plain LQR has no integral
