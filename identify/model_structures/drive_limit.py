"""``drive-limit``: the first-order motor behind a driver that delivers at most a limit of the duty it is sent.

``d omega/dt = -a omega + b clip(u, -L, L) + d``, ``L`` the ``drive_limit`` in input units: a driver (or its
firmware) that clips the duty below what the file says was commanded, a supply that cannot give more.  Below the
limit it is the linear motor with a bias, so its linear part, transfer function and frequency views are
``b/(s + a)``.  The simulator's plant has no such limit, so :meth:`plant` (and the controllers' model) refuse it by
name: a controller is designed from ``a`` and ``b`` with the limit given on purpose as its input limit.

The default (:func:`identify.fit`) fits this structure only where the low / high drive part check finds the gain
lower at high drive (:mod:`identify.default.evidence`).
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from motorsim.checks import ParameterError
from motorsim.plant import Motor, Trajectory, simulate

from ..estimators import OE_DRIVE_LIMIT
from .base import Parameter
from .first_order import BIAS, GAIN, POLE, FirstOrder

if TYPE_CHECKING:
    import control

    from ..data import Segment

__all__ = ["DriveLimit", "DRIVE_LIMIT", "clipped_drive"]

DRIVE_LIMIT = Parameter("drive_limit", "{input}", 0.0, math.inf,
                        "largest input magnitude the driver delivers (a clip below what was commanded)", strict=True)


def clipped_drive(drive: np.ndarray, limit: float) -> np.ndarray:
    """``clip(u, -limit, limit)``, elementwise."""
    return np.clip(np.asarray(drive, dtype=float), -limit, limit)


class DriveLimit(FirstOrder):
    """``d omega/dt = -a omega + b clip(u, -L, L) + d`` (module docstring)."""

    name = "drive-limit"
    description = "linear with a constant acceleration d behind a driver that clips the input at drive_limit " \
                  "(oe-drive-limit)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, DRIVE_LIMIT, BIAS)
    fixed: Mapping[str, float] = {"friction": 0.0, "dead_zone": 0.0}
    estimator = OE_DRIVE_LIMIT
    options: Mapping[str, object] = {}
    in_default = False
    simulated = False

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Motor:
        """Refused: the simulator's :class:`~motorsim.plant.Motor` and the controllers have no drive limit.

        Raises
        ------
        ParameterError
            Always, naming the limit: give ``a``, ``b`` and the limit on purpose (``--input-limit``).
        """
        v = self.values(values)
        raise ParameterError(
            f"structure must have no drive limit for a plant or a controller, got {self.name} with drive_limit "
            f"{v['drive_limit']:.6g}: the simulator and the controllers do not clip the drive, so give the model "
            f"and the limit on purpose (e.g. --a {v['a']:.6g} --b {v['b']:.6g} --input-limit "
            f"{v['drive_limit']:.6g}: a controller then keeps the duty within it)")

    def state_space(self, values: Mapping[str, float]) -> control.StateSpace:
        """The linear part below the limit, ``b/(s + a)``, as the first-order motor's continuous system."""
        v = self.values(values)
        return Motor(v["a"], v["b"]).state_space()

    def discretise(self, values: Mapping[str, float], sample_period: float) -> control.StateSpace:
        """The linear part's exact discretisation over a held sample (:meth:`state_space`)."""
        v = self.values(values)
        return Motor(v["a"], v["b"]).discretise(sample_period)

    def response(self, values: Mapping[str, float], duty, time, *, input_delay: int = 0,
                 initial_speed: float = 0.0, initial_angle: float = 0.0) -> Trajectory:
        """The model's angle and speed at ``time`` under ``duty`` (zero-order hold, exact): the first-order motor
        driven by the clipped duty (the clip acts on each held value, so the delay may come before or after it)."""
        v = self.values(values)
        return simulate(Motor(v["a"], v["b"], bias=v["bias"], input_delay=input_delay),
                        clipped_drive(duty, v["drive_limit"]), time, initial_speed=initial_speed,
                        initial_angle=initial_angle)

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's angle or speed on ``segment``, its initial speed (and angle offset) by exact least squares:
        the linear motor on the clipped drive."""
        v = self.values(values)
        return FirstOrder().segment_output({"a": v["a"], "b": v["b"], "bias": v["bias"]},
                                           dataclasses.replace(segment, drive=clipped_drive(segment.drive,
                                                                                            v["drive_limit"])))
