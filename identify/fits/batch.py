"""Estimators on many repetitions at once: one row of a 2-D array per repetition.

The repetitions of one scenario-sweep point (:mod:`scenarios.sweep`, simulated together by
:mod:`motorsim.batch`) share the duty and the clock and differ only in their encoder readings, so
the estimators that have a closed form or a separable iteration fit every row at once:

* ``euler-ls`` and ``zoh-ls`` (:func:`fit_batch`): the regressions of :mod:`identify.fits.regression`
  (pair ``omega_{k+1}`` with ``(omega_k, u_k)``) solved row by row with a two-column QR in
  closed form (modified Gram-Schmidt: ``r11 = |w|``, ``r12 = w.u / r11``,
  ``u' = u - (r12/r11) w``, ``r22 = |u'|``), which is as accurate as the ``lstsq`` of
  :func:`identify.fits.regression.solve_least_squares`; ``zoh-ls`` maps the regression back through
  the ``linear`` structure (:meth:`~identify.model_structures.first_order.FirstOrder.values_from_discrete`);
* ``oe`` (:func:`fit_output_error_batch`, where :func:`output_error_batchable`): the separable
  Gauss--Newton of :mod:`identify.fits.variable_projection` row by row
  (:func:`identify.fits.batch_output_error.output_error_batch`), started from ``zoh-ls``'s regression.

Each equals ``identify.fit(recording, method=name)`` on the row's recording, to rounding (the
tests compare them); a row a batch path cannot fit is ``nan`` for the caller to fit one by one.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Callable, Sequence, cast

import numpy as np

from motorsim.batch import speed_batch
from motorsim.checks import ParameterError
from motorsim.recording import Recording

from ..model_structures import structure
from ..model_structures.first_order import FirstOrder
from .batch_output_error import output_error_batch

__all__ = ["BatchFit", "BATCHED_METHODS", "regression_batch", "fit_batch", "output_error_batchable",
           "fit_output_error_batch"]

#: The structure the batch paths fit (first order, no bias, no friction).
BATCH_STRUCTURE = "linear"


def _linear() -> FirstOrder:
    """The registered structure the batch paths fit."""
    return cast(FirstOrder, structure(BATCH_STRUCTURE))


@dataclasses.dataclass(frozen=True)
class BatchFit:
    """One estimator's ``a`` and ``b`` on every row of a batch.

    Attributes
    ----------
    method : str
        Estimator name.
    a, b : ndarray, shape (repetitions,)
        Estimates, ``nan`` where the fit failed.
    failure : tuple of str
        ``''`` where the fit succeeded, else why it failed (worded as the estimator's own error).
    """

    method: str
    a: np.ndarray
    b: np.ndarray
    failure: tuple[str, ...]


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
        The reason per row ('' when identifiable), worded as ``identify.fits.regression``'s.
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
    # The same rules as identify.fits.regression.solve_least_squares: zero columns and a relative
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
    a, b = _linear().values_from_discrete(theta1, theta2, dt)
    return a, b, reasons


#: Estimators with a batched regression: name -> map from ``(theta1, theta2, dt, failure)``
#: to ``(a, b, failure)``.  They must equal ``identify.fit(recording, method=name)`` row by row.
BATCHED_METHODS: dict[str, Callable] = {
    "euler-ls": _euler_map,
    "zoh-ls": _zoh_map,
}


def fit_batch(methods: Sequence[str], speed: np.ndarray, duty: np.ndarray,
              sample_period: float) -> dict[str, BatchFit]:
    """Fit every row with each batched method in ``methods`` (one shared regression).

    Parameters
    ----------
    methods : sequence of str
        Names, each a key of :data:`BATCHED_METHODS`.
    speed : ndarray, shape (repetitions, n_samples)
        Backward-differenced speed in rad/s (:func:`motorsim.batch.speed_batch`).
    duty : ndarray, shape (n_samples,) or (repetitions, n_samples)
        The recorded duty.
    sample_period : float
        In s.

    Returns
    -------
    dict of str to BatchFit
        By method, in the order of ``methods``.
    """
    for m in methods:
        if m not in BATCHED_METHODS:
            raise ParameterError(f"methods must be batched methods {list(BATCHED_METHODS)}, got {m!r}")
    theta1, theta2, failure = regression_batch(speed, duty)
    out = {}
    for m in methods:
        a, b, reasons = BATCHED_METHODS[m](theta1, theta2, sample_period, failure)
        out[m] = BatchFit(m, a, b, tuple(reasons))
    return out


def output_error_batchable(recording: Recording) -> bool:
    """Whether ``oe`` takes its separable path on ``recording`` (the duty excites, one uniform segment):
    then :func:`fit_output_error_batch` fits every repetition that shares its duty and clock.  A duty of one
    constant level (a step from rest, which the fit answers from its transient alone) takes the path of one
    run at a time, where its screening says so."""
    from ..data import as_recordings, check_excitation, one_input_level, prepare_segments
    from .variable_projection import is_separable
    recs = as_recordings(recording)
    if one_input_level(recs) is not None:
        return False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_excitation(recs, 2)
    except ValueError:
        return False
    segments = prepare_segments(recs, 0)
    return len(segments) == 1 and is_separable(segments, with_bias=False)


def fit_output_error_batch(counts: np.ndarray, duty: np.ndarray, sample_period: float,
                           counts_per_rev: int) -> tuple[np.ndarray, np.ndarray]:
    """``oe`` on every row of ``counts`` at once, started from ``zoh-ls``'s regression on the same counts.

    Parameters
    ----------
    counts : ndarray, shape (repetitions, n_samples)
        Encoder counts of each repetition (exact integers, as floats or ints).
    duty : ndarray, shape (n_samples,)
        The duty every repetition shares (:func:`output_error_batchable` on one of them).
    sample_period : float
        Uniform sample period in s.
    counts_per_rev : int
        Counts per revolution.

    Returns
    -------
    a, b : ndarray, shape (repetitions,)
        ``nan`` on the rows the iteration did not fit (fit them one by one with ``identify.fit``).

    Notes
    -----
    The fit's minimum does not depend on where it starts: rows the regression cannot start
    (noisy, fast sines) start from the median of the rows fitted, or, when none was, from the
    per-fit path's grid start on the first of them (a test checks the estimates agree with
    ``identify.fit``).
    """
    linear = _linear()
    speed = speed_batch(counts, counts_per_rev, sample_period)
    theta1, theta2, _ = regression_batch(speed, duty)
    start, _ = linear.values_from_discrete(theta1, theta2, sample_period)
    angle = counts * (2.0 * math.pi / counts_per_rev)
    a, b = output_error_batch(angle, duty, sample_period, start)
    late = np.flatnonzero(~np.isfinite(start))
    if len(late):
        if np.any(np.isfinite(a)):
            a0 = float(np.nanmedian(a))
        else:
            from ..data import as_recordings, prepare_segments
            from .start import grid_guess
            first = Recording(time=np.arange(len(duty)) * sample_period, duty=duty, sample_period=sample_period,
                              counts=np.asarray(counts[late[0]]).astype(np.int64), counts_per_rev=counts_per_rev)
            a0 = grid_guess(prepare_segments(as_recordings(first), 0))[0]
        a[late], b[late] = output_error_batch(angle[late], duty, sample_period, np.full(len(late), a0))
    return a, b
