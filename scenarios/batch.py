"""The batch engine: many repetitions of one bench setting simulated, read and fitted at once.

Every repetition is a row of a 2-D array ``(repetitions, n_samples)``:

* the plant is the exact ZOH model of ``Motor(a, b).discretise(dt)`` (the same
  matrices ``control.sample_system`` computes, here in closed form from
  :func:`motorsim.plant.zoh_matrices`), run along the rows by
  ``scipy.signal.lfilter`` (speed) and a cumulative sum (angle);
* the encoder floors ``(angle + noise) counts_per_rev / 2 pi`` like
  :class:`motorsim.sensors.Encoder`, with each row's noise drawn from that row's
  own generator, so a row equals ``SimRig(...).run(...)`` with the same generator;
* speed is the backward difference of the counts (``motorsim.recording``'s
  alignment) and the regressions of ``identify.regression`` (pair ``omega_{k+1}``
  with ``(omega_k, u_k)``) are solved row by row with a two-column QR in closed
  form (modified Gram-Schmidt: ``r11 = |w|``, ``r12 = w.u / r11``,
  ``u' = u - (r12/r11) w``, ``r22 = |u'|``), which is as accurate as the
  ``lstsq`` of :func:`identify.regression.solve_least_squares`.

Only linear settings are batchable: no Coulomb friction, no bias, no timing
jitter and no dropped samples (dead zone and input delay are static maps of
the known duty, so they are).  Estimators are batched when their name is a key
of :data:`BATCHED_METHODS`; every other estimator is run through
``identify.fit`` on :class:`~motorsim.recording.Recording` objects built from
the same counts.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import re
from typing import Callable

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError
from motorsim.plant import Motor, delayed_duty, zoh_matrices

__all__ = ["MethodOutcome", "BATCHED_METHODS", "simulate_batch", "encoder_counts_batch", "speed_batch",
           "regression_batch", "fit_batch", "is_batchable"]


def is_batchable(motor: Motor, *, jitter: float = 0.0, drop_rate: float = 0.0) -> bool:
    """True when a setting can go through the batch engine (linear plant, uniform, complete samples)."""
    return motor.breakaway == 0 and motor.bias == 0 and jitter == 0 and drop_rate == 0


def simulate_batch(motor: Motor, duty: np.ndarray, sample_period: float, *,
                   initial_speed: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH simulation of every row of ``duty`` at once.

    Parameters
    ----------
    motor : Motor
        A linear plant (``friction == 0`` and ``bias == 0``); dead zone and delay are applied.
    duty : ndarray, shape (n_samples,) or (repetitions, n_samples)
        Duty of each run; ``duty[..., k]`` is held from sample k to k+1.
    sample_period : float
        Uniform sample period in s.
    initial_speed : float
        Speed at the first sample, rad/s (angle starts at 0).

    Returns
    -------
    angle, speed : ndarray, same shape as ``duty``
        Angle in rad and speed in rad/s at the sample instants.

    Notes
    -----
    ``speed[k+1] = e speed[k] + g v[k]`` and ``angle[k+1] = angle[k] + p speed[k] + q v[k]``
    with ``e = exp(-a dt)``, ``g = (b/a)(1 - e)``, ``p = (1 - e)/a``, ``q = (b/a)(dt - p)``,
    the entries of the ZOH-discretised state-space model; the angle recursion sums in
    closed form to ``angle[k] = (speed[0] - speed[k])/a + (b dt/a) sum_{j<k} v[j]``.
    """
    if not isinstance(motor, Motor):
        raise ParameterTypeError(f"motor must be a Motor, got {type(motor).__name__}")
    if not is_batchable(motor):
        raise ParameterError(f"motor must be linear (friction == 0 and bias == 0) for the batch engine, got {motor!r}")
    u = np.asarray(duty, dtype=float)
    if u.ndim not in (1, 2) or u.shape[-1] < 2:
        raise ParameterError(f"duty must have shape (n_samples,) or (repetitions, n_samples) with n_samples >= 2, "
                         f"got {u.shape}")
    if motor.input_delay or motor.dead_zone:
        u2 = np.atleast_2d(u)
        u = np.stack([motor.drive(delayed_duty(row, motor.input_delay, 0.0)) for row in u2]).reshape(u.shape)
    e, g, _, _ = (float(x) for x in zoh_matrices(motor.a, motor.b, sample_period))
    v = u[..., :-1]
    speed = np.empty(u.shape)
    angle = np.empty(u.shape)
    speed[..., 0] = initial_speed
    angle[..., 0] = 0.0
    zi = np.full(u.shape[:-1] + (1,), e * initial_speed)
    from scipy.signal import lfilter  # imported when used: it costs most of `import control`
    speed[..., 1:], _ = lfilter([g], [1.0, -e], v, axis=-1, zi=zi)
    # Summing angle[k+1] = angle[k] + p speed[k] + q v[k] with p = (1 - e)/a and
    # (1 - e) speed[k] = speed[k] - speed[k+1] + g v[k] telescopes to
    # angle[k] = (speed[0] - speed[k])/a + (b dt / a) sum_{j<k} v[j]  (exact; the sum of
    # integer duties is exact in floating point).
    np.cumsum(v, axis=-1, out=angle[..., 1:])
    angle[..., 1:] *= motor.b * sample_period / motor.a
    angle[..., 1:] += (initial_speed - speed[..., 1:]) / motor.a
    return angle, speed


def encoder_counts_batch(angle: np.ndarray, counts_per_rev: int, angle_noise: float = 0.0,
                         rngs=None) -> np.ndarray:
    """Encoder counts (as exact float integers) of each row of ``angle``.

    Row ``r`` gets noise ``rngs[r].normal(0, angle_noise, n_samples)``, the same draw
    :meth:`motorsim.sensors.Encoder.counts` makes with that generator.

    Parameters
    ----------
    angle : ndarray, shape (repetitions, n_samples)
        Angle in rad.
    counts_per_rev : int
        Counts per revolution.
    angle_noise : float
        Standard deviation of the angle noise in rad (0: none, ``rngs`` unused).
    rngs : sequence of numpy.random.Generator, optional
        One generator per row; required when ``angle_noise > 0``.
    """
    angle = np.atleast_2d(angle)
    if angle_noise > 0:
        if rngs is None or len(rngs) != angle.shape[0]:
            raise ParameterError(f"rngs must hold one Generator per repetition ({angle.shape[0]}) when angle_noise > 0")
        noisy = np.empty(angle.shape)
        for r, rng in enumerate(rngs):
            noisy[r] = angle[r] + rng.normal(0.0, angle_noise, angle.shape[1])
        angle = noisy
    else:
        angle = angle.copy()
    angle *= counts_per_rev / (2.0 * math.pi)
    return np.floor(angle, out=angle)


def speed_batch(counts: np.ndarray, counts_per_rev: int, sample_period: float) -> np.ndarray:
    """Backward-differenced speed in rad/s of each row (``nan`` in column 0), as ``Recording.speed_rad_s``
    computes it (to rounding: here from exact count differences and the nominal period)."""
    speed = np.empty(counts.shape)
    speed[..., 0] = np.nan
    # Differences of integer counts are exact; one product per sample then rounds once.
    np.subtract(counts[..., 1:], counts[..., :-1], out=speed[..., 1:])
    speed[..., 1:] *= 2.0 * math.pi / (counts_per_rev * sample_period)
    return speed


@dataclasses.dataclass(frozen=True)
class MethodOutcome:
    """One estimator's results over the repetitions of one grid point.

    Attributes
    ----------
    method : str
        Estimator name.
    a, b : ndarray, shape (repetitions,)
        Estimates, ``nan`` where the fit failed.
    failure : tuple of str
        ``''`` where the fit succeeded, else why it failed.
    """

    method: str
    a: np.ndarray
    b: np.ndarray
    failure: tuple

    @property
    def n_failed(self) -> int:
        """Failed repetitions."""
        return sum(1 for f in self.failure if f)

    def failure_summary(self, top: int = 3) -> str:
        """The most common reasons with their counts, ``reason (n) | ...``.

        Reasons are grouped by their words with every number masked as ``#`` (``cond 3.1e+08`` and
        ``cond 2.7e+08`` are one reason); a group shows its first message as it was.
        """
        first: dict[str, str] = {}
        counts: collections.Counter[str] = collections.Counter()
        for reason in self.failure:
            if reason:
                key = _NUMBER.sub("#", reason)
                first.setdefault(key, reason)
                counts[key] += 1
        return " | ".join(f"{first[key]} ({n})" for key, n in counts.most_common(top))

    def statistics(self, name: str, truth: float) -> dict[str, float]:
        """Mean, bias in % of ``truth``, standard deviation (ddof 1) and RMSE of parameter ``name``."""
        x = getattr(self, name)
        x = x[np.isfinite(x)]
        if len(x) == 0:
            return {"mean": math.nan, "bias_pct": math.nan, "std": math.nan, "rmse": math.nan}
        # Deviations from the first value first, so identical repetitions give a std of exactly 0.
        d = x - x[0]
        mean = float(x[0] + np.mean(d))
        return {"mean": mean, "bias_pct": 100.0 * (mean - truth) / truth,
                "std": float(np.std(d, ddof=1)) if len(x) > 1 else math.nan,
                "rmse": float(np.sqrt(np.mean((x - truth) ** 2)))}


#: A number in a message (integer, decimal, exponent, sign), masked when reasons are grouped.
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def regression_batch(speed: np.ndarray, duty: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Least-squares ``omega_{k+1} ~ theta1 omega_k + theta2 u_k`` for every row.

    Parameters
    ----------
    speed : ndarray, shape (repetitions, n_samples)
        Backward-differenced speed (``nan`` in column 0).
    duty : ndarray, shape (n_samples,) or (repetitions, n_samples)
        The recorded duty.

    Returns
    -------
    theta1, theta2 : ndarray, shape (repetitions,)
        ``nan`` where the regression is not identifiable.
    failure : tuple of str
        The reason per row ('' when identifiable), worded as ``identify.regression``'s.
    """
    w = speed[..., 1:-1]
    y = speed[..., 2:]
    u = np.broadcast_to(np.asarray(duty, dtype=float)[..., 1:-1], w.shape)
    n_rows = w.shape[-1]
    r11 = np.sqrt(np.einsum("ij,ij->i", w, w))
    wu = np.einsum("ij,ij->i", w, u)
    uu = np.einsum("ij,ij->i", u, u)
    with np.errstate(divide="ignore", invalid="ignore"):
        r12 = wu / r11
        c = r12 / r11
        u_perp = u - c[:, None] * w
        r22 = np.sqrt(np.einsum("ij,ij->i", u_perp, u_perp))
        theta2 = np.einsum("ij,ij->i", u_perp, y) / r22**2
        theta1 = (np.einsum("ij,ij->i", w, y) / r11 - r12 * theta2) / r11
    # The same rules as identify.regression.solve_least_squares: zero columns and a relative
    # condition below 1e-10 (singular values of the column-scaled A, here of its R factor
    # [[1, r12/|u|], [0, r22/|u|]]) are not identifiable.
    scale_u = np.sqrt(uu)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled_r = np.zeros((w.shape[0], 2, 2))
        scaled_r[:, 0, 0] = 1.0
        scaled_r[:, 0, 1] = np.where(scale_u > 0, r12 / scale_u, 0.0)
        scaled_r[:, 1, 1] = np.where(scale_u > 0, r22 / scale_u, 0.0)
    scaled_r = np.nan_to_num(scaled_r)
    sv = np.linalg.svd(scaled_r, compute_uv=False)
    collinear = sv[:, -1] < 1e-10 * sv[:, 0]
    failure = [""] * w.shape[0]
    for r in np.flatnonzero((r11 == 0) | (scale_u == 0) | collinear | (n_rows < 3)):
        if n_rows < 3:
            failure[r] = f"recording is too short: {n_rows} regression rows for 2 parameters"
        elif r11[r] == 0:
            failure[r] = "speed is identically zero: the input is not persistently exciting"
        elif scale_u[r] == 0:
            failure[r] = "input is identically zero: the input is not persistently exciting"
        else:
            failure[r] = "regressors are (nearly) collinear: the input is not persistently exciting"
    bad = np.array([bool(f) for f in failure])
    theta1 = np.where(bad, np.nan, theta1)
    theta2 = np.where(bad, np.nan, theta2)
    return theta1, theta2, tuple(failure)


def _euler_map(theta1, theta2, dt, failure):
    return (1.0 - theta1) / dt, theta2 / dt, failure


def _zoh_map(theta1, theta2, dt, failure):
    ok = (theta1 > 0) & (theta1 < 1)
    reasons = tuple(f or ("" if good else f"zoh-ls: theta1 = {t1:.6g} is not in (0, 1), so no stable "
                          "first-order model fits")
                    for f, good, t1 in zip(failure, ok, theta1))
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.where(ok, theta1, 0.5)
        a = -np.log(t1) / dt
        b = a * theta2 / (1.0 - t1)
    return np.where(ok, a, np.nan), np.where(ok, b, np.nan), reasons


#: Estimators with a batched implementation: name -> map from ``(theta1, theta2, dt, failure)``
#: to ``(a, b, failure)``.  They must equal ``identify.fit(recording, method=name)`` row by row.
BATCHED_METHODS: dict[str, Callable] = {
    "euler-ls": _euler_map,
    "zoh-ls": _zoh_map,
}


def fit_batch(methods, speed: np.ndarray, duty: np.ndarray, sample_period: float) -> dict[str, MethodOutcome]:
    """Fit every row with each batched method in ``methods`` (one shared regression).

    Parameters
    ----------
    methods : sequence of str
        Names, each a key of :data:`BATCHED_METHODS`.
    speed : ndarray, shape (repetitions, n_samples)
        Backward-differenced speed in rad/s.
    duty : ndarray, shape (n_samples,) or (repetitions, n_samples)
        The recorded duty.
    sample_period : float
        In s.
    """
    for m in methods:
        if m not in BATCHED_METHODS:
            raise ParameterError(f"methods must be batched methods {list(BATCHED_METHODS)}, got {m!r}")
    theta1, theta2, failure = regression_batch(speed, duty)
    out = {}
    for m in methods:
        a, b, reasons = BATCHED_METHODS[m](theta1, theta2, sample_period, failure)
        out[m] = MethodOutcome(m, a, b, tuple(reasons))
    return out
