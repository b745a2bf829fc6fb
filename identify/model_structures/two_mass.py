"""The two-mass motor: the motor's and the load's inertia joined by a shaft with stiffness and damping.

Per unit of the total inertia ``J = J_m + J_l``, with ``mu_m = J_m / J`` and ``mu_l = J_l / J``
(``inertia_ratio = J_l / J_m``), the twist ``delta = theta_m - theta_l`` and the shaft's torque
``kappa delta + gamma delta'``::

    mu_m omega_m' = b u - a omega_m - kappa delta - gamma (omega_m - omega_l)
    mu_l omega_l' = kappa delta + gamma (omega_m - omega_l)

with ``kappa = w_s^2 mu_m mu_l`` and ``gamma = 2 zeta w_s mu_m mu_l``: ``w_s`` (``shaft_frequency``,
rad/s) is the shaft's free resonance, ``zeta`` (``shaft_damping``) its damping ratio.  The sum is the
rigid motor, ``omega' = b u - a omega``: ``a`` and ``b`` keep their meaning, and a controller is
designed on them (the first-order part) and judged on the whole plant.  The encoder is on the
motor (``two-mass``) or on the load (``two-mass-load``).  Linear: the plant gives every response
from its continuous system (:class:`motorsim.linear_plant.LinearPlant`), the generic output-error
fit estimates it (:func:`identify.estimators.linear_estimator`).  The default does not consider
it (``in_default`` False): it is fitted when asked for by name.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Mapping

import numpy as np

from motorsim.checks import ParameterError, check_int, check_real
from motorsim.linear_plant import LinearPlant

from ..estimators import linear_estimator
from .base import ModelStructure, Parameter
from .first_order import GAIN, POLE

__all__ = ["TwoMassPlant", "TwoMass", "TwoMassLoad"]


@dataclasses.dataclass(frozen=True)
class TwoMassPlant(LinearPlant):
    """The two-mass plant (module docstring); ``encoder`` ``"motor"`` or ``"load"``: the side measured."""

    a: float
    b: float
    inertia_ratio: float
    shaft_frequency: float
    shaft_damping: float
    input_delay: int = 0
    encoder: str = "motor"

    def __post_init__(self):
        object.__setattr__(self, "a", check_real("a", self.a, positive=True))
        b = check_real("b", self.b)
        if b == 0:
            raise ParameterError(f"b must be nonzero, got {self.b!r}")
        object.__setattr__(self, "b", b)
        for name in ("inertia_ratio", "shaft_frequency"):
            object.__setattr__(self, name, check_real(name, getattr(self, name), positive=True))
        object.__setattr__(self, "shaft_damping", check_real("shaft_damping", self.shaft_damping, nonnegative=True))
        object.__setattr__(self, "input_delay", check_int("input_delay", self.input_delay, 0, 10**6))
        if self.encoder not in ("motor", "load"):
            raise ParameterError(f"encoder must be 'motor' or 'load', got {self.encoder!r}")

    def values(self) -> dict[str, float]:
        return {n: float(getattr(self, n)) for n in ("a", "b", "inertia_ratio", "shaft_frequency", "shaft_damping")}

    def initial_state(self, angle: float = 0.0, speed: float = 0.0) -> tuple[float, ...]:
        """Turning as one body: both inertias at ``speed``, the shaft untwisted."""
        return (float(angle), float(speed), float(speed), 0.0)

    def state_names(self) -> tuple[str, ...]:
        other = "load_speed" if self.encoder == "motor" else "motor_speed"
        return ("angle", "speed", other, "twist")

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        mu_m = 1.0 / (1.0 + self.inertia_ratio)
        mu_l = self.inertia_ratio / (1.0 + self.inertia_ratio)    # not 1 - mu_m: 0 for a ratio under 1e-16
        kappa = self.shaft_frequency ** 2 * mu_m * mu_l
        gamma = 2.0 * self.shaft_damping * self.shaft_frequency * mu_m * mu_l
        # rows and columns: motor angle, motor speed, load speed, twist
        A = np.array([[0.0, 1.0, 0.0, 0.0],
                      [0.0, -(self.a + gamma) / mu_m, gamma / mu_m, -kappa / mu_m],
                      [0.0, gamma / mu_l, -gamma / mu_l, kappa / mu_l],
                      [0.0, 1.0, -1.0, 0.0]])
        B = np.array([0.0, self.b / mu_m, 0.0, 0.0])
        if self.encoder == "load":       # the load's angle measured: its speed second, the motor's third
            order = [0, 2, 1, 3]
            A = A[np.ix_(order, order)]
            A[:, 0] = 0.0
            A[0] = [0.0, 1.0, 0.0, 0.0]
            B = B[order]
        return A, B


_RATIO = Parameter("inertia_ratio", "", 0.0, math.inf, "the load's inertia over the motor's, J_l/J_m", strict=True,
                   starts=(0.5, 2.0))
_FREQUENCY = Parameter("shaft_frequency", "rad/s", 0.0, math.inf, "the shaft's free resonance w_s", strict=True)
_DAMPING = Parameter("shaft_damping", "", 0.0, math.inf, "the shaft's damping ratio zeta", starts=(0.1,))


class TwoMass(ModelStructure):
    """Motor and load inertia joined by a shaft; the encoder on the motor."""

    name = "two-mass"
    description = "the motor's and the load's inertia joined by a shaft (stiffness, damping); encoder on the motor"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, _RATIO, _FREQUENCY, _DAMPING)
    fixed: Mapping[str, float] = {}
    estimator = linear_estimator("oe-two-mass", "two-mass")
    in_default = False
    rank = 2
    formula = "the two-mass system (motor, shaft, load)"
    response_parameters: tuple[str, ...] = ("a", "b", "inertia_ratio", "shaft_frequency", "shaft_damping")
    encoder = "motor"

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> TwoMassPlant:
        return TwoMassPlant(**self.values(values), input_delay=input_delay, encoder=self.encoder)

    def starts(self, recordings, guess: tuple[float, float]) -> list[dict[str, float]]:
        """The base's starts with the shaft's resonance at a tenth and at a third of the Nyquist frequency."""
        nyquist = math.pi / recordings[0].sample_period
        return [{**s, "shaft_frequency": f * nyquist} for s in super().starts(recordings, guess)
                for f in (0.1, 0.3)]


class TwoMassLoad(TwoMass):
    """Motor and load inertia joined by a shaft; the encoder on the load."""

    name = "two-mass-load"
    description = "the motor's and the load's inertia joined by a shaft (stiffness, damping); encoder on the load"
    estimator = linear_estimator("oe-two-mass-load", "two-mass-load")
    encoder = "load"
