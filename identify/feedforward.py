"""Feedforward constants kS, kV, kA of an estimate, with intervals, in the model's input unit.

The model ``d omega/dt = -a omega + b u + d - c sign(omega)`` (``a``, ``b``, friction ``c``, bias
``d``) solved for the input that gives a speed ``omega`` and acceleration ``alpha`` is the
feedforward law of WPILib's SysId and most robotics courses::

    u = kS sign(omega) + kV omega + kA alpha + k0,
    kS = c / b,   kV = a / b,   kA = 1 / b,   k0 = -d / b,

in the input's unit (duty or volts) per rad/s, per rad/s^2, and for ``kS`` and ``k0`` in the
input unit itself.  Their standard errors come from the estimate's covariance by the delta
method (first-order propagation through the ratios), their intervals are normal ones; a
constant whose parameters have no covariance (friction or bias not fitted) has none.  Where the
estimate's own intervals were widened to hold candidates the data cannot rule out (its
``model_range``), each constant's interval holds every value its ratio takes over the widened
intervals of its parameters too (``ranges``): a kA interval never excludes what ``b``'s holds.
"""
from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist
from typing import Any

import numpy as np

from motorsim.checks import ParameterError

__all__ = ["FeedforwardConstants", "feedforward_constants", "apart"]


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
    ranges : dict of str to (float, float)
        Where the estimate's intervals were widened (its ``model_range``): each constant over the
        widened intervals of its parameters, joined to its own interval.
    """

    ks: float
    kv: float
    ka: float
    k0: float
    stderr: dict[str, float]
    input_unit: str = "duty"
    ranges: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)

    def confidence_interval(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Normal intervals ``(low, high)`` of each constant at ``level`` (nan without a standard error),
        joined with its ``ranges`` (the candidates the estimate could not rule out), as the estimate's are."""
        if not 0 < level < 1:
            raise ParameterError(f"level must be in (0, 1), got {level!r}")
        z = NormalDist().inv_cdf(0.5 + level / 2)   # (scipy.stats costs identify's start-up)
        out = {k: (getattr(self, k) - z * s, getattr(self, k) + z * s) for k, s in self.stderr.items()}
        for k, (lo, hi) in self.ranges.items():
            own = out.get(k, (math.nan, math.nan))
            out[k] = (min(lo, own[0]) if math.isfinite(own[0]) else lo,
                      max(hi, own[1]) if math.isfinite(own[1]) else hi)
        return out

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
            value = getattr(self, name)
            if math.isnan(lo):
                return f"{name[0]}{name[1].upper()} {value:.4g} {unit}"
            v, low, high = apart(value, lo, hi)
            return f"{name[0]}{name[1].upper()} {v} [{low}, {high}] {unit}"
        return "feedforward " + ", ".join([one("ks", u), one("kv", f"{u}/(rad/s)"), one("ka", f"{u}/(rad/s^2)"),
                                           one("k0", u)])


def apart(value: float, low: float, high: float, digits: int = 4) -> tuple[str, str, str]:
    """``value`` and its interval with enough significant digits (``digits`` at least, 10 at most) that the
    three are told apart where they differ: ``0.12 [0.12, 0.12]`` becomes ``0.12 [0.11995, 0.12005]``.

    Examples
    --------
    >>> apart(0.12, 0.11995, 0.12005)
    ('0.12', '0.11995', '0.12005')
    """
    for n in range(digits, 11):
        v, lo, hi = (f"{x:.{n}g}" for x in (value, low, high))
        if (v != lo or value == low) and (v != hi or value == high):
            break
    return v, lo, hi


def _ratio_range(top: tuple[float, float], bottom: tuple[float, float]) -> tuple[float, float]:
    """Every value ``x / y`` takes for ``x`` in ``top`` and ``y`` in ``bottom`` (all reals when ``bottom`` holds 0)."""
    if not bottom[0] * bottom[1] > 0:
        return -math.inf, math.inf
    corners = [x / y for x in top for y in bottom]
    return min(corners), max(corners)


def _widened(estimate: Any, kv_stderr: float) -> dict[str, tuple[float, float]]:
    """Each constant over the widened intervals of its parameters, when the estimate has any (``model_range``).

    ``kA = 1/b`` is a function of ``b`` alone: its range is ``b``'s interval mapped.  ``kV = a/b`` of
    candidates that fit alike moves far less than ``a`` and ``b`` do (their static gain is what the data
    hold), so where the selection kept its candidates, ``kV``'s range is theirs (those within the noise),
    each with the chosen fit's relative width of ``kV`` (``kv_stderr``); else every ratio over both
    intervals.  ``kS``, ``k0``: the friction's and bias's intervals over ``b``'s; where ``b``'s interval is
    open (one input level: a friction the data cannot tell from ``b``) and no friction was fitted, ``kS``
    holds every value of its sign."""
    if not getattr(estimate, "model_range", None):
        return {}
    ci = estimate.confidence_interval(0.95)
    if "a" not in ci or "b" not in ci:
        return {}
    b = ci["b"]
    out = {"kv": _ratio_range(ci["a"], b), "ka": _ratio_range((1.0, 1.0), b)}
    selection = getattr(estimate, "selection", None)
    alike = [c for c in getattr(selection, "candidates", ()) if c.within_noise and c.b != 0]
    bounded = math.isfinite(b[0]) and math.isfinite(b[1])
    if alike and "b" in estimate.model_range and bounded and b[0] * b[1] > 0:
        kv = float(estimate.a) / float(estimate.b)
        width = 1.96 * kv_stderr / abs(kv) if math.isfinite(kv_stderr) and kv else 0.0
        values = [kv] + [c.a / c.b for c in alike]
        out["kv"] = (min(v - abs(v) * width for v in values), max(v + abs(v) * width for v in values))
    if "friction" in ci:
        out["ks"] = _ratio_range(ci["friction"], b)
    elif not bounded:     # b open (one input level): a friction the data cannot tell from b, of any size
        out["ks"] = (0.0, math.inf) if estimate.b > 0 else (-math.inf, 0.0)
    if "bias" in ci:
        low, high = _ratio_range(ci["bias"], b)
        out["k0"] = (-high, -low)
    return out


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
        with np.errstate(invalid="ignore", over="ignore"):   # a covariance the data left undetermined holds nan
            var = float((g / scale) @ np.asarray(cov, dtype=float) @ (g / scale)) if scale > 0 else 0.0
        stderr[k] = scale * math.sqrt(var) if var >= 0 else math.nan
    return FeedforwardConstants(ks=c / b, kv=a / b, ka=1 / b, k0=-d / b, stderr=stderr,
                                input_unit=str(getattr(estimate, "input_unit", "duty")),
                                ranges=_widened(estimate, stderr["kv"]))
