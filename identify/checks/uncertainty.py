"""How well can an experiment determine a and b?  The Cramér–Rao bound of the angle output.

The encoder measures the angle ``theta_k = theta_0 + f_k(a, b, omega_0)`` plus
white noise of variance::

    sigma^2 = angle_noise^2 + (2 pi / counts_per_rev)^2 / 12

(Gaussian angle noise plus uniform quantisation, the latter treated as white,
which holds when the shaft moves several counts per sample).  With ``J`` the
sensitivities of the noise-free angle to ``(a, b, omega_0, theta_0)``, the Fisher
information is ``J^T J / sigma^2`` and any unbiased estimator's covariance of
``(a, b)`` is at least the ``(a, b)`` block of its inverse, i.e. the bound
*after* the unknown initial speed and encoder offset are estimated alongside
(nuisance parameters).  Output error on the counts (``method="oe"``) reaches
it asymptotically; ``motorid bench accuracy`` measures how closely.

Reference: Ljung, *System Identification* (2nd ed., 1999), sec. 7.4, eq. 7.91;
Kay, *Fundamentals of Statistical Signal Processing: Estimation Theory* (1993),
ch. 3 (nuisance parameters, p. 41).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

from motorsim.checks import ParameterError, check_int, check_real

from ..fits.friction_response import friction_response
from ..fits.sensitivity import zoh_response

__all__ = ["CramerRaoBound", "cramer_rao_bound", "quantisation_variance", "covariance_from_jacobian",
           "robust_covariance", "newey_west_covariance", "WHITENESS_LEVEL"]

#: Ljung–Box p-value below which the residuals count as correlated and the Newey–West covariance is used.
WHITENESS_LEVEL = 0.01


def quantisation_variance(counts_per_rev: int | None) -> float:
    """Variance in rad^2 of a uniform quantiser of ``2 pi / counts_per_rev`` (0 for None)."""
    if counts_per_rev is None:
        return 0.0
    return (2.0 * math.pi / counts_per_rev) ** 2 / 12.0


def covariance_from_jacobian(jacobian: np.ndarray, noise_variance: float, keep: int) -> np.ndarray:
    """``noise_variance (J^T J)^{-1}``, the leading ``keep x keep`` block, via an SVD (no explicit inverse).

    Columns are scaled to unit norm first so that parameters of very different
    size (a in 1/s, an encoder offset in rad) do not spoil the conditioning.
    Returns a matrix of ``inf`` when ``J`` is rank-deficient.
    """
    J = _without_idle_nuisances(np.asarray(jacobian, dtype=float), keep)
    if J.ndim != 2 or J.shape[0] == 0 or J.shape[1] < keep or J.shape[1] == 0:
        return np.full((keep, keep), math.inf)      # no column (or no row) to tell the parameters by
    scale = np.linalg.norm(J, axis=0)
    if np.any(scale == 0) or not np.all(np.isfinite(J)):
        return np.full((keep, keep), math.inf)
    _, sv, vt = np.linalg.svd(J / scale, full_matrices=False)
    if sv[-1] <= sv[0] * 1e-13:
        return np.full((keep, keep), math.inf)
    inv = (vt.T / sv**2) @ vt
    return noise_variance * inv[:keep, :keep] / np.outer(scale[:keep], scale[:keep])


def _without_idle_nuisances(J: np.ndarray, keep: int) -> np.ndarray:
    """``J`` without the columns past the first ``keep`` that are exactly zero: a segment's initial state
    that moves no residual at the fit (a shaft at rest that friction holds there: a speed of exactly 0 sticks)
    is held where it is, rather than making every parameter's variance infinite."""
    if J.ndim != 2 or J.shape[1] <= keep:
        return J
    idle = ~np.any(J[:, keep:], axis=0)
    return J[:, np.concatenate([np.ones(keep, dtype=bool), ~idle])] if np.any(idle) else J


def newey_west_covariance(jacobian: np.ndarray, residuals: np.ndarray, keep: int, max_lag: int) -> np.ndarray:
    """Sandwich covariance ``B^-1 S B^-1`` of a least-squares fit with autocorrelated residuals.

    ``B = J^T J`` and ``S = G_0 + sum_{l=1}^{L} (1 - l/(L+1)) (G_l + G_l^T)`` with
    ``G_l = sum_t g_t g_{t-l}^T`` the lagged products of the scores ``g_t = J_t r_t``
    (Newey & West 1987, Bartlett weights keep ``S`` positive semi-definite).  It needs
    neither white nor Gaussian residuals, only that their correlation dies out within
    ``L`` samples.  Columns are scaled to unit norm as in :func:`covariance_from_jacobian`.

    Parameters
    ----------
    jacobian : ndarray, shape (n, p)
        Of the residuals.
    residuals : ndarray, shape (n,)
    keep : int
        Leading parameters to return.
    max_lag : int
        ``L`` in samples, >= 0.
    """
    J = _without_idle_nuisances(np.asarray(jacobian, dtype=float), keep)
    if J.ndim != 2 or J.shape[0] == 0 or J.shape[1] < keep or J.shape[1] == 0:
        return np.full((keep, keep), math.inf)      # no column (or no row) to tell the parameters by
    scale = np.linalg.norm(J, axis=0)
    if np.any(scale == 0) or not np.all(np.isfinite(J)):
        return np.full((keep, keep), math.inf)
    Js = J / scale
    _, sv, vt = np.linalg.svd(Js, full_matrices=False)
    if sv[-1] <= sv[0] * 1e-13:
        return np.full((keep, keep), math.inf)
    bread = (vt.T / sv**2) @ vt
    g = Js * np.asarray(residuals, dtype=float)[:, None]
    meat = g.T @ g + _weighted_lag_products(g, max_lag)
    cov = bread @ meat @ bread
    return cov[:keep, :keep] / np.outer(scale[:keep], scale[:keep])


#: Above this many lags the Newey–West sums go through the FFT (O(p^2 n log n), not O(p^2 n L)).
_DIRECT_LAGS = 32


def _weighted_lag_products(g: np.ndarray, max_lag: int) -> np.ndarray:
    """``sum_{l=1}^{L} (1 - l/(L+1)) (G_l + G_l^T)`` with ``G_l = g[l:]^T g[:-l]``, ``L = min(max_lag, n - 1)``.

    A few lags are summed directly; many (a long correlated record) through the cross-correlations of
    the columns by FFT, so millions of samples with thousands of lags take seconds, not hours.
    """
    n, p = g.shape
    lags = min(max_lag, n - 1)
    out = np.zeros((p, p))
    if lags < 1:
        return out
    weights = 1.0 - np.arange(1, lags + 1) / (max_lag + 1.0)
    if lags <= _DIRECT_LAGS:
        for lag, w in zip(range(1, lags + 1), weights):
            gamma = g[lag:].T @ g[:-lag]
            out += w * (gamma + gamma.T)
        return out
    size = 1 << int(2 * n - 1).bit_length()
    spectra = np.fft.rfft(g, size, axis=0)
    for i in range(p):
        for j in range(i, p):
            # irfft(F_i conj(F_j))[l] = sum_t g[t + l, i] g[t, j] = G_l[i, j]
            cross = np.fft.irfft(spectra[:, i] * np.conj(spectra[:, j]), size)
            forward = float(weights @ cross[1:lags + 1])                  # sum_l w_l G_l[i, j]
            backward = float(weights @ cross[size - lags:][::-1])         # sum_l w_l G_l[j, i]
            out[i, j] += forward + backward
            if i != j:
                out[j, i] += backward + forward
    return out


#: Lags of the residual autocorrelation computed by dot products (the Ljung–Box test's) before the FFT
#: is used for all of them: a white or short-correlated residual falls inside its band within these.
_DIRECT_AUTOCORRELATION_LAGS = 20


def _correlation_length(residuals: np.ndarray, limit: int) -> tuple[int, float]:
    """Lags until the residual autocorrelation first falls inside its 95 % band, and the Ljung–Box p-value.

    The first :data:`_DIRECT_AUTOCORRELATION_LAGS` lags come from dot products (O(n) each); only a
    residual still correlated beyond them takes the FFT of all lags (O(n log n), a 2n-point transform).
    """
    from scipy.special import chdtrc  # the chi-square survival function, lighter than scipy.stats

    from .validation import autocorrelation
    r = np.asarray(residuals, dtype=float) - np.mean(residuals)
    n = len(r)
    den = float(r @ r)
    if den == 0 or n < 8:
        return 0, 1.0
    lags = min(limit, n // 4)
    band = 1.96 / math.sqrt(n)
    ac = autocorrelation(r, min(lags, _DIRECT_AUTOCORRELATION_LAGS))
    inside = np.flatnonzero(np.abs(ac[1:]) < band)
    if not len(inside) and lags > _DIRECT_AUTOCORRELATION_LAGS:
        spectrum = np.fft.rfft(r, 2 * n)
        ac = np.fft.irfft(spectrum * np.conj(spectrum))[:lags + 1] / den
        inside = np.flatnonzero(np.abs(ac[1:]) < band)
    length = int(inside[0]) + 1 if len(inside) else lags
    m = min(20, lags)
    k = np.arange(1, m + 1)
    q = n * (n + 2) * float(np.sum(ac[1:m + 1] ** 2 / (n - k)))
    return length, float(chdtrc(m, q))


def robust_covariance(jacobian: np.ndarray | Callable[[], np.ndarray], residuals: np.ndarray,
                      noise_variance: float, keep: int, *,
                      gauss_newton: Callable[[], np.ndarray] | None = None) -> tuple[np.ndarray, str]:
    """The Gauss–Newton covariance when the residuals look white, else the Newey–West one.

    The residuals' Ljung–Box test (20 lags) decides: at p >= :data:`WHITENESS_LEVEL`
    ``noise_variance (J^T J)^-1`` (:func:`covariance_from_jacobian`, or ``gauss_newton()``
    when the caller has it cheaper); below it the sandwich of :func:`newey_west_covariance`
    with ``L`` twice the lag at which the autocorrelation first falls inside its 95 % band
    (at least ``4 (n/100)^(2/9)``, the Newey–West rule, at most ``n/10``).  Coarse encoders
    (quantisation error that stays put while the shaft creeps) and timing jitter make the
    residuals correlated.

    Parameters
    ----------
    jacobian : ndarray, shape (n, p), or callable returning it
        A callable is evaluated only when it is needed.
    residuals : ndarray, shape (n,)
    noise_variance : float
    keep : int
        Leading parameters whose covariance is returned.
    gauss_newton : callable, optional
        Returns the Gauss–Newton covariance when the residuals look white.

    Returns
    -------
    covariance : ndarray, shape (keep, keep)
    method : str
        ``"gauss-newton"`` or ``"newey-west"``.
    """
    r = np.asarray(residuals, dtype=float)
    n = len(r)
    length, p_white = _correlation_length(r, max(1, n // 10))

    def jac() -> np.ndarray:
        return jacobian() if callable(jacobian) else jacobian
    if p_white >= WHITENESS_LEVEL:
        if gauss_newton is not None:
            return gauss_newton(), "gauss-newton"
        return covariance_from_jacobian(jac(), noise_variance, keep), "gauss-newton"
    lag = int(min(max(2 * length, math.ceil(4 * (n / 100) ** (2 / 9))), max(1, n // 10)))
    return newey_west_covariance(jac(), r, keep, lag), "newey-west"


@dataclasses.dataclass(frozen=True)
class CramerRaoBound:
    """Lower bound on the covariance of unbiased estimates of ``(a, b)`` for one experiment.

    Attributes
    ----------
    covariance : ndarray, shape (2, 2)
        Over ``param_names``; units 1/s^2, (1/s)(rad/s^2 per duty), (rad/s^2 per duty)^2.
    param_names : tuple of str
        ``("a", "b")``.
    n_samples : int
        Angle samples in the experiment.
    a, b : float
        The parameters the bound is evaluated at.
    noise_std : float
        Standard deviation of one angle sample in rad (noise and quantisation).
    """

    covariance: np.ndarray
    n_samples: int
    a: float
    b: float
    noise_std: float
    param_names: tuple = ("a", "b")

    def __post_init__(self):
        cov = np.array(self.covariance, dtype=float)
        cov.setflags(write=False)
        object.__setattr__(self, "covariance", cov)

    def stderr(self) -> dict[str, float]:
        """Smallest achievable standard deviation of each parameter (same unit as it)."""
        return {n: float(math.sqrt(max(v, 0.0))) for n, v in zip(self.param_names, np.diag(self.covariance))}

    def relative_stderr(self) -> dict[str, float]:
        """``stderr / |value|`` per parameter (dimensionless)."""
        se = self.stderr()
        return {"a": se["a"] / abs(self.a), "b": se["b"] / abs(self.b)}


def cramer_rao_bound(a: float, b: float, duty: ArrayLike, sample_period: float, *,
                     counts_per_rev: int | None = 16667, angle_noise: float = 0.0,
                     time: ArrayLike | None = None, initial_speed: float = 0.0, friction: float = 0.0,
                     bias: float = 0.0, dead_zone: float = 0.0, input_delay: int = 0) -> CramerRaoBound:
    """Cramér–Rao bound on ``(a, b)`` from the encoder angle of one experiment.

    Parameters
    ----------
    a : float
        Pole in 1/s, > 0.
    b : float
        Gain in (rad/s^2) per duty unit, nonzero.
    duty : array_like, shape (n,)
        Input, ``duty[k]`` held from ``time[k]`` to ``time[k+1]``.
    sample_period : float
        Sample period in s, > 0 (used when ``time`` is None).
    counts_per_rev : int or None
        Encoder resolution; None means no quantisation.
    angle_noise : float
        Standard deviation in rad of Gaussian angle noise, >= 0.
    time : array_like, shape (n,), optional
        Sample instants in s (jittered clocks); default ``k * sample_period``.
    initial_speed : float
        Speed at the first sample in rad/s (estimated as a nuisance parameter).
    friction, bias, dead_zone : float
        Coulomb friction ``c`` and constant acceleration ``d`` in rad/s^2 (>= 0 and any) and a
        dead zone in input units (>= 0) of the true plant.  With friction or a dead zone the
        bound is that of ``oe-friction``: ``c`` and ``d`` (and the dead zone when nonzero) are
        estimated alongside, their sensitivities from :mod:`identify.fits.friction_response`.
    input_delay : int
        Known input delay in samples, >= 0 (the duty before the run is 0).

    Returns
    -------
    CramerRaoBound

    Raises
    ------
    ValueError
        On a bad argument, or when the noise variance is zero (the bound is 0).

    Notes
    -----
    The bound is ``sigma^2 [(J^T J)^{-1}]_{ab}`` with ``J`` the analytic sensitivities
    of the ZOH angle to ``(a, b, omega_0, theta_0)`` (:mod:`identify.fits.sensitivity`).
    A constant or zero duty gives an infinite bound (``a`` and ``b`` are not separable).
    """
    a = check_real("a", a, positive=True)
    b = check_real("b", b)
    if b == 0:
        raise ParameterError(f"b must be nonzero, got {b!r}")
    sample_period = check_real("sample_period", sample_period, positive=True)
    u = np.asarray(duty, dtype=float)
    if u.ndim != 1 or len(u) < 5:
        raise ParameterError(f"duty must be 1-D with at least 5 samples, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ParameterError("duty must be finite")
    if counts_per_rev is not None:
        counts_per_rev = check_int("counts_per_rev", counts_per_rev, lo=1, allow_integral_float=False)
    angle_noise = check_real("angle_noise", angle_noise, nonnegative=True)
    initial_speed = check_real("initial_speed", initial_speed)
    t, uniform = _bound_time(u, time, sample_period)
    variance = angle_noise ** 2 + quantisation_variance(counts_per_rev)
    if variance == 0:
        raise ParameterError("angle_noise is 0 and counts_per_rev is None: a noise-free angle gives a zero bound; "
                         "give the noise or the encoder resolution")
    friction = check_real("friction", friction, nonnegative=True)
    bias = check_real("bias", bias)
    dead_zone = check_real("dead_zone", dead_zone, nonnegative=True)
    input_delay = check_int("input_delay", input_delay, lo=0, allow_integral_float=False)
    if input_delay:
        u = np.concatenate([np.zeros(min(input_delay, len(u))), u[:max(len(u) - input_delay, 0)]])
    J = _bound_jacobian(a, float(b), friction, bias, dead_zone, u, t, float(initial_speed), uniform)
    cov = covariance_from_jacobian(J, variance, 2)
    return CramerRaoBound(covariance=cov, n_samples=len(u), a=a, b=float(b), noise_std=math.sqrt(variance))


def _bound_time(u: np.ndarray, time: ArrayLike | None, sample_period: float) -> tuple[np.ndarray, bool | None]:
    """The sample instants of the bound (uniform when ``time`` is None) and whether they are uniform."""
    if time is None:
        return np.arange(len(u)) * sample_period, True
    t = np.asarray(time, dtype=float)
    if t.shape != u.shape:
        raise ParameterError(f"time must have the shape of duty {u.shape}, got {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ParameterError("time must be finite and strictly increasing")
    return t, None


def _bound_jacobian(a: float, b: float, friction: float, bias: float, dead_zone: float, u: np.ndarray,
                    t: np.ndarray, initial_speed: float, uniform: bool | None) -> np.ndarray:
    """Angle sensitivities to (a, b, the model's other parameters, initial speed) and the offset column."""
    if friction > 0 or dead_zone > 0:
        fr = friction_response(a, b, friction, bias, dead_zone, u, t, initial_speed, uniform=uniform)
        assert fr.angle_sensitivity is not None
        cols = [0, 1, 2, 3] + ([4] if dead_zone > 0 else []) + [5]
        return np.column_stack([fr.angle_sensitivity[:, cols], np.ones(len(u))])
    resp = zoh_response(a, b, u, t, initial_speed, bias=bias, uniform=uniform)
    return np.column_stack([resp.angle_sensitivity[:, :3], np.ones(len(u))])
