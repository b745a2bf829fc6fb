"""``Recording``: one experiment's samples, and the CSV recording format v1.

Alignment (fixed for the whole project)
---------------------------------------
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
``counts``, ``angle_rad``, ``speed_rad_s``; ``seq`` is optional.
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
from typing import Iterable, Mapping

import numpy as np

from .sensors import backward_difference, counts_to_angle

__all__ = ["Recording", "RecordingFormatError", "read_recording", "write_recording", "RecordingWriter",
           "FORMAT_HEADER", "COLUMNS"]

FORMAT_HEADER = "# motorid recording v1"
#: Known columns in the order they are written.
COLUMNS = ("seq", "time_s", "duty", "counts", "angle_rad", "speed_rad_s")
_ALIASES = {"dt": "sample_period", "ppr": "counts_per_rev"}
_INT_COLUMNS = ("seq", "counts")


class RecordingFormatError(ValueError):
    """A recording file or array breaks a rule of recording format v1."""


def _as_array(name, value, dtype, n=None):
    if value is None:
        return None
    arr = np.array(value, dtype=dtype, copy=True)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if n is not None and len(arr) != n:
        raise ValueError(f"{name} must have the same length as time ({n}), got {len(arr)}")
    arr.setflags(write=False)
    return arr


@dataclasses.dataclass(frozen=True, eq=False)
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
        Sample index; a gap means dropped samples.  Default ``0 ... n-1``.
    counts_per_rev : int, optional
        Encoder counts per revolution.
    metadata : mapping of str to str, optional
        Free-form ``key: value`` pairs (``input_unit``, ``source``, ...).
    """

    time: np.ndarray
    duty: np.ndarray
    sample_period: float
    counts: np.ndarray | None = None
    angle: np.ndarray | None = None
    speed: np.ndarray | None = None
    seq: np.ndarray | None = None
    counts_per_rev: int | None = None
    metadata: Mapping[str, str] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        time = _as_array("time", self.time, float)
        n = len(time)
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "duty", _as_array("duty", self.duty, float, n))
        for name in ("angle", "speed"):
            object.__setattr__(self, name, _as_array(name, getattr(self, name), float, n))
        for name in _INT_COLUMNS:
            value = getattr(self, name)
            if value is not None:
                raw = np.asarray(value)
                if raw.dtype.kind == "f":
                    if not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
                        raise ValueError(f"{name} must hold integers, got non-integer values")
                elif raw.dtype.kind not in "iu":
                    raise TypeError(f"{name} must hold integers, got dtype {raw.dtype}")
            object.__setattr__(self, name, _as_array(name, value, np.int64, n))
        if self.seq is None:
            seq = np.arange(n, dtype=np.int64)
            seq.setflags(write=False)
            object.__setattr__(self, "seq", seq)
        sp = self.sample_period
        if isinstance(sp, bool) or not isinstance(sp, (int, float, np.floating, np.integer)) \
                or not math.isfinite(sp) or sp <= 0:
            raise ValueError(f"sample_period must be a finite number > 0 s, got {sp!r}")
        object.__setattr__(self, "sample_period", float(sp))
        if self.counts is None and self.angle is None and self.speed is None:
            raise ValueError("a Recording needs at least one of counts, angle, speed")
        if self.counts is not None:
            cpr = self.counts_per_rev
            if isinstance(cpr, bool) or not isinstance(cpr, (int, np.integer)) or cpr <= 0:
                raise ValueError(f"counts_per_rev must be a positive integer when counts are given, got {cpr!r}")
            object.__setattr__(self, "counts_per_rev", int(cpr))
        for name in ("time", "duty", "angle", "speed"):
            arr = getattr(self, name)
            if arr is not None and not np.all(np.isfinite(arr)):
                k = int(np.flatnonzero(~np.isfinite(arr))[0])
                raise ValueError(f"{name} must be finite, got {arr[k]!r} at sample {k}")
        if n > 1 and np.any(np.diff(self.time) <= 0):
            k = int(np.flatnonzero(np.diff(self.time) <= 0)[0]) + 1
            raise ValueError(f"time must be strictly increasing, got {self.time[k]!r} after {self.time[k-1]!r} at sample {k}")
        if n > 1 and np.any(np.diff(self.seq) <= 0):
            raise ValueError("seq must be strictly increasing")
        if not isinstance(self.metadata, Mapping):
            raise TypeError(f"metadata must be a mapping, got {type(self.metadata).__name__}")
        object.__setattr__(self, "metadata", {str(k): str(v) for k, v in self.metadata.items()})

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
        if self.counts is not None:
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
    cols += [c for c, v in (("counts", rec.counts), ("angle_rad", rec.angle), ("speed_rad_s", rec.speed)) if v is not None]
    return cols


def _format_rows(rec: Recording, cols: list[str], start: int = 0, stop: int | None = None) -> Iterable[str]:
    data = {"seq": rec.seq, "time_s": rec.time, "duty": rec.duty, "counts": rec.counts,
            "angle_rad": rec.angle, "speed_rad_s": rec.speed}
    integral_duty = bool(np.all(rec.duty == np.round(rec.duty)))
    fmt = {"seq": lambda x: str(int(x)), "counts": lambda x: str(int(x)),
           "time_s": repr, "angle_rad": repr, "speed_rad_s": repr,
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
        self._file = None
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
    def fail(line, rule):
        raise RecordingFormatError(f"{name}, line {line}: {rule}")

    lines = text.splitlines()
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
    header_line = i + 1
    reader = csv.reader(io.StringIO("\n".join(lines[i:])))
    header = [h.strip() for h in next(reader)]
    if len(set(header)) != len(header):
        fail(header_line, f"duplicate column names in {header}")
    for required in ("time_s", "duty"):
        if required not in header:
            fail(header_line, f"missing required column {required!r} (columns: {header})")
    if not {"counts", "angle_rad", "speed_rad_s"} & set(header):
        fail(header_line, f"needs at least one of the columns counts, angle_rad, speed_rad_s (columns: {header})")
    cols: dict[str, list] = {h: [] for h in header}
    for j, row in enumerate(reader):
        line = header_line + 1 + j
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            fail(line, f"expected {len(header)} values, got {len(row)}")
        for h, cell in zip(header, row):
            cell = cell.strip()
            if h in _INT_COLUMNS:
                try:
                    v = int(cell)
                except ValueError:
                    fail(line, f"column {h!r} must be an integer, got {cell!r}")
            else:
                try:
                    v = float(cell)
                except ValueError:
                    fail(line, f"column {h!r} must be a number, got {cell!r}")
                if not math.isfinite(v) and h in COLUMNS:
                    fail(line, f"column {h!r} must be finite, got {cell!r}")
            cols[h].append((line, v))
    if not cols["time_s"]:
        fail(header_line, "no data rows")
    times = cols["time_s"]
    for (l0, t0), (l1, t1) in zip(times, times[1:]):
        if t1 <= t0:
            fail(l1, f"time_s must be strictly increasing, got {t1!r} after {t0!r}")
    if "seq" in cols:
        s = cols["seq"]
        for (l0, s0), (l1, s1) in zip(s, s[1:]):
            if s1 <= s0:
                fail(l1, f"seq must be strictly increasing, got {s1} after {s0}")
    cpr = None
    if "counts_per_rev" in meta:
        try:
            cpr = int(meta["counts_per_rev"])
            if cpr <= 0:
                raise ValueError
        except ValueError:
            fail(1, f"counts_per_rev must be a positive integer, got {meta['counts_per_rev']!r}")
    if "counts" in cols and cpr is None:
        fail(header_line, "column 'counts' needs the metadata line '# counts_per_rev: N'")
    values = {h: np.array([v for _, v in cols[h]]) for h in header}
    if "sample_period" in meta:
        try:
            sp = float(meta["sample_period"])
            if not (math.isfinite(sp) and sp > 0):
                raise ValueError
        except ValueError:
            fail(1, f"sample_period must be a number > 0 s, got {meta['sample_period']!r}")
    elif len(values["time_s"]) > 1:
        sp = float(np.median(np.diff(values["time_s"])))
    else:
        fail(1, "a one-row recording needs the metadata line '# sample_period: S'")
    extra = {k: v for k, v in meta.items() if k not in ("sample_period", "counts_per_rev")}
    return Recording(time=values["time_s"], duty=values["duty"], sample_period=sp,
                     counts=values.get("counts"), angle=values.get("angle_rad"),
                     speed=values.get("speed_rad_s"), seq=values.get("seq"), counts_per_rev=cpr,
                     metadata=extra)
