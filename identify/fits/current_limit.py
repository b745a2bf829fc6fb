"""``oe-current-limit``: output error of the motor behind a driver that limits its current.

The structure (:class:`identify.model_structures.current_limit.CurrentLimit`) is

``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d``,

``sat_L(x) = min(max(x, -L), L)``.  The motor's current, ``(V - k_e omega) / R``, makes the torque ``b u - s a omega``
(``s`` = ``emf_share``, the share of the pole ``a`` the back-EMF gives); the driver holds that current within its
limit, the torque within ``L`` (``current_limit``, rad/s^2); the rest of the pole, ``(1 - s) a``, is the shaft's
own viscous friction, which acts whatever the current.  Below the limit it is the linear motor ``b/(s + a)`` with
a constant acceleration ``d`` (a load, outside the driver's loop).  The limit acts where the torque asked for is
large: at steps and reversals of the drive, where the back-EMF has not yet caught up.

The exact zero-order-hold response (:mod:`identify.fits.limit_response`): over each held sample the vector field is
continuous and piecewise linear in ``omega``, solved in closed form through its crossings of the limit.

The fit is nonlinear least squares (:func:`scipy.optimize.least_squares`, bounded: ``a > 0``, ``L > 0``,
``0 < s <= 1``) on ``(a, b, L, s, d)`` and each segment's initial speed, the angle offset projected out, from
several starting limits (solved in ``(1 - s) a`` for ``s``: :func:`_solve`), its Jacobian the response's exact
sensitivities (:func:`identify.fits.limit_response.limit_sensitivities`); its covariance is
:func:`identify.fits.asymmetry.fit_mapped`'s (the encoder's rounding by the linearised bootstrap where it dominates,
else Gauss--Newton or Newey--West), the initial speeds projected out of the Jacobian.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

from ..data import (
    DEFAULT_INPUT_DELAY,
    Segment,
    prepare_segments,
    residual_unit,
)
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..sums import sum_squares
from .limit_response import initial_speed_fit, limit_response, segment_model, segment_sensitivities
from .oe_common import check_rows, fit_covariance, linear_start, segment_models

__all__ = ["fit_output_error_current_limit", "asked_torque", "STRUCTURE", "FITTED", "START_QUANTILES", "START_SHARES",
           "MIN_SHARE"]

#: The structure's name.
STRUCTURE = "current-limit"
#: The parameters the fit estimates.
FITTED = ("a", "b", "current_limit", "emf_share", "bias")
#: Quantiles of the torque the linear model asks for (``|b u - a omega|`` along its run) the limit starts from.
START_QUANTILES = (0.6, 0.8, 0.95)
#: Back-EMF shares the fit starts from.
START_SHARES = (0.5, 0.9)
#: The smallest back-EMF share (the bound of the fit): a driver's current limit needs a back-EMF to act through.
MIN_SHARE = 0.01


def _residuals(x: np.ndarray, segments: Sequence[Segment]) -> np.ndarray:
    theta = x[:5]
    out = []
    for j, seg in enumerate(segments):
        r = seg.output - segment_model(theta, seg, float(x[5 + j]))
        out.append(r - r.mean() if seg.kind == "angle" else r)
    return np.concatenate(out)


def _residual_jacobian(x: np.ndarray, segments: Sequence[Segment]) -> np.ndarray:
    """The Jacobian of :func:`_residuals`: the response's exact sensitivities
    (:func:`identify.fits.limit_response.segment_sensitivities`), each segment's initial speed its own column."""
    theta = x[:5]
    J = np.zeros((sum(len(seg.time) for seg in segments), len(x)))
    row = 0
    for j, seg in enumerate(segments):
        _, sens = segment_sensitivities(theta, seg, float(x[5 + j]))
        if seg.kind == "angle":
            sens = sens - sens.mean(axis=0)
        rows = slice(row, row + len(seg.time))
        J[rows, :5] = -sens[:, :5]
        J[rows, 5 + j] = -sens[:, 5]
        row += len(seg.time)
    return J


#: The solver's settings (:func:`scipy.optimize.least_squares`): tolerances and the evaluations one start may take.
SOLVER = {"x_scale": "jac", "xtol": 1e-12, "ftol": 1e-14, "gtol": 1e-14, "max_nfev": 400}


def _from_pole_split(z: np.ndarray) -> np.ndarray:
    """The parameters ``(a, b, L, s, d, w0...)`` from ``z``, which holds the shaft's pole ``(1 - s) a`` in the
    share's place."""
    x = np.array(z, dtype=float)
    x[3] = 1.0 - z[3] / z[0]
    return x


def _solve(x0: np.ndarray, segments: Sequence[Segment]) -> tuple[np.ndarray, float] | None:
    """The bounded least-squares fit from ``x0`` (``(a, b, L, s, d)`` and each segment's initial speed): its
    parameters and cost, or None where it fails.

    Solved in ``(a, b, L, (1 - s) a, d)``: the pole the motor keeps inside the limit, ``(1 - s) a``, is what the
    saturated stretches determine, and where the run leaves ``a`` loose along ``b / a`` (a coarse speed) the share
    ``s`` runs along ``1 - (1 - s) a / a``, a curved valley the solver crawled along (all six starts of a 48-count
    speed column at 1 ms stopped at 400 evaluations, up to 0.06 % apart in cost); in these coordinates it is straight
    (the same starts converged in 73-145, to one cost).  Bounds ``a, L > 0``, ``(1 - s) a >= 0`` (``s <= 1``); where
    that answer breaks ``s >= MIN_SHARE``, the fit is made again in ``(a, b, L, s, d)`` with the share's bound."""
    from scipy.optimize import least_squares
    n = len(x0)
    lower = np.array([1e-9, -np.inf, 1e-9, 0.0, -np.inf] + [-np.inf] * (n - 5))
    z0 = np.array(x0, dtype=float)
    z0[3] = (1.0 - x0[3]) * x0[0]

    def residuals(z: np.ndarray) -> np.ndarray:
        return _residuals(_from_pole_split(z), segments)

    def jacobian(z: np.ndarray) -> np.ndarray:
        J = _residual_jacobian(_from_pole_split(z), segments)
        share = J[:, 3].copy()              # d s / d a = (1 - s) a / a^2, d s / d (1 - s) a = -1 / a
        J[:, 0] += share * z[3] / z[0] ** 2
        J[:, 3] = -share / z[0]
        return J
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            found = least_squares(residuals, np.clip(z0, lower + 1e-12, np.inf), jac=jacobian,
                                  bounds=(lower, np.full(n, np.inf)), **SOLVER)
            x = _from_pole_split(found.x)
            if not x[3] >= MIN_SHARE:
                lower[3] = MIN_SHARE
                upper = np.full(n, np.inf)
                upper[3] = 1.0
                found = least_squares(_residuals, np.clip(x, lower + 1e-12, upper), jac=_residual_jacobian,
                                      bounds=(lower, upper), args=(segments,), **SOLVER)
                x = found.x
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    return (x, float(found.cost)) if np.all(np.isfinite(x)) else None


def _starts(segments: Sequence[Segment], a: float, b: float, bias: float) -> list[np.ndarray]:
    """Start points: the linear model's ``a``, ``b``, ``bias``; limits at :data:`START_QUANTILES` of the torque it
    asks for along its run; shares :data:`START_SHARES`."""
    asked = []
    for seg in segments:
        angle, speed = limit_response(a, b, math.inf, 1.0, bias, seg.drive, seg.time, seg.initial_speed_guess())
        asked.append(np.abs(b * np.asarray(seg.drive, dtype=float) - a * speed))
    torque = np.concatenate(asked)
    torque = torque[torque > 0]
    if len(torque) < 3:
        return []
    return [np.array([a, b, float(np.quantile(torque, q)), s, bias]) for q in START_QUANTILES for s in START_SHARES]


def _fit(recs: list[Recording], delay: int, a: float, b: float, bias: float, covariance: str = "auto") -> Estimate:
    """The fit at ``delay`` from the linear model's ``a``, ``b``, ``bias`` and :func:`_starts`' limits and shares."""
    from ..checks.validation import segment_fit_percent
    segments = prepare_segments(recs, delay)
    p = len(FITTED)
    n, nuisance = check_rows(segments, p, "a current limit")
    if not (math.isfinite(a) and a > 0 and math.isfinite(b) and b != 0):
        raise NotIdentifiableError(f"a current limit needs a stable linear start, got a = {a:.6g}, b = {b:.6g}")
    starts = _starts(segments, a, abs(b), bias)
    if not starts:
        raise NotIdentifiableError("a current limit needs a motor that moved: the drive asked for no torque")
    w0s = [seg.initial_speed_guess() for seg in segments]
    best = None
    for start in starts:
        found = _solve(np.concatenate([start, w0s]), segments)
        if found is not None and (best is None or found[1] < best[1]):
            best = found
    if best is None:
        raise NotIdentifiableError("no fit with a current limit converged: the data do not show one")
    x = best[0]
    residual = _residuals(x, segments)
    rss = sum_squares(residual)
    J_all = -_residual_jacobian(x, segments)          # d model / d x, the angle offsets projected out
    W, J = J_all[:, p:], J_all[:, :p]
    if W.shape[1]:
        J = J - W @ np.linalg.lstsq(W, J, rcond=None)[0]
    models = segment_models(segments, residual)
    cov, how = fit_covariance(recs, segments, models, residual, -J, max(n - nuisance - p, 1), p, covariance)
    a1, b1, limit, share, d = (float(v) for v in x[:5])
    return Estimate(method="oe-current-limit", a=a1, b=b1, n_samples=n, sample_period=recs[0].sample_period,
                    residual_rms=math.sqrt(rss / n), fit_percent=segment_fit_percent(segments, models),
                    covariance=cov, param_names=FITTED,
                    extra={"current_limit": limit, "emf_share": share, "bias": d, "input_delay": delay},
                    residual_unit=residual_unit(segments), input_unit=recs[0].input_unit,
                    input_limit=recs[0].input_limit, structure=STRUCTURE, covariance_method=how)


def fit_output_error_current_limit(recordings: Recording | Sequence[Recording], *,
                                   input_delay: int | str = DEFAULT_INPUT_DELAY,
                                   covariance: str = "auto") -> Estimate:
    """Output-error fit of the motor behind a driver that limits its current (``oe-current-limit``).

    ``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d`` (module docstring), exact under the zero-order
    hold, on the encoder angle (or the speed column).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled: one set of parameters, an initial speed (and angle offset) per gap-free segment.
    input_delay : int or "auto"
        Whole samples, or ``"auto"`` (default): the delay ``oe`` with a bias chooses.
    covariance : {"auto", "gauss-newton"}
        As :func:`identify.fits.asymmetry.fit_output_error_asymmetric`'s.

    Returns
    -------
    Estimate
        Structure ``current-limit``: ``a``, ``b`` (the linear motor's, below the limit), ``extra``
        ``current_limit`` (rad/s^2), ``emf_share`` and ``bias``; the covariance over
        ``("a", "b", "current_limit", "emf_share", "bias")``.

    Raises
    ------
    NotIdentifiableError
        Too short, a motor that did not move, or no fit converged.

    Examples
    --------
    A driver that holds the torque within 400 rad/s^2 at steps of the duty, noise-free:

    >>> import numpy as np
    >>> from identify import fit
    >>> from identify.model_structures import structure
    >>> from motorsim import Recording
    >>> t = np.arange(3000) * 0.002
    >>> duty = np.where(np.sin(2.5 * t) > 0, 180, -150)
    >>> truth = {"a": 25.0, "b": 3.0, "current_limit": 400.0, "emf_share": 0.8, "bias": 0.0}
    >>> angle = structure("current-limit").response(truth, duty, t).angle
    >>> est = fit(Recording(time=t, duty=duty, sample_period=0.002, angle=angle), "oe-current-limit", input_delay=0)
    >>> print(f"a = {est.a:.6f}, b = {est.b:.6f}, limit {est.extra['current_limit']:.4f}, "
    ...       f"share {est.extra['emf_share']:.6f}")
    a = 25.000000, b = 3.000000, limit 400.0000, share 0.800000
    """
    recs, delay, start = linear_start(recordings, input_delay, covariance, 5)
    return _fit(recs, delay, start.a, start.b, float(start.extra.get("bias", 0.0)), covariance)


def asked_torque(est: Estimate, recs: Sequence[Recording]) -> float:
    """The largest torque (rad/s^2) the fitted model's current asks for on the recordings, ``|b u - s a omega|`` along
    its own run: what its limit cuts."""
    delay = int(est.input_delay)
    v = est.values()
    theta = (v["a"], v["b"], v["current_limit"], v["emf_share"], v["bias"])
    top = 0.0
    for seg in prepare_segments(list(recs), delay):
        w0 = initial_speed_fit(theta, seg)
        _, speed = limit_response(*theta, seg.drive, seg.time, w0)
        asked = np.abs(theta[1] * np.asarray(seg.drive, dtype=float)[:-1] - theta[3] * theta[0] * speed[:-1])
        top = max(top, float(np.max(asked, initial=0.0)))
    return top
