"""A linear structure's plant from its continuous system alone (motorsim.linear_plant): every derived
response checked against the first-order motor's own closed forms, on a LinearPlant that writes
only ``b/(s + a)``'s matrices.  Noise-free, so to ~1e-12 relative (rounding of a matrix exponential
and of the filters over a few thousand samples)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from identify.fits.zoh_response import zoh_speed_response
from motorsim.batch import unbatchable_parts
from motorsim.checks import ParameterError
from motorsim.linear_plant import LinearPlant
from motorsim.plant import Motor, simulate


@dataclasses.dataclass(frozen=True)
class _FirstOrder(LinearPlant):
    a: float
    b: float
    input_delay: int = 0

    def matrices(self):
        return np.array([[0.0, 1.0], [0.0, -self.a]]), np.array([0.0, self.b])


@dataclasses.dataclass(frozen=True)
class _SpringToGround(_FirstOrder):
    def matrices(self):
        return np.array([[0.0, 1.0], [-4.0, -self.a]]), np.array([0.0, self.b])


PLANT, MOTOR = _FirstOrder(25.0, 3.0, input_delay=2), Motor(25.0, 3.0, input_delay=2)
T = np.arange(3000) * 0.002
U = np.round(100 * np.sin(7 * T) + 50 * np.sign(np.sin(31 * T)))


def _close(x, y, rtol=1e-11):
    assert np.max(np.abs(np.asarray(x) - np.asarray(y))) <= rtol * np.max(np.abs(y))


def test_the_run_is_the_motors_on_a_uniform_clock():
    r1, r2 = simulate(PLANT, U, T, initial_speed=1.5, initial_angle=0.3), simulate(MOTOR, U, T, initial_speed=1.5,
                                                                                     initial_angle=0.3)
    _close(r1.angle, r2.angle)
    _close(r1.speed, r2.speed)


def test_the_run_is_the_motors_on_a_jittered_clock():
    t = T + np.random.default_rng(0).uniform(-2e-4, 2e-4, len(T))
    r1, r2 = simulate(PLANT, U, t), simulate(MOTOR, U, t)
    _close(r1.angle, r2.angle)
    _close(r1.speed, r2.speed)


def test_one_step_at_a_time_is_the_motors_step():
    s1, s2 = PLANT.stepper(0.002), MOTOR.stepper(0.002)
    x1, x2 = PLANT.initial_state(0.1, 2.0), MOTOR.initial_state(0.1, 2.0)
    for k in range(50):
        x1, x2 = s1.step(0, x1, float(U[k]), 1.5), s2.step(0, x2, float(U[k]), 1.5)
    _close(x1[:2], x2[:2])


def test_the_averaged_speed_model_and_the_frequency_response_are_the_closed_forms():
    for n1, n2 in zip(PLANT.speed_polynomials(0.002, 13.0), MOTOR.speed_polynomials(0.002, 13.0)):
        _close(n1, n2)
    w = np.array([0.5, 40.0, 700.0])
    for output in ("angle", "speed"):
        _close(PLANT.frequency_response(0.002, w, output=output, input_delay=1),
               zoh_speed_response(25.0, 3.0, 0.002, w, output=output, input_delay=1))


def test_the_segment_columns_rebuild_the_run_from_its_initial_state():
    forced, free = PLANT.replace(input_delay=0).columns(T, U, "angle")
    run = simulate(MOTOR.replace(input_delay=0), U, T, initial_speed=2.0, initial_angle=0.5)
    _close(forced + free @ [2.0, 0.5], run.angle)


def test_a_plant_whose_state_depends_on_its_angle_is_refused_naming_the_rule():
    with pytest.raises(ParameterError, match="nothing may depend on it"):
        simulate(_SpringToGround(25.0, 3.0), U, T)


def test_the_batch_engine_refuses_another_structure_by_name():
    assert unbatchable_parts(PLANT) == ["_FirstOrder"]
