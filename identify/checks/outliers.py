"""Isolated residual outliers after a fit: single samples the fitted model cannot explain.

A corrupted sample too small for :func:`motorsim.plausibility.implausible_samples` still
pulls a least-squares fit.  After the fit it stands out as an isolated spike in the speed
residual (measured minus the model's speed, :func:`identify.checks.validation.model_output`).

Rule: a row is an outlier when its residual exceeds :data:`RESIDUAL_FACTOR` robust
standard deviations (1.4826 times the median absolute deviation, of at most
:data:`SCALE_SAMPLES` evenly spaced residuals) and 0.1 % of the RMS
measured speed (a noise-free fit has a near-zero deviation) and :data:`ROUNDING_FACTOR` of the speed's
rounding step (:func:`rounding_step`: a coarse encoder's count is no outlier), and the outliers are isolated:
at most :data:`ISOLATED_SHARE` of the rows, each standing out by as much from the median of its
:data:`NEIGHBOURHOOD` neighbours either side (a misfit that lasts, a segment's start the model
misses, moves its neighbours with it).  Many large residuals mean a model that misses
dynamics (friction, delay), which :func:`identify.validate` reports; they are not named here.
"""
from __future__ import annotations

import numpy as np

from motorsim.checks import ParameterError
from motorsim.plausibility import spike_rows
from motorsim.recording import Recording

from ..estimate import Estimate
from .validation import model_output

__all__ = ["residual_outliers", "rounding_step", "RESIDUAL_FACTOR", "ISOLATED_SHARE", "SCALE_SAMPLES", "NEIGHBOURHOOD",
           "ROUNDING_FACTOR", "GRID_SHARE", "GRID_TOLERANCE"]

#: Robust standard deviations beyond which a residual is an outlier.
RESIDUAL_FACTOR = 10.0
#: Largest share of rows that can be outliers and still be called isolated.
ISOLATED_SHARE = 0.01
#: Rows either side whose median a corrupted sample must stand out from (a count off and back moves two
#: speed rows, so at least three of the five on either side stay put).
NEIGHBOURHOOD = 5
#: Residuals, evenly spaced, of which the median absolute deviation is taken on longer records: its
#: relative standard error is then about 0.4 %, nothing against :data:`RESIDUAL_FACTOR`.
SCALE_SAMPLES = 100_000
#: Rounding steps (:func:`rounding_step`) a residual must exceed to be an outlier: differencing a rounded angle
#: errs by less than one step either way, and the model's own misfit adds to it.
ROUNDING_FACTOR = 1.5
#: A speed's changes lie on a grid when this share of them are whole multiples of the smallest, each within
#: :data:`GRID_TOLERANCE` of it (relative, the float's printing of a multiple).
GRID_SHARE, GRID_TOLERANCE = 0.9, 1e-3


def residual_outliers(estimate: Estimate, recording: Recording, residual: np.ndarray | None = None) -> list[int]:
    """Rows (0-based) of ``recording`` whose speed residual is an isolated outlier.

    Parameters
    ----------
    estimate : Estimate
        A fit (of this recording, or pooled with it).
    recording : Recording
        The data.
    residual : ndarray, shape (n,), optional
        The recording's speed residual under ``estimate`` when the caller has it (the entry of
        :attr:`Estimate.speed_residuals` for this recording); by default it is computed
        (:func:`identify.checks.validation.model_output`).

    Returns
    -------
    list of int
        Outlier rows; a count jump and back is named by its first row.  Empty when none,
        or when too many rows exceed the limit to be isolated.

    Examples
    --------
    >>> import numpy as np
    >>> from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    >>> from identify import fit
    >>> rec = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(1)).run(
    ...     Experiment(Sine(20.0), 0.005, 4.0))
    >>> residual_outliers(fit(rec, method="zoh-ls"), rec)
    []
    """
    if residual is None:
        measured, simulated = model_output(estimate, recording)
        residual = measured - simulated
    else:
        residual = np.asarray(residual, dtype=float)
        if residual.shape != (len(recording),):
            raise ParameterError(f"residual must have one value per row of the recording ({len(recording)}), "
                                 f"got shape {residual.shape}")
        measured = recording.measured_speed()
    defined = finite_rows(residual)
    finite = residual[defined]
    if len(finite) < 10:
        return []
    spread = finite[::-(-len(finite) // SCALE_SAMPLES)]     # evenly spaced, at most SCALE_SAMPLES
    sigma = 1.4826 * float(np.median(np.abs(spread - np.median(spread))))
    speed = measured[finite_rows(residual, measured)]
    speed_rms = float(np.sqrt(np.mean(speed ** 2))) if len(speed) else 0.0
    del speed
    limit = max(RESIDUAL_FACTOR * sigma, 1e-3 * speed_rms)
    candidates = spike_rows(residual, limit)
    step = ROUNDING_FACTOR * _rounding_step_at(recording, candidates)
    rows = [k for k, s in zip(candidates, step)
            if abs(_local_deviation(residual, k)) > max(limit, s) and abs(residual[k]) > s]
    return rows if len(rows) <= max(2, ISOLATED_SHARE * len(finite)) else []


def finite_rows(*columns: np.ndarray) -> slice | np.ndarray:
    """The rows where every column is finite: a slice when the others are the first rows (a differenced speed's
    first sample), so that ``column[finite_rows(...)]`` is a view and not a copy; else a boolean mask."""
    ok = np.isfinite(columns[0])
    for column in columns[1:]:
        ok &= np.isfinite(column)
    bad = np.flatnonzero(~ok)
    if not len(bad) or bad[-1] == len(bad) - 1:
        return slice(len(bad), None)
    return ok


def rounding_step(recording: Recording) -> np.ndarray:
    """Per row, the step by which the measured speed is rounded: one count over the row's interval on an encoder;
    else the grid the speed's changes lie on (a speed column printed from counts, or to fixed decimals), or 0.

    Differenced, a rounded angle errs by up to one step either way: on a 12-count encoder at 1 ms a speed of
    0 rad/s most rows and 524 rad/s at a count is the motor's rounding, no corrupted sample."""
    n = len(recording)
    if recording.counts is not None and recording.counts_per_rev:
        dt = np.r_[np.nan, np.diff(recording.time)]
        with np.errstate(divide="ignore", invalid="ignore"):
            step = 2 * np.pi / recording.counts_per_rev / dt
        return np.nan_to_num(step, nan=0.0, posinf=0.0)
    speed = np.asarray(recording.measured_speed(), dtype=float)
    changes = np.abs(np.diff(speed[np.isfinite(speed)]))
    changes = changes[changes > 0]
    if len(changes) < 10:
        return np.zeros(n)
    grid = float(np.min(changes))
    multiples = changes / grid
    on_grid = np.mean(np.abs(multiples - np.round(multiples)) <= GRID_TOLERANCE * np.maximum(multiples, 1.0))
    return np.full(n, grid if on_grid >= GRID_SHARE else 0.0)


def _rounding_step_at(recording: Recording, rows: list[int]) -> np.ndarray:
    """``rounding_step(recording)[rows]``, the same numbers, computed at ``rows`` alone on an encoder."""
    if recording.counts is not None and recording.counts_per_rev:
        at = np.asarray(rows, dtype=np.int64)
        time = recording.time
        dt = np.where(at > 0, time[at] - time[np.maximum(at - 1, 0)], np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = 2 * np.pi / recording.counts_per_rev / dt
        return np.nan_to_num(step, nan=0.0, posinf=0.0)
    return rounding_step(recording)[rows]


def _local_deviation(residual: np.ndarray, row: int) -> float:
    """``residual[row]`` less the median of the rows within :data:`NEIGHBOURHOOD` either side (nan kept out).

    A corrupted sample stands out from its neighbours (a count off and back: two rows); a misfit that
    lasts (a segment's start, a transient the model misses) moves its neighbours with it, and is no
    corrupted sample."""
    window = residual[max(0, row - NEIGHBOURHOOD):row + NEIGHBOURHOOD + 1]
    window = window[np.isfinite(window)]
    return float(residual[row] - np.median(window)) if len(window) else 0.0
