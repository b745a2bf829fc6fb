"""The first-order motor and its family: ``d omega/dt + a omega = b u`` (+ bias, Coulomb friction, dead zone).

* ``linear``: ``d omega/dt = -a omega + b u`` (``oe``);
* ``bias``: ``+ d``, a constant acceleration (a driver offset, a load) (``oe`` with ``fit_bias``);
* ``friction``: ``- c sign(omega) + d``, sticking at rest while ``|b u + d| <= c`` (``oe-friction``);
* ``dead-zone``: friction, bias, and a duty band ``|u| <= z`` the driver does not deliver
  (``oe-friction`` with ``dead_zone``);
* ``stiction``: friction, bias, and a static friction ``c_s >= c`` the shaft at rest needs to break
  away (``oe-friction`` with ``static_friction``); judged after the others (``rank`` 1).

The input delay is not a parameter of a structure: every structure is fitted at every delay.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from motorsim.plant import Motor

from ..estimators import OE, OE_FRICTION
from .base import ModelStructure, Parameter

if TYPE_CHECKING:
    from ..data import Segment

__all__ = ["FirstOrder", "FirstOrderBias", "CoulombFriction", "DeadZone", "Stiction", "POLE", "GAIN", "BIAS",
           "FRICTION", "STATIC_FRICTION", "DEAD_ZONE", "INITIAL_WINDOW_TIME_CONSTANTS",
           "MIN_INITIAL_WINDOW", "initial_state_rule"]

#: Time constants ``1/a`` in the window that fixes a friction model's initial speed on held-out data.
INITIAL_WINDOW_TIME_CONSTANTS = 2.0
#: Fewest samples in that window.
MIN_INITIAL_WINDOW = 10

#: The parameters of the family, shared by every structure that has them (``a``, ``b`` first).
POLE = Parameter("a", "1/s", 0.0, math.inf, "pole of d omega/dt + a omega = b u", strict=True)
GAIN = Parameter("b", "(rad/s^2)/{input}", -math.inf, math.inf, "gain of d omega/dt + a omega = b u")
BIAS = Parameter("bias", "rad/s^2", -math.inf, math.inf, "constant acceleration d (driver offset, load)")
FRICTION = Parameter("friction", "rad/s^2", 0.0, math.inf, "Coulomb friction c")
DEAD_ZONE = Parameter("dead_zone", "{input}", 0.0, math.inf, "input magnitude the driver does not deliver")
STATIC_FRICTION = Parameter("static_friction", "rad/s^2", 0.0, math.inf,
                            "static friction c_s (stiction): the force the shaft at rest needs to break away")


def initial_state_rule(values: Mapping[str, float]) -> str:
    """How :meth:`FirstOrder.segment_output` finds each segment's initial state for these values (one line)."""
    if _has_friction(values):
        return (f"initial speed fitted on the first {INITIAL_WINDOW_TIME_CONSTANTS:g} time constants "
                f"(at least {MIN_INITIAL_WINDOW} samples) from the measured speed")
    return "initial speed (and angle offset) by exact least squares on each segment"


def _has_friction(values: Mapping[str, float]) -> bool:
    return any(float(values.get(n, 0.0)) > 0 for n in ("friction", "dead_zone", "static_friction"))


class FirstOrder(ModelStructure):
    """``b / (s + a)`` from the input to the speed: the article's motor."""

    name = "linear"
    description = "linear (oe)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN)
    fixed: Mapping[str, float] = {"friction": 0.0, "bias": 0.0, "dead_zone": 0.0}
    estimator = OE
    options: Mapping[str, object] = {}

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's angle or speed on ``segment``; its initial speed (and angle offset) by exact
        least squares, or, with friction or a dead zone, fitted on a short window at the start
        (:func:`initial_state_rule`)."""
        from ..fits.sensitivity import project_out_initial_state, zoh_response
        if _has_friction(values):
            return _friction_segment_output(values, segment)
        resp = zoh_response(values["a"], values["b"], segment.drive, segment.time, 0.0,
                            bias=float(values.get("bias", 0.0)), uniform=segment.uniform, sensitivities=False)
        angle = segment.kind == "angle"
        # the initial speed (and angle offset) by least squares: the measured output less what is left
        s0 = resp.angle_initial_speed if angle else resp.speed_initial_speed
        left, = project_out_initial_state(s0, angle, segment.output - (resp.angle if angle else resp.speed))
        return segment.output - left

    def values_from_discrete(self, pole: np.ndarray, gain: np.ndarray,
                             sample_period: float) -> tuple[np.ndarray, np.ndarray]:
        """``a`` and ``b`` of the exact zero-order-hold model with this pole and gain, elementwise.

        The inverse of :meth:`discrete_linear_part`: ``omega[k+1] = pole omega[k] + gain u[k]`` with
        ``pole = exp(-a h)`` and ``gain = (b/a)(1 - pole)``, so ``a = -ln(pole)/h`` and
        ``b = a gain/(1 - pole)``; ``nan`` where ``pole`` is not in (0, 1) (no stable model of this
        structure has it).
        """
        pole = np.asarray(pole, dtype=float)
        ok = (pole > 0) & (pole < 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inside = np.where(ok, pole, 0.5)
            a = -np.log(inside) / sample_period
            b = a * gain / (1.0 - inside)
        return np.where(ok, a, np.nan), np.where(ok, b, np.nan)


class FirstOrderBias(FirstOrder):
    """``b / (s + a)`` and a constant acceleration ``d``."""

    name = "bias"
    description = "linear with a constant acceleration d (oe, fit_bias)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, BIAS)
    fixed: Mapping[str, float] = {"friction": 0.0, "dead_zone": 0.0}
    options: Mapping[str, object] = {"fit_bias": True}


class CoulombFriction(FirstOrder):
    """Coulomb friction ``c`` and a bias ``d``: ``d omega/dt = -a omega + b u - c sign(omega) + d``."""

    name = "friction"
    description = "Coulomb friction c and bias d (oe-friction)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, FRICTION, BIAS)
    fixed: Mapping[str, float] = {"dead_zone": 0.0}
    estimator = OE_FRICTION
    options: Mapping[str, object] = {"dead_zone": False}
    linear = False


class DeadZone(CoulombFriction):
    """Friction, bias and a dead zone: the drive is ``u - sign(u) z`` outside ``|u| <= z``, else 0."""

    name = "dead-zone"
    description = "friction c, bias d and a duty dead zone (oe-friction)"
    parameters = (POLE, GAIN, FRICTION, BIAS, DEAD_ZONE)
    fixed: Mapping[str, float] = {}
    options: Mapping[str, object] = {}


class Stiction(CoulombFriction):
    """Friction, bias and a static friction ``c_s >= c``: the shaft at rest breaks away only when
    ``|b u + d| > c_s``, and a speed reaching zero sticks while ``|b u + d| <= c_s``.

    The static level moves only the decisions to stick, so ``oe-friction`` fits it by a profile
    (:mod:`identify.fits.stiction`).  The default judges it after the rest of the family (``rank`` 1):
    chosen only where no simpler candidate is within the noise of its fit.
    """

    name = "stiction"
    description = "friction c, static friction c_s >= c and bias d (oe-friction, static_friction)"
    parameters = (POLE, GAIN, FRICTION, STATIC_FRICTION, BIAS)
    fixed: Mapping[str, float] = {"dead_zone": 0.0}
    options: Mapping[str, object] = {"dead_zone": False, "static_friction": True}
    rank = 1

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Motor:
        v = self.values(values)
        static = v["static_friction"] if v["static_friction"] >= v["friction"] else 0.0
        return Motor(v["a"], v["b"], friction=v["friction"], bias=v["bias"], static_friction=static,
                     input_delay=input_delay)


def _friction_segment_output(values: Mapping[str, float], seg: Segment) -> np.ndarray:
    """The friction model from an initial speed fitted on a short window at the segment's start.

    The friction model is not linear in the initial speed, and a free fit of it on the whole
    run's angle can land far from the data's start (the cost has local minima at every
    stick/slip pattern).  The initial speed only matters for a few time constants, so it is
    fitted there, from the measured speed, and the whole segment is then simulated from it;
    the angle offset (linear) is the mean difference.
    """
    from scipy.optimize import least_squares  # imported when used: slow to import

    from ..fits.friction_response import friction_response
    params = (values["a"], values["b"], float(values.get("friction", 0.0)), float(values.get("bias", 0.0)),
              float(values.get("dead_zone", 0.0)))
    static = float(values.get("static_friction", 0.0))
    h = float(np.median(np.diff(seg.time)))
    window = int(min(len(seg.time), max(MIN_INITIAL_WINDOW,
                                        math.ceil(INITIAL_WINDOW_TIME_CONSTANTS / max(values["a"] * h, 1e-12)))))

    def run(w0: float, stop: int) -> np.ndarray:
        resp = friction_response(*params, seg.drive[:stop], seg.time[:stop], w0, sensitivities=False,
                                 static_friction=static)
        if seg.kind == "angle":
            return resp.angle + float(np.mean(seg.output[:stop] - resp.angle))
        return resp.speed

    w0 = float(least_squares(lambda w: seg.output[:window] - run(float(w[0]), window),
                             [seg.initial_speed_guess()], xtol=1e-10).x[0])
    return run(w0, len(seg.time))
