"""Feedforward constants kS, kV, kA of an estimate, with intervals, in the model's input unit.

The model ``d omega/dt = -a omega + b u + d - c sign(omega)`` (``a``, ``b``, friction ``c``, bias
``d``) solved for the input that gives a speed ``omega`` and acceleration ``alpha`` is the
feedforward law of WPILib's SysId and most robotics courses::

    u = kS sign(omega) + kV omega + kA alpha + k0,
    kS = c / b,   kV = a / b,   kA = 1 / b,   k0 = -d / b,

in the input's unit (duty or volts) per rad/s, per rad/s^2, and for ``kS`` and ``k0`` in the
input unit itself.  Their standard errors come from the estimate's covariance by the delta
method (first-order propagation through the ratios), their intervals are normal ones; a
constant whose parameters have no covariance (friction or bias not fitted) has none.
"""
from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist
from typing import Any

import numpy as np

from motorsim.checks import ParameterError

__all__ = ["FeedforwardConstants", "feedforward_constants"]


@dataclasses.dataclass(frozen=True)
class FeedforwardConstants:
    """kS, kV, kA and the constant term k0 of a model, with standard errors.

    Attributes
    ----------
    ks, kv, ka, k0 : float
        Input unit, input unit per rad/s, input unit per rad/s^2, input unit.
    stderr : dict of str to float
        Standard error of each (nan where the covariance does not cover it).
    input_unit : str
        ``duty`` or ``V``.
    """

    ks: float
    kv: float
    ka: float
    k0: float
    stderr: dict[str, float]
    input_unit: str = "duty"

    def confidence_interval(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Normal intervals ``(low, high)`` of each constant at ``level`` (nan without a standard error)."""
        if not 0 < level < 1:
            raise ParameterError(f"level must be in (0, 1), got {level!r}")
        z = NormalDist().inv_cdf(0.5 + level / 2)   # (scipy.stats costs identify's start-up)
        return {k: (getattr(self, k) - z * s, getattr(self, k) + z * s) for k, s in self.stderr.items()}

    def to_dict(self) -> dict[str, Any]:
        """Values, standard errors, 95 % intervals and units, for a model's JSON."""
        ci = self.confidence_interval(0.95)
        u = self.input_unit
        units = {"ks": u, "kv": f"{u}/(rad/s)", "ka": f"{u}/(rad/s^2)", "k0": u}
        return {k: {"value": getattr(self, k), "stderr": self.stderr[k], "ci95": list(ci[k]), "unit": units[k]}
                for k in ("ks", "kv", "ka", "k0")}

    def describe(self) -> str:
        """One line: each constant with its 95 % interval."""
        ci = self.confidence_interval(0.95)
        u = self.input_unit

        def one(name: str, unit: str) -> str:
            lo, hi = ci[name]
            band = "" if math.isnan(lo) else f" [{lo:.4g}, {hi:.4g}]"
            return f"{name[0]}{name[1].upper()} {getattr(self, name):.4g}{band} {unit}"
        return "feedforward " + ", ".join([one("ks", u), one("kv", f"{u}/(rad/s)"), one("ka", f"{u}/(rad/s^2)"),
                                           one("k0", u)])


def feedforward_constants(estimate: Any) -> FeedforwardConstants:
    """kS, kV, kA and k0 of an estimate (or anything with ``a``, ``b`` and optionally ``extra``).

    Parameters
    ----------
    estimate : Estimate
        Its ``covariance`` over ``param_names`` gives the standard errors.

    Returns
    -------
    FeedforwardConstants

    Examples
    --------
    >>> from identify import Estimate
    >>> est = Estimate(method="oe", a=25.0, b=3.0, n_samples=1000, sample_period=0.005,
    ...                residual_rms=1e-4, fit_percent=99.9, covariance=np.diag([0.01, 1e-4]))
    >>> ff = feedforward_constants(est)
    >>> round(ff.kv, 4), round(ff.ka, 4), round(ff.stderr["kv"], 5)
    (8.3333, 0.3333, 0.04339)
    """
    a, b = float(estimate.a), float(estimate.b)
    if b == 0:
        raise ParameterError("b must be nonzero for feedforward constants, got 0.0")
    extra = dict(getattr(estimate, "extra", {}) or {})
    for key in ("friction", "bias"):          # a design model (PlantModel, Motor) holds them as attributes
        if key not in extra and isinstance(getattr(estimate, key, None), (int, float)):
            extra[key] = getattr(estimate, key)
    c, d = float(extra.get("friction", 0.0)), float(extra.get("bias", 0.0))
    names = tuple(getattr(estimate, "param_names", ("a", "b")))
    cov = getattr(estimate, "covariance", None)
    # gradients of each constant with respect to (a, b, friction, bias)
    # (x / b) / b, never x / b ** 2: b ** 2 overflows for an input in tiny units (b ~ 1e300) where the ratio does not
    grads = {"ks": {"b": -(c / b) / b, "friction": 1 / b}, "kv": {"a": 1 / b, "b": -(a / b) / b},
             "ka": {"b": -(1 / b) / b}, "k0": {"b": (d / b) / b, "bias": -1 / b}}
    stderr = {}
    for k, grad in grads.items():
        if cov is None or any(p not in names for p, g in grad.items() if g != 0):
            stderr[k] = math.nan
            continue
        g = np.array([grad.get(p, 0.0) for p in names])
        scale = float(np.max(np.abs(g)))     # scaled first: a / b**2 squared overflows long before the result does
        var = float((g / scale) @ np.asarray(cov, dtype=float) @ (g / scale)) if scale > 0 else 0.0
        stderr[k] = scale * math.sqrt(var) if var >= 0 else math.nan
    return FeedforwardConstants(ks=c / b, kv=a / b, ka=1 / b, k0=-d / b, stderr=stderr,
                                input_unit=str(getattr(estimate, "input_unit", "duty")))
