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
``counts``, ``angle_rad``, ``speed_rad_s``; ``seq`` is optional.  A closed-loop run adds
``reference``: what the controller tracked at ``time_s[k]``, in the unit named by the
metadata ``reference_unit`` (``rad/s`` for a speed controller, ``rad`` of angle since
the first sample for a position controller).
"""
from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Iterable, Mapping, NoReturn, TextIO

import numpy as np
from numpy.typing import ArrayLike

from .checks import check_int, check_real
from .sensors import backward_difference, counts_to_angle

__all__ = ["Recording", "RecordingFormatError", "read_recording", "write_recording", "RecordingWriter",
           "FORMAT_HEADER", "COLUMNS"]

FORMAT_HEADER = "# motorid recording v1"
#: Known columns in the order they are written.
COLUMNS = ("seq", "time_s", "duty", "counts", "angle_rad", "speed_rad_s", "reference")
_ALIASES = {"dt": "sample_period", "ppr": "counts_per_rev"}
_INT_COLUMNS = ("seq", "counts")


class RecordingFormatError(ValueError):
    """A recording file or array breaks a rule of recording format v1."""


def _as_array(name: str, value: ArrayLike, dtype: type, n: int | None = None) -> np.ndarray:
    """``value`` as a read-only 1-D copy of ``dtype`` (of length ``n`` when given)."""
    arr: np.ndarray = np.array(value, dtype=dtype, copy=True)
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
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, Mapping):
            raise TypeError(f"metadata must be a mapping, got {type(metadata).__name__}")
        object.__setattr__(self, "metadata", {str(k): str(v) for k, v in metadata.items()})

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


def _replace_atomically(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


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
    _replace_atomically(path, text)
    return path


class RecordingWriter:
    """Write a recording (format v1) row by row while it is being measured; a context manager.

    Rows go to ``PATH.partial`` as they arrive (whole lines, flushed at least every
    ``flush_interval`` s), so the partial file is always a readable format-v1 file whose
    metadata say ``complete: false``.  :meth:`close` then atomically writes ``PATH``
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
    """

    _COLS = ["seq", "time_s", "duty", "counts"]

    def __init__(self, path: str | os.PathLike, sample_period: float, counts_per_rev: int, *,
                 metadata: Mapping[str, str] | None = None, flush_interval: float = 0.25):
        self.path = Path(path)
        self.partial_path = self.path.with_name(self.path.name + ".partial")
        if not self.path.parent.is_dir():
            raise ValueError(f"path must be in an existing directory, got {str(path)!r}")
        self._meta = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._sample_period = sample_period
        self._counts_per_rev = counts_per_rev
        self._probe(np.zeros(1), np.zeros(1), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), {})
        self._flush_interval = float(flush_interval)
        self._rows: list[tuple[int, float, int, int]] = []
        self._last: tuple[int, float, int, int] | None = None
        self._file: TextIO | None = None
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
        if self._file is None:
            header = _metadata_lines(self._batch(self._rows[:1], {
                "complete": "false", "incomplete_reason": "still recording (partial file)"})) + [",".join(self._COLS)]
            self._header_lines = len(header)
            self._file = open(self.partial_path, "w", encoding="utf-8", newline="")
            lines = header + lines
        self._file.write("\n".join(lines) + "\n")
        self._file.flush()
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
            return None
        self._file.close()
        if metadata:
            self._meta.update({str(k): str(v) for k, v in metadata.items()})
        extra = {"complete": "true" if complete else "false"}
        self._meta.pop("incomplete_reason", None)
        if not complete:
            extra["incomplete_reason"] = " ".join(str(reason or "unknown").split())
        header = _metadata_lines(self._batch([self._last], extra)) + [",".join(self._COLS)]
        with open(self.partial_path, encoding="utf-8") as f:
            body = f.read().split("\n")[self._header_lines:]
        _replace_atomically(self.path, "\n".join(header + body))
        os.unlink(self.partial_path)
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


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a format-v1 CSV file.

    Parameters
    ----------
    path : str or path-like
        The file.

    Raises
    ------
    RecordingFormatError
        For every broken rule, naming the file, the line and the rule.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise RecordingFormatError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise RecordingFormatError(f"{path}: cannot read: {exc.strerror}") from None
    return _parse(text, str(path))


def _parse(text: str, name: str) -> Recording:
    fail = _Failer(name)
    lines = text.splitlines()
    meta, header_index = _parse_metadata(lines, fail)
    header, cols = _parse_rows(lines, header_index, fail)
    header_line = header_index + 1
    cpr = _counts_per_rev(meta, fail)
    if "counts" in cols and cpr is None:
        fail(header_line, "column 'counts' needs the metadata line '# counts_per_rev: N'")
    values = {h: np.array([v for _, v in cols[h]]) for h in header}
    sp = _sample_period(meta, values["time_s"], fail)
    extra = {k: v for k, v in meta.items() if k not in ("sample_period", "counts_per_rev")}
    return Recording(time=values["time_s"], duty=values["duty"], sample_period=sp,
                     counts=values.get("counts"), angle=values.get("angle_rad"),
                     speed=values.get("speed_rad_s"), seq=values.get("seq"), counts_per_rev=cpr,
                     metadata=extra, reference=values.get("reference"))


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
    if column in _INT_COLUMNS:
        try:
            return int(cell)
        except ValueError:
            fail(line, f"column {column!r} must be an integer, got {cell!r}")
    try:
        v = float(cell)
    except ValueError:
        fail(line, f"column {column!r} must be a number, got {cell!r}")
    if not math.isfinite(v) and column in COLUMNS:
        fail(line, f"column {column!r} must be finite, got {cell!r}")
    return v


def _check_strictly_increasing(column: list[tuple[int, float]], name: str, fail: _Failer) -> None:
    for (_, v0), (line, v1) in zip(column, column[1:]):
        if v1 <= v0:
            fail(line, f"{name} must be strictly increasing, got {v1!r} after {v0!r}")


def _parse_rows(lines: list[str], header_index: int, fail: _Failer
                ) -> tuple[list[str], dict[str, list[tuple[int, float]]]]:
    """The column names and, per column, ``(line number, value)`` of every data row."""
    header_line = header_index + 1
    reader = csv.reader(io.StringIO("\n".join(lines[header_index:])))
    header = [h.strip() for h in next(reader)]
    _check_header(header, header_line, fail)
    cols: dict[str, list[tuple[int, float]]] = {h: [] for h in header}
    for j, row in enumerate(reader):
        line = header_line + 1 + j
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            fail(line, f"expected {len(header)} values, got {len(row)}")
        for h, cell in zip(header, row):
            cols[h].append((line, _parse_cell(h, cell, line, fail)))
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
