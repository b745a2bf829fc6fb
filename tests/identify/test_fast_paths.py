"""Every fast path that runs a plant, against the exact path, on every registered structure.

A fast path (the batch engine of the sweeps, the controller's model, ...) either runs a structure's
plant exactly or refuses it: it never drops a part of it.  Each test goes over
``identify.structures()``, so a structure registered later is checked too (it needs its example
values in ``VALUES``; a missing one fails naming it).
"""
import dataclasses

import numpy as np
import pytest

import identify
from identify import Estimate
from motorsim import Motor, Sine, simulate
from motorsim.batch import is_batchable, simulate_batch
from motorsim.checks import ParameterError
from motorsim.control import PlantModel

#: A value of every parameter of the registered structures: each part set well away from its neutral value.
VALUES = {"a": 25.0, "b": 3.0, "b_forward": 3.3, "b_reverse": 2.7, "drive_limit": 150.0, "current_limit": 400.0,
          "emf_share": 0.8, "bias": 4.0,
          "friction": 30.0, "dead_zone": 12.0, "static_friction": 45.0, "electrical_time_constant": 0.004,
          "inertia_ratio": 1.5, "shaft_frequency": 150.0, "shaft_damping": 0.1}
DT, DELAY = 0.002, 2
#: Noise-free comparisons of the same model computed two ways: 1e-9 relative (observed ~1e-13).
RTOL = 1e-9


def _values(s, alone=None):
    """Example values of structure ``s``: every part set, or (``alone``) that one alone, the others at 0 where
    0 is a value of theirs (none: an electrical time constant is > 0)."""
    missing = [n for n in s.param_names if n not in VALUES]
    assert not missing, f"give the structure {s.name!r} example values for {missing} in VALUES"
    return {p.name: VALUES[p.name] if alone is None or p.name in ("a", "b", alone) or not _takes_zero(p) else 0.0
            for p in s.parameters}


def _takes_zero(p):
    try:
        return p.check(0.0) == 0.0
    except ParameterError:
        return False


def _estimate(s, delay=DELAY):
    v = _values(s)
    return Estimate(method=s.method, structure=s.name, a=v["a"], b=v["b"], n_samples=1000, sample_period=DT,
                    residual_rms=0.0, fit_percent=100.0, param_names=s.param_names,
                    extra={k: x for k, x in v.items() if k not in ("a", "b")}, input_delay=delay)


STRUCTURES = list(identify.structures().values())
IDS = [s.name for s in STRUCTURES]
#: Each structure the simulator carries with every part set, and with each of its parts beyond a and b alone (one
#: it does not carry, a gain per direction, refuses every fast path: ``test_a_structure_the_simulator_cannot_...``).
PARTS = [(s, alone) for s in STRUCTURES if s.simulated for alone in (None, *s.param_names[2:])]
PART_IDS = [f"{s.name}-{alone or 'all'}" for s, alone in PARTS]


@pytest.mark.parametrize("s, alone", PARTS, ids=PART_IDS)
def test_the_batch_engine_runs_a_structure_exactly_or_refuses_it(s, alone):
    plant = s.plant(_values(s, alone), DELAY)
    n = 1500
    duty = np.stack([Sine(f, 200).duty(n, DT) for f in (7.0, 19.0)]).astype(float)
    if not is_batchable(plant):
        with pytest.raises(ParameterError, match="batch engine"):
            simulate_batch(plant, duty, DT)
        return
    angle, speed = simulate_batch(plant, duty, DT)
    for r in range(len(duty)):
        ref = simulate(plant, duty[r], np.arange(n) * DT)
        np.testing.assert_allclose(angle[r], ref.angle, rtol=0, atol=RTOL * np.max(np.abs(ref.angle)))
        np.testing.assert_allclose(speed[r], ref.speed, rtol=0, atol=RTOL * np.max(np.abs(ref.speed)))


@pytest.mark.parametrize("s", [s for s in STRUCTURES if not s.simulated], ids=lambda s: s.name)
def test_a_structure_the_simulator_cannot_run_is_refused_by_every_fast_path_by_name(s):
    # a gain per direction has no single-gain plant, a drive limit no plant without one: the batch engine, the
    # controller's model, the per-sample step and the python-control system refuse them, naming both gains or the
    # limit, rather than drop a part
    est = _estimate(s)
    for run in (lambda: s.plant(_values(s), DELAY), lambda: s.stepper(_values(s), np.full(3, DT)), est.motor,
                est.io_system, lambda: PlantModel.from_source(est, counts_per_rev=4096)):
        with pytest.raises(ParameterError, match="one gain.*b_forward 3.3 and b_reverse 2.7|no drive limit.*150|"
                                                  "no current limit.*400"):
            run()


def test_only_the_first_order_motor_is_batchable_among_the_registered_structures():
    # the engine's own claim, measured on the registry: what it runs is the linear structure
    batchable = [f"{s.name}-{alone or 'all'}" for s, alone in PARTS if is_batchable(s.plant(_values(s, alone), DELAY))]
    assert batchable == ["linear-all", "dead-zone-dead_zone"]


@pytest.mark.parametrize("s", [s for s in STRUCTURES if s.simulated], ids=lambda s: s.name)
def test_a_controller_model_keeps_every_part_of_the_estimate_it_is_designed_from(s):
    # A dead zone or a static friction was dropped here while Estimate.motor() kept it.
    est = _estimate(s)
    model = PlantModel.from_source(est, counts_per_rev=4096)
    assert model.motor() == est.motor()
    # at another sample period only the delay's count changes (a time: 2 samples at 2 ms, 4 at 1 ms)
    finer = PlantModel.from_source(est, sample_period=DT / 2, counts_per_rev=4096)
    assert finer.motor() == dataclasses.replace(est.motor(), input_delay=2 * DELAY)
    assert PlantModel.from_source(finer).motor() == finer.motor()


def test_a_controller_model_carries_every_part_the_simulator_has():
    # a part the simulator gains must be carried by the controller's model too, not left behind silently
    from motorsim.control.model import _PLANT_PARTS
    assert set(_PLANT_PARTS) == {f.name for f in dataclasses.fields(Motor)} - {"a", "b"}


def test_a_controller_designed_from_a_dead_zone_estimate_says_it_in_its_metadata():
    est = _estimate(identify.structure("dead-zone"), delay=0)
    from motorsim.control import design_controller
    meta = design_controller("mpc", PlantModel.from_source(est, counts_per_rev=4096), duty_weight=1e-3).metadata()
    assert float(meta["model_dead_zone"]) == VALUES["dead_zone"]
    assert "model_static_friction" not in meta            # said only when set, as before


@pytest.mark.parametrize("s, alone", PARTS, ids=PART_IDS)
def test_the_estimates_python_control_system_is_the_exact_simulation(s, alone):
    # io_system steps the plant one sample at a time: it must carry every state, the lag's current
    # included (a step that restarted the current from 0 read the second-order model wrongly)
    import control
    v = _values(s, alone)
    est = _estimate(s)
    est = dataclasses.replace(est, a=v["a"], b=v["b"], extra={k: x for k, x in v.items() if k not in ("a", "b")})
    n = 300
    t = np.arange(n) * DT
    duty = Sine(11.0, 150).duty(n, DT).astype(float)
    res = control.input_output_response(est.io_system(), t, duty)
    ref = simulate(est.motor(), duty, t)
    np.testing.assert_allclose(res.outputs[0], ref.speed, rtol=0, atol=RTOL * np.max(np.abs(ref.speed)))
    np.testing.assert_allclose(res.outputs[1], ref.angle, rtol=0, atol=RTOL * np.max(np.abs(ref.angle)))


@pytest.mark.parametrize("s", STRUCTURES, ids=IDS)
@pytest.mark.parametrize("output", ["speed", "angle"])
def test_a_structures_closed_form_frequency_response_is_its_exact_discretisation(s, output):
    # the closed form (the Bode views, the frequency-domain fit) against python-control's ZOH sampling of
    # the structure's continuous system: the sampled speed, or the mean speed over the interval (the
    # angle's increment over h); 1e-9 relative (observed ~1e-14)
    import control
    v = _values(s)
    omega = np.geomspace(0.5, 0.9 * np.pi / DT, 40)
    ours = s.frequency_response(v, DT, omega, output=output, input_delay=DELAY)
    sysd = s.discretise(v, DT)
    z = np.exp(1j * omega * DT)
    angle, speed = (np.array([complex(control.evalfr(sysd[i, 0], zk)) for zk in z]) for i in (0, 1))
    exact = (speed if output == "speed" else angle * (z - 1) / DT) * z ** (-DELAY)
    np.testing.assert_allclose(ours, exact, rtol=1e-9)


@pytest.mark.parametrize("s", STRUCTURES, ids=IDS)
def test_a_structures_continuous_system_is_its_transfer_function(s):
    import control
    v = _values(s)
    speed = control.ss2tf(s.state_space(v)[1, 0])
    num, den = s.linear_part(v)
    ours = control.tf(num, den)
    w = np.geomspace(0.1, 1e4, 30)
    np.testing.assert_allclose(speed(1j * w), ours(1j * w), rtol=1e-9)


@pytest.mark.parametrize("s, alone", PARTS, ids=PART_IDS)
def test_a_structures_step_is_its_simulation(s, alone):
    # one exact step at a time (what SimRig's closed loops and fake:// run) against the simulator's run
    v = _values(s, alone)
    n = 400
    t = np.arange(n) * DT
    duty = Sine(13.0, 140).duty(n, DT).astype(float)
    ref = s.response(v, duty, t, initial_speed=2.0)
    stepper, state, speed = s.stepper(v, np.diff(t)), s.plant(v).initial_state(0.0, 2.0), [2.0]
    for k in range(n - 1):
        state = stepper.step(k, state, duty[k])
        speed.append(state[1])
    np.testing.assert_allclose(speed, ref.speed, rtol=0, atol=RTOL * np.max(np.abs(ref.speed)))
