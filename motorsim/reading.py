"""Reading the CSV recording format v1 (:mod:`motorsim.recording`): :func:`read_recording`.

Two parsers read the same format and refuse the same files.  A large file (at least
:data:`FAST_PATH_MIN_BYTES`) goes to a fast columnar parser (pyarrow, block by block) when the
file is plain; anything it cannot vouch for -- odd cells, a broken rule, a NUL byte -- falls
back to the careful parser, which reads line by line and names the file, the line and the
rule of every error (``RecordingFormatError``).  The fast parser reads the file once: its head
(metadata, header, a byte-order mark or NUL byte refused at once), then its rows; the lines of
rows no motor can produce are counted only for a file refused for them.
"""
from __future__ import annotations

import csv
import io
import math
import os
import warnings
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator, Mapping, NamedTuple, NoReturn, Sequence

import numpy as np

from .checks import ParameterError
from .files import InputFileError, open_input
from .plausibility import ImplausibleSample
from .recording import (
    COLUMNS,
    FORMAT_HEADER,
    INTEGER_COLUMNS,
    METADATA_ALIASES,
    AngleUnitWarning,
    Recording,
    RecordingFormatError,
)

__all__ = ["read_recording", "MAX_RECORDING_BYTES", "FAST_PATH_MIN_BYTES"]


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
    head = _read_head(path)
    parsed = _parse_fast(path, head) if head.size >= FAST_PATH_MIN_BYTES else None
    if parsed is not None:
        rec = _build_fast(parsed, path, check_samples)
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


class _Head(NamedTuple):
    """A file's first block (its bytes checked), its size, and whether it ends with a newline."""

    data: bytes
    size: int
    ends_with_newline: bool


#: Bytes read as a file's head: the metadata and the header row must lie within it for the fast reader.
_HEAD_BYTES = 1 << 20


def _read_head(path: Path) -> _Head:
    """The head of a regular file of at most :data:`MAX_RECORDING_BYTES`, refused at once for a BOM or a NUL byte.

    The rest of the file is not read here: the fast reader refuses a NUL byte as a cell that is not a number,
    and the careful parser then names its line.
    """
    try:
        with _open_recording(path) as f:
            size = os.fstat(f.fileno()).st_size
            data = f.read(_HEAD_BYTES)
            last = data[-1:]
            if len(data) < size:
                f.seek(size - 1)
                last = f.read(1)
    except OSError as exc:
        raise RecordingFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    _check_bytes(data, path)
    return _Head(data, size, last == b"\n")


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


#: Bytes the fast reader parses per block (bounds its working memory).  pyarrow parses a block
#: on the calling thread (:data:`_THREADS`); larger blocks were no faster (measured with ``motorid bench parse``).
_FAST_BLOCK_BYTES = 1 << 21


def _blocks(path: Path, offset: int, size: int) -> Iterator[memoryview]:
    """The file from byte ``offset`` to ``size`` in blocks of whole lines of at most :data:`_FAST_BLOCK_BYTES`.

    Every block is a view of one reused buffer, valid until the next is asked for; the last
    one keeps whatever follows the last newline.  A line longer than the buffer raises
    ValueError (no recording has one; the careful parser names it).
    """
    buffer = bytearray(_FAST_BLOCK_BYTES)
    view = memoryview(buffer)
    kept = 0
    left = size - offset             # the size the file had when it was checked: a file that grows is read as it was
    with open(path, "rb", buffering=0) as f:
        f.seek(offset)
        while left > 0 and (got := f.readinto(view[kept:kept + min(left, len(buffer) - kept)])):
            left -= got
            end = kept + got
            cut = buffer.rfind(b"\n", 0, end) + 1
            if not cut:
                if end == len(buffer):
                    raise ParameterError(f"a line longer than {len(buffer)} bytes")
                kept = end
                continue
            yield view[:cut]
            kept = end - cut
            view[:kept] = view[cut:end]
    if kept:
        yield view[:kept]


#: Whether pyarrow parses a block's chunks on its thread pool.  No: on 10^6 rows (``motorid bench selection``)
#: the threads took as much CPU time as one thread (0.149 s against 0.142 s, the least of five), left 14 MB more
#: peak memory in their allocator arenas (169 MB against 155 MB), and on a machine whose cores are busy the
#: wall-clock time was the same.
_THREADS = False


def _read_columns_fast(path: Path, offset: int, header: list[str], size: int) -> dict[str, np.ndarray] | None:
    """The data rows (bytes ``offset`` to ``size``) by column, parsed by pyarrow's CSV reader; None when it fails.

    Blocks of whole lines are parsed one at a time and copied into arrays sized from the first
    block's bytes per row (grown if the rows get shorter), so the working memory is the columns
    plus one block, and the file is read once.  pyarrow parses floats correctly rounded: a file
    written by :func:`write_recording` reads back bit for bit.  Blank lines are skipped (the
    careful parser skips them too).  None also when pyarrow is not installed.
    """
    try:
        import pyarrow
        import pyarrow.csv
    except ImportError:
        return None
    read_options = pyarrow.csv.ReadOptions(column_names=header, use_threads=_THREADS)
    convert_options = pyarrow.csv.ConvertOptions(
        column_types={h: pyarrow.int64() if h in INTEGER_COLUMNS else pyarrow.float64() for h in header},
        null_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False)
    dtypes = {h: np.int64 if h in INTEGER_COLUMNS else np.float64 for h in header if h in COLUMNS}
    values: dict[str, np.ndarray] = {}
    n = read = 0
    try:
        for block in _blocks(path, offset, size):
            table = pyarrow.csv.read_csv(pyarrow.py_buffer(block), read_options=read_options,
                                         convert_options=convert_options, memory_pool=pyarrow.system_memory_pool())
            k = table.num_rows
            read += len(block)
            if n + k > len(values.get("time_s", ())):
                # rows so far plus the rest at the bytes per row seen so far, and a margin; untouched pages of an
                # array this size cost no memory
                capacity = max(n + k, math.ceil((n + k) * (1 + (size - offset - read) / max(read, 1)) * 1.05) + 64)
                values = {h: _grown(values.get(h), capacity, n, dtype) for h, dtype in dtypes.items()}
            for h, column in values.items():
                _copy_column(table.column(h), column[n:n + k])
            n += k
            del table       # before the buffer under ``block`` is refilled
    except Exception:   # any failure of the fast path: the careful parser names the line and the rule
        return None
    if not n:
        return None
    for v in values.values():
        v.resize(n, refcheck=False)     # in place (no other reference to it is left): an array of its own
        v.setflags(write=False)         # owned by nobody else: the Recording keeps them without a copy
    return values


def _grown(column: np.ndarray | None, capacity: int, n: int, dtype: type) -> np.ndarray:
    """An array of ``capacity`` rows whose first ``n`` are those of ``column``."""
    out: np.ndarray = np.empty(capacity, dtype=dtype)
    if column is not None and n:
        out[:n] = column[:n]
    return out


def _copy_column(column, out: np.ndarray) -> None:
    """Copy a pyarrow column without nulls into ``out`` straight from its data buffers.

    ``ChunkedArray.to_numpy`` would initialise pyarrow's compute-function registry on its
    first call, about 55 MB of resident memory (measured) for the life of the process.
    """
    i = 0
    for chunk in column.chunks:
        if chunk.null_count:
            raise ParameterError("a missing value")
        k = len(chunk)
        out[i:i + k] = np.frombuffer(chunk.buffers()[1], dtype=out.dtype, count=k, offset=chunk.offset * out.itemsize)
        i += k
    if i != len(out):
        raise ParameterError("a column shorter than its table")


class _FastParse(NamedTuple):
    """What the fast reader found: metadata, the header's line and byte offset after it, the bytes read, the columns."""

    meta: dict[str, str]
    header_line: int
    offset: int
    size: int
    counts_per_rev: int | None
    values: dict[str, np.ndarray]


def _parse_fast(path: Path, head: _Head) -> _FastParse | None:
    """``path`` parsed by pyarrow's CSV reader, or None for the careful parser to name what is wrong.

    Only a well-formed file takes this path: every row complete, every cell a number of its
    column's type, a final newline (the Recording then checks the values).
    """
    split = _split_head(head.data) if head.ends_with_newline else None
    if split is None:
        return None
    lines, offset = split
    fail = _Failer(str(path))
    meta, header_index = _parse_metadata(lines, fail)
    header = [h.strip() for h in next(csv.reader([lines[header_index]]))]
    _check_header(header, header_index + 1, fail)
    cpr = _counts_per_rev(meta, fail)
    if "counts" in header and cpr is None:
        fail(header_index + 1, "column 'counts' needs the metadata line '# counts_per_rev: N'")
    values = _read_columns_fast(path, offset, header, head.size)
    if values is None:
        return None
    return _FastParse(meta, header_index + 1, offset, head.size, cpr, values)


def _build_fast(parsed: _FastParse, path: Path, check_samples: bool) -> Recording | None:
    """The Recording of a fast parse; None when a rule is broken, for the careful parser to name the line."""
    name = str(path)
    fail = _Failer(name)
    values = parsed.values
    sp = _sample_period(parsed.meta, values["time_s"], fail)
    extra = {k: v for k, v in parsed.meta.items() if k not in ("sample_period", "counts_per_rev")}
    try:
        rec = Recording(time=values.pop("time_s"), duty=values.pop("duty"), sample_period=sp,
                        counts=values.pop("counts", None), angle=values.pop("angle_rad", None),
                        speed=values.pop("speed_rad_s", None), seq=values.pop("seq", None),
                        counts_per_rev=parsed.counts_per_rev, metadata=extra, reference=values.pop("reference", None),
                        path=name)
    except (ValueError, TypeError):
        return None    # a row breaks a rule (not finite, not increasing): the careful parser names its line
    if check_samples:
        bad = rec.implausible_samples()
        if bad:
            lines = _row_lines(path, parsed.offset, parsed.size, parsed.header_line, len(rec))
            if lines is None:
                return None     # blank lines or lone carriage returns: the careful parser knows the lines
            _refuse_implausible(bad, lines, fail)
        _warn_about_angle_unit(rec, name)
    return rec


def _row_lines(path: Path, offset: int, size: int, header_line: int, rows: int) -> range | None:
    """The line of every data row when each is one line (no blank line, no lone carriage return), else None.

    Read again, only to name the lines of a file that is refused.
    """
    newlines = 0
    for block in _blocks(path, offset, size):
        data = block.tobytes()
        newlines += data.count(b"\n")
        if data.count(b"\r") != data.count(b"\r\n"):
            return None
    return range(header_line + 1, header_line + 1 + rows) if newlines == rows else None


#: Largest recording file read, in bytes (about 40 million rows of seq,time_s,duty,counts).
MAX_RECORDING_BYTES = 1 << 30

#: Files smaller than this are read by the careful parser alone: importing pyarrow costs about
#: 0.3 s, more than the careful parser takes on such a file (about 10 000 rows).
FAST_PATH_MIN_BYTES = 256 << 10


def _open_recording(path: Path) -> BinaryIO:
    """``path`` opened once it is known to be a regular file of at most :data:`MAX_RECORDING_BYTES`.

    The kind is checked before the file is opened (:func:`motorsim.files.open_input`): a FIFO
    or a device is refused at once, never waited on.
    """
    try:
        return open_input(path, what="recording", max_bytes=MAX_RECORDING_BYTES)
    except InputFileError as exc:
        rule = str(exc).removeprefix(f"recording {path}").lstrip(": ")
        if "bytes is over" in rule:
            rule += "; split it"
        raise RecordingFormatError(f"{path}: {rule}") from None


def _read_bounded(path: Path) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_RECORDING_BYTES`, or RecordingFormatError."""
    try:
        with _open_recording(path) as f:
            data = f.read(MAX_RECORDING_BYTES + 1)
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
                        metadata=extra, reference=values.get("reference"), path=name)
    except (ValueError, TypeError) as exc:
        raise RecordingFormatError(f"{name}: {exc}") from None
    if check_samples:
        bad = rec.implausible_samples()
        if bad:
            _refuse_implausible(bad, [line for line, _ in cols["time_s"]], fail)
        _warn_about_angle_unit(rec, name)
    return rec


def _warn_about_angle_unit(rec: Recording, name: str) -> None:
    """Say when the ``angle_rad`` column reads as another unit (degrees, say): the format states radians."""
    doubt = rec.angle_unit_doubt()
    if doubt is not None:
        warnings.warn(f"{name}: column angle_rad: {doubt.reason}; write the angle in radians",
                      AngleUnitWarning, stacklevel=4)


def _refuse_implausible(bad: Sequence[ImplausibleSample], lines: Sequence[int] | np.ndarray, fail: _Failer) -> None:
    """Refuse the file for rows no motor can produce (``bad``, not empty), naming their lines."""
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
            key = METADATA_ALIASES.get(k.strip(), k.strip())
            if key in meta:
                said = f"{k.strip()!r} (an alias of {key!r})" if key != k.strip() else repr(key)
                same = "again" if meta[key] == v.strip() else f"as {v.strip()!r} after {meta[key]!r}"
                fail(i + 1, f"metadata {said} is given {same}; give each key once")
            meta[key] = v.strip()
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
    if not cell.isascii():
        fail(line, f"column {column!r} must be a plain ASCII number (digits 0-9), got {cell[:40]!r}")
    if "_" in cell:
        fail(line, f"column {column!r} must be a plain number (no '_' digit separators), got {cell!r}")
    if column in INTEGER_COLUMNS:
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
        if not meta["counts_per_rev"].isascii():
            raise ValueError
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
            if not meta["sample_period"].isascii():
                raise ValueError
            sp = float(meta["sample_period"])
            if not (math.isfinite(sp) and sp > 0):
                raise ValueError
        except ValueError:
            fail(1, f"sample_period must be a number > 0 s, got {meta['sample_period']!r}")
        return sp
    if len(time_s) > 1:
        return float(np.median(np.diff(time_s)))
    fail(1, "a one-row recording needs the metadata line '# sample_period: S'")
