"""What the output-error fits past the linear motor share: their start, their rows and their covariance.

* :func:`linear_start`: the checks of a gain per direction's, a drive limit's and a current limit's estimator
  (``oe-asymmetric``, ``oe-drive-limit``, ``oe-current-limit``), the input delay ``"auto"`` chooses (``oe`` with a
  bias, :func:`identify.fits.output_error.select_delay`) and that linear fit at the delay, their start;
* :func:`check_rows`: the rows left for the parameters once each segment's initial state (and angle offset) is
  fitted, refused when too few;
* :func:`segment_models` and :func:`segments_at`: each segment's model output from the pooled residuals, and the
  segments at a delay, refused when there are none;
* :func:`fit_covariance`: the covariance of a fit on pooled segments, the linearised encoder bootstrap
  (:func:`identify.checks.encoder_bootstrap.linearised_encoder_bootstrap_covariance`) where every segment is an
  encoder's angle and the residuals are mostly its rounding (variance at most :data:`ROUNDING_DOMINATED` times
  ``step^2/12``), else Gauss--Newton or Newey--West (:func:`identify.checks.uncertainty.robust_covariance`), or
  Gauss--Newton's alone when asked for (``covariance="gauss-newton"``): ``oe-friction``'s, ``oe-asymmetric``'s,
  ``oe-drive-limit``'s and ``oe-current-limit``'s.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.checks import check_choice
from motorsim.recording import Recording

from ..data import Segment, as_recordings, check_excitation, check_input_delay, prepare_segments
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..sums import sum_squares

__all__ = ["ROUNDING_DOMINATED", "linear_start", "check_rows", "segments_at", "segment_models", "fit_covariance"]

#: Residual variance, in units of the encoder's rounding variance ``step^2/12``, up to which the
#: residuals count as mostly rounding (then the linearised encoder bootstrap gives the covariance).
ROUNDING_DOMINATED = 4.0


def linear_start(recordings: Recording | Sequence[Recording], input_delay: int | str, covariance: str,
                 n_params: int) -> tuple[list[Recording], int, Estimate]:
    """The recordings, the input delay and the linear motor with a bias fitted by ``oe`` at it (Gauss--Newton's
    covariance): the start of a fit of ``n_params`` parameters past the linear motor.

    ``input_delay`` is checked (``"auto"``: :func:`identify.fits.output_error.select_delay` with a bias),
    ``covariance`` is ``"auto"`` or ``"gauss-newton"``, and the excitation must determine ``n_params``
    parameters (:func:`identify.data.check_excitation`).
    """
    from .output_error import fit_output_error, select_delay
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    check_choice("covariance", covariance, ("auto", "gauss-newton"))
    check_excitation(recs, n_params)
    if input_delay == "auto":
        input_delay = select_delay(recs, with_bias=True)
    delay = int(input_delay)
    return recs, delay, fit_output_error(recs, input_delay=delay, fit_bias=True, covariance="gauss-newton")


def check_rows(segments: Sequence[Segment], n_params: int, what: str) -> tuple[int, int]:
    """The rows of ``segments`` and their nuisance parameters (an initial speed each, and an angle's offset); a
    :class:`~identify.errors.NotIdentifiableError` naming ``what`` when they leave too few rows for ``n_params``."""
    n = sum(len(s.time) for s in segments)
    nuisance = sum(2 if s.kind == "angle" else 1 for s in segments)
    if not segments or n - nuisance <= n_params + 1:
        raise NotIdentifiableError(f"recording is too short for {what}: {n_params} parameters and the initial state "
                                   f"of {len(segments)} segments; record longer")
    return n, nuisance


def segments_at(recs: list[Recording], delay: int) -> list[Segment]:
    """The recordings' segments at ``delay`` samples (:func:`identify.data.prepare_segments`); a
    :class:`~identify.errors.NotIdentifiableError` when no segment is long enough."""
    segs = prepare_segments(recs, delay)
    if not segs:
        raise NotIdentifiableError(f"recording is too short for an input delay of {delay} samples")
    return segs


def segment_models(segments: Sequence[Segment], residual: np.ndarray) -> list[np.ndarray]:
    """Each segment's model output (an angle with its offset): its output less its rows of the pooled
    ``residual`` (measured less model, the segments' rows in order)."""
    models, lo = [], 0
    for seg in segments:
        hi = lo + len(seg.time)
        models.append(seg.output - residual[lo:hi])
        lo = hi
    return models


def fit_covariance(recs: list[Recording], segments: Sequence[Segment], models: Sequence[np.ndarray],
                   residual: np.ndarray, jacobian: np.ndarray, dof: int, keep: int,
                   covariance: str = "auto") -> tuple[np.ndarray, str]:
    """The covariance of the leading ``keep`` parameters of a fit on ``segments`` and how it was made (module
    docstring).

    ``models``: each segment's model output (:func:`segment_models`); ``residual``: the pooled residuals;
    ``jacobian``: theirs (``d residual / d theta``, the nuisance parameters projected out or as columns after the
    ``keep``); ``dof``: the residuals' degrees of freedom (the noise variance is ``sum r^2 / dof``).
    """
    from ..checks.encoder_bootstrap import linearised_encoder_bootstrap_covariance
    from ..checks.uncertainty import covariance_from_jacobian, robust_covariance
    s2 = sum_squares(residual) / dof
    if covariance == "gauss-newton":
        return covariance_from_jacobian(jacobian, s2, keep), "gauss-newton"
    steps = [2 * math.pi / c if c else None for c in (recs[s.recording].counts_per_rev for s in segments)]
    variance = sum_squares(residual) / len(residual)
    encoders = all(s.kind == "angle" and st for s, st in zip(segments, steps))
    if encoders and variance <= ROUNDING_DOMINATED * max(st or 0.0 for st in steps) ** 2 / 12.0:
        # mostly the encoder's rounding, which stays put while the shaft is slow: its spread over the phases
        cov = linearised_encoder_bootstrap_covariance(segments, models, steps, variance, jacobian, keep)
        return cov, "linearised-encoder-bootstrap"
    return robust_covariance(jacobian, residual, s2, keep)
