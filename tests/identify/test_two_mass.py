"""The two-mass structure (identify/model_structures/two_mass.py): simulated, fitted, run on fake://,
designed for and drawn from, through the generic extension points only.

Tolerances: noise-free simulation against python-control's own discretisation and forced response,
1e-9 relative (rounding of two different matrix exponentials and recursions over 1500 samples);
the fit on 1e-4 rad of angle noise, within 4 of its own standard errors (fixed seed)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import identify
from identify.model_structures.two_mass import TwoMassPlant
from motorsim import Encoder, Experiment, Multisine, SimRig
from motorsim.batch import simulate_batch
from motorsim.checks import ParameterError
from motorsim.control import PlantModel, design_controller
from motorsim.plant import Motor, simulate
from motorsim.robustness import draw_models

TRUE = {"a": 25.0, "b": 3.0, "inertia_ratio": 1.5, "shaft_frequency": 150.0, "shaft_damping": 0.1}
EXPERIMENT = Experiment(Multisine((3.0, 30.0, 110.0, 250.0), (60, 50, 40, 30), (0, 1, 2, 3)), 0.001, 1.5)


@pytest.mark.parametrize("encoder", ["motor", "load"])
def test_the_simulation_is_python_controls_own(encoder):
    import control
    plant = TwoMassPlant(**TRUE, encoder=encoder)
    t = np.arange(1500) * 0.001
    u = np.round(100 * np.sin(7 * t) + 60 * np.sin(140 * t))
    ours = simulate(plant, u, t, initial_speed=2.0)
    theirs = control.forced_response(control.sample_system(plant.state_space(), 0.001, method="zoh"), t, u,
                                     X0=[0.0, 2.0, 2.0, 0.0])
    for mine, ref in ((ours.angle, theirs.outputs[0]), (ours.speed, theirs.outputs[1])):
        assert np.max(np.abs(mine - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_a_stiff_shaft_is_the_rigid_motor():
    t = np.arange(500) * 0.001
    u = np.round(100 * np.sin(7 * t))
    stiff = simulate(TwoMassPlant(25.0, 3.0, 1.5, 5e4, 1.0), u, t)
    rigid = simulate(Motor(25.0, 3.0), u, t)
    assert np.max(np.abs(stiff.speed - rigid.speed)) <= 1e-3 * np.max(np.abs(rigid.speed))


def test_the_default_does_not_consider_it_and_the_estimator_is_listed_from_the_registry():
    assert "two-mass" in identify.structures() and "two-mass" not in identify.structures(in_default=True)
    assert {"oe-two-mass", "oe-two-mass-load"} <= set(identify.available_methods())
    assert "oe-two-mass" not in identify.available_methods(open_loop=True, first_order=True)


@pytest.fixture(scope="module")
def recording():
    return SimRig(TwoMassPlant(**TRUE), Encoder(4000, angle_noise=1e-4), rng=np.random.default_rng(3)).run(EXPERIMENT)


@pytest.fixture(scope="module")
def fitted(recording):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify.fit(recording, "oe-two-mass", input_delay=0)


@pytest.mark.slow
def test_the_fit_recovers_the_plant_within_its_errors(fitted):
    assert fitted.structure == "two-mass" and fitted.method == "oe-two-mass"
    se = np.sqrt(np.diag(fitted.covariance))
    for (name, value), s in zip(zip(fitted.param_names, (fitted.values()[n] for n in fitted.param_names)), se):
        assert abs(value - TRUE[name]) <= 4 * s, (name, value, s)


def test_fake_device_runs_it_as_the_simulated_bench_does():
    from hardware import protocol as P
    from hardware.fake_device import FakeDevice, FakeLockstepPort
    from hardware.serial_rig import SerialRig
    plant = TwoMassPlant(**TRUE)
    exp = Experiment(Multisine((3.0, 30.0), (60, 50), (0, 1)), 0.005, 0.5)
    device = FakeDevice(plant, Encoder(), speed=0.0, rng=np.random.default_rng(1))
    port = FakeLockstepPort(device, "fake://two-mass", 5.0)
    try:
        rec = SerialRig(port).run(exp)
    finally:
        port.close()
    sim = SimRig(plant.replace(input_delay=P.DEVICE_INPUT_DELAY)).run(exp)
    assert np.array_equal(rec.duty, sim.duty) and np.max(np.abs(rec.counts - sim.counts)) <= 1


def test_a_controller_is_designed_on_the_rigid_part_and_judged_on_the_whole_plant():
    model = PlantModel(plant=TwoMassPlant(**TRUE, input_delay=1), sample_period=0.001, counts_per_rev=4000)
    rigid = PlantModel(25.0, 3.0, 0.001, 4000, input_delay=1)
    assert model.speed_coefficients() == rigid.speed_coefficients()
    # the shaft's pair of poles besides the rigid motor's
    assert len(model.speed_transfer_function().poles()) == len(rigid.speed_transfer_function().poles()) + 2
    pi = design_controller("pi", model, time_constant=0.05)
    assert pi.margins().phase_margin != design_controller("pi", rigid, time_constant=0.05).margins().phase_margin


def test_robustness_draws_from_its_covariance_over_its_own_values():
    model = PlantModel(plant=TwoMassPlant(**TRUE), sample_period=0.001, counts_per_rev=4000)
    cov = np.diag([0.1, 0.001, 0.01, 4.0, 1e-4])
    draws = draw_models(model, cov, 200, np.random.default_rng(0), names=tuple(TRUE))
    assert len(draws) + draws.n_rejected == 200 and len(draws) > 190
    freqs = np.array([d.plant.values()["shaft_frequency"] for d in draws])
    assert abs(np.std(freqs) - 2.0) < 0.3 and all(isinstance(d.plant, TwoMassPlant) for d in draws)


def test_the_batch_engine_refuses_it_by_name():
    with pytest.raises(ParameterError, match="TwoMassPlant"):
        simulate_batch(TwoMassPlant(**TRUE), np.zeros((2, 10)), 0.001)


@pytest.mark.slow
def test_the_command_line_gives_the_python_answer(fitted, recording, tmp_path, capsys):
    import json

    from motorid.cli import main
    from motorsim.writing import write_recording
    write_recording(recording, tmp_path / "run.csv")
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["identify", str(tmp_path / "run.csv"), "--method", "oe-two-mass", "--input-delay", "0",
                     "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["input_delay"] == fitted.input_delay
    assert {n: data[n] for n in fitted.param_names} == fitted.values()


def test_a_load_far_lighter_than_the_motor_is_the_rigid_motor_not_a_division_by_zero():
    # 1 - 1/(1 + r) is 0 in floating point for r under 1e-16; the fit's bound reaches 1e-300
    t = np.arange(500) * 0.001
    u = np.round(100 * np.sin(7 * t))
    light = simulate(TwoMassPlant(25.0, 3.0, 1e-20, 150.0, 0.1), u, t)
    rigid = simulate(Motor(25.0, 3.0), u, t)
    assert np.max(np.abs(light.speed - rigid.speed)) <= 1e-9 * np.max(np.abs(rigid.speed))


def test_a_fit_that_ends_on_a_bound_is_not_identifiable_and_names_the_parameter():
    # a rigid motor on a 100-count encoder: the best two-mass fit asks for a damping below 0 and stops on its
    # bound, where the covariance's central differences stepped outside the range (a ParameterError from deep
    # inside the plant); the estimators' error for data that do not determine a structure is NotIdentifiableError
    from identify import NotIdentifiableError
    rigid = SimRig(Motor(25.0, 3.0), Encoder(100), rng=np.random.default_rng(3)).run(EXPERIMENT)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NotIdentifiableError, match=r"shaft_damping = .* \(its bound 0\)"):
            identify.fit(rigid, "oe-two-mass", input_delay=0)
