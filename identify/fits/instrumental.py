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

import dataclasses
import math

import numpy as np

from motorsim.checks import check_int
from motorsim.plant import first_order_coefficients
from motorsim.recording import Recording
from motorsim.recursion import first_order_filter

from ..checks.validation import fit_percent
from ..data import DEFAULT_INPUT_DELAY, as_recordings, check_excitation, check_input_delay, prepare_segments
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..sums import dot
from .output_error import select_delay
from .sensitivity import UNIFORM_RTOL, phi_functions, zoh_response
from .start import initial_guess, regression_guess

__all__ = ["fit_instrumental_variables"]

Stretch = tuple[np.ndarray, np.ndarray, np.ndarray]


def _rows(recs: list[Recording], delay: int) -> list[Stretch]:
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


def _model_average_speed(a: float, b: float, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    resp = zoh_response(a, b, u, t, 0.0, sensitivities=False)
    out = np.empty(len(t))
    out[0] = 0.0
    out[1:] = np.diff(resp.angle) / np.diff(t)
    return out


def _model_average_speed_rows(a: float, b: float, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """:func:`_model_average_speed` on rows ``1 ... n-2``, in one first-order filter pass on a uniform clock.

    The model's angle increment over interval ``k`` is ``b (p w_k + q u_k)`` with
    ``w_{k+1} = e w_k + p u_k`` (``w_0 = 0``), so the average speeds need neither the
    angle nor its differences.
    """
    steps = np.diff(t)
    if not (len(steps) and np.all(np.abs(steps - steps[0]) <= UNIFORM_RTOL * abs(steps[0]))):
        return _model_average_speed(a, b, u, t)[1:-1]
    h = float(steps[0])
    p1, p2, _, _ = (float(f[0]) for f in phi_functions(np.array([a * h])))
    p, q = h * p1, h * h * p2
    v = np.asarray(u[:-2], dtype=float)
    w = np.zeros(len(v))                             # w_0 = 0, w_{k+1} = e w_k + p u_k
    first_order_filter(first_order_coefficients(a, h)[0], p * v[:-1], out=w[1:])
    w *= p
    w += q * v
    w *= b
    w /= steps[:-1]
    return w


@dataclasses.dataclass(frozen=True)
class _IvSolution:
    """One IV solve: ``theta = (e, b)``, the regressor and instrument columns, ``M = Z^T Phi``.

    ``Phi = [w_now, v]`` and ``Z = [x, v]`` share the filtered input ``v``: the columns
    are kept apart rather than stacked into copies.
    """

    theta: np.ndarray
    w_now: np.ndarray
    v: np.ndarray
    x: np.ndarray
    M: np.ndarray

    def residuals(self, y: np.ndarray) -> np.ndarray:
        """``y - Phi theta``."""
        return y - self.theta[0] * self.w_now - self.theta[1] * self.v

    def instrument_gram(self) -> np.ndarray:
        """``Z^T Z``."""
        xv = dot(self.x, self.v)
        return np.array([[dot(self.x, self.x), xv], [xv, dot(self.v, self.v)]])


@dataclasses.dataclass(frozen=True)
class _IvRegression:
    """The rows of ``w_{k+1} = e w_k + b v_k`` over every stretch: regressor speed, target, sample period."""

    stretches: list[Stretch]
    w_now: np.ndarray
    y: np.ndarray
    h: float
    u_now: np.ndarray                  # u_k, row-aligned with w_now
    u_before: np.ndarray               # u_{k-1}
    moments: dict                      # dot products of the fixed columns (see :meth:`solve`)

    @classmethod
    def from_stretches(cls, stretches: list[Stretch], h: float) -> _IvRegression:
        w_now = np.concatenate([w[1:-1] for w, _, _ in stretches])
        y = np.concatenate([w[2:] for w, _, _ in stretches])
        u1 = np.concatenate([np.asarray(u[1:-1], dtype=float) for _, u, _ in stretches])
        u0 = np.concatenate([np.asarray(u[:-2], dtype=float) for _, u, _ in stretches])
        moments = {"w1": dot(w_now, u1), "w0": dot(w_now, u0), "y1": dot(y, u1), "y0": dot(y, u0),
                   "11": dot(u1, u1), "10": dot(u1, u0), "00": dot(u0, u0)}
        return cls(stretches, w_now, y, h, u1, u0, moments)

    def instruments(self, a: float, b: float) -> np.ndarray:
        """The model's own noise-free averaged speed under ``(a, b)``, row-aligned with ``w_now``."""
        return np.concatenate([_model_average_speed_rows(a, b, u, t) for _, u, t in self.stretches])

    def instrument_moments(self, x_inst: np.ndarray) -> dict:
        """The dot products of the instruments with the fixed columns (once per instrument)."""
        return {"xw": dot(x_inst, self.w_now), "xy": dot(x_inst, self.y),
                "x1": dot(x_inst, self.u_now), "x0": dot(x_inst, self.u_before)}

    def solve(self, a_filter: float, x_inst: np.ndarray, x_moments: dict, columns: bool = True) -> _IvSolution:
        """IV solve with the input filter at ``a_filter`` and instruments ``x_inst``.

        The filtered input ``v = c1 u_k + c0 u_{k-1}`` is linear in two fixed columns, so
        ``M = Z^T Phi`` and ``Z^T y`` come from dot products taken once (no pass over the
        data per solve); ``v`` itself is formed only with ``columns``.
        """
        c1, c0 = _filter_coefficients(a_filter, self.h)
        m, xm = self.moments, x_moments
        xv = c1 * xm["x1"] + c0 * xm["x0"]
        vw = c1 * m["w1"] + c0 * m["w0"]
        vv = c1 * c1 * m["11"] + 2 * c1 * c0 * m["10"] + c0 * c0 * m["00"]
        M = np.array([[xm["xw"], xv], [vw, vv]])
        if not np.all(np.isfinite(M)) or np.linalg.cond(M) > 1e12:
            raise NotIdentifiableError("iv: instruments and regressors are (nearly) collinear; the input is not "
                                       "persistently exciting (use a sine, multisine or PRBS)")
        rhs = np.array([xm["xy"], c1 * m["y1"] + c0 * m["y0"]])
        v = c1 * self.u_now + c0 * self.u_before if columns else self.u_now[:0]
        return _IvSolution(np.linalg.solve(M, rhs), self.w_now, v, x_inst, M)

    def pole(self, theta: np.ndarray) -> float:
        """``a = -ln(e) / h`` from ``theta = (e, b)``; refuses ``e`` outside (0, 1)."""
        e = float(theta[0])
        if not 0 < e < 1:
            raise NotIdentifiableError(f"iv: theta1 = e = {e:.6g} is not in (0, 1), so no stable first-order "
                                       "model fits; check the sign of the input and that the motor moved")
        return -math.log(e) / self.h

    def iterate(self, a: float, b: float, last: bool = True) -> _IvSolution:
        """One IV pass from the model ``(a, b)`` (the regressor columns formed only when ``last``).

        Instruments from the current model; then the ``a`` inside the input filter
        must agree with the ``a`` that the solved ``e`` implies: a one-dimensional
        root (plain substitution diverges for ``a h ~ 2`` on a single sine, where
        ``e`` and the filter trade off).
        """
        x_inst = self.instruments(a, b)
        xm = self.instrument_moments(x_inst)
        try:
            from scipy.optimize import root_scalar  # imported when used: slow to import
            root = root_scalar(lambda lg: math.log(self.pole(self.solve(math.exp(lg), x_inst, xm, False).theta)) - lg,
                               x0=math.log(a), x1=math.log(a) + 0.01, method="secant", xtol=1e-13, maxiter=50)
            a_new = math.exp(root.root) if root.converged else math.nan
        except (NotIdentifiableError, ValueError, OverflowError):
            a_new = math.nan
        if not (math.isfinite(a_new) and a_new > 0):
            a_new = self.pole(self.solve(a, x_inst, xm, False).theta)   # fall back to one substitution step
        return self.solve(a_new, x_inst, xm, last)


def fit_instrumental_variables(recordings: Recording | list[Recording], *,
                               input_delay: int | str = DEFAULT_INPUT_DELAY,
                               iterations: int = 3) -> Estimate:
    """Refined-IV estimate of ``a``, ``b`` from averaged (differenced) speed.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled over gap-free segments.
    input_delay : int or "auto"
        Input delay in samples, or ``"auto"`` (default, :data:`identify.data.DEFAULT_INPUT_DELAY`), chosen by
        output error.
    iterations : int
        IV passes after the ``zoh-ls`` start, >= 1 (default 3).

    Returns
    -------
    Estimate
        ``method = "iv"``; covariance over ``("a", "b")`` from the IV formula
        ``s^2 (Z^T Phi)^{-1} Z^T Z (Z^T Phi)^{-T}``, mapped to ``(a, b)`` (``v``'s
        dependence on ``a`` neglected); it treats
        the equation error as white, which differenced quantisation is not, so
        it is indicative only.  ``extra["input_delay"]`` in samples.

    Raises
    ------
    NotIdentifiableError
        As for ``oe``, or when the estimate gives ``e = exp(-a h)`` outside (0, 1).
    """
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    iterations = check_int("iterations", iterations, lo=1, allow_integral_float=False)
    check_excitation(recs, 3)
    delay = select_delay(recs) if input_delay == "auto" else int(input_delay)
    stretches = _rows(recs, delay)
    if not stretches:
        raise NotIdentifiableError("recording is too short: no gap-free stretch of 4 samples; record longer")
    h = recs[0].sample_period
    regression = _IvRegression.from_stretches(stretches, h)
    if len(regression.y) < 6:
        raise NotIdentifiableError(f"recording is too short: {len(regression.y)} IV rows for 2 coefficients; "
                                   "record longer")
    guess = regression_guess(recs)
    a, b = guess if guess is not None else initial_guess(recs, prepare_segments(recs, delay))
    for i in range(iterations):
        sol = regression.iterate(a, b, last=i == iterations - 1)
        a, b = regression.pole(sol.theta), float(sol.theta[1])
    return _estimate(regression, sol, a, b, recs, delay)


def _estimate(regression: _IvRegression, sol: _IvSolution, a: float, b: float, recs: list[Recording],
              delay: int) -> Estimate:
    """The estimate with the IV covariance (see :func:`fit_instrumental_variables`)."""
    h, y = regression.h, regression.y
    e = float(sol.theta[0])
    resid = sol.residuals(y)
    rss = dot(resid, resid)
    s2 = rss / max(len(y) - 2, 1)
    Minv = np.linalg.inv(sol.M)
    cov_theta = s2 * Minv @ sol.instrument_gram() @ Minv.T
    jac = np.array([[-1.0 / (e * h), 0.0], [0.0, 1.0]])
    cov = jac @ cov_theta @ jac.T
    return Estimate(method="iv", structure="linear", a=a, b=b, n_samples=len(y), sample_period=h,
                    residual_rms=math.sqrt(rss / len(y)),
                    fit_percent=fit_percent(a, b, recs, input_delay=delay), covariance=cov,
                    extra={"input_delay": delay}, input_unit=recs[0].input_unit, input_limit=recs[0].input_limit,
                    covariance_method="instrumental-variables")


def _filter_coefficients(a: float, h: float) -> tuple[float, float]:
    """``(q / h, (p^2 - e q) / h)``: the filtered input per unit ``b`` is ``c1 u_k + c0 u_{k-1}``."""
    e, p, q = first_order_coefficients(a, h)
    return q / h, (p * p - e * q) / h
