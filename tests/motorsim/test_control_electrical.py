"""Control design on a model with an electrical time constant: designed on the first-order part, judged
on the full plant ``b / ((s + a)(tau_e s + 1))`` with its input delay.

The independent reference is python-control on the simulator's own plant: ``Motor.discretise``
(``control.sample_system`` of the three-state model, zero-order hold) for the angle, differenced and
delayed, then ``stability_margins``, ``feedback`` and ``forced_response`` on it.
"""
import math
import warnings

import control
import numpy as np
import pytest

from motorsim import Encoder, Motor, SimRig
from motorsim.control import (
    CONTROLLERS,
    MIN_PHASE_MARGIN,
    ClosedLoopExperiment,
    DesignLimitWarning,
    OneStepMPC,
    PISpeed,
    PlantModel,
    UnstableDesignError,
    design_controller,
    parse_reference,
)
from motorsim.control.pole_placement import ELECTRICAL_PHASE_COST
from motorsim.plant import simulate
from motorsim.robustness import analyse_robustness, draw_models, loop_margins

A, B, TAU = 25.0, 3.0, 0.004
FEEDBACK = [k for k in CONTROLLERS if k != "feedforward"]


def _model(h=0.001, tau=TAU, delay=1, **kw):
    return PlantModel(A, B, h, 16667, input_delay=delay, electrical_time_constant=tau, **kw)


def _reference_plant(controller, model=None):
    """Duty -> what the controller measures on ``model`` (default its own), by python-control from the Motor.

    ``control.sample_system`` of the three-state ``[angle, speed, current]`` model gives, row by row,
    ``angle' - angle`` from ``[speed, current]`` and the duty: the measured speed is that, one sample
    late (the counts are differenced backwards), in counts per sample; a position loop measures the angle.
    """
    m = controller.model if model is None else model
    h = m.sample_period
    motor = Motor(m.a, m.b, electrical_time_constant=m.electrical_time_constant)
    sysd = control.sample_system(motor.state_space(), h, method="zoh")
    delay = control.tf([1.0], [1.0, *([0.0] * m.input_delay)], h)
    if controller.quantity == "angle":
        return control.ss(sysd.A, sysd.B, sysd.C[:1], 0.0, h) * control.ss(delay) * m.angle_scale
    step = control.ss(sysd.A[1:, 1:], sysd.B[1:], sysd.A[:1, 1:], sysd.B[:1], h)
    return step * control.ss(control.tf([1.0], [1.0, 0.0], h) * delay) * (m.speed_scale / h)


def _margins(loop):
    """``(gain margin, phase margin, crossover)`` by python-control, on the loop's own frequency response
    (a dense grid to Nyquist, interpolated smoothly: ``stability_margins`` of an ``FRD``)."""
    omega = np.geomspace(1e-2, 0.99999 * math.pi / loop.dt, 20000)
    gm, pm, _, _, wc, _ = control.stability_margins(control.FRD(loop, omega, smooth=True))
    return gm, pm, wc


def _laws(controller):
    """The controller's ``(Cr, Cy)`` in state space (python-control then never forms a plant polynomial)."""
    return tuple(control.ss(law) for law in controller.laws())


def _design(kind, model, **settings):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignLimitWarning)
        return design_controller(kind, model, **settings)


def _quiet(cls, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignLimitWarning)
        return cls(*args, **kw)


@pytest.mark.parametrize("delay", [0, 2])
@pytest.mark.parametrize("h,tau", [(0.001, 0.004), (0.005, 0.004), (0.005, 0.0005)], ids=["1ms", "5ms", "fast"])
def test_the_full_plant_is_python_controls_sampled_motor(h, tau, delay):
    m = _model(h, tau, delay)
    motor = Motor(A, B, electrical_time_constant=tau)
    ss = control.sample_system(motor.state_space(), h, method="zoh")
    mine = m.speed_transfer_function()
    for w in np.geomspace(0.01 / h, 0.999 * math.pi / h, 40):
        z = np.exp(1j * w * h)
        # the angle's response from python-control's state space, differenced and delayed
        angle = (ss.C[0] @ np.linalg.solve(z * np.eye(3) - ss.A, ss.B))[0]
        ref = angle * (1 - 1 / z) * z ** -delay * m.speed_scale / h
        assert abs(mine(z) - ref) <= 1e-9 * abs(ref)      # exact: both are the ZOH of the same plant
    assert mine.poles() == pytest.approx(np.r_[np.exp(-A * h), np.exp(-h / tau), np.zeros(delay + 1)][
        np.argsort(-np.r_[np.exp(-A * h), np.exp(-h / tau), np.zeros(delay + 1)])], abs=1e-7)


def test_a_first_order_model_is_unchanged_and_says_nothing_of_a_lag():
    m = PlantModel(A, B, 0.005, 16667, input_delay=1)
    assert m.first_order() is m and "model_electrical_time_constant" not in m.metadata()
    lag = _model(0.005, 1e-12)                      # a lag far below the sample: the first-order model
    w = np.geomspace(0.1, 600.0, 30)
    z = np.exp(1j * w * 0.005)
    assert lag.speed_transfer_function()(z) == pytest.approx(m.speed_transfer_function()(z), rel=1e-8)
    assert _model().metadata()["model_electrical_time_constant"] == "0.004"


@pytest.mark.parametrize("kind", FEEDBACK)
def test_margins_verdict_and_prediction_are_python_controls_on_the_full_plant(kind):
    controller = _design(kind, _model())
    _, cy = _laws(controller)
    loop = -(_reference_plant(controller) * cy)
    gm, pm, wc = _margins(loop)
    mine = controller.margins()
    # python-control interpolates its frequency grid (its "poly" method loses digits here, 1e-2 deg on
    # pi): the two agree to ~3e-8 deg, 2e-9 in the gain margin; poles and responses below are exact
    assert mine.phase_margin == pytest.approx(pm, abs=1e-6)
    assert mine.crossover == pytest.approx(wc, rel=1e-7)
    assert mine.gain_margin == pytest.approx(gm, rel=1e-8)
    poles = control.feedback(loop, 1).poles()
    assert controller.is_stable() == bool(np.all(np.abs(poles) < 1)) is True
    # the predicted response: python-control's feedback and forced_response on the same plant
    cr, cy = _laws(controller)
    p = _reference_plant(controller)
    t_y = p * control.feedback(control.ss([], [], [], 1.0, p.dt), p * cy, sign=1) * cr
    ref = parse_reference("sine:10,5" if controller.quantity == "speed" else "sine:10,1")
    pred = controller.predict(ref, 0.5)
    n = len(pred.time)
    r = ref.samples(n + controller.preview, p.dt, controller.reference_scale).astype(float)
    y = control.forced_response(t_y, timepts=pred.time, inputs=r[controller.preview:controller.preview + n]).outputs
    scale = controller.model.angle_scale if controller.quantity == "angle" else controller.model.speed_scale
    assert np.max(np.abs(pred.output - y / scale)) <= 1e-9 * np.max(np.abs(pred.output))


def test_a_first_order_verdict_is_replaced_by_the_full_models():
    """PI at 10 ms on a 4 ms lag sampled at 1 ms: the first-order part reports about 61 deg, the motor has 31."""
    model = _model(0.001, TAU, 1)
    with pytest.warns(DesignLimitWarning, match=r"electrical time constant 0.004 s costs the pi design"):
        pi = PISpeed(model, 0.01, min_phase_margin=0.0)
    _, cy = _laws(pi)
    _, pm_part, _ = _margins(-(_reference_plant(pi, pi.model.first_order()) * cy))
    _, pm_full, _ = _margins(-(_reference_plant(pi) * cy))
    assert pi.first_order_margins().phase_margin == pytest.approx(pm_part, abs=1e-6)
    assert pi.margins().phase_margin == pytest.approx(pm_full, abs=1e-6)
    assert pm_part > MIN_PHASE_MARGIN > pm_full + ELECTRICAL_PHASE_COST    # what dropping tau_e would hide
    assert loop_margins(pi).phase_margin == pi.margins().phase_margin


def _first(controller):
    """The controller on its model's first-order part (same gains: the design only reads that part)."""
    import dataclasses
    return dataclasses.replace(controller, model=controller.model.first_order())


@pytest.mark.parametrize("kind,settings", [("mpc", {"duty_weight": 1e-6}), ("pi", {"time_constant": 0.01,
                                                                                     "min_phase_margin": 0.0})],
                         ids=["mpc", "pi"])
def test_a_design_unstable_on_the_full_model_is_refused_though_its_first_order_part_is_stable(kind, settings):
    model = _model(0.005, TAU, 1)
    first = design_controller(kind, model.first_order(), **settings)
    _, cy = _laws(first)
    part_poles = control.feedback(-(first.plant() * cy), 1).poles()
    assert np.all(np.abs(part_poles) < 1)                                 # the first-order verdict: stable
    full_poles = control.feedback(-(_reference_plant(first, model) * cy), 1).poles()
    assert np.max(np.abs(full_poles)) > 1                                 # python-control: unstable on the motor
    with pytest.raises(UnstableDesignError, match=r"unstable loop on the full model with its electrical time constant "
                                             r"0.004 s: (raise duty_weight|lengthen time_constant)"):
        design_controller(kind, model, **settings)


@pytest.mark.parametrize("time_constant,delay", [(0.003, 1), (0.01, 0)], ids=["3ms-delay1", "10ms-delay0"])
def test_pi_keeps_the_phase_margin_on_the_full_model_with_the_shortest_time_constant(time_constant, delay):
    model = _model(0.001, TAU, delay)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pi = PISpeed(model, time_constant)
    _, cy = _laws(pi)
    _, pm, _ = _margins(-(_reference_plant(pi) * cy))
    assert pm >= MIN_PHASE_MARGIN
    assert [w.category for w in caught] == [DesignLimitWarning]        # one warning, not one per candidate
    assert pi.time_constant > time_constant and "electrical time constant 0.004 s" in str(caught[0].message)
    # the time constant a first-order design keeps 60 deg with leaves less on the motor
    part = _quiet(PISpeed, model.first_order(), time_constant)
    assert part.time_constant < pi.time_constant
    _, cy = _laws(_quiet(PISpeed, model, part.time_constant, min_phase_margin=0.0))
    _, pm_short, _ = _margins(-(_reference_plant(pi) * cy))
    assert pm_short < MIN_PHASE_MARGIN
    # and the time constant chosen is the shortest (3 digits) that keeps it on the full model
    step = 10.0 ** (math.floor(math.log10(pi.time_constant)) - 2)
    try:
        shorter = _quiet(PISpeed, model, pi.time_constant - step, min_phase_margin=0.0).margins()
        assert not (shorter.stable and shorter.phase_margin >= MIN_PHASE_MARGIN)
    except UnstableDesignError:
        pass


def test_estimate_of_the_second_order_structure_carries_its_lag_into_the_design():
    from identify import Estimate
    est = Estimate("oe-electrical", A, B, 1000, 0.001, 1e-3, 99.0, np.diag([0.01, 1e-4, 1e-8, 1e-4]),
                   ("a", "b", "electrical_time_constant", "bias"), {"electrical_time_constant": TAU, "bias": 0.2},
                   input_delay=2, structure="second-order")
    model = PlantModel.from_source(est, counts_per_rev=16667)
    assert model == _model(0.001, TAU, 2, bias=0.2)
    assert PlantModel.from_source(est, 0.002, 16667).input_delay == 1     # the delay is a time: 2 ms at 2 ms
    assert PlantModel.from_source(est.motor(), 0.001, 16667) == model    # the structure's plant, the simulator's


def test_robustness_draws_keep_the_lag_and_close_every_loop_on_the_full_plant():
    model = _model(0.001, TAU, 1)
    draws = draw_models(model, [[0.25, 0.0], [0.0, 0.0025]], 20, np.random.default_rng(1))
    assert {m.electrical_time_constant for m in draws} == {TAU}
    pi = PISpeed(model)
    r = analyse_robustness(pi, None, parse_reference("sine:10,5"), 0.5, models=draws, rng=np.random.default_rng(0))
    assert r.point == pi.margins() and r.point != pi.first_order_margins()
    assert r.worst_phase_margin == pytest.approx(min(loop_margins(pi, m).phase_margin for m in draws), abs=0)
    assert "electrical time constant 0.004 s kept" in r.method


@pytest.mark.parametrize("kind", list(CONTROLLERS))
def test_simrig_runs_every_controller_on_a_second_order_motor_exactly(kind):
    """Each interval of the closed loop is the simulator's exact plant: the run equals ``simulate`` of its duty."""
    motor = Motor(A, B, bias=0.4, input_delay=1, electrical_time_constant=TAU)
    controller = _design(kind, PlantModel.from_source(motor, 0.001, 16667))
    assert controller.model.electrical_time_constant == TAU
    ref = parse_reference("sine:10,5" if controller.quantity == "speed" else "sine:10,1")
    rec = SimRig(motor, Encoder(), record_speed=True).run(ClosedLoopExperiment(controller, ref, 1.0))
    traj = simulate(motor, rec.duty.astype(float), rec.time)
    assert np.max(np.abs(rec.speed - traj.speed)) <= 1e-12 * np.max(np.abs(traj.speed))
    # rounding of counts agrees except where the two sums of ~1e-16 differ across a count boundary
    counts = np.floor(traj.angle * 16667 / (2 * math.pi)).astype(int)
    assert np.max(np.abs(counts - rec.counts)) <= 1
    assert rec.metadata["true_electrical_time_constant"] == "0.004"
    assert rec.metadata["model_electrical_time_constant"] == "0.004"


def test_the_prediction_on_the_full_model_is_what_simrig_measures():
    """Closed loop on the lag motor: the full model predicts the tracking the rig measures; dropping tau_e does not."""
    motor = Motor(A, B, input_delay=1, electrical_time_constant=TAU)
    model = PlantModel.from_source(motor, 0.001, 2**20)
    mpc = _quiet(OneStepMPC, model, duty_weight=1e-5)
    ref = parse_reference("sine:20,5")
    rec = SimRig(motor, Encoder(counts_per_rev=2**20)).run(ClosedLoopExperiment(mpc, ref, 1.0))
    measured = rec.measured_speed()[1:]
    full = mpc.predict(ref, 1.0).output[1:]
    part = _first(mpc).predict(ref, 1.0).output[1:]
    # duty rounding to integers is the only difference from the full model: a small fraction of the part's miss
    assert np.sqrt(np.mean((measured - full) ** 2)) < 0.2 * np.sqrt(np.mean((measured - part) ** 2))
