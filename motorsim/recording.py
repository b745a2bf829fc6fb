"""``Recording``: one experiment's samples, and the CSV recording format v1.

:class:`Recording` holds the sample columns (read-only arrays) and the metadata of one
run, checks them when built, converts counts to angle (:meth:`Recording.measured_angle`),
differences the angle into speed (:meth:`Recording.measured_speed`) and splits at dropped
samples (:meth:`Recording.segments`).  This module holds the type and the format's
constants; :mod:`motorsim.writing` writes format v1 (below) -- :func:`write_recording`, and
:class:`RecordingWriter` row by row during a run, so that an interrupted run still leaves a
readable file -- and :mod:`motorsim.reading` reads it (:func:`read_recording`).

Alignment (every package follows it)
------------------------------------
Row ``k``'s encoder reading (``counts``/``angle_rad``) is taken at ``time_s[k]``;
then ``duty[k]`` is applied until ``time_s[k+1]``.  Speed at ``k`` is the backward
difference ``(angle[k] - angle[k-1]) / (time[k] - time[k-1])``, the average over
the interval *before* ``k``.  Regressions pair ``speed[k+1]`` with
``(speed[k], duty[k])``.  A gap in ``seq`` means samples were dropped: the duty
applied during a gap is unknown, so nothing is paired across it.

Format v1 (CSV, UTF-8)::

    # motorid recording v1
    # counts_per_rev: 16667
    # sample_period: 0.005
    seq,time_s,duty,counts
    0,0.000000,0,0

Leading ``#`` lines hold ``key: value`` metadata (unknown keys are kept; ``dt``
and ``ppr`` are read as ``sample_period`` and ``counts_per_rev``).  Columns may
come in any order: ``time_s`` and ``duty`` are required, and at least one of
``counts``, ``angle_rad``, ``speed_rad_s``; ``seq`` is optional.  ``time_s`` is in seconds:
its median interval per ``seq`` step must be within :data:`TIME_BASE_TOLERANCE` of
``sample_period`` (a column in ms, or a wrong period, is refused with both figures).
Only a regular file of at most :data:`MAX_RECORDING_BYTES` is read; a byte-order mark, a
NUL byte, a cell with ``_`` digit separators, a count beyond 64 bits and a torn last line
(no final newline) are refused, each with its own message.
A closed-loop run adds
``reference``: what the controller tracked at ``time_s[k]``, in the unit named by the
metadata ``reference_unit`` (``rad/s`` for a speed controller, ``rad`` of angle since
the first sample for a position controller).
"""
from __future__ import annotations

import builtins
import dataclasses
import math
import os
import warnings
from typing import Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from .checks import ParameterError, ParameterTypeError, check_int, check_real, real_array
from .lazy import lazy_attributes
from .plausibility import AngleUnitDoubt, ImplausibleSample, angle_unit_doubt, implausible_samples, saturated_runs
from .quantiles import median
from .sensors import backward_difference, counts_to_angle
from .units import SPEED_UNITS

__all__ = ["Recording", "RecordingFormatError", "AngleUnitWarning", "FORMAT_HEADER", "COLUMNS", "METADATA_ALIASES",
           "INTEGER_COLUMNS", "TIME_BASE_TOLERANCE"]

FORMAT_HEADER = "# motorid recording v1"
#: Known columns in the order they are written.
COLUMNS = ("seq", "time_s", "duty", "counts", "angle_rad", "speed_rad_s", "reference")
#: Metadata keys read under another name (older files).
METADATA_ALIASES = {"dt": "sample_period", "ppr": "counts_per_rev"}
#: Columns written and read as integers.
INTEGER_COLUMNS = ("seq", "counts")
#: Largest relative disagreement allowed between the median interval of ``time_s`` (per step
#: of ``seq``) and the declared ``sample_period``.  Timing jitter (< 1 sample period, see
#: ``SimRig.jitter``) and dropped samples leave the median interval within a few per cent of
#: the period; a time column in ms or µs, or a wrong period, is off by a large factor.
TIME_BASE_TOLERANCE = 0.2


class RecordingFormatError(ValueError):
    """A recording file or array breaks a rule of recording format v1."""


class AngleUnitWarning(UserWarning):
    """An angle column said to be in radians reads as another unit (:meth:`Recording.angle_unit_doubt`)."""


def _as_array(name: str, value: ArrayLike, dtype: type, n: int | None = None) -> np.ndarray:
    """``value`` as a read-only 1-D copy of ``dtype`` (of length ``n`` when given).

    An array nobody can write to (read-only, owning its memory) is kept as it is: copying it
    would only double the memory of a large recording.
    """
    arr: np.ndarray
    if isinstance(value, np.ndarray) and value.dtype == dtype and value.base is None and not value.flags.writeable:
        arr = value
    elif dtype is float:
        arr = np.array(real_array(name, value), dtype=float, copy=True)
    else:
        arr = np.array(value, dtype=dtype, copy=True)
    if arr.ndim != 1:
        raise ParameterError(f"{name} must be 1-D, got shape {arr.shape}")
    if n is not None and len(arr) != n:
        raise ParameterError(f"{name} must have the same length as time ({n}), got {len(arr)}")
    arr.setflags(write=False)
    return arr


def _optional_array(name: str, value: ArrayLike | None, n: int) -> np.ndarray | None:
    """A float column, or None when absent."""
    return None if value is None else _as_array(name, value, float, n)


def _integer_array(name: str, value: ArrayLike | None, n: int) -> np.ndarray | None:
    """An integer column (``seq``, ``counts``): integral floats are accepted, fractions refused."""
    if value is None:
        return None
    raw = np.asarray(value)
    if raw.dtype.kind == "f":
        if not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
            raise ParameterError(f"{name} must hold integers, got non-integer values")
    elif raw.dtype.kind not in "iu":
        raise ParameterTypeError(f"{name} must hold integers, got dtype {raw.dtype}")
    return _as_array(name, value, np.int64, n)


#: The largest magnitude of an angle (rad), speed (rad/s), duty or reference a recording may hold:
#: beyond it no motor is measured, and the fits' squares overflow.
MAX_MAGNITUDE = 1e12
#: The largest encoder resolution a recording may state, counts per revolution (2**32: a 32-bit absolute
#: encoder's; a high-resolution incremental one gives 2**24-2**27): beyond it a count is a fraction of a
#: nanoradian, and a counts_per_rev of 1e20 made every speed and b 1e-16 of the truth without a word.
MAX_COUNTS_PER_REV = 2 ** 32
#: Beyond this magnitude a float64 no longer holds every integer count: :meth:`Recording.measured_angle`
#: then measures the counts from their median, exactly, before converting them.
MAX_EXACT_COUNT = 2 ** 53
#: The range of a sample period in s (a GHz sampler to one sample per few hours).
SAMPLE_PERIOD_RANGE = (1e-9, 1e4)


def _check_finite(name: str, arr: np.ndarray | None) -> None:
    if arr is None:
        return
    if not np.all(np.isfinite(arr)):
        k = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ParameterError(f"{name} must be finite, got {arr[k]!r} at sample {k}")
    if name != "time" and len(arr) and max(float(arr.max()), -float(arr.min())) > MAX_MAGNITUDE:
        k = int(np.argmax(np.abs(arr)))
        raise ParameterError(f"{name} must be within +-{MAX_MAGNITUDE:g} (no motor gives more), got {arr[k]!r} "
                             f"at sample {k}")


def _check_sample_period(sample_period: float) -> float:
    value = check_real("sample_period", sample_period, positive=True)
    lo, hi = SAMPLE_PERIOD_RANGE
    if not lo <= value <= hi:
        raise ParameterError(f"sample_period must be in {lo:g}...{hi:g} s, got {value!r}")
    return value


#: Metadata keys that would name another unit for a column whose unit the format fixes, and that unit
#: (``speed_unit`` is not one: it names the unit results are shown in, the column staying in rad/s).
FIXED_UNITS = {"time_unit": ("s", "time_s"), "angle_unit": ("rad", "angle_rad")}


def _refuse_unit_metadata(metadata: Mapping[str, str]) -> None:
    """Refuse ``time_unit: ms`` and the like: the columns are in SI units, and reading them otherwise is silent.
    An ``input_limit`` or ``duty_limit`` that is no magnitude (``nan``, ``-1``) is refused too: taken as unknown,
    it silently turned off the checks of a run at its limit."""
    for key in ("input_limit", "duty_limit"):
        text = metadata.get(key)
        if text is None or str(text).strip().lower() in ("", "none", "null"):
            continue
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and 0 < value <= MAX_MAGNITUDE):
            raise ParameterError(f"metadata {key} must be a number > 0 (the largest input magnitude the drive "
                                 f"accepts) or none, got {text!r}")
    for key, (unit, column) in FIXED_UNITS.items():
        given = metadata.get(key)
        if given is not None and given.strip() != unit:
            quantity = key.removesuffix("_unit")
            raise ParameterError(f"metadata {key} must be {unit!r} (the column {column} is in {unit}), got "
                                 f"{given!r}: convert the file once with motorid import FILE --{quantity} "
                                 f"{column}:{given.strip()} ...")


def _check_time_base(time: np.ndarray, seq: np.ndarray, sample_period: float,
                     intervals: np.ndarray | None = None) -> None:
    """Refuse a time column whose median interval per ``seq`` step is not ``sample_period`` (``intervals``:
    ``np.diff(time)`` when the caller has it)."""
    if len(time) < 3:
        return
    per_step = np.diff(time) if intervals is None else intervals
    # seq strictly increasing (checked first) from seq[0] to seq[0] + n - 1 steps by ones: a division by them
    # would change nothing, and costs a conversion
    if int(seq[-1]) - int(seq[0]) != len(seq) - 1:
        per_step = per_step / np.maximum(np.diff(seq), 1)
    interval = median(per_step)
    del per_step
    ratio = interval / sample_period
    if abs(ratio - 1) > TIME_BASE_TOLERANCE:
        raise ParameterError(
            f"time and sample_period disagree: time advances {interval:.6g} s per sample (median over "
            f"{len(time) - 1} intervals) but sample_period is {sample_period!r} s, a factor {ratio:.4g} "
            f"(allowed: within {TIME_BASE_TOLERANCE:.0%}); is time in seconds, and is the period right?")


def _check_increasing(time: np.ndarray, seq: np.ndarray, intervals: np.ndarray | None = None) -> None:
    intervals = np.diff(time) if intervals is None else intervals
    if len(time) > 1 and np.any(intervals <= 0):
        k = int(np.flatnonzero(intervals <= 0)[0]) + 1
        raise ParameterError(f"time must be strictly increasing, got {time[k]!r} after {time[k-1]!r} at sample {k}")
    if len(seq) > 1 and np.any(np.diff(seq) <= 0):
        raise ParameterError("seq must be strictly increasing")


@dataclasses.dataclass(frozen=True, eq=False, init=False)
class Recording:
    """Samples of one experiment (see the module docstring for the alignment).

    Parameters
    ----------
    time : array_like, shape (n,)
        Sample instants in s, strictly increasing.
    duty : array_like, shape (n,)
        Input applied from ``time[k]`` until ``time[k+1]`` (integer duty on the bench).
    sample_period : float
        Nominal sample period in s.
    counts : array_like of int, optional
        Encoder counts at ``time[k]`` (any offset); needs ``counts_per_rev``.
    angle : array_like, optional
        Angle in rad at ``time[k]``.
    speed : array_like, optional
        Measured speed in rad/s at ``time[k]``.
    seq : array_like of int, optional
        Sample index; a gap means dropped samples.  Default ``0 ... n-1`` (the attribute is
        always an array).
    counts_per_rev : int, optional
        Encoder counts per revolution.
    metadata : mapping of str to str, optional
        Free-form ``key: value`` pairs (``input_unit``, ``source``, ...).
    reference : array_like, optional
        What a controller tracked at ``time[k]`` (closed-loop runs; unit in metadata ``reference_unit``).
    path : str, optional
        The file the recording was read from (set by the readers, kept by :meth:`slice` and
        :meth:`drop_rows`): every refusal of these data names it instead of ``recordings[i]``.
        Never written to a file.

    Examples
    --------
    >>> rec = Recording(time=[0.0, 0.005, 0.01], duty=[100, 100, 0], sample_period=0.005,
    ...                 counts=[0, 3, 9], counts_per_rev=16667)
    >>> rec.seq
    array([0, 1, 2])
    >>> rec.measured_speed()[1:].round(3).tolist()   # rad/s; nan at the first sample
    [0.226, 0.452]
    """

    time: np.ndarray
    duty: np.ndarray
    sample_period: float
    counts: np.ndarray | None
    angle: np.ndarray | None
    speed: np.ndarray | None
    seq: np.ndarray
    counts_per_rev: int | None
    metadata: Mapping[str, str]
    reference: np.ndarray | None
    path: str | None

    def __init__(self, time: ArrayLike, duty: ArrayLike, sample_period: float, counts: ArrayLike | None = None,
                 angle: ArrayLike | None = None, speed: ArrayLike | None = None, seq: ArrayLike | None = None,
                 counts_per_rev: int | None = None, metadata: Mapping[str, str] | None = None,
                 reference: ArrayLike | None = None, path: str | os.PathLike | None = None):
        t = _as_array("time", time, float)
        n = len(t)
        columns = {"time": t, "duty": _as_array("duty", duty, float, n),
                   "angle": _optional_array("angle", angle, n), "speed": _optional_array("speed", speed, n),
                   "counts": _integer_array("counts", counts, n),
                   "reference": _optional_array("reference", reference, n)}
        seq_array = _integer_array("seq", seq, n)
        if seq_array is None:
            seq_array = np.arange(n, dtype=np.int64)
            seq_array.setflags(write=False)
        for name, value in (*columns.items(), ("seq", seq_array)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "sample_period", _check_sample_period(sample_period))
        if counts is None and angle is None and speed is None:
            raise ParameterError("a Recording needs at least one of counts, angle, speed")
        if counts is not None:
            if counts_per_rev is None:
                raise ParameterError("counts_per_rev must be a positive integer when counts are given, got None")
            counts_per_rev = check_int("counts_per_rev", counts_per_rev, 1, MAX_COUNTS_PER_REV,
                                       allow_integral_float=False)
        object.__setattr__(self, "counts_per_rev", counts_per_rev)
        for name in ("time", "duty", "angle", "speed", "reference"):
            _check_finite(name, columns[name])
        intervals = np.diff(t)           # once, for both checks of the clock
        _check_increasing(t, seq_array, intervals)
        _check_time_base(t, seq_array, self.sample_period, intervals)
        del intervals
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, Mapping):
            raise ParameterTypeError(f"metadata must be a mapping, got {type(metadata).__name__}")
        object.__setattr__(self, "metadata", {str(k): str(v) for k, v in metadata.items()})
        _refuse_unit_metadata(self.metadata)
        if path is not None and not isinstance(path, (str, os.PathLike)):
            raise ParameterTypeError(f"path must be a str or path-like, got {type(path).__name__}")
        object.__setattr__(self, "path", None if path is None else os.fspath(path))

    def name(self, index: int | None = None) -> str:
        """How a message names this recording: its :attr:`path`, else ``recordings[index]`` (``recording``).

        Examples
        --------
        >>> rec = Recording(time=[0.0, 0.01], duty=[0, 1], sample_period=0.01, speed=[0, 0], path="run.csv")
        >>> rec.name(0), rec.slice(0, 1).name(3)
        ('run.csv', 'run.csv')
        >>> Recording(time=[0.0, 0.01], duty=[0, 1], sample_period=0.01, speed=[0, 0]).name(2)
        'recordings[2]'
        """
        if self.path is not None:
            return self.path
        return "recording" if index is None else f"recordings[{index}]"

    @classmethod
    def from_columns(cls, time: ArrayLike, duty: ArrayLike, **columns) -> "Recording":
        """A recording from columns in any supported unit, the sample period inferred from ``time``.

        Parameters
        ----------
        time : array_like, shape (n,)
            Sample instants (numpy array or pandas Series), in ``time_unit`` (default s).
        duty : array_like, shape (n,)
            Input, in ``input_unit`` (``duty``, ``V`` or ``%``).
        **columns
            ``speed``, ``angle``, ``counts``, ``counts_per_rev``, ``input_unit``, ``time_unit``,
            ``speed_unit``, ``angle_unit``, ``sample_period``, ``metadata``: as
            :func:`motorsim.units.columns_in_si`, which documents the units and the timing rule.
            A non-uniform time column is kept and a ``UserWarning`` says so.

        Returns
        -------
        Recording

        Examples
        --------
        >>> rec = Recording.from_columns(time=[0.0, 0.02, 0.04], duty=[1.5, 1.5, 2.7],
        ...                              speed=[0.0, 90.0, 180.0], speed_unit="deg/s", input_unit="V")
        >>> rec.sample_period, rec.input_unit
        (0.02, 'V')
        """
        from .units import columns_in_si, timing_note
        rec = cls(**columns_in_si(time, duty, **columns))
        note = timing_note(rec.metadata, rec.sample_period)
        if note:
            warnings.warn(note, UserWarning, stacklevel=2)
        if columns.get("angle") is not None and columns.get("angle_unit", "rad") == "rad":
            doubt = rec.angle_unit_doubt()
            if doubt is not None:
                warnings.warn(f"angle, in rad: {doubt.reason}; if it is not in radians give angle_unit="
                              f"{doubt.unit or 'its unit'!r}", AngleUnitWarning, stacklevel=2)
        return rec

    def __len__(self) -> int:
        return len(self.time)

    @property
    def n_samples(self) -> int:
        """Number of rows."""
        return len(self.time)

    @property
    def input_unit(self) -> str:
        """What ``duty`` is measured in (metadata ``input_unit``, default ``duty``)."""
        return self.metadata.get("input_unit", "duty")

    @property
    def speed_unit(self) -> str:
        """The speed unit the data came in (metadata ``speed_unit``, default ``rad/s``): results are shown in it
        beside SI; the columns themselves are always SI."""
        unit = self.metadata.get("speed_unit", "rad/s")
        return unit if unit in SPEED_UNITS else "rad/s"

    @property
    def input_limit(self) -> float | None:
        """Largest input magnitude the drive accepts, in :attr:`input_unit`, or None when unknown.

        The metadata ``input_limit`` (``motorid import --input-limit``), else for an input in duty
        the run's ``duty_limit`` (default 255); None for volts or percent without the metadata.
        """
        text = self.metadata.get("input_limit")
        if text is None and self.input_unit == "duty":
            text = self.metadata.get("duty_limit", "255")
        if text is None or str(text).strip().lower() in ("", "none", "null"):
            return None
        try:
            value = float(text)
        except ValueError:
            return None
        return value if math.isfinite(value) and value > 0 else None

    def measured_angle(self, rows: slice | None = None) -> np.ndarray | None:
        """Angle in rad: the ``angle`` column, else counts converted, else None.

        Counts beyond +-2**53 (an offset of 2**62, say) are measured from their median count
        first, so that no count loses its last bits in the conversion to float.

        Parameters
        ----------
        rows : slice, optional
            Only these rows, converted alone (the same numbers as the whole column's rows).
        """
        rows = slice(None) if rows is None else rows
        if self.angle is not None:
            return self.angle[rows]
        if self.counts is None or self.counts_per_rev is None:
            return None
        counts = self.counts[rows]
        origin = self._count_origin()
        if origin:
            # counts offset by 2**62 would lose their last bits as floats: measure them from the median
            # count, in exact (wrapping) integer arithmetic; only the angle's offset changes
            with np.errstate(over="ignore"):
                counts = counts - origin
        return counts_to_angle(counts, self.counts_per_rev)

    def _count_origin(self) -> int:
        """The count the angle is measured from: 0, or the median count when a count lies beyond +-2**53
        (found once: the recording never changes)."""
        origin = self.__dict__.get("_origin")
        if origin is None:
            counts = self.counts
            origin = 0
            if counts is not None and len(counts) and (int(counts.max()) > MAX_EXACT_COUNT
                                                       or int(counts.min()) < -MAX_EXACT_COUNT):
                origin = np.partition(counts, len(counts) // 2)[len(counts) // 2]
            object.__setattr__(self, "_origin", origin)
        return origin

    def measured_speed(self) -> np.ndarray:
        """Speed in rad/s: the ``speed`` column, else the backward difference of the angle.

        The difference is ``nan`` at the first sample and wherever ``seq`` has a gap
        before the sample (its interval is longer than one sample).  Differenced once (the
        recording never changes) and kept with it, since the screens, the plausibility rules
        and the outlier check all ask for it; each call returns its own copy.
        """
        if self.speed is not None:
            return self.speed
        speed = self.__dict__.get("_measured_speed")
        if speed is None:
            speed = backward_difference(self.measured_angle(), self.time)
            speed[np.asarray(self._gaps(), dtype=np.intp)] = np.nan
            speed.setflags(write=False)
            object.__setattr__(self, "_measured_speed", speed)
        return speed.copy()

    def segments(self) -> list["Recording"]:
        """Split at gaps in ``seq`` into gap-free recordings (one if there is no gap)."""
        cuts = self._gaps()
        if not cuts:
            return [self]
        bounds = [0, *cuts, len(self)]
        return [self.slice(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]

    def _gaps(self) -> list[int]:
        """The rows after a gap in ``seq`` (found once: the recording never changes, and every fit asks)."""
        cuts = self.__dict__.get("_cuts")
        if cuts is None:
            cuts = (np.flatnonzero(np.diff(self.seq) != 1) + 1).tolist()
            object.__setattr__(self, "_cuts", cuts)
        return list(cuts)

    def slice(self, start: int, stop: int) -> "Recording":
        """Rows ``start:stop`` as a new Recording."""
        return self._rows(slice(start, stop))

    def _rows(self, rows: "builtins.slice | np.ndarray") -> "Recording":
        """The rows ``rows`` of this checked recording, not checked again: every rule of a recording holds on
        its rows (a short run of a jittered clock would fail the time-base rule, which is the whole clock's)."""
        sub = object.__new__(type(self))
        for name in ("time", "duty", "counts", "angle", "speed", "seq", "reference"):
            x = getattr(self, name)
            if x is not None:
                x = x[rows]
                x.setflags(write=False)
            object.__setattr__(sub, name, x)
        for name in ("sample_period", "counts_per_rev", "path"):
            object.__setattr__(sub, name, getattr(self, name))
        object.__setattr__(sub, "metadata", dict(self.metadata))
        return sub

    def implausible_samples(self) -> list[ImplausibleSample]:
        """Rows no motor can produce: a speed, time or duty step far beyond the rest of the run.

        See :mod:`motorsim.plausibility` for the rules; one count per sample period is the
        smallest speed scale of a counts recording.

        Examples
        --------
        >>> rec = Recording(time=np.arange(50) * 0.01, duty=np.full(50, 100), sample_period=0.01,
        ...                 counts=np.arange(50) * 7, counts_per_rev=400)
        >>> rec.implausible_samples()
        []
        >>> counts = rec.counts.copy(); counts[20] ^= 1 << 40           # one flipped bit
        >>> [s.row for s in dataclasses.replace(rec, counts=counts).implausible_samples()]
        [20]
        """
        floor = 0.0
        if self.counts is not None and self.counts_per_rev is not None:
            floor = 2 * np.pi / self.counts_per_rev / self.sample_period
        return implausible_samples(self.time, self.seq, self.measured_speed(), self.sample_period, floor,
                                   duty=self.duty, duty_limit=self.duty_limit)

    def angle_unit_doubt(self) -> AngleUnitDoubt | None:
        """Why the angle column, in rad, reads as another unit (degrees, say), or None.

        The rules are :func:`motorsim.plausibility.angle_unit_doubt`'s (against the speed column,
        an encoder's steps, a speed beyond any motor); None without an angle column.

        Examples
        --------
        >>> t = np.arange(400) * 0.005
        >>> degrees = np.round(400 * np.sin(3 * t)) * 360 / 1024      # a 1024-count encoder, in degrees
        >>> rec = Recording(time=t, duty=np.round(200 * np.sin(3 * t)), sample_period=0.005, angle=degrees)
        >>> rec.angle_unit_doubt().unit
        'deg'
        """
        if self.angle is None:
            return None
        return angle_unit_doubt(self.angle, self.time, self.seq, self.speed)

    @property
    def duty_limit(self) -> float | None:
        """The duty limit the metadata declare (``duty_limit``), or None."""
        try:
            value = float(self.metadata.get("duty_limit", "nan"))
        except ValueError:
            return None
        return value if np.isfinite(value) and value > 0 else None

    def saturated_runs(self) -> list[tuple[int, int]]:
        """The runs of two or more samples at the input limit, as ``(first row, length)``.

        The limit is the one the metadata declare (``input_limit``, else a duty's ``duty_limit``,
        as :attr:`input_limit` reads them); no runs when none is declared: a duty beyond 255 in a
        file that declares no limit was not clipped at 255.

        Examples
        --------
        >>> rec = Recording(time=np.arange(8) * 0.01, duty=[0, 255, 255, 255, 10, -255, 3, 0], sample_period=0.01,
        ...                 counts=np.arange(8), counts_per_rev=400, metadata={"duty_limit": "255"})
        >>> rec.saturated_runs(), rec.saturated_samples()
        ([(1, 3)], 3)
        """
        runs = self.__dict__.get("_saturated_runs")      # computed once: the recording never changes
        if runs is None:
            declared = "input_limit" in self.metadata or "duty_limit" in self.metadata
            limit = self.input_limit if declared else None
            runs = [] if limit is None else saturated_runs(self.duty, limit)
            object.__setattr__(self, "_saturated_runs", runs)
        return list(runs)

    def saturated_samples(self) -> int:
        """How many samples sit at the input limit in runs of two or more (:meth:`saturated_runs`)."""
        return sum(n for _, n in self.saturated_runs())

    def drop_rows(self, rows: Iterable[int]) -> "Recording":
        """This recording without ``rows`` (0-based): they become gaps in ``seq``.

        Parameters
        ----------
        rows : iterable of int
            Row indices to remove.
        """
        keep = np.ones(len(self), dtype=bool)
        keep[list(rows)] = False

        return self._rows(keep)

    @property
    def has_gaps(self) -> bool:
        """True when ``seq`` shows dropped samples."""
        return bool(self._gaps())


#: Names that moved out of this module, and where to (old imports warn for one release).
_MOVED = {"read_recording": "motorsim.reading", "MAX_RECORDING_BYTES": "motorsim.reading",
          "FAST_PATH_MIN_BYTES": "motorsim.reading",
          "write_recording": "motorsim.writing", "RecordingWriter": "motorsim.writing"}


# imported when asked, so that the reading and writing modules can import this one
__getattr__, __dir__ = lazy_attributes(__name__, moved=_MOVED, hint=" (or motorsim.{name})")
