"""Whether a torque of the angle explains a speed that turns under a constant recorded input.

:func:`identify.data.check_constant_input_runs` refuses a recording whose speed both rises and falls
while its recorded input stays constant: a motor whose torque depends on its speed alone moves one way
under a constant input, so the log does not hold the input the motor received (a duty logged flat at
+-60 while the drive applied +-200).  A torque of the *angle* breaks that premise: an arm under gravity,
a spring, a cable or an unbalanced load makes the speed rise and fall under any constant input, and such
a recording is valid.

:func:`angle_torque_explains` tells the two apart without the right structure for either.  It fits the
speed's changes over windows of :data:`WINDOW` samples *outside* the runs that turn, in the integrated
form of ``dω/dt = -a ω + b u + c + g(θ)``,

    ``ω(t + L h) - ω(t) = -a Δθ + b h Σ u + c L h + h Σ g(θ)``,

``g`` a spring's ``θ`` and the first :data:`HARMONICS` harmonics of a turn (``sin kθ``, ``cos kθ``): the
regressors are the angle and the logged input, so the speed's noise is on the left alone and biases
nothing.  Then it predicts each turning run from its first sample by the same sum and asks whether the
run still turns in what is left (the screen's own measure of a turn, at the thresholds it used).

A torque of the angle acts the same in every part of the run, so what it learns outside the turning runs
predicts them: the turns are explained.  A log that misses the input the motor received does not: outside
the runs the logged input is the applied one and the fit finds no torque of the angle (a clipped log's
unclipped rows), so the turns stay.  Where too few rows lie outside the turning runs to learn from
(:data:`MIN_WINDOWS`), nothing is explained and the screen refuses as before.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from motorsim.recording import Recording

__all__ = ["angle_torque_explains", "recorded_angle", "whole_windows", "WINDOW", "HARMONICS", "MIN_WINDOWS"]

#: Samples over which the speed's change is summed: enough for the angle's change to stand above an
#: encoder's count, few enough that the windows outside the turning runs are many.
WINDOW = 8
#: Harmonics of a turn in ``g(θ)``: gravity on an arm and a load unbalanced once a turn (1), a crank (2).
HARMONICS = 2
#: Least windows outside the turning runs, per column fitted, to learn ``a``, ``b``, ``c`` and ``g`` from.
MIN_WINDOWS = 10


def recorded_angle(rec: Recording) -> np.ndarray | None:
    """The angle in rad: measured, else the speed column integrated by trapezoids (its offset is arbitrary)."""
    theta = rec.measured_angle()
    if theta is not None:
        return np.asarray(theta, dtype=float)
    w = np.nan_to_num(np.asarray(rec.speed, dtype=float))
    return np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(rec.time))])


def whole_windows(seq: np.ndarray, speed: np.ndarray, first: int, width: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Consecutive windows of ``width`` rows from row ``first``: their first and last rows, and whether each is
    whole (no gap in ``seq`` inside it, a finite ``speed`` at both ends)."""
    n = len(seq)
    gaps = np.cumsum(np.r_[False, np.diff(seq) != 1])
    starts = np.arange(first, n - width, width)
    ends = starts + width
    return starts, ends, (gaps[ends] == gaps[starts]) & np.isfinite(speed[starts]) & np.isfinite(speed[ends])


def _columns(theta: np.ndarray, u: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Per sample, the integrands of the fit: ``u h``, ``h``, and ``g(θ) h`` for each column of ``g``."""
    cols = [u * h, h, (theta - float(np.mean(theta))) * h]
    for k in range(1, HARMONICS + 1):
        cols += [np.sin(k * theta) * h, np.cos(k * theta) * h]
    return np.column_stack(cols)


def angle_torque_explains(rec: Recording, runs: Sequence[tuple[int, int, float]], input_delay: int,
                          turns: Callable[[np.ndarray], tuple[float, float, float]]) -> bool:
    """Whether a torque of the angle, learned outside the turning ``runs``, explains their turns (module docstring).

    Parameters
    ----------
    rec : Recording
        The recording the screen judged.
    runs : sequence of (start, end, threshold)
        The rows ``start:end`` of each run whose speed turned, and the rise and fall (rad/s) the screen counted
        as a turn there.
    input_delay : int
        The fitted input delay, in samples.
    turns : callable
        A run's speed to its rise, fall and the noise they are judged against (the screen's own,
        :func:`identify.data.run_turns`).
    """

    theta = recorded_angle(rec)
    n = len(rec)
    w = np.asarray(rec.measured_speed(), dtype=float)
    if theta is None or n < 2 or not np.all(np.isfinite(theta)):
        return False
    d = int(input_delay)
    u = np.r_[np.zeros(d), np.asarray(rec.duty, dtype=float)[:n - d]] if d else np.asarray(rec.duty, dtype=float)
    h = np.r_[np.diff(rec.time), 0.0]
    cols = _columns(theta, u, h)
    sums = np.vstack([np.zeros(cols.shape[1]), np.cumsum(cols, axis=0)])   # sums[k] = Σ_{j<k}
    inside = np.zeros(n, dtype=bool)
    for start, end, _ in runs:
        inside[max(start - WINDOW, 0):end] = True
    starts, ends, whole = whole_windows(rec.seq, w, 0, WINDOW)
    blocked = np.cumsum(np.r_[0, inside.astype(int)])
    keep = ((blocked[ends + 1] - blocked[starts]) == 0) & whole
    design = np.column_stack([-(theta[ends] - theta[starts]), sums[ends] - sums[starts]])
    if int(keep.sum()) < MIN_WINDOWS * design.shape[1]:
        return False
    coef, *_ = np.linalg.lstsq(design[keep], w[ends[keep]] - w[starts[keep]], rcond=None)
    if not np.all(np.isfinite(coef)):
        return False
    for start, end, threshold in runs:
        rows = np.arange(start, end)
        rows = rows[np.isfinite(w[rows])]
        if len(rows) < 2:
            continue
        k0 = rows[0]
        drift = np.column_stack([-(theta[rows] - theta[k0]), sums[rows] - sums[k0]]) @ coef
        rise, fall, noise = turns(w[rows] - w[k0] - drift)
        if min(rise, fall) > max(noise, threshold):
            return False
    return True
