"""``oe`` on many repetitions at once: the separable Gauss--Newton of ``identify.fits.variable_projection`` row by row.

The kernel of :func:`identify.fits.batch.fit_output_error_batch`.  The repetitions of one sweep
point share the duty and the (uniform) clock and differ only in their encoder readings, so
every quantity of the separable fit (:mod:`identify.fits.variable_projection`: ``b``, the initial speed and the offset
projected out, Gauss--Newton in ``a`` alone) is a 2-D array with one row per
repetition and one ``a`` per row.  The first-order filters with a different
pole per row are solved in closed form over blocks,
``y_{s+j} = e^j (e y_{s-1} + sum_{i<=j} e^{-i} x_{s+i})``, the blocks short
enough that ``e^{-j}`` stays far from overflow.  Rows that do not converge
are left ``nan`` for the caller to fit one by one (``identify.fit``), which
then also reports why.  On the rows that converge the minimiser is that of
``identify.fit(recording, method="oe")``: the two agree to rounding (a test
compares them).
"""
from __future__ import annotations

import math

import numpy as np

from .sensitivity import phi_functions

__all__ = ["output_error_batch"]

#: ``a h j`` at most this within one block of the closed-form filter (``e^{150}`` is far from overflow).
_BLOCK_EXPONENT = 150.0
#: As :data:`identify.fits.variable_projection.STEP_RTOL` and ``MAX_ITERATIONS``.
_STEP_RTOL = 1e-8
_MAX_ITERATIONS = 30


def _filter_rows(a_h: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``y_0 = x_0``, ``y_k = exp(-a_h[r]) y_{k-1} + x_k`` along each row (``x`` 1-D is shared by all rows)."""
    rows, n = len(a_h), x.shape[-1]
    out = np.empty((rows, n))
    carry = np.zeros(rows)
    length = max(1, int(_BLOCK_EXPONENT / max(float(np.max(a_h)), 1e-300)))
    j = np.arange(min(length, n))
    for start in range(0, n, length):
        stop = min(n, start + length)
        jj = j[:stop - start]
        grow = np.exp(np.outer(a_h, jj))                 # e^{-j}
        block = x[..., start:stop] * grow
        np.cumsum(block, axis=1, out=block)
        block += (np.exp(-a_h) * carry)[:, None]
        block /= grow                                    # times e^{j}
        out[:, start:stop] = block
        carry = block[:, -1]
    return out


def _rowdot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", x, y)


def _centre(x: np.ndarray) -> np.ndarray:
    x -= x.mean(axis=1, keepdims=True)
    return x


def _evaluate(a: np.ndarray, y: np.ndarray, u: np.ndarray, h_sum: np.ndarray, h: float, direction: bool):
    """Per row: ``b`` and, with ``direction``, the Gauss--Newton step in ``a`` (see
    identify.fits.variable_projection)."""
    x = a * h
    p1, _, d1, _ = phi_functions(x)
    e = np.exp(-x)
    p, dp, hep = h * p1, h * h * d1, h * e * h * p1
    f = _filter_rows(x, u)                                # F_k = e F_{k-1} + u_k
    n = y.shape[1]
    bcol = np.empty_like(y)
    bcol[:, 0] = 0.0
    np.multiply(f, -p[:, None], out=bcol[:, 1:])
    bcol += h_sum
    _centre(bcol)
    tau_a = np.outer(a * h, np.arange(n))
    d = _centre(-np.exp(-np.minimum(tau_a, 50.0)))       # D = -exp(-a tau) (2e-22 below: negligible)
    dd = _rowdot(d, d)
    bd = _rowdot(bcol, d) / dd
    yd = _rowdot(y, d) / dd
    bb = _rowdot(bcol, bcol) - bd * bd * dd
    beta = (_rowdot(bcol, y) - bd * yd * dd) / bb
    gamma = yd - beta * bd
    if not direction:
        return beta * a, None
    g_col = _filter_rows(x, f)
    g = np.empty_like(y)
    g[:, 0] = 0.0
    np.multiply(f, (-beta * dp)[:, None], out=g[:, 1:])
    g[:, 2:] += (beta * hep)[:, None] * g_col[:, :-1]
    g += (gamma * h)[:, None] * np.arange(n) * np.exp(-np.minimum(tau_a, 50.0))   # - gamma tau D
    _centre(g)
    gd = _rowdot(g, d)
    gdb = _rowdot(g, bcol)
    gb = gdb - gd * bd
    gr = _rowdot(g, y) - beta * gdb - gamma * gd
    curvature = _rowdot(g, g) - gd * gd / dd - gb * gb / bb
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(curvature > 0, gr / curvature, np.nan)
    return beta * a, step


def output_error_batch(angle: np.ndarray, duty: np.ndarray, sample_period: float,
                       start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``oe``'s ``a`` and ``b`` of every row of ``angle`` (``nan`` where the iteration fails).

    Parameters
    ----------
    angle : ndarray, shape (repetitions, n_samples)
        Measured angle in rad (counts times ``2 pi / counts_per_rev``).
    duty : ndarray, shape (n_samples,)
        The duty of every repetition, held from each sample to the next.
    sample_period : float
        Uniform sample period in s.
    start : ndarray, shape (repetitions,)
        Start values of ``a`` in 1/s (e.g. ``zoh-ls``'s); ``nan`` rows are not fitted.

    Returns
    -------
    a, b : ndarray, shape (repetitions,)
    """
    h = float(sample_period)
    y = _centre(np.array(angle, dtype=float))
    u = np.asarray(duty, dtype=float)[:-1]
    h_sum = np.zeros(y.shape[1])
    np.cumsum(u, out=h_sum[1:])
    h_sum *= h
    a = np.array(start, dtype=float)
    active = np.isfinite(a) & (a > 0)
    done = np.zeros(len(a), bool)
    for _ in range(_MAX_ITERATIONS):
        rows = np.flatnonzero(active & ~done)
        if len(rows) == 0:
            break
        _, step = _evaluate(a[rows], y[rows], u, h_sum, h, True)
        bad = ~np.isfinite(step)
        a[rows] += np.where(bad, 0.0, step)
        active[rows[bad]] = False
        with np.errstate(invalid="ignore"):
            done[rows[np.abs(step) <= _STEP_RTOL * np.abs(a[rows])]] = True
        active &= np.isfinite(a) & (a > 0)
    ok = active & done
    a_out = np.full(len(a), math.nan)
    b_out = np.full(len(a), math.nan)
    rows = np.flatnonzero(ok)
    if len(rows):
        b, _ = _evaluate(a[rows], y[rows], u, h_sum, h, False)
        a_out[rows], b_out[rows] = a[rows], b
    return a_out, b_out
