"""Starting values of the iterative estimators (``oe``, ``iv``, ``oe-friction``).

:func:`regression_guess` maps ``zoh-ls``'s one-step regression exactly back to
``(a, b)`` (see :mod:`identify.fits.regression`); when that finds no stable model,
:func:`initial_guess` falls back to :func:`grid_guess`, the best ``a`` on a logarithmic grid with ``b``
and every segment's initial state solved linearly, which needs nothing but the
segments and always returns a start.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

from ..data import MIN_SEGMENT_SAMPLES, Segment
from ..errors import NotIdentifiableError
from .regression import regression_rows, solve_least_squares
from .sensitivity import project_out_initial_state, zoh_response

__all__ = ["initial_guess", "regression_guess", "grid_guess"]


def regression_guess(recordings: Sequence[Recording]) -> tuple[float, float] | None:
    """``zoh-ls``'s regression mapped exactly to ``(a, b)`` (without its fit score), or None.

    None when the regression fails or finds no stable model with a nonzero gain.  Found once per
    recording and kept with it (it never changes): the default's linear candidates at every input
    delay start from it when their own regression finds no start.

    Parameters
    ----------
    recordings : sequence of Recording
        The pooled runs (one sample period).
    """
    recs = list(recordings)
    if len(recs) != 1:                  # pooled: nothing kept (a recording keeps only what it can pickle alone)
        return _regression_guess(recs)
    kept = recs[0].__dict__.get("_regression_guess")
    if kept is None:
        kept = (_regression_guess(recs),)
        object.__setattr__(recs[0], "_regression_guess", kept)
    return kept[0]


def _regression_guess(recordings: Sequence[Recording]) -> tuple[float, float] | None:
    """:func:`regression_guess`, computed."""
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
        # least squares in b and every segment's initial state: the states are each segment's own, so
        # they are projected out segment by segment and b solved on what is left (the same solution
        # as one least-squares problem over all the columns, without its (n, 1 + 2 segments) matrix)
        gy = gg = yy = 0.0
        for seg in segments:
            # with b = 1 and no initial speed the response is its own b-column: no sensitivities needed
            resp = zoh_response(a, 1.0, seg.drive, seg.time, 0.0, uniform=seg.uniform, sensitivities=False)
            angle = seg.kind == "angle"
            g = resp.angle if angle else resp.speed
            s0 = resp.angle_initial_speed if angle else resp.speed_initial_speed
            g_left, y_left = project_out_initial_state(s0, angle, g, np.asarray(seg.output, dtype=float))
            gy += float(g_left @ y_left)
            gg += float(g_left @ g_left)
            yy += float(y_left @ y_left)
        if gg > 0 and gy != 0:
            rss = yy - gy * gy / gg
            if rss < best[0]:
                best = (rss, float(a), gy / gg)
    return best[1], best[2]
