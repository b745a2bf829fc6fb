"""Part checks of a closed-loop answer, on its one-step prediction errors: they need no right structure.

In a closed loop the output-error residual holds the fed-back noise, which the duty answers, so the open-loop part
checks (:mod:`identify.default.consistency`) cannot be made on it.  The ``pem-disturbance`` fit's innovations (its
one-step prediction errors) can be tested instead: under the right model they are white and each is independent of
everything measured before it (Ljung, *System Identification*, 2nd ed. (1999), sec. 16.6).  A column that is a
function of the past (the predicted speed on one part of the rows, the duty on another, a curve of the speed) then
explains none of them, whatever the loop feeds back: that is a Lagrange-multiplier (score) test of the model with
per-part parameters against the model as fitted, made without refitting it.

For each check the model's own parameters (``a``, ``b``, friction, bias, the disturbance's pole and intensity) get
per-part companions, ``dω/dt = -(a + δa 1_S) ω + (b + δb 1_S) u + δd 1_S + ...`` as the open-loop checks form them
(the same parts and the same columns: early / late as a trend along the run, forward / reverse, low / high drive,
slow / fast, the gain by duty, a torque of the angle, friction by speed), with ``ω`` the filter's predicted mean
speed over each interval.  Each companion's column is the derivative of the scaled innovations with respect to it,
at zero: an extra acceleration carried through the Kalman predictor with its gain (:func:`extra_input_pass`, the
friction's stuck intervals passing none of it on).  The innovations are regressed on the model's own Jacobian and
the companions' columns (one Gauss--Newton step of the model with per-part parameters, from the fit), and the
companions are tested against zero by :mod:`identify.default.consistency`'s tests (Hotelling's ``T^2`` with the
blocks' jackknife and the classical covariance, both at the level over the number of checks made); the parts'
``a`` and ``b`` are the step's, with their intervals.  Where parts disagree the answer's intervals widen to hold
each part's, and where a part is materially off (:data:`~identify.default.comparison.MATERIAL`) the answer is not
clear: the caller (:func:`identify.default.feedback.fit_closed_loop`) says which part differs and what it suggests.

On a long recording the check takes :data:`WINDOWS` windows of each segment, in proportion, up to
:data:`MAX_ROWS` rows (each window's filter starts diffuse, as every segment's does): its cost stays a few
filter passes however long the run.
"""
from __future__ import annotations

import functools
import math
from typing import Any, Callable, Sequence

import numpy as np

from motorsim.compiled import numba_jit
from motorsim.plant import first_order_coefficients

from ..comparison import _block_starts
from ..data import Segment
from ..fits.prediction_error import (
    LOG_RATIO_LIMIT,
    PredictionErrorFit,
    _friction_mode,
    _Problem,
    compiled_steps,
    gain_step,
    initial_covariance,
    next_covariance,
    with_compiled,
)
from .consistency import (
    ANGLE,
    CURVE,
    PART_LEVEL,
    SPEED_CURVE,
    PartCheck,
    _angle_inputs,
    _beside_check,
    _check,
    _curve_check,
    _curve_inputs,
    _fit_on,
    _friction_curve_inputs,
    _Moments,
    _parted_inputs,
    _Rows,
    _split_labels,
)

__all__ = ["innovation_checks", "extra_input_pass", "MAX_ROWS", "WINDOWS", "MIN_WINDOW"]

#: Rows the check uses at most (windows of every segment, in proportion).
MAX_ROWS = 20_000
#: Windows of a long segment the check takes, and the fewest rows of one.
WINDOWS = 4
MIN_WINDOW = 500


def extra_input_pass(u: np.ndarray, y: np.ndarray, speed_kind: bool, e: float, p: float, q: float, a: float,
                     h: float, b: float, c: float, bias: float, phi: float, ratio: float, w0: float,
                     z: np.ndarray, eps: np.ndarray, speed: np.ndarray, deps: np.ndarray) -> float:
    """:func:`identify.fits.prediction_error.filter_pass` on one segment, with what the checks need besides.

    Into ``eps`` the innovations over their standard deviations, as the filter's pass gives them; into ``speed`` the
    predicted mean speed over each interval (its angle over ``h``; the last row's interval too); into ``deps`` (shape
    ``(n, K)``) the derivatives of ``eps`` with respect to extra accelerations ``θ_j z[:, j]`` (held over each
    interval, entering where the duty does) at ``θ = 0``: the inputs' responses carried through the predictor and
    corrected by its gain, which they do not change.  An interval in which friction holds the shaft passes none of
    an extra acceleration on, and one in which friction stops (or reverses) the shaft passes it on exactly
    (through the instant it stops: :func:`_event_sensitivity`).
    Returns the sum of the logarithms of the innovations' variances."""
    n = len(u)
    k_cols = z.shape[1]
    th = y[0] if not speed_kind else 0.0
    w = w0 if not speed_kind else y[0]
    d = 0.0
    sth = np.zeros(k_cols)
    sw = np.zeros(k_cols)
    sd = np.zeros(k_cols)
    p00, p01, p02, p11, p12, p22 = initial_covariance(h, speed_kind)
    log_det = 0.0
    settled = steady = False
    s_var = k0 = k1 = k2 = scale = 1.0
    g0 = g1 = g2 = 0.0
    for k in range(n):
        if not steady:
            s_var, g0, g1, g2, k0, k1, k2, scale = gain_step(p00, p01, p02, p11, p12, speed_kind)
            log_det += (n - k if settled else 1) * math.log(s_var)
            steady = settled
        ek = y[k] - (w if speed_kind else th)
        eps[k] = ek * scale
        th += k0 * ek
        w += k1 * ek
        d += k2 * ek
        for j in range(k_cols):
            dek = -(sw[j] if speed_kind else sth[j])
            deps[k, j] = dek * scale
            sth[j] += k0 * dek
            sw[j] += k1 * dek
            sd[j] += k2 * dek
        force = b * u[k] + bias + d
        s, event, w_next, d_angle = _friction_mode(w, force, c, a, h, e, p, q)
        speed[k] = d_angle / h
        stuck = c > 0.0 and s == 0.0
        for j in range(k_cols):
            dforce = sd[j] + z[k, j]
            if stuck:
                sw[j] = 0.0
            elif event:
                dw_next, dth = _event_sensitivity(w, force, c, a, h, s, sw[j], dforce)
                sth[j] += dth
                sw[j] = dw_next
            else:
                sth[j] += p * sw[j] + q * dforce
                sw[j] = e * sw[j] + p * dforce
            sd[j] *= phi
        th += d_angle
        w = w_next
        d = phi * d
        if steady:
            continue
        p00, p01, p02, p11, p12, p22, settled = next_covariance(p00, p01, p02, p11, p12, p22, g0, g1, g2, k0, k1, k2,
                                                                e, p, q, phi, ratio, speed_kind)
    return log_det


def _event_sensitivity(w: float, force: float, c: float, a: float, h: float, s: float, dw: float,
                       dforce: float) -> tuple[float, float]:
    """The derivatives of an event interval's end speed and angle (:func:`identify.fits.friction_kernel.
    event_interval`, the static friction ``c``) along a change ``dw`` of its start speed and ``dforce`` of its
    force: through the instant the speed reaches zero, and on from it where the force turns the shaft back."""
    target = (force - s * c) / a
    ratio = (w - target) / (-target) if target != 0 else 0.0
    if not ratio >= 1.0:                      # a plain step (event_interval's own fallback)
        ex = math.exp(-a * h)
        return ex * dw + (1.0 - ex) / a * dforce, (1.0 - ex) / a * dw + (h - (1.0 - ex) / a) / a * dforce
    d_target = dforce / a
    t_zero = math.log(ratio) / a
    d_ratio = -dw / target + w * d_target / (target * target)
    d_t_zero = d_ratio / ratio / a
    d_angle = d_target * t_zero + target * d_t_zero + dw / a
    if abs(force) <= c:
        return 0.0, d_angle
    rest = h - t_zero
    target2 = (force + s * c) / a
    grown = -math.expm1(-a * rest)
    d_rest = -d_t_zero
    d_grown = a * math.exp(-a * rest) * d_rest
    return (d_target * grown + target2 * d_grown,
            d_angle + d_target * (rest - grown / a) + target2 * (d_rest - d_grown / a))


@functools.cache
def compiled_extra_input_pass() -> Callable[..., float] | None:
    """:func:`extra_input_pass` compiled by numba (cached on disk); None without numba or with ``MOTORID_NUMBA=0``."""
    jit = numba_jit()
    if jit is None:
        return None
    return with_compiled(extra_input_pass, jit, **compiled_steps(), _event_sensitivity=jit(_event_sensitivity))


def _windows(segments: Sequence[Segment]) -> tuple[list[Segment], list[int], int]:
    """The segments, or on more than :data:`MAX_ROWS` rows :data:`WINDOWS` windows of each spread evenly over it
    (in proportion, at least :data:`MIN_WINDOW` rows); each one's first row's place among all rows, and their
    number."""
    total = sum(len(seg.time) for seg in segments)
    out, places, place = [], [], 0
    for seg in segments:
        n = len(seg.time)
        keep = n if total <= MAX_ROWS else max(MIN_WINDOW, n * MAX_ROWS // total)
        if keep >= n:
            out.append(seg)
            places.append(place)
        else:
            width = max(MIN_WINDOW, keep // WINDOWS)
            for lo in np.linspace(0, n - width, max(1, keep // width)).astype(int):
                out.append(seg.rows(int(lo), int(lo) + width))
                places.append(place + int(lo))
        place += n
    return out, places, total


def _moments_of(X: np.ndarray, r: np.ndarray) -> _Moments:
    """:class:`~identify.default.consistency._Moments` of the columns ``X`` and the residual ``r`` over the blocks
    of :func:`identify.default.comparison.block_sums`."""
    n, k = X.shape
    bounds = np.append(_block_starts(n), n)
    scale = np.sqrt(np.einsum("ij,ij->j", X, X))
    scale[~(scale > 0)] = 1.0
    Xs = X / scale
    grams = np.empty((len(bounds) - 1, k, k))
    xr = np.empty((len(bounds) - 1, k))
    for i, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:])):
        part = Xs[lo:hi]
        grams[i] = part.T @ part
        xr[i] = r[lo:hi] @ part
    return _Moments(scale, grams.sum(axis=0), xr.sum(axis=0), float(r @ r), grams, xr, n)


def innovation_checks(estimate: Any, fit: PredictionErrorFit, *, level: float = PART_LEVEL) -> tuple[PartCheck, ...]:
    """The closed-loop answer's ``a`` and ``b`` on each part of its rows, tested on its innovations (module
    docstring).

    Parameters
    ----------
    estimate : Estimate
        ``fit``'s estimate (``pem-disturbance``).
    fit : PredictionErrorFit
        The solved fit on all rows (:func:`identify.fits.prediction_error.solve_prediction_error`).
    level : float
        Level of the whole check; each check's test is at ``level`` over the number made.

    Returns
    -------
    tuple of PartCheck
        One per check made; none where the innovations or their columns cannot be formed.
    """
    problem = fit.problem
    segs, places, total = _windows(problem.segments)
    a, b, c, bias, phi, lr = problem.unpack(np.asarray(fit.x, dtype=float))
    h = problem.h
    if not (segs and problem.disturbance and all(math.isfinite(v) for v in (a, b, c, bias, phi)) and a * h < 2.0):
        return ()
    windowed = _Problem(segs, problem.friction, h, problem.pole, problem.disturbance)
    r, jac = windowed.jacobian(np.asarray(fit.x, dtype=float))
    own = [jac[:, j] for j in range(jac.shape[1])]
    if not (np.all(np.isfinite(own[0])) and np.all(np.isfinite(own[1])) and np.all(np.isfinite(r))):
        return ()
    # a and b first (the checks' maps take them there), then the rest the data determine
    own = own[:2] + [col for col in own[2:] if np.all(np.isfinite(col)) and np.any(col != 0)]
    e, p, q = first_order_coefficients(a, h)
    args = (e, p, q, a, h, b, c, bias, phi, math.exp(min(lr, LOG_RATIO_LIMIT)))
    rows = _predicted_rows(segs, windowed.w0, places, total, args, r, problem.friction and c > 0)
    inputs, where = _check_inputs(rows)
    if not where:
        return ()
    deps = _derivatives(segs, windowed.w0, args, np.column_stack(inputs), len(r))
    if not np.all(np.isfinite(deps)):
        return ()
    # the model's output moves against its innovations: the columns are the prediction's derivatives
    moments = _moments_of(-np.column_stack(own + [deps[:, j] for j in range(deps.shape[1])]), r)
    p_own = len(own)
    base = list(range(p_own))
    alone = _fit_on(moments, base)
    each = level / len(where)
    checks = []
    for name, columns in where.items():
        fitted = _fit_on(moments, base + [p_own + j for j in columns])
        if name == CURVE:
            checks.append(_curve_check(estimate, fitted, p_own, each))
        elif name in (ANGLE, SPEED_CURVE):
            checks.append(_beside_check(name, estimate, alone, fitted, p_own, each))
        else:
            checks.append(_check(estimate, fitted, p_own, name, each))
    return tuple(checks)


def _predicted_rows(segs: list[Segment], w0: list[float], places: list[int], total: int, args: tuple,
                    r: np.ndarray, friction: bool) -> _Rows:
    """What the parts are made of, segments concatenated: the filter's predicted mean speed over each interval, the
    drive, each row's place in the run and the angle (a speed column's integrated); the last row's interval of each
    segment, which moves no innovation, is 0."""
    speeds, drives, orders, angles = [], [], [], []
    for seg, start, place in zip(segs, w0, places):
        n = len(seg.time)
        sp = np.empty(n)
        _pass()(seg.drive, seg.output, seg.kind == "speed", *args, float(start), np.zeros((n, 0)), np.empty(n), sp,
                np.empty((n, 0)))
        speeds.append(np.append(sp[:-1], 0.0))
        drives.append(np.append(np.asarray(seg.drive, dtype=float)[:-1], 0.0))
        orders.append((place + np.arange(n)) / max(total - 1, 1))
        if seg.kind == "angle":
            angles.append(np.asarray(seg.output, dtype=float))
        else:
            mean = 0.5 * (seg.output[1:] + seg.output[:-1])
            angles.append(np.concatenate([[0.0], np.cumsum(mean * np.diff(seg.time))]))
    return _Rows(r, np.concatenate(speeds), np.concatenate(drives), np.concatenate(orders), [],
                 np.concatenate(angles), [], friction, 1.0, None)


def _check_inputs(rows: _Rows) -> tuple[list[np.ndarray], dict[str, list[int]]]:
    """Every check's extra inputs (:mod:`identify.default.consistency`'s parts and curves) and, by check, their
    places among them."""
    inputs: list[np.ndarray] = []
    where: dict[str, list[int]] = {}
    made = [(name, _parted_inputs(rows, name, masks)) for name, masks in _split_labels(rows).items()]
    made += [(CURVE, _curve_inputs(rows)), (ANGLE, _angle_inputs(rows)), (SPEED_CURVE, _friction_curve_inputs(rows))]
    for name, cols in made:
        if cols:
            where[name] = list(range(len(inputs), len(inputs) + len(cols)))
            inputs.extend(cols)
    return inputs, where


def _derivatives(segs: list[Segment], w0: list[float], args: tuple, z: np.ndarray, n_rows: int) -> np.ndarray:
    """The scaled innovations' derivatives with respect to the extra inputs ``z`` (:func:`extra_input_pass`), scaled
    as :class:`~identify.fits.prediction_error._Problem`'s innovations are (by the geometric mean of their
    deviations)."""
    out = np.empty((n_rows, z.shape[1]))
    row, log_det = 0, 0.0
    for seg, start in zip(segs, w0):
        n = len(seg.time)
        log_det += _pass()(seg.drive, seg.output, seg.kind == "speed", *args, float(start),
                           np.ascontiguousarray(z[row:row + n]), np.empty(n), np.empty(n), out[row:row + n])
        row += n
    out *= math.exp(min(0.5 * log_det / max(n_rows, 1), LOG_RATIO_LIMIT))
    return out


def _pass() -> Callable[..., float]:
    """:func:`extra_input_pass`, compiled where numba is."""
    return compiled_extra_input_pass() or extra_input_pass
