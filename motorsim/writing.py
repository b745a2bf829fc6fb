"""Writing the CSV recording format v1 (:mod:`motorsim.recording`): a whole recording at once, or row by row.

:func:`write_recording` writes a finished :class:`~motorsim.recording.Recording`
atomically; :class:`RecordingWriter` writes the rows while they are measured, to a
``.partial`` file that is always readable and becomes the recording when the run ends.
Floats are written with ``repr``, so reading a file back gives the same numbers bit for bit.
"""
from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Iterable, Mapping, TextIO

import numpy as np

from .checks import ParameterError, ParameterTypeError
from .files import OutputFileError, check_output_file, open_exclusive, write_atomically
from .recording import FORMAT_HEADER, INTEGER_COLUMNS, Recording
from .text import printable

__all__ = ["write_recording", "RecordingWriter"]


def _metadata_lines(rec: Recording) -> list[str]:
    meta = {"sample_period": repr(rec.sample_period)}
    if rec.counts_per_rev is not None:
        meta["counts_per_rev"] = str(rec.counts_per_rev)
    for k, v in rec.metadata.items():
        if k not in meta:
            meta[k] = v
    lines = [FORMAT_HEADER]
    for k, v in meta.items():
        if ":" in k or not k.strip():
            raise ParameterError(f"metadata key {printable(k)!r} must be a name without ':'")
        # a line break, carriage return or NUL (a device's board name) would cut the line: written escaped
        lines.append(f"# {printable(k)}: {printable(v)}")
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
        yield ",".join(fmt[c](float(data[c][k]) if c not in INTEGER_COLUMNS else data[c][k]) for c in cols)


def write_recording(recording: Recording, path: str | os.PathLike, *, at_once: bool = False) -> Path:
    """Write ``recording`` to ``path`` in format v1, atomically (temporary file, then rename).

    Floats are written with ``repr``, so reading the file back gives the same numbers bit for bit.

    Parameters
    ----------
    recording : Recording
        What to write.
    path : str or path-like
        Destination; replaced if it exists.
    at_once : bool
        Move it into place now even within :func:`motorsim.files.deferred_outputs` (a bench
        run's data, kept whatever happens next).
    """
    if not isinstance(recording, Recording):
        raise ParameterTypeError(f"recording must be a Recording, got {type(recording).__name__}")
    path = Path(path)
    cols = _columns(recording)
    text = "\n".join([*_metadata_lines(recording), ",".join(cols), *_format_rows(recording, cols)]) + "\n"
    write_atomically(path, text, at_once=at_once)
    return path


def _lock(f: TextIO) -> None:
    """Hold an advisory lock on the partial file ``f`` while rows go to it (where ``fcntl`` exists)."""
    with contextlib.suppress(ImportError, OSError):
        import fcntl
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


def _being_written(path: Path) -> bool:
    """Whether another :class:`RecordingWriter` holds the lock of the partial file ``path``."""
    try:
        import fcntl
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except (ImportError, OSError):
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)
    return False


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
    ``incomplete_reason``, and removes the partial file; it is written at once, even within
    :func:`motorsim.files.deferred_outputs`, since it holds a run that cannot be repeated.  An
    incomplete run never replaces a file that was at ``PATH`` before (``overwrite``): it stays
    in ``PATH.partial``, with the final metadata, and ``PATH`` is unchanged.  Leaving the ``with`` block by
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
        self._replaces = os.path.lexists(self.path)
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
            if _being_written(self.partial_path):
                raise OutputFileError(f"{self.partial_path} is being written by another run now; give this run "
                                      f"another --out (leave that file alone)") from None
            raise OutputFileError(f"{self.partial_path} exists: an earlier run that did not finish left it. "
                                  f"It is a readable recording; rename or delete it, then run again") from None
        except OSError as exc:
            raise OutputFileError(f"cannot create {self.partial_path}: {exc.strerror or exc}", exc.errno) from None
        _lock(self._file)
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
            raise ParameterError(f"this RecordingWriter for {self.path} is closed")
        row = (int(seq), float(time_s), int(duty), int(counts))
        last = self._rows[-1] if self._rows else self._last
        if last is not None and (row[0] <= last[0] or row[1] <= last[1]):
            raise ParameterError(f"seq and time_s must be strictly increasing, got seq {row[0]} at {row[1]!r} s "
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
            raise ParameterError(f"this RecordingWriter for {self.path} is closed")
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
        target = self._target(complete)
        write_atomically(target, "\n".join(header + body), at_once=True)
        if target != self.partial_path:
            os.unlink(self.partial_path)
        return target

    def _target(self, complete: bool) -> Path:
        """Where the final file goes: ``PATH``, or the partial file for an incomplete run replacing an old ``PATH``."""
        return self.path if complete or not self._replaces else self.partial_path

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
            raise ParameterTypeError(f"recording must be a Recording, got {type(recording).__name__}")
        self.closed = True
        self._rows = []
        if self._file is not None:
            self._file.close()
            self._file = None
        target = self._target(recording.metadata.get("complete", "true") != "false")
        write_recording(recording, target, at_once=True)
        if target != self.partial_path:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.partial_path)
        self.n_rows = len(recording)
        return target

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close(True)
        elif exc_type is KeyboardInterrupt:
            self.close(False, "interrupted (Ctrl-C)")
        else:
            self.close(False, f"{exc_type.__name__}: {exc}")
