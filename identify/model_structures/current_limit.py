"""``current-limit``: the first-order motor behind a driver that limits its current.

``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d``: the torque the motor's current gives, ``b u`` less
the back-EMF's share ``s a omega`` of the pole, held within ``L`` (``current_limit``, rad/s^2) by the driver; the
rest of the pole, ``(1 - s) a``, the shaft's own friction, and ``d`` a constant acceleration act whatever the current
(:mod:`identify.fits.current_limit`).  Below the limit it is the linear motor with a bias, so its linear part, transfer
function and frequency views are ``b/(s + a)``.  The simulator's plant has no such limit, so :meth:`plant` (and the
controllers' model) refuse it by name: a controller is designed from ``a`` and ``b``, the limit given on purpose.

The default (:func:`identify.fit`) fits it only where its answer's part checks find the gain or the pole materially
different between parts and the structure fits better beyond the noise (:mod:`identify.default.evidence`).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from motorsim.checks import ParameterError
from motorsim.plant import Motor, Trajectory

from ..estimators import Estimator, EstimatorOption, _input_delay
from .base import Parameter
from .first_order import BIAS, GAIN, POLE, FirstOrder

if TYPE_CHECKING:
    import control

    from ..data import Segment

__all__ = ["CurrentLimit", "CURRENT_LIMIT", "EMF_SHARE", "OE_CURRENT_LIMIT"]

CURRENT_LIMIT = Parameter("current_limit", "rad/s^2", 0.0, math.inf,
                          "largest acceleration the driver's current gives (its current limit as a torque)",
                          strict=True)
EMF_SHARE = Parameter("emf_share", "1", 0.0, 1.0,
                      "share of the pole a that the back-EMF gives (inside the current limit); the rest is the "
                      "shaft's friction", strict=True)

#: Its estimator (listed by name from the structure registry).
OE_CURRENT_LIMIT = Estimator("oe-current-limit", "current_limit:fit_output_error_current_limit", (
    _input_delay(),
    EstimatorOption("covariance", "'auto' or 'gauss-newton'", "auto",
                    "intervals that hold when the noise is not white, or the fit's own (white noise assumed)")),
    beyond_first_order=True)


class CurrentLimit(FirstOrder):
    """``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d`` (module docstring)."""

    name = "current-limit"
    description = "linear with a constant acceleration d behind a driver that limits its current " \
                  "(oe-current-limit)"
    parameters: tuple[Parameter, ...] = (POLE, GAIN, CURRENT_LIMIT, EMF_SHARE, BIAS)
    fixed: Mapping[str, float] = {"friction": 0.0, "dead_zone": 0.0}
    estimator = OE_CURRENT_LIMIT
    options: Mapping[str, object] = {}
    in_default = False
    simulated = False

    def values(self, given: Mapping[str, float]) -> dict[str, float]:
        """Every parameter's value; ``emf_share`` not given is 1 (all of the pole the back-EMF's)."""
        given = dict(given)
        given.setdefault("emf_share", 1.0)
        return super().values(given)

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Motor:
        """Refused: the simulator's :class:`~motorsim.plant.Motor` and the controllers have no current limit.

        Raises
        ------
        ParameterError
            Always, naming the limit: give ``a`` and ``b`` on purpose, the limit as the loop's.
        """
        v = self.values(values)
        raise ParameterError(
            f"structure must have no current limit for a plant or a controller, got {self.name} with current_limit "
            f"{v['current_limit']:.6g} rad/s^2: the simulator and the controllers do not limit the current, so give "
            f"the model on purpose (e.g. --a {v['a']:.6g} --b {v['b']:.6g}) and keep the loop's acceleration "
            "within the limit")

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
        """The model's angle and speed at ``time`` under ``duty`` (zero-order hold, exact:
        :func:`identify.fits.limit_response.limit_response`), the duty delayed by ``input_delay`` samples (0 before)."""
        from ..fits.limit_response import limit_response
        v = self.values(values)
        t = np.asarray(time, dtype=float)
        u = np.asarray(duty, dtype=float)
        if input_delay:
            u = np.concatenate([np.zeros(input_delay), u[:max(len(u) - input_delay, 0)]])
        angle, speed = limit_response(v["a"], v["b"], v["current_limit"], v["emf_share"], v["bias"], u, t,
                                      initial_speed, initial_angle)
        return Trajectory(t, angle, speed)

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's angle or speed on ``segment``, its initial speed fitted (the model is not linear in it) and,
        on an angle, its offset by least squares."""
        from ..fits.limit_response import initial_speed_fit, segment_model
        v = self.values(values)
        theta = (v["a"], v["b"], v["current_limit"], v["emf_share"], v["bias"])
        out = segment_model(theta, segment, initial_speed_fit(theta, segment))
        if segment.kind == "angle":
            out = out + float(np.mean(segment.output - out))
        return out
