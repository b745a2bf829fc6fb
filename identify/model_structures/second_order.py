"""The motor behind a first-order electrical lag: ``b / ((s + a)(tau_e s + 1))``.

A driver whose current lags the commanded duty (the winding's ``L/R``, a driver's filter) adds a
second pole, ``c = 1/tau_e``, usually much faster than the mechanical one: ``di/dt = c (u - i)``,
``d omega/dt = -a omega + b i + d``.  Sampled slowly it looks like an input delay of a fraction
of a sample; sampled fast (``tau_e`` of several samples) a first-order model absorbs it as a delay
of a few samples and misses ``a`` and ``b`` by a percent or more.  Fitted by ``oe-electrical``
(:mod:`identify.fits.electrical`); the simulator carries it as :attr:`motorsim.plant.Motor.electrical_time_constant`.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from motorsim.checks import ParameterError, check_real
from motorsim.plant import Motor, lag_coefficients, lag_response

from ..estimators import OE_ELECTRICAL
from .base import ModelStructure, Parameter
from .first_order import BIAS, GAIN, POLE

if TYPE_CHECKING:
    from ..data import Segment

__all__ = ["SecondOrder", "segment_columns"]

_TAU = Parameter("electrical_time_constant", "s", 0.0, math.inf,
                 "time constant tau_e of the lag between the duty and the motor's torque", strict=True)


class SecondOrder(ModelStructure):
    """``b / ((s + a)(tau_e s + 1))`` and a constant acceleration ``d``: the electrical pole ``1/tau_e``."""

    name = "second-order"
    description = "an electrical pole 1/tau_e behind the motor's, and a bias d (oe-electrical)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, _TAU, BIAS)
    fixed: Mapping[str, float] = {"friction": 0.0, "dead_zone": 0.0}
    estimator = OE_ELECTRICAL
    options: Mapping[str, object] = {}
    rank = 1
    formula = "b/((s + a)(tau_e s + 1))"
    response_parameters: tuple[str, ...] = ("a", "b", "electrical_time_constant")

    def frequency_response(self, values: Mapping[str, float], sample_period: float, omega, *,
                           output: str = "angle", input_delay: int = 0) -> np.ndarray:
        """The exact zero-order-hold response at ``omega`` rad/s, both poles, in the simulator's coefficients.

        Over a sample ``h`` with the input ``v`` held, :func:`motorsim.plant.lag_coefficients` give
        ``omega' = e_a omega + b q i + b (p - q) v`` and ``i' = e_c i + (1 - e_c) v``, so
        ``i(z) = (1 - e_c) / (z - e_c)`` and ``omega(z) = (b (p - q) + b q i(z)) / (z - e_a)`` per unit
        input (``"speed"``); the angle advances by ``p omega + b s i + b (r - s) v`` over the interval,
        so the mean speed there (``"angle"``) is that over ``h``.  At ``tau_e -> 0`` both are
        :func:`identify.frequency.frequency_estimate.zoh_speed_response`'s.
        """
        from ..fits.zoh_response import OUTPUTS
        if output not in OUTPUTS:
            raise ParameterError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")
        h = check_real("sample_period", sample_period, positive=True)
        b, tau = float(values["b"]), float(values["electrical_time_constant"])
        if not tau > 0:
            raise ParameterError(f"electrical_time_constant must be > 0 s for its frequency response, got {tau!r}")
        e_a, e_c, p, r, q, s = (float(x) for x in lag_coefficients(float(values["a"]), 1.0 / tau, h))
        z = np.exp(1j * np.asarray(omega, dtype=float) * h)
        current = (1.0 - e_c) / (z - e_c)
        speed = b * ((p - q) + q * current) / (z - e_a)
        g = speed if output == "speed" else (p * speed + b * s * current + b * (r - s)) / h
        return g * z ** (-int(input_delay))

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Motor:
        v = self.values(values)
        return Motor(v["a"], v["b"], bias=v["bias"], input_delay=input_delay,
                     electrical_time_constant=v["electrical_time_constant"])

    def linear_part(self, values: Mapping[str, float]) -> tuple[list[float], list[float]]:
        v = self.values(values)
        tau = v["electrical_time_constant"]
        return [v["b"]], [tau, 1.0 + tau * v["a"], v["a"]]

    def discrete_linear_part(self, values: Mapping[str, float], sample_period: float) -> tuple[list[float],
                                                                                                list[float]]:
        import control
        num, den = self.linear_part(values)
        tf = control.sample_system(control.tf(num, den), sample_period, method="zoh")
        return [float(x) for x in tf.num[0][0]], [float(x) for x in tf.den[0][0]]

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's angle or speed on ``segment``, its initial speed, current (and angle offset) by
        exact least squares (the output is linear in them)."""
        v = self.values(values)
        forced, free = segment_columns(v["a"], 1.0 / v["electrical_time_constant"], segment)
        model = v["b"] * forced[:, 0] + v["bias"] * forced[:, 1]
        coef, *_ = np.linalg.lstsq(free, segment.output - model, rcond=None)
        return model + free @ coef


def segment_columns(a: float, c: float, segment: Segment) -> tuple[np.ndarray, np.ndarray]:
    """The output's columns on ``segment`` at poles ``a`` and ``c``: ``forced`` (n, 2), the responses to
    the drive with ``b = 1`` and to a unit bias; ``free`` (n, 2 or 3), the responses to a unit initial
    speed, to a unit initial ``b i`` and (angle) the offset.  The output is ``b forced[:, 0] + d
    forced[:, 1] + free @ initial``."""
    angle = segment.kind == "angle"
    t, u = segment.time, segment.drive
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _columns(a, c, t, u, angle)


def _columns(a: float, c: float, t: np.ndarray, u: np.ndarray, angle: bool) -> tuple[np.ndarray, np.ndarray]:
    forced = lag_response(a, 1.0, c, 0.0, u, t)
    # the free responses and the bias's in closed form over the elapsed time (lag_coefficients' terms)
    e_a, _, p, r, q, s = lag_coefficients(a, c, t - t[0])
    if angle:
        return np.column_stack([forced.angle, r]), np.column_stack([p, s, np.ones_like(t)])
    return np.column_stack([forced.speed, p]), np.column_stack([e_a, q])
