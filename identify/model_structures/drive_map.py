"""A map of the drive: the first-order motor driven by a static function of the duty, ``g(u)``.

``d omega/dt = -a omega + g(u) + d``: what the driver (or the gearbox) makes of the duty it is sent, before the
motor's linear dynamics.  Two structures are such maps, and share everything but the map and its parameters
(:class:`DriveMap`: the exact response, the model output on a segment, the linear part, the refusal of the
simulator's single-gain plant):

* ``asymmetric-gain`` (:class:`AsymmetricGain`): ``g(u) = b_forward u+ + b_reverse u-``, ``u+ = max(u, 0)`` and
  ``u- = min(u, 0)``: an H-bridge or a gearbox that delivers more in one direction than in the other.  Friction per
  direction needs no structure of its own: a Coulomb friction ``c`` with a constant acceleration ``d`` is ``c - d``
  forward and ``c + d`` in reverse, which ``friction`` already fits.
* ``drive-limit`` (:class:`DriveLimit`): ``g(u) = b clip(u, -L, L)``, ``L`` the ``drive_limit`` in input units: a
  driver (or its firmware) that clips the duty below what the file says was commanded, a supply that cannot give
  more.

What ``a`` and ``b`` mean.  For a gain per direction, ``b_forward`` and ``b_reverse`` are the structure's own
parameters, each with its interval; ``b`` is their mean, ``(b_forward + b_reverse) / 2``: the gain of the best
linear approximation of the motor under any input symmetric about zero (a sine, a multisine, a PRBS: the part
``|u| (b_forward - b_reverse)/2`` is even in the input and uncorrelated with it).  Behind a drive limit ``b`` is the
gain below the limit.  Either way the linear part, the transfer function and the frequency views are
``b/(s + a)``.  The simulator's plant has one gain and no clip, so :meth:`DriveMap.plant` (and the controllers'
model) refuse these structures by name: a controller is designed from one gain, or with the limit, given on purpose.

The default (:func:`identify.fit`) fits a gain per direction only where the forward / reverse part check finds the
chosen model's parts differ; the drive limit is not among its rules (:mod:`identify.default.evidence` says why).
Both are fitted by :func:`identify.fits.asymmetry.fit_mapped` with their map.
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from motorsim.checks import ParameterError
from motorsim.plant import Motor, Trajectory, simulate

from ..estimators import OE_ASYMMETRIC, OE_DRIVE_LIMIT
from .base import Parameter
from .first_order import BIAS, GAIN, POLE, FirstOrder

if TYPE_CHECKING:
    import control

    from ..data import Segment

__all__ = ["DriveMap", "AsymmetricGain", "DriveLimit", "GAIN_MEAN", "GAIN_FORWARD", "GAIN_REVERSE", "DRIVE_LIMIT",
           "directional_drive", "clipped_drive"]

GAIN_MEAN = Parameter("b", "(rad/s^2)/{input}", -math.inf, math.inf,
                      "mean of the forward and reverse gains, (b_forward + b_reverse)/2")
GAIN_FORWARD = Parameter("b_forward", "(rad/s^2)/{input}", -math.inf, math.inf, "gain for a positive drive")
GAIN_REVERSE = Parameter("b_reverse", "(rad/s^2)/{input}", -math.inf, math.inf, "gain for a negative drive")
DRIVE_LIMIT = Parameter("drive_limit", "{input}", 0.0, math.inf,
                        "largest input magnitude the driver delivers (a clip below what was commanded)", strict=True)


def directional_drive(drive: np.ndarray, b_forward: float, b_reverse: float) -> np.ndarray:
    """``b_forward u+ + b_reverse u-``: the acceleration the drive ``u`` gives (elementwise)."""
    u = np.asarray(drive, dtype=float)
    return np.where(u > 0, b_forward * u, b_reverse * u)


def clipped_drive(drive: np.ndarray, limit: float) -> np.ndarray:
    """``clip(u, -limit, limit)``, elementwise."""
    return np.clip(np.asarray(drive, dtype=float), -limit, limit)


class DriveMap(FirstOrder):
    """``d omega/dt = -a omega + g(u) + d``, ``g(u) = gain * mapped drive`` (:meth:`mapped`; module docstring)."""

    fixed: Mapping[str, float] = {"friction": 0.0, "dead_zone": 0.0}
    options: Mapping[str, object] = {}
    in_default = False
    simulated = False

    def mapped(self, values: Mapping[str, float], drive) -> tuple[float, np.ndarray]:
        """``(gain, drive)``: the map of the drive as a gain times the drive it passes (every value checked)."""
        raise NotImplementedError

    def refusal(self, values: Mapping[str, float]) -> str:
        """Why the simulator's plant cannot carry these values, and what to give on purpose instead."""
        raise NotImplementedError

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Motor:
        """Refused: the simulator's :class:`~motorsim.plant.Motor` and the controllers take one gain and no clip.

        Raises
        ------
        ParameterError
            Always, naming the map's values (:meth:`refusal`).
        """
        raise ParameterError(self.refusal(self.values(values)))

    def state_space(self, values: Mapping[str, float]) -> control.StateSpace:
        """The linear part, ``b/(s + a)`` (module docstring), as the simulator's first-order motor's continuous
        system (bias omitted, as every structure's nonlinear or constant parts are)."""
        v = self.values(values)
        return Motor(v["a"], v["b"]).state_space()

    def discretise(self, values: Mapping[str, float], sample_period: float) -> control.StateSpace:
        """The linear part's exact discretisation over a held sample (:meth:`state_space`)."""
        v = self.values(values)
        return Motor(v["a"], v["b"]).discretise(sample_period)

    def response(self, values: Mapping[str, float], duty, time, *, input_delay: int = 0,
                 initial_speed: float = 0.0, initial_angle: float = 0.0) -> Trajectory:
        """The model's angle and speed at ``time`` under ``duty`` (zero-order hold, exact): the first-order motor
        driven by the mapped duty (the map acts on each held value, so the delay may come before or after it)."""
        v = self.values(values)
        gain, drive = self.mapped(v, np.asarray(duty, dtype=float))
        return simulate(Motor(v["a"], gain, bias=v["bias"], input_delay=input_delay), drive, time,
                        initial_speed=initial_speed, initial_angle=initial_angle)

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's angle or speed on ``segment``, its initial speed (and angle offset) by exact least squares:
        the linear motor on the mapped drive."""
        v = self.values(values)
        gain, drive = self.mapped(v, segment.drive)
        return FirstOrder().segment_output({"a": v["a"], "b": gain, "bias": v["bias"]},
                                           dataclasses.replace(segment, drive=drive))


class AsymmetricGain(DriveMap):
    """``d omega/dt = -a omega + b_forward u+ + b_reverse u- + d`` (module docstring); ``b`` is the mean gain."""

    name = "asymmetric-gain"
    description = "linear with a gain per direction of the drive and a constant acceleration d (oe-asymmetric)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN_MEAN, GAIN_FORWARD, GAIN_REVERSE, BIAS)
    estimator = OE_ASYMMETRIC
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

    def mapped(self, values: Mapping[str, float], drive) -> tuple[float, np.ndarray]:
        """Gain 1 on :func:`directional_drive`."""
        return 1.0, directional_drive(drive, values["b_forward"], values["b_reverse"])

    def refusal(self, values: Mapping[str, float]) -> str:
        v = values
        return (f"structure must have one gain for a plant or a controller, got {self.name} with b_forward "
                f"{v['b_forward']:.6g} and b_reverse {v['b_reverse']:.6g}: the simulator and the controllers take one "
                f"gain, so give one on purpose (e.g. --a {v['a']:.6g} --b {min(v['b_forward'], v['b_reverse']):.6g}, "
                "the lower one: the loop is then no faster than designed in either direction)")


class DriveLimit(DriveMap):
    """``d omega/dt = -a omega + b clip(u, -L, L) + d`` (module docstring)."""

    name = "drive-limit"
    description = "linear with a constant acceleration d behind a driver that clips the input at drive_limit " \
                  "(oe-drive-limit)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, DRIVE_LIMIT, BIAS)
    estimator = OE_DRIVE_LIMIT

    def mapped(self, values: Mapping[str, float], drive) -> tuple[float, np.ndarray]:
        """``b`` on :func:`clipped_drive`."""
        return values["b"], clipped_drive(drive, values["drive_limit"])

    def refusal(self, values: Mapping[str, float]) -> str:
        v = values
        return (f"structure must have no drive limit for a plant or a controller, got {self.name} with drive_limit "
                f"{v['drive_limit']:.6g}: the simulator and the controllers do not clip the drive, so give the model "
                f"and the limit on purpose (e.g. --a {v['a']:.6g} --b {v['b']:.6g} --input-limit "
                f"{v['drive_limit']:.6g}: a controller then keeps the duty within it)")
