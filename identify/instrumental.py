"""``iv``: instrumental variables with instruments from the simulated noise-free output.

Speed from a differenced encoder is the *average* over the last interval,
``w_k = (theta_k - theta_{k-1}) / h``.  Under a ZOH duty the averages obey,
exactly (derivation: difference the angle recursion of ``motorsim.plant``)::

    w_{k+1} = e w_k + b v_k,   v_k = (q u_k + (p^2 - e q) u_{k-1}) / h
    e = exp(-a h),  p = (1 - e)/a,  q = (h - p)/a

(``e``, ``b`` are the two unknowns; ``v`` depends on ``a`` only through known
functions and is recomputed at each pass).  The regressor ``w_k`` carries the
quantisation error that is also in ``w_{k+1}`` (errors in variables), which
biases least squares.  The instruments ``(x_k, v_k)`` replace ``w_k`` by
``x_k``, the model's own noise-free averaged speed under the current estimate,
uncorrelated with the measurement error; ``iterations`` passes (Young's
simplified refined IV without prefilters) from the ``zoh-ls`` start (a log-grid
start when ``zoh-ls`` finds no stable model) (Söderström & Stoica, *System Identification* (1989), ch. 8;
Young, *Recursive Estimation and Time-Series Analysis* (2011), ch. 7).  It is
not iterative-to-convergence: a fixed number of linear solves.

Assumes a uniform clock (jitter adds an error of order ``jitter * a h``); for
speed-only recordings the speed column is used as the averages.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import root_scalar

from .errors import NotIdentifiableError
from .estimate import Estimate
from .output_error import _check_delay, check_excitation, select_delay
from .regression import as_recordings
from .sensitivity import zoh_response
from .validation import fit_percent

__all__ = ["fit_instrumental_variables"]


def _rows(recs, delay):
    """Per gap-free stretch: (w, u, time) with the delayed input."""
    out = []
    for rec in recs:
        w_all = rec.measured_speed()
        start = 0
        for seg in rec.segments():
            n = len(seg)
            w = w_all[start:start + n]
            start += n
            u = seg.duty
            if delay:
                u = np.concatenate([np.full(delay, np.nan), u[:-delay]])
            ok = np.isfinite(w) & np.isfinite(u)
            first = int(np.argmax(ok)) if ok.any() else n
            if n - first >= 4 and np.all(ok[first:]):
                out.append((w[first:], u[first:], seg.time[first:]))
    return out


def _model_average_speed(a, b, u, t):
    resp = zoh_response(a, b, u, t, 0.0)
    out = np.empty(len(t))
    out[0] = 0.0
    out[1:] = np.diff(resp.angle) / np.diff(t)
    return out


def fit_instrumental_variables(recordings, *, delay: int | str = 0, iterations: int = 3) -> Estimate:
    """Refined-IV estimate of ``a``, ``b`` from averaged (differenced) speed.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled over gap-free segments.
    delay : int or "auto"
        Input delay in samples (``"auto"`` chooses it by output error).
    iterations : int
        IV passes after the ``zoh-ls`` start, >= 1 (default 3).

    Returns
    -------
    Estimate
        ``method = "iv"``; covariance over ``("a", "b")`` from the IV formula
        ``s^2 (Z^T Phi)^{-1} Z^T Z (Z^T Phi)^{-T}``, mapped to ``(a, b)`` (``v``'s
        dependence on ``a`` neglected); it treats
        the equation error as white, which differenced quantisation is not, so
        it is indicative only.

    Raises
    ------
    NotIdentifiableError
        As for ``oe``, or when the estimate gives ``e = exp(-a h)`` outside (0, 1).
    """
    recs = as_recordings(recordings)
    delay = _check_delay(delay)
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
    check_excitation(recs, 3)
    if delay == "auto":
        delay = select_delay(recs)
    delay = delay or 0
    stretches = _rows(recs, delay)
    if not stretches:
        raise NotIdentifiableError("recording is too short: no gap-free stretch of 4 samples; record longer")
    h = recs[0].sample_period
    w_now = np.concatenate([w[1:-1] for w, _, _ in stretches])
    y = np.concatenate([w[2:] for w, _, _ in stretches])
    if len(y) < 6:
        raise NotIdentifiableError(f"recording is too short: {len(y)} IV rows for 2 coefficients; record longer")
    a, b = _start(recs, delay)

    def solve(a_filter, x_inst):
        """IV solve with the input filter at ``a_filter`` and instruments ``x_inst``."""
        Phi = np.column_stack([w_now, _filtered_input(a_filter, stretches, h)])
        Z = np.column_stack([x_inst, Phi[:, 1]])
        M = Z.T @ Phi
        if not np.all(np.isfinite(M)) or np.linalg.cond(M) > 1e12:
            raise NotIdentifiableError("iv: instruments and regressors are (nearly) collinear; the input is not "
                                       "persistently exciting (use a sine, multisine or PRBS)")
        return np.linalg.solve(M, Z.T @ y), Phi, Z, M

    def a_of(theta):
        e = float(theta[0])
        if not 0 < e < 1:
            raise NotIdentifiableError(f"iv: theta1 = e = {e:.6g} is not in (0, 1), so no stable first-order "
                                       "model fits; check the sign of the input and that the motor moved")
        return -math.log(e) / h

    for _ in range(int(iterations)):
        # instruments from the current model; then the a inside the input filter must agree with
        # the a that the solved e implies: a one-dimensional root (plain substitution diverges
        # for a h ~ 2 on a single sine, where e and the filter trade off)
        x_inst = np.concatenate([_model_average_speed(a, b, u, t)[1:-1] for _, u, t in stretches])
        try:
            root = root_scalar(lambda lg: math.log(a_of(solve(math.exp(lg), x_inst)[0])) - lg,
                               x0=math.log(a), x1=math.log(a) + 0.01, method="secant", xtol=1e-13, maxiter=50)
            a_new = math.exp(root.root) if root.converged else math.nan
        except (NotIdentifiableError, ValueError, OverflowError):
            a_new = math.nan
        if not (math.isfinite(a_new) and a_new > 0):
            a_new = a_of(solve(a, x_inst)[0])   # fall back to one substitution step
        theta, Phi, Z, M = solve(a_new, x_inst)
        a, b = a_of(theta), float(theta[1])
    e = float(theta[0])
    resid = y - Phi @ theta
    s2 = float(resid @ resid) / max(len(y) - 2, 1)
    Minv = np.linalg.inv(M)
    cov_theta = s2 * Minv @ (Z.T @ Z) @ Minv.T
    jac = np.array([[-1.0 / (e * h), 0.0], [0.0, 1.0]])
    cov = jac @ cov_theta @ jac.T
    return Estimate(method="iv", a=a, b=b, n_samples=len(y), sample_period=h,
                    residual_rms=math.sqrt(float(resid @ resid) / len(y)),
                    fit_percent=fit_percent(a, b, recs, input_delay=delay), covariance=cov,
                    extra={"input_delay": float(delay)}, input_unit=recs[0].input_unit)


def _filtered_input(a, stretches, h):
    """``(q u_k + (p^2 - e q) u_{k-1}) / h`` per row: the input term per unit ``b``."""
    e = math.exp(-a * h)
    p = -math.expm1(-a * h) / a
    q = (h - p) / a
    return np.concatenate([(q * u[1:-1] + (p * p - e * q) * u[:-2]) / h for _, u, _ in stretches])


def _start(recs, delay) -> tuple[float, float]:
    """zoh-ls, else the output-error module's robust log-grid start."""
    from .output_error import _grid_guess, prepare_segments
    from .regression import fit_zoh_ls
    try:
        est = fit_zoh_ls(recs)
        if est.a > 0 and math.isfinite(est.b):
            return est.a, est.b
    except NotIdentifiableError:
        pass
    segments = prepare_segments(recs, delay)
    if not segments:
        raise NotIdentifiableError("recording is too short: no gap-free stretch of 4 samples; record longer")
    return _grid_guess(segments)
