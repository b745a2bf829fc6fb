"""``Recording``: one experiment's samples, and the CSV recording format v1.

:class:`Recording` holds the sample columns (read-only arrays) and the metadata of one
run, checks them when built, converts counts to angle (:meth:`Recording.measured_angle`),
differences the angle into speed (:meth:`Recording.measured_speed`) and splits at dropped
samples (:meth:`Recording.segments`).  :func:`write_recording` and :func:`read_recording`
write and read format v1 (below); :class:`RecordingWriter` writes it row by row during a
run, so that an interrupted run still leaves a readable file.

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

import contextlib
import csv
import dataclasses
import io
import math
import os
import stat
import time
import warnings
from pathlib import Path
from typing import Iterable, Iterator, Mapping, NamedTuple, NoReturn, Sequence, TextIO

import numpy as np
from numpy.typing import ArrayLike

from .checks import check_int, check_real
from .files import OutputFileError, check_output_file, open_exclusive, write_atomically
from .plausibility import ImplausibleSample, implausible_samples
from .sensors import backward_difference, counts_to_angle

__all__ = ["Recording", "RecordingFormatError", "read_recording", "write_recording", "RecordingWriter",
           "FORMAT_HEADER", "COLUMNS", "TIME_BASE_TOLERANCE", "MAX_RECORDING_BYTES"]

FORMAT_HEADER = "# motorid recording v1"
#: Known columns in the order they are written.
COLUMNS = ("seq", "time_s", "duty", "counts", "angle_rad", "speed_rad_s", "reference")
_ALIASES = {"dt": "sample_period", "ppr": "counts_per_rev"}
_INT_COLUMNS = ("seq", "counts")
#: Largest relative disagreement allowed between the median interval of ``time_s`` (per step
#: of ``seq``) and the declared ``sample_period``.  Timing jitter (< 1 sample period, see
#: ``SimRig.jitter``) and dropped samples leave the median interval within a few per cent of
#: the period; a time column in ms or µs, or a wrong period, is off by a large factor.
TIME_BASE_TOLERANCE = 0.2


class RecordingFormatError(ValueError):
    """A recording file or array breaks a rule of recording format v1."""


def _as_array(name: str, value: ArrayLike, dtype: type, n: int | None = None) -> np.ndarray:
    """``value`` as a read-only 1-D copy of ``dtype`` (of length ``n`` when given).

    An array nobody can write to (read-only, owning its memory) is kept as it is: copying it
    would only double the memory of a large recording.
    """
    arr: np.ndarray
    if isinstance(value, np.ndarray) and value.dtype == dtype and value.base is None and not value.flags.writeable:
        arr = value
    else:
        arr = np.array(value, dtype=dtype, copy=True)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if n is not None and len(arr) != n:
        raise ValueError(f"{name} must have the same length as time ({n}), got {len(arr)}")
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
            raise ValueError(f"{name} must hold integers, got non-integer values")
    elif raw.dtype.kind not in "iu":
        raise TypeError(f"{name} must hold integers, got dtype {raw.dtype}")
    return _as_array(name, value, np.int64, n)


def _check_finite(name: str, arr: np.ndarray | None) -> None:
    if arr is not None and not np.all(np.isfinite(arr)):
        k = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name} must be finite, got {arr[k]!r} at sample {k}")


def _check_time_base(time: np.ndarray, seq: np.ndarray, sample_period: float) -> None:
    """Refuse a time column whose median interval per ``seq`` step is not ``sample_period``."""
    if len(time) < 3:
        return
    per_step = np.diff(time)
    per_step /= np.maximum(np.diff(seq), 1)
    interval = float(np.median(per_step, overwrite_input=True))
    del per_step
    ratio = interval / sample_period
    if abs(ratio - 1) > TIME_BASE_TOLERANCE:
        raise ValueError(
            f"time and sample_period disagree: time advances {interval:.6g} s per sample (median over "
            f"{len(time) - 1} intervals) but sample_period is {sample_period!r} s, a factor {ratio:.4g} "
            f"(allowed: within {TIME_BASE_TOLERANCE:.0%}); is time in seconds, and is the period right?")


def _check_increasing(time: np.ndarray, seq: np.ndarray) -> None:
    if len(time) > 1 and np.any(np.diff(time) <= 0):
        k = int(np.flatnonzero(np.diff(time) <= 0)[0]) + 1
        raise ValueError(f"time must be strictly increasing, got {time[k]!r} after {time[k-1]!r} at sample {k}")
    if len(seq) > 1 and np.any(np.diff(seq) <= 0):
        raise ValueError("seq must be strictly increasing")


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

    def __init__(self, time: ArrayLike, duty: ArrayLike, sample_period: float, counts: ArrayLike | None = None,
                 angle: ArrayLike | None = None, speed: ArrayLike | None = None, seq: ArrayLike | None = None,
                 counts_per_rev: int | None = None, metadata: Mapping[str, str] | None = None,
                 reference: ArrayLike | None = None):
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
        object.__setattr__(self, "sample_period", check_real("sample_period", sample_period, positive=True))
        if counts is None and angle is None and speed is None:
            raise ValueError("a Recording needs at least one of counts, angle, speed")
        if counts is not None:
            if counts_per_rev is None:
                raise ValueError("counts_per_rev must be a positive integer when counts are given, got None")
            counts_per_rev = check_int("counts_per_rev", counts_per_rev, 1, allow_integral_float=False)
        object.__setattr__(self, "counts_per_rev", counts_per_rev)
        for name in ("time", "duty", "angle", "speed", "reference"):
            _check_finite(name, columns[name])
        _check_increasing(t, seq_array)
        _check_time_base(t, seq_array, self.sample_period)
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, Mapping):
            raise TypeError(f"metadata must be a mapping, got {type(metadata).__name__}")
        object.__setattr__(self, "metadata", {str(k): str(v) for k, v in metadata.items()})

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

    def measured_angle(self) -> np.ndarray | None:
        """Angle in rad: the ``angle`` column, else counts converted, else None."""
        if self.angle is not None:
            return self.angle
        if self.counts is not None and self.counts_per_rev is not None:
            return counts_to_angle(self.counts, self.counts_per_rev)
        return None

    def measured_speed(self) -> np.ndarray:
        """Speed in rad/s: the ``speed`` column, else the backward difference of the angle.

        The difference is ``nan`` at the first sample and wherever ``seq`` has a gap
        before the sample (its interval is longer than one sample).
        """
        if self.speed is not None:
            return self.speed
        speed = backward_difference(self.measured_angle(), self.time)
        speed[1:][np.diff(self.seq) != 1] = np.nan
        return speed

    def segments(self) -> list["Recording"]:
        """Split at gaps in ``seq`` into gap-free recordings (one if there is no gap)."""
        cuts = np.flatnonzero(np.diff(self.seq) != 1) + 1
        if len(cuts) == 0:
            return [self]
        bounds = [0, *cuts.tolist(), len(self)]
        return [self.slice(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]

    def slice(self, start: int, stop: int) -> "Recording":
        """Rows ``start:stop`` as a new Recording."""
        def cut(x):
            return None if x is None else x[start:stop]
        return dataclasses.replace(self, time=cut(self.time), duty=cut(self.duty), counts=cut(self.counts),
                                   angle=cut(self.angle), speed=cut(self.speed), seq=cut(self.seq),
                                   reference=cut(self.reference))

    def implausible_samples(self) -> list[ImplausibleSample]:
        """Rows no motor can produce: a speed or time step far beyond the rest of the run.

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
        return implausible_samples(self.time, self.seq, self.measured_speed(), self.sample_period, floor)

    def drop_rows(self, rows: Iterable[int]) -> "Recording":
        """This recording without ``rows`` (0-based): they become gaps in ``seq``.

        Parameters
        ----------
        rows : iterable of int
            Row indices to remove.
        """
        keep = np.ones(len(self), dtype=bool)
        keep[list(rows)] = False

        def cut(x):
            return None if x is None else x[keep]
        return dataclasses.replace(self, time=cut(self.time), duty=cut(self.duty), counts=cut(self.counts),
                                   angle=cut(self.angle), speed=cut(self.speed), seq=cut(self.seq))

    @property
    def has_gaps(self) -> bool:
        """True when ``seq`` shows dropped samples."""
        return bool(np.any(np.diff(self.seq) != 1))


def _metadata_lines(rec: Recording) -> list[str]:
    meta = {"sample_period": repr(rec.sample_period)}
    if rec.counts_per_rev is not None:
        meta["counts_per_rev"] = str(rec.counts_per_rev)
    for k, v in rec.metadata.items():
        if k not in meta:
            meta[k] = v
    lines = [FORMAT_HEADER]
    for k, v in meta.items():
        if "\n" in k or "\n" in v or ":" in k:
            raise ValueError(f"metadata key {k!r} / value {v!r} must be single-line, and keys must not contain ':'")
        lines.append(f"# {k}: {v}")
    return lines


def _columns(rec: Recording) -> list[str]:
    cols = ["seq", "time_s", "duty"]
    optional = (("counts", rec.counts), ("angle_rad", rec.angle), ("speed_rad_s", rec.speed),
                ("reference", rec.reference))
    cols += [c for c, v in optional if v is not None]
    return cols


def _format_rows(rec: Recording, cols: list[str], start: int = 0, stop: int | None = None) -> Iterable[str]:
    columns = {"seq": rec.seq, "time_s": rec.time, "duty": rec.duty, "counts": rec.counts,
               "angle_rad": rec.angle, "speed_rad_s": rec.speed, "reference": rec.reference}
    data = {c: arr for c, arr in columns.items() if arr is not None}
    integral_duty = bool(np.all(rec.duty == np.round(rec.duty)))
    fmt = {"seq": lambda x: str(int(x)), "counts": lambda x: str(int(x)),
           "time_s": repr, "angle_rad": repr, "speed_rad_s": repr, "reference": repr,
           "duty": (lambda x: str(int(x))) if integral_duty else repr}
    stop = len(rec) if stop is None else stop
    for k in range(start, stop):
        yield ",".join(fmt[c](float(data[c][k]) if c not in _INT_COLUMNS else data[c][k]) for c in cols)


def write_recording(recording: Recording, path: str | os.PathLike) -> Path:
    """Write ``recording`` to ``path`` in format v1, atomically (temporary file, then rename).

    Floats are written with ``repr``, so reading the file back gives the same numbers bit for bit.

    Parameters
    ----------
    recording : Recording
        What to write.
    path : str or path-like
        Destination; replaced if it exists.
    """
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {type(recording).__name__}")
    path = Path(path)
    cols = _columns(recording)
    text = "\n".join([*_metadata_lines(recording), ",".join(cols), *_format_rows(recording, cols)]) + "\n"
    write_atomically(path, text)
    return path


class RecordingWriter:
    """Write a recording (format v1) row by row while it is being measured; a context manager.

    Rows go to ``PATH.partial`` as they arrive (whole lines, flushed at least every
    ``flush_interval`` s), so the partial file is always a readable format-v1 file whose
    metadata say ``complete: false``.  Everything that could stop the recording being
    written is checked when the writer is made, before a motor turns: the folder takes
    new files, ``PATH`` is not a folder or a device, an existing ``PATH`` is refused
    unless ``overwrite``, and the partial file is created exclusively (an existing one, the
    data of an earlier run that did not finish, or a link planted there, is refused, never
    truncated or followed) (:mod:`motorsim.files`).  :meth:`close` then atomically writes ``PATH``
    with the final metadata, ``complete: true`` or ``complete: false`` and
    ``incomplete_reason``, and removes the partial file.  Leaving the ``with`` block by
    an exception (including Ctrl-C) closes it as incomplete, naming the exception.

    Parameters
    ----------
    path : str or os.PathLike
        Final file.
    sample_period : float
        Nominal sample period in s.
    counts_per_rev : int
        Encoder counts per revolution (rows carry ``counts``).
    metadata : mapping of str to str, optional
        Metadata known at the start (more can be given to :meth:`close`).
    flush_interval : float, optional
        Longest time in s rows wait in memory, default 0.25.
    overwrite : bool, optional
        Replace an existing ``PATH`` (never a folder or a device); default False.

    Raises
    ------
    motorsim.files.OutputFileError
        From the constructor, when ``PATH`` cannot be written; from :meth:`append`,
        :meth:`flush` or :meth:`close` when writing fails (a full disk): the rows not yet
        written are the caller's to keep.
    """

    _COLS = ["seq", "time_s", "duty", "counts"]

    def __init__(self, path: str | os.PathLike, sample_period: float, counts_per_rev: int, *,
                 metadata: Mapping[str, str] | None = None, flush_interval: float = 0.25, overwrite: bool = False):
        self.path = check_output_file(path, overwrite=overwrite, flag="recording")
        self.partial_path = self.path.with_name(self.path.name + ".partial")
        self._meta = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._sample_period = sample_period
        self._counts_per_rev = counts_per_rev
        self._probe(np.zeros(1), np.zeros(1), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), {})
        self._flush_interval = float(flush_interval)
        self._rows: list[tuple[int, float, int, int]] = []
        self._last: tuple[int, float, int, int] | None = None
        try:
            self._file: TextIO | None = open_exclusive(self.partial_path)
        except FileExistsError:
            if self.partial_path.is_symlink():
                raise OutputFileError(f"{self.partial_path} is a symbolic link; a partial recording is never "
                                      f"written through a link: remove it, then run again") from None
            raise OutputFileError(f"{self.partial_path} exists: an earlier run that did not finish left it. "
                                  f"It is a readable recording; rename or delete it, then run again") from None
        except OSError as exc:
            raise OutputFileError(f"cannot create {self.partial_path}: {exc.strerror or exc}", exc.errno) from None
        self._header_written = False
        self._header_lines = 0
        self._last_flush = time.monotonic()
        self.n_rows = 0
        self.closed = False

    def _probe(self, time_s, duty, counts, seq, extra) -> Recording:
        return Recording(time=time_s, duty=duty, sample_period=self._sample_period, counts=counts, seq=seq,
                         counts_per_rev=self._counts_per_rev, metadata={**self._meta, **extra})

    def append(self, seq: int, time_s: float, duty: int, counts: int) -> None:
        """Add one row (``seq`` and ``time_s`` strictly increasing)."""
        if self.closed:
            raise ValueError(f"this RecordingWriter for {self.path} is closed")
        row = (int(seq), float(time_s), int(duty), int(counts))
        last = self._rows[-1] if self._rows else self._last
        if last is not None and (row[0] <= last[0] or row[1] <= last[1]):
            raise ValueError(f"seq and time_s must be strictly increasing, got seq {row[0]} at {row[1]!r} s "
                             f"after seq {last[0]} at {last[1]!r} s")
        self._rows.append(row)
        if time.monotonic() - self._last_flush >= self._flush_interval:
            self.flush()

    def _batch(self, rows, extra) -> Recording:
        seq, t, duty, counts = (np.array(c) for c in zip(*rows))
        return self._probe(t, duty.astype(np.int64), counts.astype(np.int64), seq.astype(np.int64), extra)

    def flush(self) -> None:
        """Write the buffered rows to the partial file (whole lines, then flush)."""
        self._last_flush = time.monotonic()
        if not self._rows:
            return
        batch = self._batch(self._rows, {})
        lines = list(_format_rows(batch, self._COLS))
        if not self._header_written:
            header = _metadata_lines(self._batch(self._rows[:1], {
                "complete": "false", "incomplete_reason": "still recording (partial file)"})) + [",".join(self._COLS)]
            self._header_lines = len(header)
            self._header_written = True
            lines = header + lines
        if self._file is None:
            raise ValueError(f"this RecordingWriter for {self.path} is closed")
        try:
            self._file.write("\n".join(lines) + "\n")
            self._file.flush()
        except OSError as exc:
            raise OutputFileError(f"writing {self.partial_path} failed: {exc.strerror or exc}", exc.errno) from None
        self.n_rows += len(self._rows)
        self._last = self._rows[-1]
        self._rows = []

    def close(self, complete: bool = True, reason: str = "", metadata: Mapping[str, str] | None = None
              ) -> Path | None:
        """Write the final file atomically and remove the partial one.

        Parameters
        ----------
        complete : bool
            Whether the run finished (metadata ``complete: true``/``false``).
        reason : str
            Why it did not (metadata ``incomplete_reason``), when ``complete`` is False.
        metadata : mapping, optional
            Metadata to add or override (e.g. the rig's counters).

        Returns
        -------
        pathlib.Path or None
            The final file, or None when no row was ever appended (nothing is written).
        """
        if self.closed:
            return self.path if self.n_rows else None
        self.flush()
        self.closed = True
        if self._file is None:
            return self.path if self.n_rows else None
        self._file.close()
        self._file = None
        if not self.n_rows:
            os.unlink(self.partial_path)
            return None
        if metadata:
            self._meta.update({str(k): str(v) for k, v in metadata.items()})
        extra = {"complete": "true" if complete else "false"}
        self._meta.pop("incomplete_reason", None)
        if not complete:
            extra["incomplete_reason"] = " ".join(str(reason or "unknown").split())
        header = _metadata_lines(self._batch([self._last], extra)) + [",".join(self._COLS)]
        with open(self.partial_path, encoding="utf-8") as f:
            body = f.read().split("\n")[self._header_lines:]
        write_atomically(self.path, "\n".join(header + body))
        os.unlink(self.partial_path)
        return self.path

    def close_with(self, recording: Recording) -> Path:
        """Write ``recording`` as the final file instead of the rows appended, and remove the partial file.

        For a caller that holds every row in memory anyway (``SerialRig`` attaches them to
        the exception that ended a run): rows that arrived after the last :meth:`append`
        and the final metadata are kept too.

        Returns
        -------
        pathlib.Path
            The final file.
        """
        if not isinstance(recording, Recording):
            raise TypeError(f"recording must be a Recording, got {type(recording).__name__}")
        self.closed = True
        self._rows = []
        if self._file is not None:
            self._file.close()
            self._file = None
        write_recording(recording, self.path)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.partial_path)
        self.n_rows = len(recording)
        return self.path

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close(True)
        elif exc_type is KeyboardInterrupt:
            self.close(False, "interrupted (Ctrl-C)")
        else:
            self.close(False, f"{exc_type.__name__}: {exc}")


def read_recording(path: str | os.PathLike, *, check_samples: bool = True) -> Recording:
    """Read a format-v1 CSV file.

    Parameters
    ----------
    path : str or path-like
        The file.
    check_samples : bool, optional
        Refuse rows no motor can produce (default True; see :mod:`motorsim.plausibility`).
        With False they are kept, for the caller to find and drop.

    Raises
    ------
    RecordingFormatError
        For every broken rule, naming the file, the line and the rule.
    """
    path = Path(path)
    scan = _scan_file(path)
    parsed = _parse_fast(path, scan) if scan.size >= FAST_PATH_MIN_BYTES else None
    if parsed is not None:
        rec = _build_fast(parsed, str(path), check_samples)
        if rec is not None:
            return rec
    data = _read_bounded(path)
    _check_bytes(data, path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RecordingFormatError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    del data
    return _parse(text, str(path), check_samples)


def _check_bytes(data: bytes, path: Path) -> None:
    """Refuse a byte-order mark and NUL bytes, each with its own message."""
    if data.startswith(b"\xef\xbb\xbf"):
        raise RecordingFormatError(f"{path}, line 1: starts with a UTF-8 byte-order mark (BOM); "
                                   "save it as UTF-8 without BOM")
    if b"\0" in data:
        at = data.index(b"\0")
        line = data.count(b"\n", 0, at) + 1
        raise RecordingFormatError(f"{path}, line {line}: contains a NUL byte "
                                   f"(at byte {at}): binary data or a corrupted file, not a recording")


class _FileScan(NamedTuple):
    """One pass over a file in blocks: its first block, its number of newlines, whether it ends with one."""

    head: bytes
    newlines: int
    ends_with_newline: bool
    size: int


#: Bytes read per block when a file is scanned.
_SCAN_BLOCK_BYTES = 1 << 20


def _scan_file(path: Path) -> _FileScan:
    """Check a file block by block (regular, size, BOM, NUL) without holding it in memory."""
    head, newlines, last = b"", 0, b""
    try:
        with open(path, "rb") as f:
            _check_regular(path, os.fstat(f.fileno()))
            total = 0
            while block := f.read(_SCAN_BLOCK_BYTES):
                if not head:
                    head = block
                    _check_bytes(block, path)
                elif b"\0" in block:
                    line = newlines + block.count(b"\n", 0, block.index(b"\0")) + 1
                    raise RecordingFormatError(f"{path}, line {line}: contains a NUL byte: binary data or a "
                                               "corrupted file, not a recording")
                newlines += block.count(b"\n")
                total += len(block)
                last = block[-1:]
                if total > MAX_RECORDING_BYTES:
                    raise RecordingFormatError(f"{path}: over the {MAX_RECORDING_BYTES} bytes a recording may have; "
                                               "split it")
    except IsADirectoryError:
        raise RecordingFormatError(f"{path}: not a regular file (a directory); give a recording file") from None
    except OSError as exc:
        raise RecordingFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return _FileScan(head, newlines, last == b"\n", total)


def _split_head(data: bytes) -> tuple[list[str], int] | None:
    """The lines up to and including the header row, decoded, and the byte offset after it; None if odd."""
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            return None
        line = data[pos:end]
        pos = end + 1
        if not (line.startswith(b"#") or not line.strip()):
            break
    try:
        return data[:pos].decode("utf-8").splitlines(), pos
    except UnicodeDecodeError:
        return None


#: Bytes the fast reader parses per block (bounds its working memory).
_FAST_BLOCK_BYTES = 1 << 21


def _blocks(path: Path, offset: int) -> Iterator[memoryview]:
    """The file from byte ``offset`` in blocks of whole lines of at most :data:`_FAST_BLOCK_BYTES`.

    Every block is a view of one reused buffer, valid until the next is asked for; the last
    one keeps whatever follows the last newline.  A line longer than the buffer raises
    ValueError (no recording has one; the careful parser names it).
    """
    buffer = bytearray(_FAST_BLOCK_BYTES)
    view = memoryview(buffer)
    kept = 0
    with open(path, "rb", buffering=0) as f:
        f.seek(offset)
        while got := f.readinto(view[kept:]):
            end = kept + got
            cut = buffer.rfind(b"\n", 0, end) + 1
            if not cut:
                if end == len(buffer):
                    raise ValueError(f"a line longer than {len(buffer)} bytes")
                kept = end
                continue
            yield view[:cut]
            kept = end - cut
            view[:kept] = view[cut:end]
    if kept:
        yield view[:kept]


def _read_columns_fast(path: Path, offset: int, header: list[str], max_rows: int) -> dict[str, np.ndarray] | None:
    """The data rows (from byte ``offset``) by column, parsed by pyarrow's CSV reader; None when it fails.

    Blocks of whole lines are parsed one at a time and copied into arrays of ``max_rows``
    (the number of lines), so the working memory is the columns plus one block.  pyarrow
    parses floats correctly rounded: a file written by :func:`write_recording` reads back
    bit for bit.  None also when pyarrow is not installed.
    """
    try:
        import pyarrow
        import pyarrow.csv
    except ImportError:
        return None
    read_options = pyarrow.csv.ReadOptions(column_names=header, use_threads=False)
    convert_options = pyarrow.csv.ConvertOptions(
        column_types={h: pyarrow.int64() if h in _INT_COLUMNS else pyarrow.float64() for h in header},
        null_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False)
    values = {h: np.empty(max_rows, dtype=np.int64 if h in _INT_COLUMNS else np.float64)
              for h in header if h in COLUMNS}
    n = 0
    try:
        for block in _blocks(path, offset):
            table = pyarrow.csv.read_csv(pyarrow.py_buffer(block), read_options=read_options,
                                         convert_options=convert_options, memory_pool=pyarrow.system_memory_pool())
            k = table.num_rows
            if n + k > max_rows:
                return None
            for h, column in values.items():
                _copy_column(table.column(h), column[n:n + k])
            n += k
            del table       # before the buffer under ``block`` is refilled
    except Exception:   # any failure of the fast path: the careful parser names the line and the rule
        return None
    values = {h: v if n == max_rows else v[:n] for h, v in values.items()}
    for v in values.values():
        v.setflags(write=False)     # owned by nobody else: the Recording keeps them without a copy
    return values if n else None


def _copy_column(column, out: np.ndarray) -> None:
    """Copy a pyarrow column without nulls into ``out`` straight from its data buffers.

    ``ChunkedArray.to_numpy`` would initialise pyarrow's compute-function registry on its
    first call, about 55 MB of resident memory (measured) for the life of the process.
    """
    i = 0
    for chunk in column.chunks:
        if chunk.null_count:
            raise ValueError("a missing value")
        k = len(chunk)
        out[i:i + k] = np.frombuffer(chunk.buffers()[1], dtype=out.dtype, count=k, offset=chunk.offset * out.itemsize)
        i += k
    if i != len(out):
        raise ValueError("a column shorter than its table")


class _FastParse(NamedTuple):
    """What the fast reader found: metadata, the header's line, the columns, each row's line (if known)."""

    meta: dict[str, str]
    header_line: int
    counts_per_rev: int | None
    values: dict[str, np.ndarray]
    row_lines: range | None


def _parse_fast(path: Path, scan: _FileScan) -> _FastParse | None:
    """``path`` parsed by pyarrow's CSV reader, or None for the careful parser to name what is wrong.

    Only a well-formed file takes this path: every row complete, every cell a number of its
    column's type, a final newline (the Recording then checks the values).
    """
    head = _split_head(scan.head) if scan.ends_with_newline else None
    if head is None:
        return None
    lines, offset = head
    fail = _Failer(str(path))
    meta, header_index = _parse_metadata(lines, fail)
    header = [h.strip() for h in next(csv.reader([lines[header_index]]))]
    _check_header(header, header_index + 1, fail)
    cpr = _counts_per_rev(meta, fail)
    if "counts" in header and cpr is None:
        fail(header_index + 1, "column 'counts' needs the metadata line '# counts_per_rev: N'")
    n_lines = scan.newlines - scan.head.count(b"\n", 0, offset)
    values = _read_columns_fast(path, offset, header, n_lines)
    if values is None:
        return None
    n = len(values["time_s"])
    row_lines = range(header_index + 2, header_index + 2 + n) if n_lines == n else None   # no array: 8 bytes a row
    return _FastParse(meta, header_index + 1, cpr, values, row_lines)


def _build_fast(parsed: _FastParse, name: str, check_samples: bool) -> Recording | None:
    """The Recording of a fast parse; None when a rule is broken, for the careful parser to name the line."""
    fail = _Failer(name)
    values = parsed.values
    sp = _sample_period(parsed.meta, values["time_s"], fail)
    extra = {k: v for k, v in parsed.meta.items() if k not in ("sample_period", "counts_per_rev")}
    try:
        rec = Recording(time=values.pop("time_s"), duty=values.pop("duty"), sample_period=sp,
                        counts=values.pop("counts", None), angle=values.pop("angle_rad", None),
                        speed=values.pop("speed_rad_s", None), seq=values.pop("seq", None),
                        counts_per_rev=parsed.counts_per_rev, metadata=extra, reference=values.pop("reference", None))
    except (ValueError, TypeError):
        return None    # a row breaks a rule (not finite, not increasing): the careful parser names its line
    if check_samples:
        if parsed.row_lines is None:
            return None if rec.implausible_samples() else rec   # blank lines: the careful parser knows the lines
        _refuse_implausible(rec, parsed.row_lines, fail)
    return rec


#: Largest recording file read, in bytes (about 40 million rows of seq,time_s,duty,counts).
MAX_RECORDING_BYTES = 1 << 30

#: Files smaller than this are read by the careful parser alone: importing pyarrow costs about
#: 0.3 s, more than the careful parser takes on such a file (about 10 000 rows).
FAST_PATH_MIN_BYTES = 256 << 10


def _check_regular(path: Path, st: os.stat_result) -> None:
    """Refuse anything but a regular file of at most :data:`MAX_RECORDING_BYTES`."""
    if not stat.S_ISREG(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "a device, pipe or socket"
        raise RecordingFormatError(f"{path}: not a regular file ({kind}); give a recording file")
    if st.st_size > MAX_RECORDING_BYTES:
        raise RecordingFormatError(f"{path}: {st.st_size} bytes is over the {MAX_RECORDING_BYTES} bytes a "
                                   "recording may have; split it")


def _read_bounded(path: Path) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_RECORDING_BYTES`, or RecordingFormatError."""
    try:
        with open(path, "rb") as f:
            _check_regular(path, os.fstat(f.fileno()))
            data = f.read(MAX_RECORDING_BYTES + 1)
    except IsADirectoryError:
        raise RecordingFormatError(f"{path}: not a regular file (a directory); give a recording file") from None
    except OSError as exc:
        raise RecordingFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_RECORDING_BYTES:
        raise RecordingFormatError(f"{path}: over the {MAX_RECORDING_BYTES} bytes a recording may have; split it")
    return data


def _parse(text: str, name: str, check_samples: bool = True) -> Recording:
    fail = _Failer(name)
    lines = text.splitlines()
    meta, header_index = _parse_metadata(lines, fail)
    header, cols = _parse_rows(lines, header_index, fail, torn=bool(text) and not text.endswith(("\n", "\r")))
    header_line = header_index + 1
    cpr = _counts_per_rev(meta, fail)
    if "counts" in cols and cpr is None:
        fail(header_line, "column 'counts' needs the metadata line '# counts_per_rev: N'")
    values = {h: np.array([v for _, v in cols[h]]) for h in header}
    sp = _sample_period(meta, values["time_s"], fail)
    extra = {k: v for k, v in meta.items() if k not in ("sample_period", "counts_per_rev")}
    try:
        rec = Recording(time=values["time_s"], duty=values["duty"], sample_period=sp,
                        counts=values.get("counts"), angle=values.get("angle_rad"),
                        speed=values.get("speed_rad_s"), seq=values.get("seq"), counts_per_rev=cpr,
                        metadata=extra, reference=values.get("reference"))
    except (ValueError, TypeError) as exc:
        raise RecordingFormatError(f"{name}: {exc}") from None
    if check_samples:
        _refuse_implausible(rec, [line for line, _ in cols["time_s"]], fail)
    return rec


def _refuse_implausible(rec: Recording, lines: Sequence[int] | np.ndarray, fail: _Failer) -> None:
    """Refuse the file when rows no motor can produce are found, naming their lines."""
    bad = rec.implausible_samples()
    if bad:
        others = "" if len(bad) == 1 else f" (and {len(bad) - 1} more, lines " + ", ".join(
            str(lines[s.row]) for s in bad[1:6]) + (", ..." if len(bad) > 6 else "") + ")"
        fail(lines[bad[0].row], f"implausible sample (seq {bad[0].seq}): {bad[0].reason}{others}; "
                                  "a corrupted row? remove it, or drop such rows as gaps "
                                  "(motorid identify --drop-outliers)")


class _Failer:
    """Raises :class:`RecordingFormatError` as ``"FILE, line N: rule"``."""

    def __init__(self, name: str):
        self.name = name

    def __call__(self, line: int, rule: str) -> NoReturn:
        raise RecordingFormatError(f"{self.name}, line {line}: {rule}")


def _parse_metadata(lines: list[str], fail: _Failer) -> tuple[dict[str, str], int]:
    """The ``# key: value`` lines (aliases resolved) and the index of the header row."""
    meta: dict[str, str] = {}
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        body = lines[i][1:].strip() if lines[i].startswith("#") else ""
        if body.startswith("motorid recording"):
            if body != FORMAT_HEADER[1:].strip():
                fail(i + 1, f"unsupported format {body!r}; this version reads {FORMAT_HEADER[2:]!r}")
        elif ":" in body:
            k, _, v = body.partition(":")
            meta[_ALIASES.get(k.strip(), k.strip())] = v.strip()
        i += 1
    if i == len(lines):
        fail(i, "no header row (expected column names such as seq,time_s,duty,counts)")
    return meta, i


def _check_header(header: list[str], line: int, fail: _Failer) -> None:
    if len(set(header)) != len(header):
        fail(line, f"duplicate column names in {header}")
    for required in ("time_s", "duty"):
        if required not in header:
            fail(line, f"missing required column {required!r} (columns: {header})")
    if not {"counts", "angle_rad", "speed_rad_s"} & set(header):
        fail(line, f"needs at least one of the columns counts, angle_rad, speed_rad_s (columns: {header})")


def _parse_cell(column: str, cell: str, line: int, fail: _Failer) -> float:
    cell = cell.strip()
    if "_" in cell:
        fail(line, f"column {column!r} must be a plain number (no '_' digit separators), got {cell!r}")
    if column in _INT_COLUMNS:
        try:
            value = int(cell)
        except ValueError:
            fail(line, f"column {column!r} must be an integer, got {cell[:40]!r}")
        if not -(1 << 63) <= value < (1 << 63):
            fail(line, f"column {column!r} must fit a 64-bit integer, got {cell[:40]}{'...' if len(cell) > 40 else ''}")
        return value
    try:
        v = float(cell)
    except ValueError:
        fail(line, f"column {column!r} must be a number, got {cell[:40]!r}")
    if not math.isfinite(v) and column in COLUMNS:
        fail(line, f"column {column!r} must be finite, got {cell!r}")
    return v


def _check_strictly_increasing(column: list[tuple[int, float]], name: str, fail: _Failer) -> None:
    for (_, v0), (line, v1) in zip(column, column[1:]):
        if v1 <= v0:
            fail(line, f"{name} must be strictly increasing, got {v1!r} after {v0!r}")


def _csv_rows(reader, header_line: int, fail: _Failer) -> Iterable[list[str]]:
    """The csv rows, a csv error (a field over the module's limit, a stray quote) as RecordingFormatError."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            fail(header_line + reader.line_num - 1, f"not a CSV row: {exc}")
        yield row


def _parse_rows(lines: list[str], header_index: int, fail: _Failer, torn: bool = False
                ) -> tuple[list[str], dict[str, list[tuple[int, float]]]]:
    """The column names and, per column, ``(line number, value)`` of every data row.

    ``torn`` says the text does not end with a newline: an error on the last line names it as torn.
    """
    header_line = header_index + 1
    reader = csv.reader(io.StringIO("\n".join(lines[header_index:])))
    header = [h.strip() for h in next(iter(_csv_rows(reader, header_line, fail)), [])]
    _check_header(header, header_line, fail)
    cols: dict[str, list[tuple[int, float]]] = {h: [] for h in header}
    last_line = len(lines)
    for j, row in enumerate(_csv_rows(reader, header_line, fail)):
        line = header_line + 1 + j
        if not row or all(not c.strip() for c in row):
            continue
        try:
            if len(row) != len(header):
                fail(line, f"expected {len(header)} values, got {len(row)}")
            for h, cell in zip(header, row):
                cols[h].append((line, _parse_cell(h, cell, line, fail)))
        except RecordingFormatError as exc:
            if line == last_line and torn:
                fail(line, f"the last line is torn (the file ends mid-row, without a newline: a run cut off or "
                           f"a full disk?): {str(exc).partition(': ')[2]}")
            raise
    if not cols["time_s"]:
        fail(header_line, "no data rows")
    _check_strictly_increasing(cols["time_s"], "time_s", fail)
    if "seq" in cols:
        _check_strictly_increasing(cols["seq"], "seq", fail)
    return header, cols


def _counts_per_rev(meta: Mapping[str, str], fail: _Failer) -> int | None:
    if "counts_per_rev" not in meta:
        return None
    try:
        cpr = int(meta["counts_per_rev"])
        if cpr <= 0:
            raise ValueError
    except ValueError:
        fail(1, f"counts_per_rev must be a positive integer, got {meta['counts_per_rev']!r}")
    return cpr


def _sample_period(meta: Mapping[str, str], time_s: np.ndarray, fail: _Failer) -> float:
    """The metadata's sample period, else the median interval of ``time_s``."""
    if "sample_period" in meta:
        try:
            sp = float(meta["sample_period"])
            if not (math.isfinite(sp) and sp > 0):
                raise ValueError
        except ValueError:
            fail(1, f"sample_period must be a number > 0 s, got {meta['sample_period']!r}")
        return sp
    if len(time_s) > 1:
        return float(np.median(np.diff(time_s)))
    fail(1, "a one-row recording needs the metadata line '# sample_period: S'")
