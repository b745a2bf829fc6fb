"""Covariance of a fit on a coarse encoder, by refitting re-quantised model angles (a parametric bootstrap).

When the shaft sweeps only a few tens of counts, the encoder's rounding error is a
deterministic, strongly structured function of the angle: neither white nor Gaussian,
and not a noise whose autocorrelation a sandwich estimator can absorb (with 44
counts/rev and about 24 counts of motion, Gauss–Newton and Newey–West intervals of
``oe`` covered the truth in only 36–46 % of ``motorid bench accuracy`` runs).  The
spread that matters is over the encoder's unknown phase: so the fitted model's angle
is shifted by a random fraction of a count, floored like the encoder, any residual
variance beyond the rounding's ``step^2/12`` added as white noise, and refitted,
``runs`` times; the covariance is that of the refits.

:func:`linearised_encoder_bootstrap_covariance` replaces each refit by the one
Gauss–Newton step from the fit that the re-quantised data's residuals call for
(``-(J^T J)^-1 J^T r``, the Jacobian at the solution), first-order exact, and the random
phases by 64 evenly spaced ones (a quadrature of the average over the phase): no
evaluation of the model, and the rounding at all phases binned by the phase at which each
sample rounds up (:func:`rounding_steps`), not a floor per sample and phase.
``oe-friction`` uses it whenever its angle is read by an encoder and the residuals are
mostly rounding: while the shaft sticks near a reversal the rounding error stays put
for many samples, which neither Gauss–Newton nor Newey–West intervals absorb (``b``'s
95 % interval covered the truth in 88.5 % of the Coulomb-friction runs of ``motorid
bench accuracy --only coverage`` with them).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable, Sequence

import numpy as np

from ..data import Segment

__all__ = ["COARSE_COUNTS", "is_coarse", "encoder_bootstrap_covariance", "linearised_encoder_bootstrap_covariance",
           "rounding_steps"]

#: Motion (counts swept by the model's angle) below which an encoder counts as coarse.
COARSE_COUNTS = 40


def is_coarse(segments: Sequence[Segment], models: Sequence[np.ndarray], steps: Sequence[float | None]) -> bool:
    """Whether some angle segment's model angle sweeps fewer than :data:`COARSE_COUNTS` counts."""
    for seg, model, step in zip(segments, models, steps):
        if seg.kind == "angle" and step and float(np.ptp(model)) < COARSE_COUNTS * step:
            return True
    return False


def encoder_bootstrap_covariance(segments: Sequence[Segment], models: Sequence[np.ndarray],
                                 steps: Sequence[float | None], residual_variance: float,
                                 refit: Callable[[list[Segment]], np.ndarray | None], keep: int, *,
                                 runs: int = 40, seed: int = 0) -> np.ndarray:
    """Covariance of the first ``keep`` parameters over refits of re-quantised model angles (module docstring).

    Parameters
    ----------
    segments : sequence of Segment
        The data (time, drive and kind are kept; the output is replaced).
    models : sequence of ndarray
        The fitted model's output on each segment, with its angle offset.
    steps : sequence of float or None
        Encoder step ``2 pi / counts_per_rev`` in rad of each segment (None: not an encoder).
    residual_variance : float
        Variance of the fit's residuals in rad^2 (or (rad/s)^2).
    refit : callable
        Fits a list of segments and returns the parameter vector, or None when it fails.
    keep : int
        Leading parameters to return.
    runs : int
        Refits (default 40).
    seed : int
        Seed of the phases and noise (fixed: the covariance is a property of the data).

    Returns
    -------
    ndarray, shape (keep, keep)
        ``inf`` everywhere when fewer than half the refits succeed.
    """
    rng = np.random.default_rng(seed)
    fits = []
    for _ in range(runs):
        new = [dataclasses.replace(seg, output=out)
               for seg, out in zip(segments, _requantised(segments, models, steps, residual_variance, rng))]
        x = refit(new)
        if x is not None and np.all(np.isfinite(x[:keep])):
            fits.append(np.asarray(x[:keep], dtype=float))
    if len(fits) < runs // 2:
        return np.full((keep, keep), math.inf)
    return np.atleast_2d(np.cov(np.array(fits), rowvar=False))


def _requantised(segments: Sequence[Segment], models: Sequence[np.ndarray], steps: Sequence[float | None],
                 residual_variance: float, rng: np.random.Generator) -> list[np.ndarray]:
    """One bootstrap draw of each segment's output: the model plus the white noise beyond the rounding,
    floored like the encoder after a random phase within one count."""
    outputs = []
    for seg, model, step in zip(segments, models, steps):
        extra_var = residual_variance - (step * step / 12.0 if step else 0.0)
        noisy = model + (rng.normal(0.0, math.sqrt(extra_var), len(model)) if extra_var > 0 else 0.0)
        if seg.kind == "angle" and step:
            noisy = np.floor((noisy + rng.uniform(0.0, step)) / step) * step
        outputs.append(noisy)
    return outputs


def linearised_encoder_bootstrap_covariance(segments: Sequence[Segment], models: Sequence[np.ndarray],
                                            steps: Sequence[float | None], residual_variance: float,
                                            jacobian: np.ndarray, keep: int, *, runs: int = 64) -> np.ndarray:
    """Covariance of the first ``keep`` parameters over one-step refits of re-quantised model angles.

    Parameters
    ----------
    segments, models, steps, residual_variance
        As for :func:`encoder_bootstrap_covariance`; angle segments' residuals are centred (their
        offsets projected out), as the fits do.
    jacobian : ndarray, shape (n_rows, n_params)
        Jacobian of the residuals (measured minus model, segments concatenated) at the solution.
    keep : int
        Leading parameters to return.
    runs : int
        Encoder phases, evenly spaced over one count (a quadrature of the average over the
        unknown phase, not random draws; default 64).

    Returns
    -------
    ndarray, shape (keep, keep)
        The phases' covariance of the steps plus the Gauss–Newton covariance of the white noise
        beyond the rounding (``residual_variance - step^2/12`` when positive); ``inf`` everywhere
        when the Jacobian is rank-deficient.  A column after the first ``keep`` that is exactly
        zero (a segment's initial speed while the shaft starts stuck by friction: the data do not
        see it) is left out: it changes nothing the data say about the others.
    """
    J = np.asarray(jacobian, dtype=float)
    norms = np.sqrt(np.einsum("ij,ij->j", J, J))
    seen = np.concatenate([np.ones(keep, bool), norms[keep:] > 0])
    if not seen.all():
        J, norms = J[:, seen], norms[seen]
    H = (J / norms).T @ (J / norms)         # columns scaled to unit norm for the rank test
    if not (np.all(np.isfinite(H)) and np.all(norms > 0)) or np.linalg.cond(H) > 1e14:
        return np.full((keep, keep), math.inf)
    inverse = np.linalg.inv(H) / np.outer(norms, norms)
    weights = inverse[:keep] @ J.T          # each row: one parameter's Gauss-Newton step per unit residual
    spread = np.zeros((keep, runs))
    white = residual_variance
    row = 0
    for seg, model, step in zip(segments, models, steps):
        n = len(model)
        if seg.kind == "angle" and step:
            white = min(white, residual_variance - step * step / 12.0)
            spread += step * rounding_steps(weights[:, row:row + n], np.asarray(model, dtype=float) / step, runs)
        row += n
    # the model, the same for every phase, and the segment's mean (its offset: the Jacobian's
    # columns are centred) drop out of the spread
    spread -= spread.mean(axis=1, keepdims=True)
    # the white noise beyond the rounding enters linearly: its Gauss-Newton covariance adds
    return spread @ spread.T / runs + max(white, 0.0) * inverse[:keep, :keep]


def rounding_steps(weights: np.ndarray, counts: np.ndarray, runs: int) -> np.ndarray:
    """``weights @ floor(counts[:, None] + phases)`` less ``weights @ floor(counts)``, for ``runs`` phases.

    The phases are ``(j + 0.5) / runs``, ``j = 0 .. runs - 1``.  Sample ``i`` rounds up one count
    more exactly from the phase ``j >= runs (1 - frac(counts_i)) - 1/2`` on, so each column is a
    running sum over the phases of the weights binned by that first phase: ``O(n)``, where the
    product with the ``(n, runs)`` matrix of floors costs ``O(n runs)``.

    Parameters
    ----------
    weights : ndarray, shape (k, n)
        Per-sample weights (e.g. rows of ``(J^T J)^-1 J^T``).
    counts : ndarray, shape (n,)
        Model angle in encoder counts (angle over the encoder step).
    runs : int
        Phases, >= 1.

    Returns
    -------
    ndarray, shape (k, runs)
    """
    frac = counts - np.floor(counts)
    first = np.clip(np.ceil(runs * (1.0 - frac) - 0.5), 0, runs).astype(np.intp)
    binned = np.stack([np.bincount(first, weights=w, minlength=runs + 1) for w in np.atleast_2d(weights)])
    return np.cumsum(binned[:, :runs], axis=1)
