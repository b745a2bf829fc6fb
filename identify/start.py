"""Starting values of the iterative estimators (``oe``, ``iv``, ``oe-friction``).

:func:`regression_guess` maps ``zoh-ls``'s one-step regression exactly back to
``(a, b)`` (see :mod:`identify.regression`); when that finds no stable model,
:func:`initial_guess` falls back to :func:`grid_guess`, the best ``a`` on a logarithmic grid with ``b``
and every segment's initial state solved linearly, which needs nothing but the
segments and always returns a start.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

from .data import MIN_SEGMENT_SAMPLES, Segment
from .errors import NotIdentifiableError
from .regression import regression_rows, solve_least_squares
from .sensitivity import zoh_response

__all__ = ["initial_guess", "regression_guess", "grid_guess"]


def regression_guess(recordings: Sequence[Recording]) -> tuple[float, float] | None:
    """``zoh-ls``'s regression mapped exactly to ``(a, b)`` (without its fit score), or None.

    None when the regression fails or finds no stable model with a nonzero gain.

    Parameters
    ----------
    recordings : sequence of Recording
        The pooled runs (one sample period).
    """
    try:
        A, y = regression_rows(recordings)
        (t1, t2), _, _ = solve_least_squares(A, y)
    except NotIdentifiableError:
        return None
    dt = recordings[0].sample_period
    if 0 < t1 < 1:
        a = -math.log(t1) / dt
        b = a * t2 / (1.0 - t1)
        if math.isfinite(a) and math.isfinite(b) and b != 0:
            return a, b
    return None


def initial_guess(recordings: Sequence[Recording], segments: Sequence[Segment]) -> tuple[float, float]:
    """:func:`regression_guess`, else :func:`grid_guess` on ``segments``.

    Parameters
    ----------
    recordings : sequence of Recording
        The pooled runs (one sample period).
    segments : sequence of Segment
        The same runs cut at gaps, for the fallback.

    Returns
    -------
    a, b : float
        Pole in 1/s and gain per input unit.
    """
    guess = regression_guess(recordings)
    if guess is not None:
        return guess
    if not segments:
        raise NotIdentifiableError(f"recording is too short: no gap-free stretch of {MIN_SEGMENT_SAMPLES} "
                                   "samples; record longer")
    return grid_guess(segments)


def grid_guess(segments: Sequence[Segment]) -> tuple[float, float]:
    """Best ``a`` on a log grid with ``b`` and initial states solved linearly (robust start).

    Parameters
    ----------
    segments : sequence of Segment
        At least one segment.

    Returns
    -------
    a, b : float
        Pole in 1/s and gain per input unit.
    """
    dt = float(np.median(np.concatenate([np.diff(s.time) for s in segments])))
    span = max(s.time[-1] - s.time[0] for s in segments)
    best = (math.inf, 1.0, 1.0)
    for a in np.geomspace(0.5 / span, 2.0 / dt, 40):
        cols, ys = [], []
        for i, seg in enumerate(segments):
            # with b = 1 and no initial speed the response is its own b-column: no sensitivities needed
            resp = zoh_response(a, 1.0, seg.drive, seg.time, 0.0, uniform=seg.uniform, sensitivities=False)
            sens = resp.angle_sensitivity if seg.kind == "angle" else resp.speed_sensitivity
            block = np.zeros((len(seg.time), 1 + 2 * len(segments)))
            block[:, 0] = resp.angle if seg.kind == "angle" else resp.speed
            block[:, 1 + 2 * i] = sens[:, 2]
            if seg.kind == "angle":
                block[:, 2 + 2 * i] = 1.0
            cols.append(block)
            ys.append(seg.output)
        A, y = np.vstack(cols), np.concatenate(ys)
        keep = np.linalg.norm(A, axis=0) > 0
        sol, *_ = np.linalg.lstsq(A[:, keep], y, rcond=None)
        rss = float(np.sum((y - A[:, keep] @ sol) ** 2))
        if rss < best[0] and sol[0] != 0:
            best = (rss, float(a), float(sol[0]))
    return best[1], best[2]
