"""Units of a lab's own columns and the timing rule: arrays in, the SI columns of a recording out.

:func:`columns_in_si` converts columns given in any of the units below to the SI keyword
arguments of :class:`~motorsim.recording.Recording` and infers the sample period from the
time column (:meth:`Recording.from_columns` is the public way in; foreign files are read by
:mod:`motorsim.columns`).

=========  ============================================================
quantity   units (the first is the one a recording stores)
=========  ============================================================
time       ``s``, ``ms``, ``us`` (also ``µs``)
input      ``duty``, ``V``, ``%`` (values kept as they are; the unit goes to the
           metadata ``input_unit``)
angle      ``rad``, ``deg``, ``rev``, ``counts`` (needs ``counts_per_rev``)
speed      ``rad/s``, ``deg/s``, ``rpm``, ``rev/s`` (converted to rad/s; the unit the user
           brought goes to the metadata ``speed_unit``, for showing results in it)
=========  ============================================================

Timing rule: the sample period is the median interval of the time column.  When every
interval is a whole number of sample periods (within 1 %), longer intervals are dropped
samples (gaps in ``seq``); otherwise the clock is non-uniform: the time column is kept as it
is (``time_s``) and the metadata say ``time_uniform: false`` with the range of the intervals
(:meth:`Recording.from_columns` also warns); on such a clock an interval longer than
:data:`PAUSE_FACTOR` periods is a pause between runs (a gap in ``seq``; ``time_pauses`` counts them).
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike

from .checks import ParameterError, ParameterTypeError

__all__ = ["TIME_UNITS", "INPUT_UNITS", "ANGLE_UNITS", "SPEED_UNITS", "ANGLE_RATE_UNITS", "UNITS", "DEFAULT_UNITS",
           "UNIFORM_TOLERANCE", "PAUSE_FACTOR", "columns_in_si", "timing_note", "speed_in"]

#: Seconds per unit of the time column.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6}
#: Input units (values are not converted; the unit is kept as metadata).
INPUT_UNITS = ("duty", "V", "%")
#: Radians per unit of an angle column (``counts`` goes through ``counts_per_rev``).
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180, "rev": 2 * math.pi, "counts": math.nan}
#: (rad/s) per unit of a speed column.
SPEED_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180, "rpm": 2 * math.pi / 60, "rev/s": 2 * math.pi}

#: The speed unit an angle unit implies (the unit a recording of that angle shows its speed in).
ANGLE_RATE_UNITS = {"rad": "rad/s", "deg": "deg/s", "rev": "rev/s", "counts": "rad/s"}

#: The units of each quantity, by quantity.
UNITS: dict[str, tuple[str, ...]] = {"time": tuple(TIME_UNITS), "input": INPUT_UNITS, "angle": tuple(ANGLE_UNITS),
                                      "counts": ("counts",), "speed": tuple(SPEED_UNITS)}
#: The unit of a column given without one.
DEFAULT_UNITS = {"time": "s", "input": "duty", "angle": "rad", "counts": "counts", "speed": "rad/s"}
#: Largest departure of an interval from a whole number of sample periods on a uniform clock.
UNIFORM_TOLERANCE = 0.01
#: On a non-uniform clock, an interval longer than this many sample periods is a pause (the robot disabled between
#: two tests, a logger stopped): a gap in ``seq``, where the runs either side are cut apart, not one long sample.
PAUSE_FACTOR = 4.0


def _as_float(name: str, value: ArrayLike) -> np.ndarray:
    """``value`` (a numpy array, pandas Series, list) as a 1-D float array."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise ParameterTypeError(f"{name} must hold numbers, got dtype {arr.dtype}")
    arr = np.ravel(arr) if arr.ndim == 2 and 1 in arr.shape else arr
    if arr.ndim != 1:
        raise ParameterError(f"{name} must be 1-D, got shape {arr.shape}")
    return arr.astype(float)


def _timing(time_s: np.ndarray) -> tuple[float, np.ndarray, dict[str, str]]:
    """Sample period, ``seq`` and timing metadata of a time column in s (module docstring's rule)."""
    if len(time_s) < 2:
        raise ParameterError(f"time needs at least 2 samples to infer the sample period, got {len(time_s)}")
    steps = np.diff(time_s)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ParameterError(f"time must be strictly increasing, got {float(time_s[k])!r} after "
                             f"{float(time_s[k - 1])!r} at sample {k}")
    period = float(f"{np.median(steps):.12g}")   # 0.02, not 0.019999999999999574 from rounding in the file
    ratio = steps / period
    whole = np.round(ratio)
    if np.max(np.abs(ratio - whole)) <= UNIFORM_TOLERANCE:
        seq = np.concatenate([[0], np.cumsum(whole.astype(np.int64))])
        return period, seq, {}
    pause = ratio > PAUSE_FACTOR
    kept = steps[~pause]
    meta = {"time_uniform": "false", "time_step_min": f"{kept.min():.9g}", "time_step_max": f"{kept.max():.9g}"}
    if pause.any():
        meta["time_pauses"] = str(int(pause.sum()))
    seq = np.concatenate([[0], np.cumsum(np.where(pause, np.round(ratio), 1).astype(np.int64))])
    return period, seq, meta


def columns_in_si(time: ArrayLike, duty: ArrayLike, *, speed: ArrayLike | None = None,
                  angle: ArrayLike | None = None, counts: ArrayLike | None = None,
                  counts_per_rev: int | None = None, input_unit: str = "duty", time_unit: str = "s",
                  speed_unit: str = "rad/s", angle_unit: str = "rad",
                  sample_period: float | None = None,
                  metadata: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Columns in any supported unit as the SI keyword arguments of ``Recording``, sample period inferred.

    Parameters
    ----------
    time : array_like, shape (n,)
        Sample instants in ``time_unit`` (numpy array, pandas Series, list).
    duty : array_like, shape (n,)
        Input in ``input_unit``, applied from ``time[k]`` to ``time[k+1]``.
    speed, angle, counts : array_like, shape (n,), optional
        Measured speed (``speed_unit``), angle (``angle_unit``) or encoder counts; at least one.
    counts_per_rev : int, optional
        Encoder resolution in counts/rev; needed with ``counts`` or ``angle_unit="counts"``.
    input_unit : str
        ``duty``, ``V`` or ``%``: kept as the metadata ``input_unit`` (values unchanged).
    time_unit, speed_unit, angle_unit : str
        Units of the columns (module docstring).
    sample_period : float, optional
        Nominal sample period in s; default the median interval of ``time``.  When given, it
        must agree with that median within 1 %.
    metadata : mapping of str to str, optional
        Further metadata (``source``, ...).

    Returns
    -------
    dict
        ``time`` in s, ``duty``, ``speed`` in rad/s, ``angle`` in rad, ``counts``, ``seq`` (gaps
        where an interval spans several sample periods), ``sample_period`` in s,
        ``counts_per_rev`` and ``metadata`` (``input_unit``; ``time_uniform: false`` with the
        range of the intervals on a non-uniform clock; ``speed_unit``, the speed column's unit or
        the one the angle's implies).

    Examples
    --------
    >>> cols = columns_in_si(time=[0, 20, 40, 60], duty=[1.5, 1.5, 2.7, 2.7],
    ...                      speed=[0.0, 180.0, 360.0, 360.0], time_unit="ms", speed_unit="deg/s", input_unit="V")
    >>> cols["sample_period"], cols["metadata"]["input_unit"], round(float(cols["speed"][1]), 6)
    (0.02, 'V', 3.141593)
    """
    for quantity, unit in (("time", time_unit), ("input", input_unit), ("speed", speed_unit), ("angle", angle_unit)):
        if unit not in UNITS[quantity]:
            raise ParameterError(f"{quantity}_unit must be one of {list(UNITS[quantity])}, got {unit!r}")
    if speed is None and angle is None and counts is None:
        raise ParameterError("a recording needs at least one of speed, angle, counts")
    time_s = _as_float("time", time) * TIME_UNITS[time_unit]
    if not np.all(np.isfinite(time_s)):
        k = int(np.flatnonzero(~np.isfinite(time_s))[0])
        raise ParameterError(f"time must be finite, got {float(time_s[k])!r} at sample {k}")
    period, seq, meta = _timing(time_s)
    if sample_period is not None and abs(sample_period / period - 1) > UNIFORM_TOLERANCE:
        raise ParameterError(f"sample_period must agree with the median interval of time ({period!r} s) within "
                         f"{UNIFORM_TOLERANCE:.0%}, got {sample_period!r}")
    if angle is not None and angle_unit == "counts":
        counts, angle = angle, None
    angle_rad = None if angle is None else _as_float("angle", angle) * ANGLE_UNITS[angle_unit]
    speed_rad_s = None if speed is None else _as_float("speed", speed) * SPEED_UNITS[speed_unit]
    meta = {**(metadata or {}), **meta, "input_unit": input_unit,
            "speed_unit": speed_unit if speed is not None else ANGLE_RATE_UNITS[angle_unit]}
    return {"time": time_s, "duty": _as_float("duty", duty), "sample_period": sample_period or period,
            "speed": speed_rad_s, "angle": angle_rad, "counts": counts, "seq": seq,
            "counts_per_rev": counts_per_rev, "metadata": meta}


def timing_note(metadata: Mapping[str, str], sample_period: float) -> str:
    """What a user should know about the clock of :func:`columns_in_si`'s result ('' when uniform)."""
    if metadata.get("time_uniform") != "false":
        return ""
    pauses = metadata.get("time_pauses")
    cut = (f"; {pauses} pause(s) longer than {PAUSE_FACTOR:g} periods cut it into runs fitted apart"
           if pauses else "")
    return (f"the time column is not uniform (intervals from {metadata['time_step_min']} to "
            f"{metadata['time_step_max']} s, median {sample_period!r} s): kept as time_s, sample_period is the "
            f"median{cut}")


def speed_in(value: float, unit: str) -> float:
    """A speed (or a speed per something) in rad/s expressed in ``unit``.

    Examples
    --------
    >>> round(speed_in(157.07963, "rpm"), 3)
    1500.0
    """
    if unit not in SPEED_UNITS:
        raise ParameterError(f"speed unit must be one of {list(SPEED_UNITS)}, got {unit!r}")
    return value / SPEED_UNITS[unit]
