"""Controllers from a model: the fixed-point step, its optimality, and prediction against the simulated rig."""
import math

import numpy as np
import pytest

from motorsim import Encoder, Experiment, Motor, Recording, SimRig, Sine, read_recording, write_recording
from motorsim.control import (
    CONTROLLERS,
    ClosedLoopExperiment,
    Feedforward,
    LQRPosition,
    LQRSpeed,
    LQRSpeedIntegral,
    OneStepMPC,
    PISpeed,
    PlantModel,
    PositionPD,
    design_controller,
    parse_reference,
    tracking_error,
)
from motorsim.excitation import multisine_duty, phase_increment

MODEL = PlantModel(25.0, 3.0, 0.005, 16667)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def _run(controller, spec, duration=4.0, motor=None, **rig):
    exp = ClosedLoopExperiment(controller, parse_reference(spec), duration=duration)
    return SimRig(motor or Motor(25.0, 3.0), **rig).run(exp)


# The controllers track as predicted.  The prediction is linear (no duty limit, no encoder
# quantisation); the references keep the duty below the limit, so the measured RMS differs
# from the predicted one only by the encoder's quantisation (1 count per sample = 0.075 rad/s)
# and the rounding of the duty: 10 % is the tolerance the controllers are held to.
@pytest.mark.parametrize("controller, spec", [
    (OneStepMPC(MODEL, 1e-4), "sine:10,10"),
    (OneStepMPC(MODEL, 1e-3), "multisine:5,6;20,3"),
    (PISpeed(MODEL, 0.05), "trapezoid:15,0.5,1,0.2"),
    (PISpeed(MODEL, 0.05, feedforward=True), "sine:10,10"),
    (Feedforward(MODEL), "sine:10,10"),
    (PositionPD(MODEL, 0.05), "step:1,0.1"),
    (PositionPD(MODEL, 0.1, derivative=False), "sine:3,1"),
    (LQRSpeed(MODEL), "sine:10,10"),
    (LQRSpeed(MODEL, 1e-2), "multisine:5,6;20,3"),
    (LQRSpeedIntegral(MODEL), "sine:10,10"),
    (LQRSpeedIntegral(MODEL, 1e-2, 1000.0), "trapezoid:15,0.5,1,0.2"),
    (LQRPosition(MODEL), "trapezoid:3,0.3,0.5,0.1"),
    (LQRPosition(MODEL, 1e-5), "sine:3,1"),
], ids=["mpc-sine", "mpc-multisine", "pi-trapezoid", "pi-ff-sine", "feedforward", "pd-step", "p-sine", "lqr-sine",
        "lqr-multisine", "lqr-integral-sine", "lqr-integral-trapezoid", "lqr-position-trapezoid", "lqr-position-sine"])
def test_measured_tracking_rms_within_10_percent_of_the_prediction(controller, spec):
    rec = _run(controller, spec)
    predicted = controller.predict(parse_reference(spec), 4.0)
    measured = _rms(tracking_error(rec))
    assert predicted.tracking_rms > 0.02  # well above the encoder's quantisation, so the test can fail
    assert measured == pytest.approx(predicted.tracking_rms, rel=0.10)
    assert np.abs(predicted.duty).max() < 255
    np.testing.assert_allclose(rec.reference, predicted.reference, rtol=0, atol=1e-12)


def test_mpc_step_is_the_integer_minimiser_of_its_cost():
    """Closed form, rounded and clipped, against a brute-force search over every duty."""
    mpc = OneStepMPC(MODEL, 2e-5)
    e, _, b1, b2 = MODEL.speed_coefficients()
    lam = mpc.duty_weight * MODEL.speed_scale ** 2
    rng = np.random.default_rng(3)
    u_all = np.arange(-255, 256)
    diffs = []
    for _ in range(300):
        r = int(rng.integers(-6000, 6000))  # 1/16 count per sample
        y, u_prev = int(rng.integers(-400, 400)), int(rng.integers(-255, 256))
        loop = mpc.start([0, r], 255)
        loop.history = [u_prev]
        loop.previous = 1000 - y
        u = loop.step(0, 1000)
        cost = (r / 16 - (e * y + b1 * u_all + b2 * u_prev)) ** 2 + lam * u_all ** 2
        diffs.append(u - int(u_all[np.argmin(cost)]))
    diffs = np.abs(diffs)
    # The Q16 gains are rounded (relative error < 2**-16 per gain), which moves the step's
    # optimum by far less than one duty: only near-ties can round the other way.
    assert diffs.max() <= 1 and np.mean(diffs == 0) >= 0.97


def test_pi_anti_windup_recovers_after_saturation():
    pi = PISpeed(MODEL, 0.05)
    # 50 rad/s is out of reach (b/a 255 = 30.6 rad/s): 1 s at the limit, then 10 rad/s
    rec = _run(pi, "step:10,1.0,50", duration=3.0)
    assert np.all(rec.duty[50:200] == 255)
    # the integral did not grow while at the limit: the duty leaves it within 2 samples of the
    # step down (a wound-up integral of 1 s of ~20 rad/s error would hold it for seconds)
    assert rec.duty[202] < 255
    # and the loop settles to the encoder's quantisation (1 count per sample = 0.075 rad/s)
    assert np.abs(rec.measured_speed()[400:] - 10.0).max() < 0.15


def test_mpc_compensates_bias_and_friction_of_its_model():
    motor = Motor(25.0, 3.0, friction=40.0, bias=-20.0)
    # The cost weighs the whole duty, so a model offset o is compensated by the fraction
    # K beta1 = beta1^2 / (beta1^2 + lambda): 0.98 at lambda = 1e-6 (0.84 at 1e-5).
    blind = OneStepMPC(MODEL, 1e-6)
    aware = OneStepMPC(PlantModel.from_source(motor, 0.005, 16667), 1e-6)
    ideal = np.mean(tracking_error(_run(blind, "constant:10", 2.0))[200:])
    err_blind = np.mean(tracking_error(_run(blind, "constant:10", 2.0, motor))[200:])
    err_aware = np.mean(tracking_error(_run(aware, "constant:10", 2.0, motor))[200:])
    assert abs(err_blind - ideal) > 0.2  # (friction - bias)/b = 20 duty unmodelled: 0.29 rad/s
    assert abs(err_aware - ideal) < 0.02  # 2 % of it left: 0.006 rad/s, plus quantisation


def test_delay_is_designed_for_and_predicted():
    motor = Motor(25.0, 3.0, input_delay=2)
    mpc = OneStepMPC(PlantModel.from_source(motor, 0.005, 16667), 1e-4)
    assert mpc.preview == 3 and "ku3" in mpc.gains()
    rec = _run(mpc, "sine:10,10", motor=motor)
    assert _rms(tracking_error(rec)) == pytest.approx(mpc.predict(parse_reference("sine:10,10"), 4.0).tracking_rms,
                                                      rel=0.10)


@pytest.mark.parametrize("design", [LQRSpeed, LQRPosition], ids=["lqr", "lqr-position"])
@pytest.mark.parametrize("delay", [0, 1, 3])
def test_lqr_gain_is_python_controls_dlqr_on_the_model_with_the_delay_in_the_state(design, delay):
    import control
    motor = Motor(25.0, 3.0, input_delay=delay)
    lqr = design(PlantModel.from_source(motor, 0.005, 16667))
    e, _, b1, b2 = lqr.model.speed_coefficients()
    n = delay + 2                                   # [y, u(k-1) ... u(k-D-1)]
    a, b = np.zeros((n, n)), np.zeros((n, 1))
    a[0, 0], b[1, 0] = e, 1.0
    a[0, delay + 1] += b2
    if delay:
        a[0, delay] += b1
    else:
        b[0, 0] = b1
    a[2:, 1:-1] = np.eye(n - 2)
    scale = lqr.model.speed_scale
    if lqr.quantity == "angle":                     # [theta, y, ...]: theta(k+1) = theta(k) + y(k+1)
        a = np.block([[np.ones((1, 1)), a[:1]], [np.zeros((n, 1)), a]])
        b = np.vstack([b[:1], b])
        scale = lqr.model.angle_scale
    q = np.zeros_like(a)
    q[0, 0] = 1.0 / scale ** 2
    k, _, poles = control.dlqr(a, b, q, lqr.duty_weight)
    np.testing.assert_allclose(lqr.state_gain(), k.ravel(), rtol=1e-6)
    # the step's laws close the same loop: its poles are the LQR's, to the gains' quantisation (the
    # delay line's multiple pole at 0 splits by about (2**-16)**(1/m) for an m-fold pole: left out)
    loop = control.feedback(-(lqr.plant() * lqr.laws()[1]), 1).poles()
    nonzero = np.sort_complex(loop[np.abs(loop) > 0.1])
    np.testing.assert_allclose(nonzero, np.sort_complex(poles[np.abs(poles) > 0.1]), atol=2e-3)
    assert lqr.is_stable() and lqr.preview == delay + 1


def test_lqr_tracks_a_delayed_motor_as_predicted_and_cancels_its_bias_and_friction():
    motor = Motor(25.0, 3.0, input_delay=2)
    lqr = LQRSpeed(PlantModel.from_source(motor, 0.005, 16667))
    assert lqr.preview == 3 and "ku3" in lqr.gains()
    rec = _run(lqr, "sine:10,10", motor=motor)
    assert _rms(tracking_error(rec)) == pytest.approx(lqr.predict(parse_reference("sine:10,10"), 4.0).tracking_rms,
                                                      rel=0.10)
    # the steady speed is the reference: kr and k0, kf are computed from the quantised feedback gains
    motor = Motor(25.0, 3.0, friction=40.0, bias=-20.0, input_delay=2)
    lqr = LQRSpeed(PlantModel.from_source(motor, 0.005, 16667))
    steady = tracking_error(_run(lqr, "constant:10", 2.0, motor))[200:]
    assert abs(np.mean(steady)) < 0.02
    position = LQRPosition(PlantModel.from_source(Motor(25.0, 3.0, bias=-20.0), 0.005, 16667))
    rec = _run(position, "constant:2", 2.0, Motor(25.0, 3.0, bias=-20.0))
    assert abs(np.mean(tracking_error(rec)[200:])) < 2 * 2 * math.pi / 16667   # two counts


def test_recording_keeps_reference_and_settings(tmp_path):
    rec = _run(PISpeed(MODEL, 0.04), "sine:10,10", duration=0.5)
    back = read_recording(write_recording(rec, tmp_path / "run.csv"))
    np.testing.assert_array_equal(back.reference, rec.reference)
    assert back.metadata["controller"] == "pi" and back.metadata["controller_time_constant"] == "0.04"
    assert back.metadata["reference"] == "sine:10.0,10.0,0.0" and back.metadata["reference_unit"] == "rad/s"
    assert back.metadata["controller_gains"].startswith("kp=")
    assert back.slice(0, 10).reference is not None and len(back.slice(0, 10).reference) == 10


def test_references_are_integer_exact():
    r = parse_reference("sine:10,20,0.5@3")
    scale = MODEL.speed_scale * 16
    words = [(int(round(20 * scale)), int(round(0.5 / (2 * math.pi) * 2**32)), phase_increment(10, 0.005))]
    np.testing.assert_array_equal(r.samples(500, 0.005, scale), multisine_duty(words, int(round(3 * scale)), 500))
    step = parse_reference("step:2,0.01,-1").samples(4, 0.005, 10.0)
    assert step.tolist() == [-10, -10, 20, 20]
    assert parse_reference("trapezoid:-10,0.02,0").samples(9, 0.005, 1.0).tolist() == [0, -3, -5, -8, -10,
                                                                                         -8, -5, -3, 0]


@pytest.mark.parametrize("spec, match", [
    ("sine:10", "FREQ,AMP"), ("ramp:1", "kind must be one of"), ("step:a", "comma-separated numbers"),
    ("trapezoid:1,0,1", "ramp_time must be > 0"), ("constant:1e9", "beyond the device's limit"),
])
def test_bad_references_are_refused_with_the_rule(spec, match):
    with pytest.raises(ValueError, match=match):
        ClosedLoopExperiment(OneStepMPC(MODEL), parse_reference(spec), duration=1.0)


def test_design_from_an_estimate_and_bad_settings():
    from identify import fit
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10), 0.005, 2.0))
    est = fit(rec)
    model = PlantModel.from_source(est, counts_per_rev=16667)
    assert model.sample_period == 0.005 and model.a == pytest.approx(25.0, rel=1e-4)
    with pytest.raises(ValueError, match="controller 'pi' takes"):
        design_controller("pi", model, duty_weight=1.0)
    with pytest.raises(ValueError, match="controller must be one of"):
        design_controller("lqg", model)
    with pytest.raises(ValueError, match="counts_per_rev must be given"):
        PlantModel.from_source(est)
    assert set(CONTROLLERS) == {"mpc", "pi", "position", "feedforward", "lqr", "lqr-integral", "lqr-position"}


def test_closed_loop_with_noise_drops_and_jitter_is_reproducible():
    def run(seed):
        return _run(OneStepMPC(MODEL), "sine:10,10", 1.0, encoder=Encoder(angle_noise=1e-3), jitter=0.1,
                    drop_rate=0.05, rng=np.random.default_rng(seed))
    a, b = run(4), run(4)
    np.testing.assert_array_equal(a.duty, b.duty)
    assert a.has_gaps and isinstance(a, Recording) and len(a.reference) == len(a)


@pytest.mark.parametrize("name", ["GAIN_BITS", "GAIN_ORDER", "gains_from_wire"])
def test_names_moved_to_fixed_point_still_import_from_control_with_a_warning(name):
    import motorsim.control
    import motorsim.fixed_point
    with pytest.warns(DeprecationWarning, match="motorsim.fixed_point"):
        old = getattr(motorsim.control, name)
    assert old is getattr(motorsim.fixed_point, name)
