"""A lab's own files as a :class:`~motorsim.recording.Recording`: text tables and MATLAB ``.mat``.

:func:`read_table` reads the columns of a text table (CSV, TSV, ``;`` or whitespace
separated, with a header line or none) or of a MATLAB ``.mat`` file (v5 through scipy;
v7.3/HDF5 through h5py when it is installed) or of a robot log (a ROS 2 bag, a WPILib ``.wpilog``:
:mod:`motorsim.robot_logs`); :func:`import_recording` maps its columns,
chosen by name or 0-based index with a unit (:class:`ColumnSpec`, ``"y:deg/s"``), to a
recording through :meth:`Recording.from_columns`.  Units and the timing rule:
:mod:`motorsim.units`.  Every refusal is an :class:`ImportFormatError` naming the file, the
line or column, and the rule.
"""
from __future__ import annotations

import dataclasses
import math
import os
import re
import warnings
from pathlib import Path
from typing import Any, Mapping, NoReturn

import numpy as np

from .checks import ParameterError
from .recording import AngleUnitWarning, Recording, RecordingFormatError
from .robot_logs import is_robot_log, read_log_table
from .units import DEFAULT_UNITS, UNITS

__all__ = ["ColumnSpec", "Table", "read_table", "import_recording", "ImportFormatError", "UNIT_SUFFIXES",
           "UNIT_NAMES", "UNIT_REQUIRED", "unit_in_name", "shift_input", "SECONDS_BEYOND_DOUBT", "MAX_INPUT_SHIFT"]

class ImportFormatError(RecordingFormatError):
    """A foreign file, column or unit that cannot become a recording (the message names which and why)."""


@dataclasses.dataclass(frozen=True)
class ColumnSpec:
    """Which column holds a quantity, and in what unit: ``"NAME[:UNIT]"`` or ``"INDEX[:UNIT]"``.

    Parameters
    ----------
    quantity : str
        ``time``, ``input``, ``angle``, ``counts`` or ``speed``.
    column : str or int
        Column name (header cell, MATLAB variable) or 0-based index.
    unit : str
        One of the quantity's units (:mod:`motorsim.units`).

    Examples
    --------
    >>> ColumnSpec.parse("speed", "y:deg/s")
    ColumnSpec(quantity='speed', column='y', unit='deg/s')
    >>> ColumnSpec.parse("time", "0:ms")
    ColumnSpec(quantity='time', column=0, unit='ms')
    """

    quantity: str
    column: str | int
    unit: str | None

    @classmethod
    def parse(cls, quantity: str, text: str) -> "ColumnSpec":
        """Parse ``"NAME[:UNIT]"``; a column that is a non-negative integer is an index.

        Without ``:UNIT`` the unit is None: :func:`import_recording` takes it from the file's header
        cell (``speed_rpm``, ``w [rad/s]``), else the quantity's default for time and angle, and
        refuses a speed or input column whose unit nothing states.
        """
        if quantity not in UNITS:
            raise ParameterError(f"quantity must be one of {list(UNITS)}, got {quantity!r}")
        column, unit = text, None
        if ":" in text:
            column, unit = text.rsplit(":", 1)
            unit = unit.strip()
            if unit not in UNITS[quantity]:
                raise ParameterError(f"the unit of the {quantity} column must be one of {list(UNITS[quantity])}, "
                                     f"got {unit!r} (in {text!r})")
        column = column.strip()
        if not column:
            raise ParameterError(f"the {quantity} column needs a name or a 0-based index, got {text!r}")
        return cls(quantity, int(column) if column.isdigit() else column, unit)


#: Quantities whose column must say its unit (a flag's ``:UNIT`` or the header cell): no default is safe.
UNIT_REQUIRED = ("speed", "input")


#: the end of a column name -> the unit it says, per quantity (``time_ms``, ``speed_rpm``, ``u_pct`` ...)
UNIT_SUFFIXES: dict[str, dict[str, str]] = {
    "time": {"s": "s", "sec": "s", "ms": "ms", "msec": "ms", "us": "us", "usec": "us", "µs": "us", "μs": "us"},
    "input": {"duty": "duty", "pwm": "duty", "v": "V", "volt": "V", "volts": "V", "pct": "%", "percent": "%"},
    "speed": {"rpm": "rpm", "degs": "deg/s", "deg_s": "deg/s", "dps": "deg/s", "rads": "rad/s", "rad_s": "rad/s",
              "revs": "rev/s", "rev_s": "rev/s", "rps": "rev/s"},
    "angle": {"rad": "rad", "deg": "deg", "degs": "deg", "rev": "rev", "revs": "rev", "counts": "counts",
              "cnt": "counts"},
    "counts": {},
}


#: a column named by its unit alone (``rpm``, ``ms``, ``pwm``): the names no other quantity or unit shares (not
#: ``s`` or ``v``, which a column of speed or velocity may be called)
UNIT_NAMES: dict[str, dict[str, str]] = {
    "time": {"ms": "ms", "msec": "ms", "millis": "ms", "us": "us", "usec": "us", "micros": "us", "µs": "us",
             "μs": "us", "sec": "s", "seconds": "s"},
    "input": {"volts": "V", "pct": "%", "percent": "%"},
    "speed": {"rpm": "rpm", "rps": "rev/s", "dps": "deg/s"},
    "angle": {},
    "counts": {},
}


def unit_in_name(quantity: str, column: str) -> str | None:
    """The unit a column's name ends with (``time_ms`` -> ``ms``), or None.

    Examples
    --------
    >>> unit_in_name("speed", "w_degs"), unit_in_name("input", "u_pct"), unit_in_name("time", "t")
    ('deg/s', '%', None)
    >>> unit_in_name("speed", "rpm"), unit_in_name("time", "millis"), unit_in_name("speed", "v")
    ('rpm', 'ms', None)
    """
    words = [w for w in re.split(r"[_\-\s\[\]()./]+", column.lower()) if w]
    if len(words) == 1:
        return UNIT_NAMES.get(quantity, {}).get(words[0])
    if len(words) < 2:
        return None
    suffixes = UNIT_SUFFIXES.get(quantity, {})
    return suffixes.get("_".join(words[-2:])) or suffixes.get(words[-1])


#: Spellings of one unit.
_SAME_UNIT = {"µs": "us", "μs": "us"}


def _resolve_unit(table: "Table", spec: ColumnSpec) -> tuple[ColumnSpec | None, str]:
    """``spec`` with its unit and where the unit came from (``given``, ``header``, ``default``), or
    None and the problem when nothing states the unit of a speed or input column."""
    header = spec.column if isinstance(spec.column, str) else (
        table.names[spec.column] if table.has_header and spec.column < len(table.names) else None)
    stated = None if header is None else (table.units.get(header) or unit_in_name(spec.quantity, header))
    if spec.unit is not None:
        if stated is not None and _SAME_UNIT.get(stated, stated) != _SAME_UNIT.get(spec.unit, spec.unit):
            return None, (f"the {spec.quantity} column {header!r} is in {stated}, as the file states, but "
                          f"--{spec.quantity} gives {spec.unit}: one of them is wrong; give the unit the "
                          "values are in")
        return spec, "given"
    if stated is not None and stated not in UNITS[spec.quantity]:
        return None, (f"the {spec.quantity} column {spec.column!r} is in {stated}, as the file states, which is not "
                      f"a unit of the {spec.quantity} ({', '.join(UNITS[spec.quantity])})")
    if stated is not None:
        return dataclasses.replace(spec, unit=stated), "header"
    if spec.quantity not in UNIT_REQUIRED:
        return dataclasses.replace(spec, unit=DEFAULT_UNITS[spec.quantity]), "default"
    units = ", ".join(u for u in UNITS[spec.quantity] if u != "μs")
    return None, (f"the {spec.quantity} column {spec.column!r} has no unit and the file does not state one: give "
                  f"--{spec.quantity} {spec.column}:UNIT with UNIT one of {units}")


@dataclasses.dataclass(frozen=True)
class Table:
    """Named numeric columns read from a file, with the file line of each row (1-based; 0 for .mat)."""

    path: str
    names: tuple[str, ...]
    columns: tuple[np.ndarray, ...]
    lines: np.ndarray
    has_header: bool
    units: Mapping[str, str] = dataclasses.field(default_factory=dict)   # the units the file states, by column
    #: A text table with empty cells (held as nan): columns logged at different times, each row holding the
    #: values logged at its instant (a plotting tool's export of topics); :func:`import_recording` aligns them.
    sparse: bool = False

    def column(self, spec: ColumnSpec) -> np.ndarray:
        """The column ``spec`` names (by name, else by 0-based index); :class:`ImportFormatError` if none."""
        return self.columns[self.index(spec)]

    def index(self, spec: ColumnSpec) -> int:
        """The 0-based index of the column ``spec`` names; :class:`ImportFormatError` if none."""
        if isinstance(spec.column, str):
            if spec.column in self.names:
                return self.names.index(spec.column)
            raise ImportFormatError(f"{self.path}: no column named {spec.column!r} for the {spec.quantity} "
                                    f"(columns: {', '.join(self.names)}; or give a 0-based index)")
        if spec.column < len(self.columns):
            return spec.column
        raise ImportFormatError(f"{self.path}: column index {spec.column} for the {spec.quantity} is out of range "
                                f"(the file has {len(self.columns)} columns, 0-based)")


def _fail(path: str, line: int, rule: str) -> NoReturn:
    raise ImportFormatError(f"{path}, line {line}: {rule}")


_SEPARATORS = (",", "\t", ";")


def _split(line: str, sep: str | None) -> list[str]:
    return [c.strip().strip('"').strip("'").strip() for c in (line.split(sep) if sep else line.split())]


def _number(cell: str) -> float | None:
    try:
        return float(cell)
    except ValueError:
        return None


#: The largest foreign file read, in bytes (that of a recording).
MAX_TABLE_BYTES = 1 << 30


def _read_bytes(path: str) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_TABLE_BYTES` (FIFOs and devices refused, not waited on)."""
    from .files import InputFileError, read_input_bytes
    try:
        return read_input_bytes(path, what="file", max_bytes=MAX_TABLE_BYTES)
    except InputFileError as exc:
        message = str(exc).removeprefix("file ").replace(": cannot read: No such file or directory", ": no such file")
        raise ImportFormatError(message) from None
    except OSError as exc:
        raise ImportFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None


#: The error values of Excel, LibreOffice and Google Sheets (#N/A, #VALUE!, #DIV/0!, #NAME? ...).
_SPREADSHEET_ERROR = re.compile(r"#(?:N/A|NA|[A-Z][A-Z0-9_/]*[!?]|GETTING_DATA)(?:[\s,;\t]|$)")


#: The timestamp the Arduino IDE's serial monitor puts before each line it shows (``12:00:01.005 -> ``).
_SERIAL_MONITOR_STAMP = re.compile(r"^\d{1,2}:\d{2}:\d{2}\.\d{3} -> ")
#: A number written with a decimal comma (a spreadsheet's export in a European locale: ``0,005``).
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")
#: Rows at the start of a file a separator is taken from: the one most of them hold.
_SNIFF_ROWS = 50


def _decode(path: str, data: bytes) -> str:
    """UTF-8 (a BOM allowed), or UTF-16 where its BOM says so (a spreadsheet's "Unicode text" export)."""
    try:
        if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
            return data.decode("utf-16")
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ImportFormatError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None


def _as_written(lines: list[str]) -> list[str]:
    """The table in lines as other tools write it: a LabVIEW measurement file (``.lvm``) from its last header
    block's channel names on, an Arduino serial monitor's timestamps taken off each line."""
    if lines and lines[0].startswith("LabVIEW Measurement"):
        ends = [i for i, line in enumerate(lines) if line.strip().startswith("***End_of_Header***")]
        if ends:
            lines = [""] * (ends[-1] + 1) + lines[ends[-1] + 1:]      # line numbers kept
    first = next((line for line in lines if line.strip()), "")
    if _SERIAL_MONITOR_STAMP.match(first):
        lines = [_SERIAL_MONITOR_STAMP.sub("", line) for line in lines]
    return lines


def _read_text(path: str) -> Table:
    text = _decode(path, _read_bytes(path))
    lines = _as_written(text.splitlines())
    # a line starting with # or % is a comment, unless it starts with a spreadsheet's error value (#N/A): a row
    rows = [(i + 1, s) for i, s in enumerate(lines)
            if s.strip() and (s.lstrip()[0] not in "#%" or _SPREADSHEET_ERROR.match(s.lstrip()))]
    if not rows:
        raise ImportFormatError(f"{path}: no data rows (blank lines and lines starting with # or % are skipped)")
    counts = {s: sum(s in line for _, line in rows[:_SNIFF_ROWS]) for s in _SEPARATORS}
    sep = max(_SEPARATORS, key=lambda s: counts[s]) if max(counts.values()) > 0 else None
    if sep is not None and counts[sep] > len(rows[:_SNIFF_ROWS]) // 2:
        while rows and sep not in rows[0][1]:     # a preamble ('Starting...') before the table: no row of it
            rows = rows[1:]
    if not rows:
        raise ImportFormatError(f"{path}: no data rows (blank lines and lines starting with # or % are skipped)")
    first = rows[0][1]
    sep = sep if sep is not None and sep in first else next((s for s in _SEPARATORS if s in first), None)
    head = _split(first, sep)
    has_header = any(_number(c) is None for c in head)
    names = tuple(head) if has_header else tuple(str(i) for i in range(len(head)))
    if has_header:
        rows = rows[1:]
    if len(set(names)) != len(names):
        _fail(path, rows[0][0] - 1 if rows else 1, f"the header repeats a column name ({', '.join(names)})")
    if has_header and rows and names and names[-1] == "Comment" and len(_split(rows[0][1], sep)) == len(names) - 1:
        names = names[:-1]                        # LabVIEW's comment column, empty on every row
    decimal_comma = sep in (";", "\t") and bool(rows) and any(_DECIMAL_COMMA.match(c) for c in _split(rows[0][1], sep))
    values = np.empty((len(rows), len(names)))
    sparse = False
    for r, (line, s) in enumerate(rows):
        cells = _split(s, sep)
        if len(cells) != len(names):
            _fail(path, line, f"{len(cells)} cells where the {'header' if has_header else 'first row'} has "
                              f"{len(names)}")
        for c, cell in enumerate(cells):
            if not cell:               # nothing logged in this column at this row's instant: aligned on import
                values[r, c] = math.nan
                sparse = True
                continue
            x = _number(cell.replace(",", ".") if decimal_comma else cell)
            if x is None or not math.isfinite(x):
                said = " (a spreadsheet's error value: fix or delete the row where the file was made)" \
                    if _SPREADSHEET_ERROR.match(cell) else ""
                _fail(path, line, f"column {names[c]!r} must hold a finite number, got {cell!r}{said}")
            values[r, c] = x
    if not rows:
        raise ImportFormatError(f"{path}: a header but no data rows")
    return Table(path, names, tuple(values.T.copy()), np.array([line for line, _ in rows]), has_header,
                 sparse=sparse)


def _read_mat(path: str) -> Table:
    """A MATLAB file's variables as a table (:mod:`motorsim.mat_files`: only this file read, memory bounded,
    in a process of its own)."""
    from .mat_files import MatFileRefused, read_mat_variables
    raw = _read_bytes(path)
    if not raw:
        raise ImportFormatError(f"{path}: an empty file (0 bytes), not a MATLAB .mat file")
    try:
        variables = read_mat_variables(raw)
    except MatFileRefused as exc:
        raise ImportFormatError(f"{path}: {exc}") from None
    return _table_from_variables(path, variables)


def _table_from_variables(path: str, variables: Mapping[str, Any]) -> Table:
    """Vectors become columns by name; a single numeric matrix gives its columns by index."""
    numeric = {k: np.asarray(v) for k, v in variables.items()
               if isinstance(v, np.ndarray) and v.dtype.kind in "biuf" and v.size > 1}
    vectors = {k: v.ravel().astype(float) for k, v in numeric.items() if v.ndim == 2 and 1 in v.shape}
    matrices = {k: v for k, v in numeric.items() if k not in vectors and v.ndim == 2}
    if not vectors and len(matrices) == 1:
        (name, m), = matrices.items()
        if m.shape[0] < m.shape[1]:
            m = m.T
        cols = tuple(m[:, i].astype(float) for i in range(m.shape[1]))
        return Table(path, tuple(str(i) for i in range(len(cols))), cols, np.zeros(len(cols[0]), int), False)
    if not vectors:
        raise ImportFormatError(f"{path}: no numeric vector variables (found: {', '.join(variables) or 'none'}); "
                                "save each column as its own vector, or one N-by-k matrix")
    return Table(path, tuple(vectors), tuple(vectors.values()), np.zeros(max(map(len, vectors.values())), int),
                 True)


def read_table(path: str | os.PathLike) -> Table:
    """The numeric columns of a text table or a MATLAB ``.mat`` file.

    Parameters
    ----------
    path : str or path-like
        ``.mat`` (v5 through scipy; v7.3 needs h5py), else text: columns separated by
        commas, tabs, semicolons or whitespace (decided on the first row); the first row is
        a header when a cell is not a number; blank lines and lines starting with ``#`` or
        ``%`` are skipped.

    Returns
    -------
    Table
        Columns by name (header cells, MATLAB variables; ``"0"``, ``"1"``, ... without a header).

    Raises
    ------
    ImportFormatError
        Naming the file, the line and the column of what cannot be read.
    """
    path = os.fspath(path)
    if is_robot_log(path):
        return _read_log(path, None)
    if path.lower().endswith(".mat"):
        return _read_mat(path)
    return _read_text(path)


def import_recording(path: str | os.PathLike, *, time: str | ColumnSpec, input: str | ColumnSpec,
                     speed: str | ColumnSpec | None = None, angle: str | ColumnSpec | None = None,
                     counts: str | ColumnSpec | None = None, counts_per_rev: int | None = None,
                     input_shift: int = 0) -> Recording:
    """Read a foreign file and map its columns to a :class:`Recording`.

    Parameters
    ----------
    path : str or path-like
        Text table or ``.mat`` file (:func:`read_table`).
    time, input : str or ColumnSpec
        ``"NAME[:UNIT]"`` or ``"INDEX[:UNIT]"``: the time and input columns.
    speed, angle, counts : str or ColumnSpec, optional
        The measured quantity (at least one), in the same form.
    counts_per_rev : int, optional
        Encoder resolution in counts/rev, for counts (or an angle in ``counts``).
    input_shift : int
        Move the input this many rows earlier (:func:`shift_input`): a log whose command is written
        just after the state it answers needs 1.

    A time column whose unit nothing states is read in s only where its intervals leave no doubt
    (a median below :data:`SECONDS_BEYOND_DOUBT`, said by a warning); otherwise it is refused as
    an unlabelled speed is.  Every problem of the columns is named in one message.

    Returns
    -------
    Recording
        With the metadata ``source`` (the file name) and ``input_unit``.

    Examples
    --------
    >>> from pathlib import Path
    >>> _ = Path("lab.csv").write_text("t,u,y\\n0,1.5,0\\n20,1.5,90\\n40,2.7,180\\n")
    >>> rec = import_recording("lab.csv", time="t:ms", input="u:V", speed="y:deg/s")
    >>> rec.sample_period, rec.input_unit, rec.speed.round(4).tolist()
    (0.02, 'V', [0.0, 1.5708, 3.1416])
    """
    path = os.fspath(path)
    specs: dict[str, ColumnSpec] = {}
    problems: list[str] = []
    for quantity, spec in (("time", time), ("input", input), ("speed", speed), ("angle", angle),
                           ("counts", counts)):
        if spec is not None:
            try:
                specs[quantity] = spec if isinstance(spec, ColumnSpec) else ColumnSpec.parse(quantity, spec)
            except ValueError as exc:
                problems.append(str(exc))
    if speed is None and angle is None and counts is None:
        problems.append("give the speed, angle or counts column")
    if is_robot_log(path):
        base = next((specs[q].column for q in ("speed", "angle", "counts") if q in specs), None)
        table = _read_log(path, base if isinstance(base, str) else None)
    else:
        table = read_table(path)
    problems += _shared_columns(table, specs)
    cols, defaulted, notes = _columns_read(table, specs, problems)
    if table.sparse and not problems:
        table, cols = _aligned(table, specs, cols, problems, notes)
    if "time" in defaulted:
        _time_unit_inferred(specs["time"], cols["time"], problems, notes)
    if not problems:
        problems += _counts_problems(table, specs, cols, counts_per_rev)
    if "time" in cols and specs["time"].unit is not None:
        problems += _time_problems(table, specs["time"], cols["time"])
    if problems:
        _refuse(path, problems)
    for note in notes:                 # said once the file is accepted
        warnings.warn(note, UserWarning, stacklevel=2)
    rec = _recording(path, specs, cols, counts_per_rev, angle_stated="angle" not in defaulted)
    return shift_input(rec, input_shift)


#: The median interval (in the column's own numbers) below which a time column without a unit is read in s with
#: no doubt: 0.05 s is a 20 Hz log, 0.05 ms a 20 kHz one no logger of a motor writes, 0.05 us none at all.
SECONDS_BEYOND_DOUBT = 0.05
#: Below this median interval a time column without a unit is in doubt too (100 kHz as seconds).
_SECONDS_FLOOR = 1e-5


def _median_interval(t: np.ndarray) -> float:
    steps = np.diff(t[np.isfinite(t)])
    return float(np.median(steps)) if len(steps) else math.nan


def _time_unit_doubt(spec: ColumnSpec, t: np.ndarray) -> str | None:
    """The problem of a time column with no unit whose intervals leave its unit in doubt, or None."""
    step = _median_interval(t)
    if not math.isfinite(step) or step <= 0 or _SECONDS_FLOOR <= step <= SECONDS_BEYOND_DOUBT:
        return None                   # too short or not increasing: said where the time is checked
    return (f"the time column {spec.column!r} has no unit and the file does not state one; its median interval "
            f"{step:.6g} leaves it in doubt ({step:.6g} s, or ms, or us?): give --time {spec.column}:UNIT with "
            "UNIT one of s, ms, us")


def _columns_read(table: Table, specs: dict[str, ColumnSpec], problems: list[str]
                  ) -> tuple[dict[str, np.ndarray], set[str], list[str]]:
    """Each named column, its unit resolved into ``specs``: the columns, the quantities left to their default
    unit, and the notes to say once the file is accepted; every problem appended to ``problems``."""
    cols = {}
    defaulted = set()
    notes: list[str] = []
    for quantity, spec in list(specs.items()):
        try:
            cols[quantity] = table.column(spec)
        except ImportFormatError as exc:
            problems.append(str(exc))
            continue
        resolved, source = _resolve_unit(table, spec)
        if resolved is None:
            problems.append(source)
            continue
        specs[quantity] = resolved
        if source == "default":
            defaulted.add(quantity)
        elif source == "header" and (quantity in UNIT_REQUIRED or resolved.unit != DEFAULT_UNITS[quantity]):
            notes.append(f"the {quantity} column {spec.column!r} is read in {resolved.unit}, the unit its header "
                         "states")
    return cols, defaulted, notes


def _aligned(table: Table, specs: Mapping[str, ColumnSpec], cols: Mapping[str, np.ndarray], problems: list[str],
             notes: list[str]) -> tuple[Table, dict[str, np.ndarray]]:
    """A table with empty cells read as PlotJuggler's users expect of its CSV export (each row holds the values
    logged at its instant, the other cells empty): a sample at each row where every measured column holds a
    value, its input the one in force over most of the interval to the next sample (the last logged at or
    before the interval's middle, held as a drive holds its command: a command logged just after the state it
    answers drives the interval that state starts).  Rows with no measurement, and samples with no input logged
    yet, are left out; what was done is said in ``notes``.  An empty time cell is a problem (every row has its
    instant)."""
    n = len(table.lines)
    measured = [q for q in ("speed", "angle", "counts") if q in cols]
    empty = {q: ~np.isfinite(cols[q]) for q in cols}
    if not any(e.any() for e in empty.values()):
        return table, dict(cols)
    if empty["time"].any():
        k = int(np.flatnonzero(empty["time"])[0])
        problems.append(f"{_where(table, specs['time'], k)}: the time cell is empty; every row needs its instant")
        return table, dict(cols)
    t = cols["time"]
    logged = np.flatnonzero(~empty["input"])
    if not len(logged):
        problems.append(f"the input column {specs['input'].column!r} holds no value (every cell empty)")
        return table, dict(cols)
    if np.any(np.diff(t) <= 0):
        return table, dict(cols)          # refused where the time is checked, naming the row
    rows = np.flatnonzero(np.logical_and.reduce([~empty[q] for q in measured]))
    what = " and ".join(f"{q} ({specs[q].column!r})" for q in measured)
    if len(rows) < 2:
        problems.append(f"cells are empty and only {len(rows)} row(s) hold the {what}: nothing to align")
        return table, dict(cols)
    start = t[rows]
    end = np.empty(len(rows))
    end[:-1] = start[1:]
    end[-1] = start[-1] + (start[-1] - start[-2])
    tc, uc = t[logged], cols["input"][logged]
    area = np.concatenate([[0.0], np.cumsum(uc[:-1] * np.diff(tc))])      # the input's integral to each command

    def integral(x: np.ndarray) -> np.ndarray:
        j = np.maximum(np.searchsorted(tc, x, side="right") - 1, 0)
        return area[j] + uc[j] * (x - tc[j])
    ok = start >= tc[0]
    kept = rows[ok]
    if len(kept) < 2:
        problems.append(f"cells are empty and only {len(kept)} row(s) hold the {what} with an input logged by "
                        "then: nothing to align")
        return table, dict(cols)
    mean = (integral(end[ok]) - integral(start[ok])) / (end[ok] - start[ok])
    changes = np.searchsorted(tc, start[ok], side="right") != np.searchsorted(tc, end[ok], side="left")
    out = {q: (mean if q == "input" else c[kept]) for q, c in cols.items()}
    early = len(rows) - len(kept)
    notes.append(f"cells are empty (columns logged at different times, as PlotJuggler exports topics): read as "
                 f"{len(kept)} samples at the rows holding the {what}, each with the input held from the last one "
                 f"logged (as a drive holds its command), averaged over the sample's interval where a new one came "
                 f"within it ({int(np.count_nonzero(changes))} samples); {n - len(kept)} of {n} rows left out (no "
                 f"{' or '.join(measured)} in them" + (f", or {early} before any input" if early else "") + ")")
    return dataclasses.replace(table, lines=table.lines[kept], columns=tuple(c[kept] for c in table.columns),
                               sparse=False), out


def _time_unit_inferred(spec: ColumnSpec, t: np.ndarray, problems: list[str], notes: list[str]) -> None:
    """A time column read in s by default: a problem when its intervals leave that in doubt, else a note."""
    doubt = _time_unit_doubt(spec, t)
    if doubt:
        problems.append(doubt)
    else:
        notes.append(f"the time column {spec.column!r} has no unit: read in s, as its intervals (median "
                     f"{_median_interval(t):.6g}) leave no doubt; give --time {spec.column}:UNIT if they are not "
                     "seconds")


def shift_input(rec: Recording, rows: int) -> Recording:
    """``rec`` with its input moved ``rows`` samples earlier (later when negative): a log whose command is written
    just after the state it answers.  Each sample takes the input logged ``rows`` samples after it (by ``seq``);
    samples with none logged there are dropped (they become gaps), and the metadata say ``input_shift_rows``.

    Examples
    --------
    >>> rec = Recording(time=np.arange(5) * 0.01, duty=[0, 0, 5, 5, 5], sample_period=0.01, speed=[0, 0, 0, 1, 2])
    >>> shifted = shift_input(rec, 1)
    >>> shifted.duty.tolist(), shifted.seq.tolist(), shifted.metadata["input_shift_rows"]
    ([0.0, 5.0, 5.0, 5.0], [0, 1, 2, 3], '1')
    """
    if isinstance(rows, bool) or not isinstance(rows, (int, np.integer)) or not -MAX_INPUT_SHIFT <= rows <= \
            MAX_INPUT_SHIFT:
        raise ParameterError(f"input shift must be a whole number of rows in -{MAX_INPUT_SHIFT}...{MAX_INPUT_SHIFT}, "
                             f"got {rows!r}")
    if rows == 0:
        return rec
    k = np.searchsorted(rec.seq, rec.seq + rows)
    k = np.minimum(k, len(rec) - 1)
    have = rec.seq[k] == rec.seq + rows
    if have.sum() < 2:
        raise ParameterError(f"input shift of {rows} rows leaves fewer than 2 samples of the {len(rec)}")
    kept = np.flatnonzero(have)

    def cut(x):
        return None if x is None else x[kept]
    return dataclasses.replace(rec, time=rec.time[kept], duty=rec.duty[k[kept]], counts=cut(rec.counts),
                               angle=cut(rec.angle), speed=cut(rec.speed), seq=rec.seq[kept],
                               reference=cut(rec.reference),
                               metadata={**rec.metadata, "input_shift_rows": str(int(rows))})


#: The largest input shift, in rows.
MAX_INPUT_SHIFT = 10_000


def _shared_columns(table: Table, specs: Mapping[str, ColumnSpec]) -> list[str]:
    """One column named for two quantities (``--speed y --angle y``): one of them is wrong."""
    taken: dict[int, str] = {}
    problems = []
    for quantity, spec in specs.items():
        try:
            k = table.index(spec)
        except ImportFormatError:
            continue                 # named as missing where the column is read
        if k in taken:
            name = table.names[k] if k < len(table.names) else str(k)
            problems.append(f"column {name!r} is named both as the {taken[k]} (--{taken[k]}) and as the "
                            f"{quantity} (--{quantity}); each column has one role")
        else:
            taken[k] = quantity
    return problems


def _read_log(path: str, base: str | None) -> Table:
    """A robot log (:mod:`motorsim.robot_logs`) as a table whose rows are ``base``'s messages (the log's
    longest entry's when it has no ``base``: every column named wrong is then said at once)."""
    try:
        try:
            names, columns, units = read_log_table(path, base)
        except RecordingFormatError as exc:
            if base is None or f"no column named {base!r}" not in str(exc):
                raise
            names, columns, units = read_log_table(path, None)
    except RecordingFormatError as exc:
        raise ImportFormatError(str(exc)) from None
    return Table(path, names, columns, np.zeros(len(columns[0]), dtype=int), True, units)


def _refuse(path: str, problems: list[str]) -> NoReturn:
    """Every problem of the columns in one message (each named by the file once)."""
    bare = [p.removeprefix(f"{path}: ").removeprefix(f"{path}, ") for p in problems]
    if len(problems) == 1:
        raise ImportFormatError(problems[0] if problems[0].startswith(path) else f"{path}: {problems[0]}")
    raise ImportFormatError(f"{path}: {len(problems)} problems with the columns: "
                            + "; ".join(f"({k}) {p}" for k, p in enumerate(bare, 1)))


def _recording(path: str, specs: Mapping[str, ColumnSpec], cols: Mapping[str, np.ndarray],
               counts_per_rev: int | None, *, angle_stated: bool) -> Recording:
    """The recording of checked columns, with the units the user brought in its metadata."""
    units = {q: str(s.unit) for q, s in specs.items()}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AngleUnitWarning)     # said below, by the column's name and flag
            rec = Recording.from_columns(
                time=cols["time"], duty=cols["input"], speed=cols.get("speed"), angle=cols.get("angle"),
                counts=cols.get("counts"), counts_per_rev=counts_per_rev, input_unit=units["input"],
                time_unit=units["time"], metadata={"source": Path(path).name},
                speed_unit=units.get("speed", "rad/s"), angle_unit=units.get("angle", "rad"))
    except ValueError as exc:
        raise ImportFormatError(f"{path}: {exc}") from None
    rec = dataclasses.replace(rec, path=str(path))       # every later refusal names the file
    if "angle" in specs and units["angle"] == "rad":
        _check_angle_unit(path, rec, specs["angle"], stated=angle_stated)
    return rec


def _check_angle_unit(path: str, rec: Recording, spec: ColumnSpec, *, stated: bool) -> None:
    """An angle column read as radians that reads as another unit: refused when its unit was left to the
    default, said (:class:`~motorsim.recording.AngleUnitWarning`) when radians were stated."""
    doubt = rec.angle_unit_doubt()
    if doubt is None:
        return
    column = spec.column
    likely = {"deg": f"{column}:deg", "rev": f"{column}:rev",
              "counts": f"{column}:counts with --counts-per-rev N (or {column}:deg)"}.get(doubt.unit or "")
    if stated:
        warnings.warn(f"the angle column {column!r}, stated in rad: {doubt.reason}; if it is not in "
                      f"radians give --angle {likely or f'{column}:UNIT'}", AngleUnitWarning, stacklevel=3)
        return
    fix = f"give --angle {likely}" if likely else f"give its unit, --angle {column}:UNIT, and check the speed's"
    raise ImportFormatError(f"{path}: the angle column {column!r}, read as rad (no unit given): {doubt.reason}; "
                            f"{fix} ({column}:rad if it really is in radians)")


def _where(table: Table, spec: ColumnSpec, k: int) -> str:
    line = int(table.lines[k]) if k < len(table.lines) else 0
    place = f"line {line}" if line else f"element {k}"
    return f"{table.path}, {place}, column {spec.column!r} ({spec.quantity})"


def _time_problems(table: Table, spec: ColumnSpec, t: np.ndarray) -> list[str]:
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        return [f"{_where(table, spec, k)}: time must be strictly increasing, got {float(t[k])!r} after "
                f"{float(t[k - 1])!r}"]
    return []


def _counts_problems(table: Table, specs: Mapping[str, ColumnSpec], cols: Mapping[str, np.ndarray],
                     counts_per_rev: int | None) -> list[str]:
    spec = specs.get("counts") or (specs["angle"] if "angle" in specs and specs["angle"].unit == "counts" else None)
    if spec is None:
        return []
    if counts_per_rev is None:
        return [f"counts in column {spec.column!r} need the encoder resolution (--counts-per-rev N, counts/rev)"]
    x = cols[spec.quantity]
    bad = np.flatnonzero(x != np.round(x))
    if len(bad):
        k = int(bad[0])
        return [f"{_where(table, spec, k)}: counts must be integers, got {float(x[k])!r}"]
    return []
