"""Samples no motor can produce: a count jump or a time step far beyond the rest of the run.

A single corrupted sample (a flipped bit in ``counts``, a wrong timestamp) fits into a
recording without breaking any format rule, and a fit through it is confidently wrong.
:func:`implausible_samples` (:meth:`motorsim.Recording.implausible_samples`) finds such rows
from the recording alone, before any fit;
:meth:`motorsim.Recording.drop_rows` removes rows so that they become gaps in ``seq``
(nothing is paired across them).  ``read_recording`` refuses a file with implausible rows unless told not to check.

Rules
-----
* **Speed**: a row whose speed (differenced angle, or the speed column) exceeds
  :data:`SPEED_FACTOR` times the larger of the run's 99th-percentile speed (its largest 1 %,
  at least 3 samples, left out) and the speed of one count per sample period.  A corrupted
  count at row ``k`` makes the speed jump at ``k`` and back at ``k + 1``; only ``k`` is named.
* **Time**: a row whose interval per ``seq`` step exceeds :data:`INTERVAL_FACTOR` sample
  periods (jitter keeps it below 2).
* **Duty beyond its limit**: a row whose duty exceeds the recording's declared duty limit
  (the ``duty_limit`` metadata): the bench clamps every duty it applies.
* **Duty spike**: a row whose duty jumps away from both neighbours, on the same side, by more
  than :data:`DUTY_SPIKE_FACTOR` times the run's 99th-percentile step of the duty (its largest
  1 %, at least 3 steps, left out; at least one duty unit): no excitation motorid knows makes
  a one-sample excursion that large, a corrupted cell does.

:func:`saturated_runs` finds the runs of samples at the duty limit (the model's linear
input no longer reaches the motor there); they are reported, with their number of samples.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["ImplausibleSample", "implausible_samples", "spike_rows", "saturated_runs", "SPEED_FACTOR",
           "INTERVAL_FACTOR", "DUTY_SPIKE_FACTOR"]

#: A speed this many times the run's 99th-percentile speed is not physical.
SPEED_FACTOR = 30.0
#: An interval this many sample periods per ``seq`` step is not a jittered sample.
INTERVAL_FACTOR = 10.0
#: A one-sample duty excursion this many times the run's 99th-percentile duty step is a corrupted cell.
DUTY_SPIKE_FACTOR = 4.0


class ImplausibleSample(NamedTuple):
    """One row that no motor can produce: its index (0-based), ``seq`` and why."""

    row: int
    seq: int
    reason: str


def spike_rows(values: np.ndarray, threshold: float) -> list[int]:
    """Rows where ``|values|`` exceeds ``threshold``, a jump-and-back pair named by its first row.

    Parameters
    ----------
    values : ndarray, shape (n,)
        Speeds or residuals (``nan`` is ignored).
    threshold : float
        Magnitude above which a row is flagged.

    Returns
    -------
    list of int
        The flagged rows; of two consecutive flagged rows of opposite sign only the first.
    """
    flagged = np.flatnonzero(np.abs(values) > threshold).tolist()   # nan compares False
    rows: list[int] = []
    for k in flagged:
        if rows and rows[-1] == k - 1 and np.sign(values[k]) == -np.sign(values[k - 1]):
            continue
        rows.append(k)
    return rows


def _speed_rows(speed: np.ndarray, seq: np.ndarray, speed_floor: float) -> list[ImplausibleSample]:
    magnitude = np.abs(speed)
    magnitude = magnitude[np.isfinite(magnitude)]
    if len(magnitude) < 10:
        return []
    top = len(magnitude) - 1 - max(3, len(magnitude) // 100)    # leave out the largest 1 %, at least 3
    magnitude.partition(top)
    scale = max(float(magnitude[top]), speed_floor)
    del magnitude
    if scale == 0:
        return []
    return [ImplausibleSample(k, int(seq[k]),
                              f"speed {speed[k]:.4g} rad/s is {abs(speed[k]) / scale:.3g} times the run's "
                              f"99th-percentile speed {scale:.4g} rad/s (limit {SPEED_FACTOR:g} times)")
            for k in spike_rows(speed, SPEED_FACTOR * scale)]


def _interval_rows(time: np.ndarray, seq: np.ndarray, sample_period: float) -> list[ImplausibleSample]:
    if len(time) < 2:
        return []
    per_step = np.diff(time)
    per_step /= np.diff(seq)
    per_step /= sample_period
    return [ImplausibleSample(k, int(seq[k]),
                              f"time step {time[k] - time[k - 1]:.6g} s is {per_step[k - 1]:.3g} sample "
                              f"periods per seq step (limit {INTERVAL_FACTOR:g})")
            for k in (np.flatnonzero(per_step > INTERVAL_FACTOR) + 1).tolist()]


def _duty_rows(duty: np.ndarray, seq: np.ndarray, duty_limit: float | None) -> list[ImplausibleSample]:
    found: list[ImplausibleSample] = []
    if duty_limit is not None:
        found += [ImplausibleSample(k, int(seq[k]), f"duty {duty[k]:.6g} is beyond the recording's duty limit "
                                                    f"+-{duty_limit:g}")
                  for k in np.flatnonzero(np.abs(duty) > duty_limit).tolist()]
    if len(duty) < 10:
        return found
    step = np.diff(duty)
    magnitude = np.abs(step)
    top = len(magnitude) - 1 - max(3, len(magnitude) // 100)
    scale = max(float(np.partition(magnitude, top)[top]), 1.0)
    away_before, away_after = step[:-1], -step[1:]          # duty[k] - duty[k-1], duty[k] - duty[k+1]
    same_side = np.sign(away_before) == np.sign(away_after)
    size = np.minimum(np.abs(away_before), np.abs(away_after))
    limit = DUTY_SPIKE_FACTOR * scale
    seen = {s.row for s in found}
    for k in (np.flatnonzero(same_side & (size > limit)) + 1).tolist():
        if k not in seen:
            found.append(ImplausibleSample(k, int(seq[k]), f"duty {duty[k]:.6g} jumps {size[k - 1]:.4g} away from "
                                                           f"both neighbours, {size[k - 1] / scale:.3g} times the "
                                                           f"run's 99th-percentile duty step {scale:.4g} (limit "
                                                           f"{DUTY_SPIKE_FACTOR:g} times)"))
    return found


def saturated_runs(duty: np.ndarray, duty_limit: float) -> list[tuple[int, int]]:
    """The runs of at least two consecutive samples at ``|duty| >= duty_limit``, as ``(first row, length)``.

    Examples
    --------
    >>> import numpy as np
    >>> saturated_runs(np.array([0, 255, 255, 255, 10, -255, 3]), 255)
    [(1, 3)]
    """
    at = np.abs(np.asarray(duty, float)) >= duty_limit
    edges = np.flatnonzero(np.diff(np.concatenate([[0], at.astype(np.int8), [0]])))
    return [(int(a), int(b - a)) for a, b in zip(edges[::2], edges[1::2]) if b - a >= 2]


def implausible_samples(time: np.ndarray, seq: np.ndarray, speed: np.ndarray, sample_period: float,
                        speed_floor: float = 0.0, *, duty: np.ndarray | None = None,
                        duty_limit: float | None = None) -> list[ImplausibleSample]:
    """The rows that no motor or sampler can produce (see the module's rules).

    :meth:`motorsim.Recording.implausible_samples` calls this on a recording's columns.

    Parameters
    ----------
    time : ndarray, shape (n,)
        Sample instants in s.
    seq : ndarray of int, shape (n,)
        Sample indices (gaps allowed).
    speed : ndarray, shape (n,)
        Measured speed in rad/s (``nan`` where undefined).
    sample_period : float
        Nominal sample period in s.
    speed_floor : float, optional
        Smallest speed scale in rad/s, e.g. one encoder count per sample period (default 0).
    duty : ndarray, shape (n,), optional
        The input; when given, its spikes are rows too.
    duty_limit : float, optional
        The declared duty limit; a duty beyond it is a row too.

    Returns
    -------
    list of ImplausibleSample
        Sorted by row; empty for a plausible recording.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(100) * 0.01
    >>> speed = np.sin(t); speed[40] = 500.0
    >>> [s.row for s in implausible_samples(t, np.arange(100), speed, 0.01)]
    [40]
    """
    found = {s.row: s for s in _interval_rows(time, seq, sample_period)}
    for s in _speed_rows(speed, seq, speed_floor):
        found.setdefault(s.row, s)
    if duty is not None:
        for s in _duty_rows(np.asarray(duty, float), seq, duty_limit):
            found.setdefault(s.row, s)
    return [found[k] for k in sorted(found)]
