"""One-step regressions on differenced speed: the article's method and its exact ZOH mapping.

Both regress ``omega_{k+1}`` on ``(omega_k, u_k)`` (article eqs. 13-17)::

    A = [[omega_0, u_0], ..., [omega_n, u_n]],  b = [omega_1, ..., omega_{n+1}],
    x = argmin ||A x - b||  (eq. 19, solved by QR/SVD via ``lstsq``, never an explicit inverse)

and differ in how ``x = (theta1, theta2)`` maps back to ``(a, b)``:

* ``euler-ls`` (forward Euler, eqs. 12, 25-28): ``[a, b] = C (x - d)`` with
  ``C = diag(-1, 1)/dt`` and ``d = [1, 0]``, i.e. ``a = (1 - theta1)/dt``, ``b = theta2/dt``.
  On noise-free sampled speed it converges to ``a_E = (1 - exp(-a dt))/dt``,
  ``b_E = b a_E / a``, not to ``(a, b)``.
* ``zoh-ls`` (exact zero-order hold): ``theta1 = exp(-a dt)``, ``theta2 = (b/a)(1 - theta1)``,
  so ``a = -ln(theta1)/dt``, ``b = a theta2 / (1 - theta1)``; requires ``0 < theta1 < 1``.

Rows are built inside each gap-free segment of each recording (the speed at k is
the backward difference of the angle, see ``motorsim.recording``), so recordings
are pooled into one regression.  The covariance is the ordinary least-squares one,
``s^2 (A^T A)^{-1}`` mapped to ``(a, b)`` by the Jacobian of the mapping; it
assumes noise-free regressors, which differenced encoder speed is not (errors in
variables), so treat it as optimistic.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

from ..checks.validation import fit_percent
from ..data import as_recordings
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..sums import dot

__all__ = ["regression_rows", "solve_least_squares", "fit_euler_ls", "fit_zoh_ls"]


def regression_rows(recordings: Sequence[Recording]) -> tuple[np.ndarray, np.ndarray]:
    """The article's ``A`` (rows ``[omega_k, u_k]``) and ``b`` (``omega_{k+1}``), pooled over segments."""
    rows, targets = [], []
    for rec in recordings:
        w = rec.measured_speed()
        u = rec.duty
        # pair (w_k, u_k) -> w_{k+1} only where both speeds are defined (no gap between k and k+1)
        ok = np.isfinite(w[:-1]) & np.isfinite(w[1:]) & (np.diff(rec.seq) == 1)
        rows.append(np.column_stack([w[:-1][ok], u[:-1][ok]]))
        targets.append(w[1:][ok])
    return np.concatenate(rows), np.concatenate(targets)


def solve_least_squares(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``x = argmin ||A x - y||`` with its OLS covariance and the residual RMS.

    Raises
    ------
    NotIdentifiableError
        Fewer rows than 3, or ``A`` rank-deficient (e.g. a constant or zero input).
    """
    n, p = A.shape
    if n < p + 1:
        raise NotIdentifiableError(f"recording is too short: {n} regression rows for {p} parameters; "
                                   "record more samples")
    cols = [np.ascontiguousarray(A[:, j], dtype=float) for j in range(p)]
    scale = np.sqrt([dot(c, c) for c in cols])
    if np.any(scale == 0):
        which = ["speed", "input"][int(np.flatnonzero(scale == 0)[0])] if p == 2 else "a regressor"
        raise NotIdentifiableError(f"{which} is identically zero: the input is not persistently exciting "
                                   "(use a sine, multisine or PRBS)")
    q, r = _thin_qr([c / s for c, s in zip(cols, scale)])
    sv = np.linalg.svd(r, compute_uv=False)      # the singular values of the scaled A
    if not sv[-1] > 0 or sv[-1] / sv[0] < 1e-10:
        raise NotIdentifiableError("regressors are (nearly) collinear: the input is not persistently exciting "
                                   "(use a sine, multisine or PRBS that moves the motor)")
    x = np.linalg.solve(r, [dot(qj, y) for qj in q]) / scale
    resid = np.array(y, dtype=float)
    for c, xj in zip(cols, x):
        resid -= xj * c
    rss = dot(resid, resid)
    # cov = s^2 (A^T A)^{-1} = s^2 (R^T R)^{-1} of the scaled A (no explicit inverse of A^T A)
    r_inv = np.linalg.inv(r)
    cov = rss / max(n - p, 1) * (r_inv @ r_inv.T) / np.outer(scale, scale)
    return x, cov, math.sqrt(rss / n)


def _thin_qr(columns: list[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
    """``A = Q R`` of a few long columns by Gram--Schmidt with one reorthogonalisation.

    Twice-iterated Gram--Schmidt is orthogonal to rounding (Giraud et al. 2005,
    *Numer. Math.* 101, 87), so ``R`` is as accurate as Householder's; the
    columns are processed with ``einsum``, not a threaded BLAS.
    """
    p = len(columns)
    r = np.zeros((p, p))
    q: list[np.ndarray] = []
    for j, v in enumerate(columns):
        v = v.copy()
        for _ in range(2):
            for i, qi in enumerate(q):
                c = dot(qi, v)
                r[i, j] += c
                v -= c * qi
        r[j, j] = math.sqrt(dot(v, v))
        q.append(v / r[j, j] if r[j, j] > 0 else v)
    return q, r


def _finish(method, a, b, jac, cov_x, rms, n, recs) -> Estimate:
    cov = jac @ cov_x @ jac.T
    return Estimate(method=method, a=float(a), b=float(b), n_samples=int(n),
                    sample_period=recs[0].sample_period, residual_rms=rms,
                    fit_percent=fit_percent(float(a), float(b), recs) if a > 0 else math.nan,
                    covariance=cov, input_unit=recs[0].input_unit,
                    input_limit=recs[0].input_limit, covariance_method="regression", structure="linear")


def fit_euler_ls(recordings) -> Estimate:
    """The article's method, eqs. 14-28: forward-Euler regression and ``[a, b] = C (x - d)``.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled into one regression (one sample period).

    Returns
    -------
    Estimate
        ``method = "euler-ls"``.
    """
    recs = as_recordings(recordings)
    A, y = regression_rows(recs)
    x, cov_x, rms = solve_least_squares(A, y)
    dt = recs[0].sample_period
    C = np.diag([-1.0, 1.0]) / dt          # eq. 27
    d = np.array([1.0, 0.0])               # eq. 28
    a, b = C @ (x - d)                     # eq. 26
    return _finish("euler-ls", a, b, C, cov_x, rms, len(y), recs)


def fit_zoh_ls(recordings) -> Estimate:
    """The same regression mapped back exactly through the ZOH model.

    ``a = -ln(theta1)/dt``, ``b = a theta2/(1 - theta1)``.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled into one regression (one sample period).

    Returns
    -------
    Estimate
        ``method = "zoh-ls"``.

    Raises
    ------
    NotIdentifiableError
        When ``theta1`` is not in (0, 1) (no stable first-order ZOH model matches the data).
    """
    recs = as_recordings(recordings)
    A, y = regression_rows(recs)
    x, cov_x, rms = solve_least_squares(A, y)
    dt = recs[0].sample_period
    t1, t2 = x
    if not 0 < t1 < 1:
        raise NotIdentifiableError(
            f"zoh-ls: theta1 = {t1:.6g} is not in (0, 1), so no stable first-order model fits "
            f"(a = -ln(theta1)/dt is undefined or negative); check the sign of the input, "
            f"the sample period ({dt!r} s) and that the motor actually moved")
    a = -math.log(t1) / dt
    b = a * t2 / (1.0 - t1)
    da1 = -1.0 / (t1 * dt)
    jac = np.array([[da1, 0.0],
                    [t2 * (da1 * (1 - t1) + a) / (1 - t1) ** 2, a / (1 - t1)]])
    return _finish("zoh-ls", a, b, jac, cov_x, rms, len(y), recs)
