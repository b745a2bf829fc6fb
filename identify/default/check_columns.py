"""The columns the part checks put beside the chosen model (the part checks'): a torque of the angle,
a friction or a drag that changes with speed, the gain as a curve of the duty, the model's own torque through a curve.

Each is a function of the chosen model's rows (its speed, drive, measured angle and torque over each interval) that
a right model leaves unexplained and a model one step past its structure may not; the checks fit them beside the
model's own columns and test them against zero.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

__all__ = ["MIN_TURN_RANGE", "KNEES"]


@dataclasses.dataclass
class _Rows:
    """The chosen model on every segment, what the checks need, segments concatenated."""

    residual: np.ndarray          # measured less model output (angle or speed)
    speed: np.ndarray             # model speed over each interval (held like the drive; last row 0)
    drive: np.ndarray             # the drive the gain multiplies, over each interval
    order: np.ndarray             # the row's place in the run, 0 ... 1
    respond: list[Callable[..., np.ndarray]]   # per segment: x (its rows) -> projected response
    angle: np.ndarray             # measured angle (integrated from a speed column), rad
    bounds: list[tuple[int, int]]  # per segment: its rows
    friction: bool
    output_rms: float             # of the measured output less each segment's first value
    interval: np.ndarray | None = None   # each row's sample interval, s (last row 0); None on uniform clocks
    push: np.ndarray | None = None       # the model's acceleration over each interval, b v - a w (last row 0)


def _push_curve_inputs(rows: _Rows) -> list[np.ndarray]:
    """The model's torque ``T = b v - a ω`` through a curve, ``T |T| / P`` and ``T^3 / P^2`` (``P`` its largest
    magnitude): Ramsey's RESET in the model's own terms.  A plant whose torque bends where the model's is large (a
    current limit, a driver or a supply that saturates) fits these; a right model does not.  None without the
    model's torque."""
    push = rows.push
    if push is None or not len(push):
        return []
    top = float(np.max(np.abs(push)))
    if not (math.isfinite(top) and top > 0):
        return []
    return [push * np.abs(push) / top, push * push * push / top ** 2]


#: Least range of the angle, rad, over which a torque of ``sin θ`` and ``cos θ`` is tested beside one of ``θ``: over
#: less they are a line and a constant (the spring's column and the constant acceleration).
MIN_TURN_RANGE = 1.0


def _angle_inputs(rows: _Rows) -> list[np.ndarray]:
    """The accelerations of a torque of the angle ``θ`` (the part checks'): ``θ`` itself (a spring, a cable, gravity
    near its balance), and over :data:`MIN_TURN_RANGE` ``sin θ`` and ``cos θ`` too (gravity on an arm, whatever its
    zero; a load unbalanced once a turn); none where the angle does not move."""
    theta = rows.angle
    if not (len(theta) and np.all(np.isfinite(theta))) or float(np.ptp(theta)) == 0:
        return []
    out = [-(theta - float(np.mean(theta)))]
    if float(np.ptp(theta)) >= MIN_TURN_RANGE:
        out += [-np.sin(theta), -np.cos(theta)]
    return out


#: Speeds, as shares of the model's largest, at which the friction curve's columns fall to ``1/e`` of their level at
#: rest (:func:`_friction_curve_inputs`): Stribeck's knee sits at 2-20 % of the top speed on the benches we know.
KNEES = (0.05, 0.2)


def _friction_curve_inputs(rows: _Rows) -> list[np.ndarray]:
    """A friction that changes with speed (the part checks'): ``sign(ω) exp(-(ω/s)²)`` at each knee ``s`` of
    :data:`KNEES` (times the model's top speed), friction that weakens (or grows) from rest, as Stribeck's does; a
    constant Coulomb level is the model's own, or the constant's.  None where the speed does not move."""
    w = rows.speed
    top = float(np.max(np.abs(w))) if len(w) else 0.0
    if not (math.isfinite(top) and top > 0):
        return []
    return [-np.sign(w) * np.exp(-(w / (share * top)) ** 2) for share in KNEES]


def _drag_inputs(rows: _Rows) -> list[np.ndarray]:
    """A drag that grows with speed, ``ω |ω| / W`` (``W`` the model's top speed), beside the friction curve's knees
    in the open-loop check (a fan, a propeller, a viscous load that is not linear); none where the speed does not
    move."""
    w = rows.speed
    top = float(np.max(np.abs(w))) if len(w) else 0.0
    if not (math.isfinite(top) and top > 0):
        return []
    return [-w * np.abs(w) / top]


def _curve_inputs(rows: _Rows) -> list[np.ndarray]:
    """The drive's curve (the part checks'): ``v |v| / V`` and ``v^3 / V^2`` (``V`` its largest magnitude), a gain
    that changes smoothly with the duty (a supply that sags, a current limit, a driver's curved map); none where
    the drive takes fewer than three magnitudes (no curve to see)."""
    v = rows.drive
    moving = np.abs(v[v != 0])
    if not _three_magnitudes(moving):
        return []
    top = float(moving.max())
    return [v * np.abs(v) / top, v * v * v / top ** 2]


def _three_magnitudes(moving: np.ndarray) -> bool:
    """Whether the magnitudes ``moving`` take three values or more (``len(np.unique(moving)) >= 3``, without its
    sort): one strictly between the least and the largest."""
    if len(moving) == 0:
        return False
    least, largest = float(moving.min()), float(moving.max())
    return bool(np.any((moving > least) & (moving < largest)))
