"""``asymmetric-gain``: the first-order motor whose gain differs by the sign of the drive.

``d omega/dt = -a omega + b_forward u+ + b_reverse u- + d``, with ``u+ = max(u, 0)`` and ``u- = min(u, 0)``: an
H-bridge or a gearbox that delivers more in one direction than in the other.  Friction per direction needs no
structure of its own: a Coulomb friction ``c`` with a constant acceleration ``d`` is ``c - d`` forward and
``c + d`` in reverse, which ``friction`` already fits.

What ``a`` and ``b`` mean here.  ``b_forward`` and ``b_reverse`` are the structure's own parameters, each with its
interval; ``b`` is their mean, ``(b_forward + b_reverse) / 2``: the gain of the best linear approximation of the
motor under any input symmetric about zero (a sine, a multisine, a PRBS: the part ``|u| (b_forward -
b_reverse)/2`` is even in the input and uncorrelated with it), so the linear part, the transfer function and the
frequency views are ``b/(s + a)`` with that mean.  The default's estimate holds ``b``'s interval over both
directions' (no single gain is the motor's), and the simulator's plant, which has one gain, is refused: a
controller designed from this model must be given one direction's gain, on purpose.

The default (:func:`identify.fit`) fits this structure only where the forward / reverse part check finds the
chosen model's parts differ (:mod:`identify.fits.asymmetry`), so it costs nothing elsewhere.
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from motorsim.checks import ParameterError
from motorsim.plant import Motor, Trajectory, simulate

from ..estimators import OE_ASYMMETRIC
from .base import Parameter
from .first_order import BIAS, POLE, FirstOrder

if TYPE_CHECKING:
    import control

    from ..data import Segment

__all__ = ["AsymmetricGain", "GAIN_MEAN", "GAIN_FORWARD", "GAIN_REVERSE", "directional_drive"]

GAIN_MEAN = Parameter("b", "(rad/s^2)/{input}", -math.inf, math.inf,
                      "mean of the forward and reverse gains, (b_forward + b_reverse)/2")
GAIN_FORWARD = Parameter("b_forward", "(rad/s^2)/{input}", -math.inf, math.inf, "gain for a positive drive")
GAIN_REVERSE = Parameter("b_reverse", "(rad/s^2)/{input}", -math.inf, math.inf, "gain for a negative drive")


def directional_drive(drive: np.ndarray, b_forward: float, b_reverse: float) -> np.ndarray:
    """``b_forward u+ + b_reverse u-``: the acceleration the drive ``u`` gives (elementwise)."""
    u = np.asarray(drive, dtype=float)
    return np.where(u > 0, b_forward * u, b_reverse * u)


class AsymmetricGain(FirstOrder):
    """``d omega/dt = -a omega + b_forward u+ + b_reverse u- + d`` (module docstring); ``b`` is the mean gain."""

    name = "asymmetric-gain"
    description = "linear with a gain per direction of the drive and a constant acceleration d (oe-asymmetric)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN_MEAN, GAIN_FORWARD, GAIN_REVERSE, BIAS)
    fixed: Mapping[str, float] = {"friction": 0.0, "dead_zone": 0.0}
    estimator = OE_ASYMMETRIC
    options: Mapping[str, object] = {}
    in_default = False
    simulated = False
    formula = "b/(s + a), b the mean of b_forward and b_reverse"

    @property
    def n_params(self) -> int:
        """Four: ``a``, the two gains and the bias (``b`` is their mean)."""
        return len(self.parameters) - 1

    def values(self, given: Mapping[str, float]) -> dict[str, float]:
        """Every parameter's value: a direction's gain not given is ``b``; ``b`` not given is their mean.

        Raises
        ------
        ParameterError
            ``a`` missing, no gain given, or ``b`` given with both directions' gains and not their mean.
        """
        given = dict(given)
        if "b_forward" in given and "b_reverse" in given:
            mean = 0.5 * (float(given["b_forward"]) + float(given["b_reverse"]))
            if "b" in given and not math.isclose(float(given["b"]), mean, rel_tol=1e-9, abs_tol=1e-300):
                raise ParameterError(f"b must be the mean of b_forward and b_reverse ({mean!r}) in the {self.name} "
                                     f"structure, got {given['b']!r}")
            given["b"] = mean
        elif "b" in given:
            given.setdefault("b_forward", given["b"])
            given.setdefault("b_reverse", given["b"])
        return super().values(given)

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Motor:
        """Refused: the simulator's :class:`~motorsim.plant.Motor` and the controllers take one gain.

        Raises
        ------
        ParameterError
            Always, naming both gains: give one direction's gain on purpose (``--a A --b B``).
        """
        v = self.values(values)
        raise ParameterError(
            f"structure must have one gain for a plant or a controller, got {self.name} with b_forward "
            f"{v['b_forward']:.6g} and b_reverse {v['b_reverse']:.6g}: the simulator and the controllers take one "
            f"gain, so give one on purpose (e.g. --a {v['a']:.6g} --b {min(v['b_forward'], v['b_reverse']):.6g}, "
            "the lower one: the loop is then no faster than designed in either direction)")

    def state_space(self, values: Mapping[str, float]) -> control.StateSpace:
        """The linear part, ``b/(s + a)`` with ``b`` the mean gain (module docstring), as the simulator's first-order
        motor's continuous system (bias omitted, as every structure's nonlinear or constant parts are)."""
        v = self.values(values)
        return Motor(v["a"], v["b"]).state_space()

    def discretise(self, values: Mapping[str, float], sample_period: float) -> control.StateSpace:
        """The linear part's exact discretisation over a held sample (:meth:`state_space`)."""
        v = self.values(values)
        return Motor(v["a"], v["b"]).discretise(sample_period)

    def response(self, values: Mapping[str, float], duty, time, *, input_delay: int = 0,
                 initial_speed: float = 0.0, initial_angle: float = 0.0) -> Trajectory:
        """The model's angle and speed at ``time`` under ``duty`` (zero-order hold, exact): the first-order motor
        with gain 1 driven by :func:`directional_drive` of the duty (the gain acts on each held value, so the
        delay may come before or after it)."""
        v = self.values(values)
        drive = directional_drive(np.asarray(duty, dtype=float), v["b_forward"], v["b_reverse"])
        return simulate(Motor(v["a"], 1.0, bias=v["bias"], input_delay=input_delay), drive, time,
                        initial_speed=initial_speed, initial_angle=initial_angle)

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's angle or speed on ``segment``, its initial speed (and angle offset) by exact least squares:
        the linear motor of gain 1 on the directional drive."""
        v = self.values(values)
        drive = directional_drive(segment.drive, v["b_forward"], v["b_reverse"])
        return FirstOrder().segment_output({"a": v["a"], "b": 1.0, "bias": v["bias"]},
                                           dataclasses.replace(segment, drive=drive))
