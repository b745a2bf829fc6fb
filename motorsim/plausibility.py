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

Units of an angle column
------------------------
:func:`angle_unit_doubt` says why an angle column read as radians reads as another unit -- the
commonest being degrees, whose every speed and ``b`` come out 57.3 times too large while the
fit looks perfect.  It speaks only on evidence no radian angle gives (a miss is better than a
false alarm on a good recording):

* **Speed column**: with a speed column too, the differenced angle must move as fast as the
  speed column says; a factor of 180/pi (or any factor beyond 1.5 either way) between the two,
  on motion that correlates (:data:`MIN_CORRELATION`), is a unit read wrong.
* **Encoder steps**: an encoder's angle moves in whole steps of one revolution over its counts
  per revolution.  An angle that spans at least :data:`MIN_POSITIONS` steps, all on an
  exact lattice of step ``q`` with ``360 / q`` a whole number of counts and ``2 pi / q`` not, is
  an encoder's angle in degrees -- when ``q`` is known well enough: the whole count resolved to
  1e-3 (the digits the file prints count against it: radians rounded to a coarse grid can stay
  on a lattice for a few positions), or an exact decimal lattice over :data:`MIN_EXACT_SPAN`
  steps.  An angle that holds only whole numbers is counts or whole degrees.
* **Speed**: a sustained speed (the 99th percentile, as for the speed rule) beyond
  :data:`MAX_SPEED` rad/s is beyond any motor motorid identifies.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .quantiles import kth_smallest

__all__ = ["ImplausibleSample", "implausible_samples", "spike_rows", "saturated_runs", "SPEED_FACTOR",
           "INTERVAL_FACTOR", "DUTY_SPIKE_FACTOR", "angle_unit_doubt", "AngleUnitDoubt", "MAX_SPEED",
           "MIN_CORRELATION"]

#: A speed this many times the run's 99th-percentile speed is not physical.
SPEED_FACTOR = 30.0
#: An interval this many sample periods per ``seq`` step is not a jittered sample.
INTERVAL_FACTOR = 10.0
#: A one-sample duty excursion this many times the run's 99th-percentile duty step is a corrupted cell.
DUTY_SPIKE_FACTOR = 4.0
#: A sustained speed beyond this, in rad/s (about 190 000 rpm), is beyond any motor motorid identifies.
MAX_SPEED = 2e4
#: Correlation of the differenced angle with a speed column above which their factor is trusted.
MIN_CORRELATION = 0.9
#: Steps an angle must span before its steps are read as an encoder's.
MIN_POSITIONS = 10
#: Steps an exact decimal lattice must span before it alone says "degrees" (a coarsely printed angle).
MIN_EXACT_SPAN = 1000


class AngleUnitDoubt(NamedTuple):
    """Why an angle column said to be in radians reads as another unit, and the unit it reads as (or None)."""

    reason: str
    unit: str | None


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
    finite = int(np.count_nonzero(np.isfinite(magnitude)))
    if finite < 10:
        return []
    # the finite magnitudes' order statistic, taken among all: inf and nan sort after every finite value
    top = finite - 1 - max(3, finite // 100)    # leave out the largest 1 %, at least 3
    scale = max(float(kth_smallest(magnitude, top)), speed_floor)
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
    steps = np.diff(seq)
    if not np.all(steps == 1):      # a division by whole steps of one changes nothing, and costs a conversion
        per_step /= steps
    del steps
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
    # a spike leaves both neighbours by more than the limit on the same side: duty[k] - duty[k-1] = step[k-1]
    # and duty[k] - duty[k+1] = -step[k] of one sign (checked only where both are large: few rows)
    size = np.minimum(magnitude[:-1], magnitude[1:])
    top = len(magnitude) - 1 - max(3, len(magnitude) // 100)
    scale = max(float(kth_smallest(magnitude, top)), 1.0)
    del magnitude
    limit = DUTY_SPIKE_FACTOR * scale
    large = np.flatnonzero(size > limit)
    spikes = large[np.sign(step[large]) == -np.sign(step[large + 1])]
    seen = {s.row for s in found}
    for k in (spikes + 1).tolist():
        if k not in seen:
            found.append(ImplausibleSample(k, int(seq[k]), f"duty {duty[k]:.6g} jumps {size[k - 1]:.4g} away from "
                                                           f"both neighbours, {size[k - 1] / scale:.3g} times the "
                                                           f"run's 99th-percentile duty step {scale:.4g} (limit "
                                                           f"{DUTY_SPIKE_FACTOR:g} times)"))
    return found


def saturated_runs(duty: np.ndarray, duty_limit: float) -> list[tuple[int, int]]:
    """The runs of at least two consecutive samples at ``|duty| = duty_limit``, as ``(first row, length)``.

    A duty beyond the limit is not a clipped one (it is an implausible row when the limit is the
    recording's ``duty_limit``); equality is to 1e-9 relative.

    Examples
    --------
    >>> import numpy as np
    >>> saturated_runs(np.array([0, 255, 255, 255, 10, -255, 3]), 255)
    [(1, 3)]
    """
    duty = np.asarray(duty)
    if not len(duty) or max(float(duty.max()), -float(duty.min())) < duty_limit * (1 - 2e-9):
        return []                           # no sample reaches the limit: two reductions, no pass building masks
    if duty.dtype.kind in "iu" and float(duty_limit).is_integer():     # exact: no float pass
        at = (duty == int(duty_limit)) | (duty == -int(duty_limit))
    else:
        at = np.abs(np.abs(duty.astype(float)) - duty_limit) <= 1e-9 * duty_limit
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
        duty = np.asarray(duty)
        for s in _duty_rows(duty if duty.dtype.kind in "if" else duty.astype(float), seq, duty_limit):
            found.setdefault(s.row, s)
    return [found[k] for k in sorted(found)]


def angle_unit_doubt(angle: np.ndarray, time: np.ndarray, seq: np.ndarray,
                     speed: np.ndarray | None = None) -> AngleUnitDoubt | None:
    """Why an angle column said to be in radians reads as another unit, or None (the module's rules).

    Parameters
    ----------
    angle : ndarray, shape (n,)
        The angle column as read, in the radians it is said to be in.
    time : ndarray, shape (n,)
        Sample instants in s.
    seq : ndarray of int, shape (n,)
        Sample indices (no speed is formed across a gap).
    speed : ndarray, shape (n,), optional
        A speed column in rad/s.

    Returns
    -------
    AngleUnitDoubt or None
        The rule and the value (``"it moves only in exact steps of 0.351562, 1024 per 360 ..."``) and
        the unit the evidence points to (``"deg"``, ``"rev"``, ``"counts"``, None when the
        speed column may be the one wrong); None when nothing says the angle is not in radians.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(400) * 0.005
    >>> counts = np.round(400 * np.sin(3 * t))                  # a 1024-count encoder
    >>> angle_unit_doubt(counts * 2 * np.pi / 1024, t, np.arange(400)) is None
    True
    >>> doubt = angle_unit_doubt(counts * 360 / 1024, t, np.arange(400))
    >>> doubt.unit, doubt.reason[:62]
    ('deg', 'it moves only in exact steps of 0.351562, 1024 per 360 but 17.')
    """
    angle = np.asarray(angle, float)
    if len(angle) < 10:
        return None
    steps = np.diff(angle)
    rate = steps / np.diff(time)
    rate[np.diff(seq) != 1] = np.nan
    return _against_speed(rate, speed) or _encoder_steps(angle, steps) or _beyond_any_motor(rate)


def _against_speed(rate: np.ndarray, speed: np.ndarray | None) -> AngleUnitDoubt | None:
    """The speed-column rule: the factor between the differenced angle and the speed column."""
    if speed is None:
        return None
    mean_speed = (speed[1:] + speed[:-1]) / 2          # over the interval the difference spans
    ok = np.isfinite(rate) & np.isfinite(mean_speed)
    x, y = mean_speed[ok], rate[ok]
    if len(x) < 10 or float(x @ x) == 0 or float(y @ y) == 0:
        return None
    factor = float(x @ y) / float(x @ x)
    correlation = float(x @ y) / math.sqrt(float(x @ x) * float(y @ y))
    if abs(correlation) < MIN_CORRELATION or 1 / 1.5 <= factor <= 1.5:
        return None
    known = {180 / math.pi: ("an angle in degrees (or a speed column in rad/s read as deg/s)", "deg"),
             1 / (2 * math.pi): ("an angle in revolutions (or a speed column in rev/s read as rad/s)", "rev")}
    reading, unit = next((known[k] for k in known if abs(factor / k - 1) < 0.05),
                         ("the units of the two columns do not match", None))
    return AngleUnitDoubt(f"its difference moves {factor:.4g} times as fast as the speed column says "
                          f"(correlation {correlation:.3f}): {reading}", unit)


def _decimal_grid(values: np.ndarray) -> float:
    """The coarsest ``10**-k`` every value is a whole multiple of (how the file printed them), else 0."""
    def on_grid(x: np.ndarray, k: int) -> bool:
        scaled = x * 10.0 ** k
        return bool(np.all(np.abs(scaled - np.round(scaled)) <= np.maximum(1e-6, 4 * np.spacing(np.abs(scaled)))))
    top = float(np.max(np.abs(values)))
    head = values[:1 << 16]                           # tried on the first values, confirmed on all
    for k in range(0, 16):
        if top * 10.0 ** k > 1e13:
            break
        if on_grid(head, k) and on_grid(values, k):
            return 10.0 ** -k
    return 0.0


def _encoder_steps(angle: np.ndarray, steps: np.ndarray) -> AngleUnitDoubt | None:
    """The encoder-step rule: an angle on an exact lattice of ``360 / N`` but not of ``2 pi / N``."""
    moves = steps[steps != 0]
    if len(moves) < 20:
        return None
    grid = _decimal_grid(angle)
    if grid >= 1:
        return AngleUnitDoubt("it holds only whole numbers, as counts or whole degrees do, never an angle in "
                              f"radians (it moves in steps as small as {float(np.min(np.abs(moves))):g})", "counts")
    smallest = float(np.min(np.abs(moves)))
    whole = np.round(steps / smallest)
    if np.max(np.abs(steps / smallest - whole)) > 0.05:
        return None                                   # not whole multiples of one step: no encoder lattice
    n = np.concatenate([[0.0], np.cumsum(whole)])     # whole steps from the first sample, exactly
    n_centred = n - n.mean()
    step = float(n_centred @ (angle - angle.mean())) / max(float(n_centred @ n_centred), 1.0)   # least squares
    error = float(np.max(np.abs(angle - angle.mean() - step * n_centred)))
    step = abs(float(step))
    span = float(n.max() - n.min())
    decade = 10.0 ** round(math.log10(step)) if step > 0 else 0.0
    if step == 0 or error > 0.02 * step or (grid and step < 2 * grid) or abs(step / decade - 1) < 1e-9:
        return None        # off the lattice, or a lattice that may be only the digits the file prints
    if span < MIN_POSITIONS:
        return None        # a few positions fit many lattices, rounded radians among them
    # relative uncertainty of the step: the largest departure over the span, at least the rounding the
    # printed digits allow (half the grid: radians rounded to a coarse grid can look like an exact lattice)
    relative = 2 * (max(error, grid / 2) + 1e-15 * float(np.max(np.abs(angle)))) / (span * step)
    per_degrees, per_radians = 360 / step, 2 * math.pi / step
    tolerance_degrees = max(4 * per_degrees * relative, 1e-9 * per_degrees)
    tolerance_radians = max(4 * per_radians * relative, 1e-9 * per_radians)
    # evidence enough: whole counts per 360 resolved to 1e-3, or an exact decimal lattice over a long span
    # (radians rounded to the grid stay on a lattice over n positions with a chance of about 2 / n)
    decisive = tolerance_degrees <= 1e-3 or (grid > 0 and error <= 1e-6 * grid and span >= MIN_EXACT_SPAN)
    if not decisive or not 2 <= per_degrees <= 1e7:
        return None
    off_degrees = abs(per_degrees - round(per_degrees))
    off_radians = abs(per_radians - round(per_radians))
    if off_degrees <= tolerance_degrees and off_radians > max(0.01, 10 * tolerance_radians):
        return AngleUnitDoubt(f"it moves only in exact steps of {step:.6g}, {round(per_degrees)} per 360 but "
                              f"{per_radians:.6g} per 2 pi: an encoder's angle in degrees ({round(per_degrees)} "
                              "counts/rev), not radians", "deg")
    return None


def _beyond_any_motor(rate: np.ndarray) -> AngleUnitDoubt | None:
    """The speed rule: the run's 99th-percentile speed beyond :data:`MAX_SPEED`."""
    magnitude = np.abs(rate[np.isfinite(rate)])
    if len(magnitude) < 10:
        return None
    top = len(magnitude) - 1 - max(3, len(magnitude) // 100)
    sustained = float(kth_smallest(magnitude, top))
    if sustained <= MAX_SPEED:
        return None
    return AngleUnitDoubt(f"its speed reaches {sustained:.4g} rad/s ({sustained * 60 / (2 * math.pi):.3g} rpm) "
                          f"for 1 % of the run, beyond the {MAX_SPEED:g} rad/s of any motor (in degrees it would "
                          f"be {math.radians(sustained):.4g} rad/s)", "deg")
