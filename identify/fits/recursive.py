"""Recursive least squares: a running estimate of a and b while the samples arrive.

:class:`RecursiveLeastSquares` is the textbook recursion (Ljung 1999, *System
Identification*, 2nd ed., eqs. 11.19-11.20, pp. 365-366; Åström & Wittenmark,
*Adaptive Control*, 2nd ed., Thm. 2.3): for a regressor ``phi`` and target ``y``,

    K     = P phi / (lambda + phi^T P phi)
    theta = theta + K (y - phi^T theta)
    P     = (P - K phi^T P) / lambda

which, with ``lambda = 1`` and ``P0 = delta^-1 I``, equals the batch least-squares
solution of the rows seen so far regularised by ``delta ||theta||^2``.

:class:`RunningEstimator` feeds it from incoming encoder samples (sample index,
time, duty, counts), with speed as the backward difference of the angle, as the
batch estimators do, and never pairs samples across a gap in the index.  Two
regressions are offered:

- ``"zoh-ls"``: ``omega_{k+1}`` on ``(omega_k, u_k)`` mapped back exactly as
  :func:`identify.fits.regression.fit_zoh_ls` does (the two agree to rounding on the
  same recording); biased on differenced encoder speed;
- ``"zoh-avg"`` (default): the exact model of the *differenced* speed
  ``v_k = (theta_k - theta_{k-1}) / h`` under ZOH, which is second order in
  the input::

      v_{k+1} = e v_k + beta1 u_k + beta0 u_{k-1},  e = exp(-a h),
      beta1 = q / h,  beta0 = (p g - q e) / h   (p, q, g as in motorsim.plant),

  fitted in ``(a, b)`` directly (the static gain ``(beta1 + beta0)/(1 - e) = b/a``).
  On noise-free samples it recovers a and b exactly; only the encoder's
  quantisation is left (0.03 % on the article's 200 sin(10 t) with 16 667 counts/rev).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from motorsim.checks import ParameterError, check_int, check_real
from motorsim.plant import speed_coefficients

__all__ = ["RecursiveLeastSquares", "RunningEstimator", "RunningEstimate", "RUNNING_MODELS"]

#: Regressions :class:`RunningEstimator` offers.
RUNNING_MODELS = ("zoh-avg", "zoh-ls")


class RecursiveLeastSquares:
    """Recursive least squares for ``y = phi^T theta``, updated one row at a time.

    Parameters
    ----------
    n_params : int
        Length of ``theta``.
    forgetting : float
        ``lambda`` in (0, 1]; 1 (default) weights every row equally.
    initial_covariance : float
        ``P0 = initial_covariance I``; large means a vague start (default 1e8).
    """

    def __init__(self, n_params: int, *, forgetting: float = 1.0, initial_covariance: float = 1e8):
        n_params = check_int("n_params", n_params, lo=1, allow_integral_float=False)
        forgetting = check_real("forgetting", forgetting, positive=True)
        if forgetting > 1:
            raise ParameterError(f"forgetting must be in (0, 1], got {forgetting!r}")
        initial_covariance = check_real("initial_covariance", initial_covariance, positive=True)
        self._theta = np.zeros(n_params)
        self._P = np.eye(n_params) * float(initial_covariance)
        self._lambda = float(forgetting)
        self.n_updates = 0

    @property
    def theta(self) -> np.ndarray:
        """The current estimate (a copy)."""
        return self._theta.copy()

    @property
    def covariance(self) -> np.ndarray:
        """The current ``P`` (a copy); times the noise variance it is theta's covariance."""
        return self._P.copy()

    def update(self, phi, y: float) -> None:
        """Take one row: regressor ``phi`` (length ``n_params``) and target ``y``."""
        phi = np.asarray(phi, dtype=float)
        if phi.shape != self._theta.shape:
            raise ParameterError(f"phi must have shape {self._theta.shape}, got {phi.shape}")
        if not (np.all(np.isfinite(phi)) and math.isfinite(y)):
            raise ParameterError(f"phi and y must be finite, got {phi!r} and {y!r}")
        Pphi = self._P @ phi
        gain = Pphi / (self._lambda + phi @ Pphi)
        self._theta += gain * (y - phi @ self._theta)
        P = (self._P - np.outer(gain, Pphi)) / self._lambda
        self._P = 0.5 * (P + P.T)     # keep it symmetric against rounding
        self.n_updates += 1


@dataclasses.dataclass(frozen=True)
class RunningEstimate:
    """A running estimate: ``a`` in 1/s and ``b`` in (rad/s^2)/duty (nan until identifiable), rows used."""

    model: str
    a: float
    b: float
    n_rows: int

    @property
    def ready(self) -> bool:
        """True when a and b are finite."""
        return math.isfinite(self.a) and math.isfinite(self.b)

    def to_dict(self) -> dict:
        """Plain types for JSON."""
        return {"model": self.model, "a": self.a if self.ready else None, "b": self.b if self.ready else None,
                "n_rows": self.n_rows}


class RunningEstimator:
    """Running estimate of a and b from samples as they arrive.

    Parameters
    ----------
    sample_period : float
        Nominal sample period h in s (the ZOH mapping uses it).
    counts_per_rev : int
        Encoder counts per revolution.
    model : {"zoh-avg", "zoh-ls"}
        The regression (see the module docstring); default ``"zoh-avg"``.
    forgetting : float
        Forgetting factor lambda in (0, 1], default 1 (every row weighs the same).
    input_delay : int
        Samples between a sample's duty and the interval it acts on (a device that applies each
        duty at the next tick records 1); default 0.

    Notes
    -----
    ``"zoh-ls"`` runs :class:`RecursiveLeastSquares` on ``(omega_k, u_k) -> omega_{k+1}``.
    ``"zoh-avg"`` keeps the normal equations of the three-regressor model recursively,
    ``R = lambda R + phi phi^T`` and ``r = lambda r + phi y`` with
    ``phi = (v_k, u_k, u_{k-1})``, ``y = v_{k+1}`` (RLS in information form, O(1) per
    sample), and :meth:`estimate` minimises the least-squares criterion
    ``beta^T R beta - 2 beta^T r`` over ``(a, b)`` through the exact map
    ``beta(a, b) = (e, beta1, beta0)`` (two parameters, Gauss-Newton warm-started from
    the previous estimate).  Constraining the three coefficients to the two physical
    parameters keeps it well posed on a single sine, where the three regressors are
    nearly collinear.
    """

    def __init__(self, sample_period: float, counts_per_rev: int, *, model: str = "zoh-avg",
                 forgetting: float = 1.0, input_delay: int = 0):
        self._input_delay = check_int("input_delay", input_delay, lo=0, hi=50)
        sample_period = check_real("sample_period", sample_period, positive=True)
        counts_per_rev = check_int("counts_per_rev", counts_per_rev, lo=1, allow_integral_float=False)
        if model not in RUNNING_MODELS:
            raise ParameterError(f"model must be one of {list(RUNNING_MODELS)}, got {model!r}")
        self.model = model
        self._h = float(sample_period)
        self._rad_per_count = 2.0 * math.pi / counts_per_rev
        self._rls = RecursiveLeastSquares(2, forgetting=forgetting)   # zoh-ls; validates forgetting
        self._lambda = float(forgetting)
        self._R = np.zeros((3, 3))
        self._r = np.zeros(3)
        self._n = 0
        self._cache: RunningEstimate | None = None
        self._last_ab: tuple[float, float] | None = None
        self._hist: list[tuple[int, float, float, float]] = []   # (seq, time, angle, duty), consecutive seqs
        self._duties: list[float] = []      # the last input_delay duties, not acting yet
        self._last_seq = -1

    def add(self, seq: int, time_s: float, duty: float, counts: int) -> None:
        """Take one sample; rows are formed only from consecutive sample indices."""
        angle = counts * self._rad_per_count
        if self._duties and seq != self._last_seq + 1 or self._hist and seq != self._hist[-1][0] + 1:
            self._hist, self._duties = [], []
        self._last_seq = seq
        self._duties.append(float(duty))
        if len(self._duties) <= self._input_delay:
            return                          # the duty acting from this sample on is not known yet
        self._hist.append((seq, time_s, angle, self._duties.pop(0)))
        if len(self._hist) > 4:
            del self._hist[0]
        hist = self._hist
        if len(hist) < 3:
            return
        # speed at the newest sample and the one before it (backward differences)
        v1 = (hist[-1][2] - hist[-2][2]) / (hist[-1][1] - hist[-2][1])
        v0 = (hist[-2][2] - hist[-3][2]) / (hist[-2][1] - hist[-3][1])
        if self.model == "zoh-ls":
            self._rls.update([v0, hist[-2][3]], v1)
        elif len(hist) >= 4:
            phi = np.array([v0, hist[-2][3], hist[-3][3]])
            self._R = self._lambda * self._R + np.outer(phi, phi)
            self._r = self._lambda * self._r + phi * v1
            self._n += 1
        self._cache = None

    @property
    def n_rows(self) -> int:
        """Rows taken so far."""
        return self._rls.n_updates if self.model == "zoh-ls" else self._n

    def estimate(self) -> RunningEstimate:
        """a and b now (nan until the rows identify a stable model)."""
        if self._cache is None:
            self._cache = self._estimate_zoh_ls() if self.model == "zoh-ls" else self._estimate_zoh_avg()
        return self._cache

    def _estimate_zoh_ls(self) -> RunningEstimate:
        theta, n = self._rls.theta, self._rls.n_updates
        e = theta[0]
        if n < 3 or not 0 < e < 1:
            return RunningEstimate(self.model, math.nan, math.nan, n)
        a = -math.log(e) / self._h
        return RunningEstimate(self.model, float(a), float(a * theta[1] / (1.0 - e)), n)

    def _beta(self, a: float, b: float) -> np.ndarray:
        e, _, beta1, beta2 = speed_coefficients(a, b, self._h)
        return np.array([e, beta1, beta2])

    def _estimate_zoh_avg(self) -> RunningEstimate:
        n = self._n
        nan = RunningEstimate(self.model, math.nan, math.nan, n)
        if n < 4:
            return nan
        lam, vec = np.linalg.eigh(self._R)
        keep = lam > lam[-1] * 1e-13
        if not np.any(keep):
            return nan
        S = np.sqrt(lam[keep])[:, None] * vec[:, keep].T          # criterion = ||S beta - t||^2 + const
        t = (vec[:, keep].T @ self._r) / np.sqrt(lam[keep])
        start = self._last_ab
        if start is None:                                         # the unconstrained solution as a start
            x = np.linalg.lstsq(self._R, self._r, rcond=None)[0]
            if not 0 < x[0] < 1:
                return nan
            a0 = -math.log(x[0]) / self._h
            start = (a0, a0 * (x[1] + x[2]) / (1.0 - x[0]))
        try:
            from scipy.optimize import least_squares  # imported when used: slow to import
            sol = least_squares(lambda ab: S @ self._beta(ab[0], ab[1]) - t, start,
                                bounds=([1e-9, -np.inf], [np.inf, np.inf]), x_scale="jac")
        except ValueError:     # e.g. a start outside the bounds after a bad stretch of data
            return nan
        a, b = (float(x) for x in sol.x)
        if not (math.isfinite(a) and math.isfinite(b)):
            return nan
        self._last_ab = (a, b)
        return RunningEstimate(self.model, a, b, n)
