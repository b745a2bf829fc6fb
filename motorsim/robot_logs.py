"""Robot software's logs as tables of columns: ROS 2 bags and WPILib data logs (``.wpilog``).

:func:`read_log_table` turns a log into the same :class:`~motorsim.columns.Table` a CSV gives,
so :func:`~motorsim.columns.import_recording` maps it with the same column flags, unit rules
and refusals.  The rows are the messages of the *base* entry (the measured speed or angle);
every other column holds, at each row, the last value logged at or before it (the command a
drive was applying), and rows before the first value of a column are dropped.  A column
``time_s`` holds each row's log time in s.

ROS 2 bag (a folder with ``metadata.yaml``, or its ``.db3``/``.mcap`` file; optional extra
``ros``: the pure-Python ``rosbags``)
    A ``sensor_msgs/msg/JointState`` topic gives ``TOPIC/JOINT/position``, ``.../velocity`` and
    ``.../effort`` (time from the message header); by REP 103 a revolute joint's position is in
    rad and its velocity in rad/s, so those units are stated by the file.  A ``std_msgs`` number
    (``Float64``, ``Float32``, ``Int*``) gives ``TOPIC``, a ``Float64MultiArray`` ``TOPIC/0``,
    ``TOPIC/1``, ... (time: the bag's receive time); their unit is not stated.
WPILib data log (``.wpilog``; optional extra ``wpilib``: ``robotpy-wpiutil``'s ``DataLogReader``)
    Every ``double``, ``float`` and ``int64`` entry is a column by its name (``voltage-drive``,
    ``velocity-drive``: the entries SysId's ``SysIdRoutineLog`` writes), time from the record
    timestamps (µs).  An entry's metadata naming a unit (SysId writes ``Volt``, ``Rotation per
    Second``, ...) states it.  A string entry ``sysid-test-state-...`` marks the tests: rows
    logged while it says ``none`` are dropped.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .recording import RecordingFormatError

__all__ = ["is_robot_log", "read_log_table", "check_wpilog_records", "WPILIB_UNITS", "ROS_EXTRA", "WPILIB_EXTRA",
           "MAX_LOG_BYTES"]

#: The largest robot log file read, in bytes: its records, held as numbers, take some five times its size.
MAX_LOG_BYTES = 256 << 20

#: What ``pip install`` needs for each kind of log (the optional extras of pyproject.toml).
ROS_EXTRA = "rosbags>=0.10,<0.12"
WPILIB_EXTRA = "robotpy-wpiutil>=2025.1,<2027"

#: WPILib unit names (an entry's metadata, as SysId writes it) -> motorid's units.
WPILIB_UNITS = {"volt": "V", "volts": "V", "v": "V", "percent": "%",
                "rotation per second": "rev/s", "rotations per second": "rev/s", "rotations-per-second": "rev/s",
                "radian per second": "rad/s", "radians per second": "rad/s", "degree per second": "deg/s",
                "degrees per second": "deg/s", "revolutions per minute": "rpm", "rpm": "rpm",
                "rotation": "rev", "rotations": "rev", "radian": "rad", "radians": "rad", "degree": "deg",
                "degrees": "deg"}

_NUMBER_TYPES = {"double", "float", "int64"}


def is_robot_log(path: str) -> bool:
    """Whether ``path`` is a ROS 2 bag (folder, ``.db3``, ``.mcap``) or a WPILib ``.wpilog``."""
    p = Path(path)
    return p.suffix.lower() in (".wpilog", ".db3", ".mcap") or (p.is_dir() and (p / "metadata.yaml").is_file())


def _missing(path: str, what: str, requirement: str, extra: str) -> Exception:
    return RecordingFormatError(f"{path}: reading {what} needs {requirement.split('>')[0]} "
                             f"(pip install '{requirement}', or motorid's extra: pip install -e '.[{extra}]')")


def read_log_table(path: str | os.PathLike, base: str | None) -> tuple[tuple[str, ...], tuple[np.ndarray, ...],
                                                                        dict[str, str]]:
    """The columns of a robot log, one row per message of ``base``: names, columns, the units the log states.

    Parameters
    ----------
    path : str or path-like
        A ROS 2 bag or a ``.wpilog``.
    base : str or None
        The column whose messages are the rows (the measured speed or angle); None: the column with
        the most messages.

    Raises
    ------
    RecordingFormatError
        The reader is not installed, the file cannot be read, or ``base`` is not one of its columns.
    """
    path = os.fspath(path)
    _check_inputs(path)
    if Path(path).suffix.lower() == ".wpilog":
        whole = check_wpilog_records(path)
        series, units, keep = _wpilog_series(path, whole)
    else:
        series, units, keep = _bounded_ros_series(path), {}, None
        units = {name: unit for name in series for suffix, unit in (("/position", "rad"), ("/velocity", "rad/s"))
                 if name.endswith(suffix) and name.count("/") >= 2}
    return _table(path, series, units, base, keep)


def _check_inputs(path: str) -> None:
    """A log's files are regular files of at most :data:`MAX_LOG_BYTES` (a FIFO would block its reader, a
    device never end, a sparse file of gigabytes take minutes): refused before any reader opens them."""
    from .files import InputFileError, open_input
    p = Path(path)
    folder = p if p.is_dir() else p.parent if p.suffix.lower() in (".db3", ".mcap") else None
    files = [p]
    if folder is not None:      # a bag's reader reads its folder: its metadata and every database file in it
        files = [q for q in sorted(folder.iterdir()) if not q.is_dir()
                 and (q.name == "metadata.yaml" or q.suffix.lower() in (".db3", ".mcap"))]
        inside = folder.resolve()
        for q in files:
            if q.is_symlink() and inside not in q.resolve().parents:
                raise RecordingFormatError(f"{q}: a link to {os.readlink(q)!r}, outside the bag's folder "
                                           f"{str(folder)!r}; motorid reads only the log it is given: copy the "
                                           "file into the folder")
    for name in files:
        try:
            open_input(name, what="log", max_bytes=MAX_LOG_BYTES).close()
        except InputFileError as exc:
            raise RecordingFormatError(str(exc).removeprefix("log ")) from None


#: Payload bytes of a value of each number type.
_WPILOG_SIZES = {"double": 8, "float": 4, "int64": 8}


def check_wpilog_records(path: str) -> int | None:
    """Walk a ``.wpilog``'s records and refuse one that is malformed, before the reader sees them.

    The record layout is WPILib's data log format (version 1.0): a header byte giving the lengths
    of the entry id, payload size and timestamp, then those fields and the payload; entry 0 holds
    the control records (start, finish, set metadata).  A record whose declared length runs past
    the end of the file ends the log there (a log cut off while written): said as a warning, the
    records before it kept.  Anything else malformed -- a control record of the wrong length, a
    number whose payload is not the size of its type, a name that is not UTF-8 -- is refused,
    naming the byte.

    Returns
    -------
    int or None
        The bytes of whole records when the log ends inside one (the reader is given only those: given the
        rest it read the cut record's bytes as one more value); None when every record is whole.

    Raises
    ------
    RecordingFormatError
        Naming the file, the byte offset and the rule.
    """
    import warnings

    from .files import read_input_bytes
    data = read_input_bytes(path, what="log", max_bytes=MAX_LOG_BYTES)
    if len(data) < 12 or data[:6] != b"WPILOG":
        return None                              # not a data log: the reader says so
    pos = 12 + int.from_bytes(data[8:12], "little")
    end = len(data)
    types: dict[int, tuple[str, str]] = {}

    def fail(at: int, rule: str) -> None:
        raise RecordingFormatError(f"{path}: byte {at}: {rule}; a damaged log")
    while pos < end:
        head = data[pos]
        n_entry, n_size, n_time = (head & 3) + 1, ((head >> 2) & 3) + 1, ((head >> 4) & 7) + 1
        body = pos + 1 + n_entry + n_size + n_time
        size = int.from_bytes(data[pos + 1 + n_entry:pos + 1 + n_entry + n_size], "little") if body <= end else 0
        if body > end or body + size > end:
            warnings.warn(f"the log ends inside a record (byte {pos} declares {size} bytes of payload, "
                          f"{max(end - body, 0)} are left): cut off while it was written? The {end - pos} bytes "
                          "from there are left out", UserWarning, stacklevel=3)
            return pos
        entry = int.from_bytes(data[pos + 1:pos + 1 + n_entry], "little")
        payload = data[body:body + size]
        if entry == 0:
            _check_control(payload, pos, types, fail)
        elif entry in types:
            name, kind = types[entry]
            need = _WPILOG_SIZES.get(kind)
            if need is not None and size != need:
                fail(pos, f"the record of {name!r} ({kind}) holds {size} bytes, a {kind} holds {need}")
            if kind == "string":
                try:
                    payload.decode("utf-8")
                except UnicodeDecodeError:
                    fail(pos, f"the record of {name!r} (string) is not UTF-8 text")
        pos = body + size
    return None


def _check_control(payload: bytes, pos: int, types: dict[int, tuple[str, str]], fail: Any) -> None:
    """A control record: start (entry, name, type, metadata), finish (entry) or set metadata (entry, metadata)."""
    if not payload:
        fail(pos, "a control record with no payload (a file of zeros: sparse or preallocated?)")
    kind = payload[0]
    if kind == 1 and len(payload) == 5 or kind == 2 and len(payload) >= 9 and \
            9 + int.from_bytes(payload[5:9], "little") == len(payload):
        return
    if kind != 0:
        fail(pos, f"a control record of kind {kind} and {len(payload)} bytes (start 0, finish 1, set metadata 2)")
    fields, at = [], 5
    for _ in range(3):
        if at + 4 > len(payload):
            fail(pos, "a start record shorter than its fields")
        n = int.from_bytes(payload[at:at + 4], "little")
        if at + 4 + n > len(payload):
            fail(pos, f"a start record whose field of {n} bytes runs past its end")
        try:
            fields.append(payload[at + 4:at + 4 + n].decode("utf-8"))
        except UnicodeDecodeError:
            fail(pos, "a start record whose name, type or metadata is not UTF-8 text")
        at += 4 + n
    if at != len(payload):
        fail(pos, f"a start record of {len(payload)} bytes whose fields take {at}")
    types[int.from_bytes(payload[1:5], "little")] = (fields[0], fields[1])


def _table(path: str, series: Mapping[str, tuple[np.ndarray, np.ndarray]], units: Mapping[str, str],
           base: str | None, keep: tuple[np.ndarray, np.ndarray] | None
           ) -> tuple[tuple[str, ...], tuple[np.ndarray, ...], dict[str, str]]:
    """Rows at ``base``'s times; the other series held (last value at or before each row)."""
    if not series:
        raise RecordingFormatError(f"{path}: no numeric entries or topics")
    if base is None:
        base = max(series, key=lambda k: len(series[k][0]))
    if base not in series:
        raise RecordingFormatError(f"{path}: no column named {base!r} (columns: {', '.join(sorted(series))})")
    t = series[base][0]
    rows = np.ones(len(t), dtype=bool)
    columns = {}
    for name, (times, values) in series.items():
        k = np.searchsorted(times, t, side="right") - 1        # the last value at or before each row
        rows &= k >= 0
        columns[name] = values[np.maximum(k, 0)]
    if keep is not None:                                       # SysId: rows inside a test only
        k = np.searchsorted(keep[0], t, side="right") - 1
        rows &= (k >= 0) & keep[1][np.maximum(k, 0)]
    if not rows.any():
        raise RecordingFormatError(f"{path}: no row of {base!r} has a value of every other column before it")
    names = ("time_s", *sorted(columns))
    cols = (t[rows], *(columns[n][rows] for n in names[1:]))
    return names, cols, {"time_s": "s", **units}


def _wpilog_series(path: str, whole: int | None = None) -> tuple[dict, dict, tuple[np.ndarray, np.ndarray] | None]:
    """``{name: (times in s, values)}``, the units the entries' metadata state, the SysId test marks; ``whole``:
    read only the first ``whole`` bytes (the log's whole records, :func:`check_wpilog_records`)."""
    try:
        from wpiutil.log import DataLogReader
    except ImportError:
        raise _missing(path, "a WPILib data log", WPILIB_EXTRA, "wpilib") from None
    if whole is None:
        reader = DataLogReader(path)
    else:
        from .files import read_input_bytes
        kept = read_input_bytes(path, what="log", max_bytes=MAX_LOG_BYTES)[:whole]
        reader = DataLogReader(kept, path)
    if not reader.isValid():
        raise RecordingFormatError(f"{path}: not a WPILib data log (no valid WPILOG header)")
    entries: dict[int, tuple[str, str, str]] = {}
    data: dict[str, tuple[list, list]] = {}
    state: tuple[list, list] = ([], [])
    for record in reader:
        if record.isStart():
            start = record.getStartData()
            entries[start.entry] = (start.name, start.type, start.metadata)
            continue
        if record.isControl() or record.getEntry() not in entries:
            continue
        name, kind, _ = entries[record.getEntry()]
        time_s = record.getTimestamp() * 1e-6
        if kind in _NUMBER_TYPES:
            value = {"double": record.getDouble, "float": record.getFloat, "int64": record.getInteger}[kind]()
            data.setdefault(name, ([], []))[0].append(time_s)
            data[name][1].append(float(value))
        elif kind == "string" and name.startswith("sysid-test-state"):
            state[0].append(time_s)
            state[1].append(record.getString() != "none")
    units = {}
    for name, _, metadata in entries.values():
        unit = WPILIB_UNITS.get(metadata.strip().lower()) if metadata else None
        if unit is not None:
            units[name] = unit
    series = {name: _sorted(times, values) for name, (times, values) in data.items()}
    keep = _sorted(state[0], state[1]) if state[0] else None
    return series, units, keep


def _sorted(times: list, values: list) -> tuple[np.ndarray, np.ndarray]:
    t, v = np.asarray(times, dtype=float), np.asarray(values)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def _ros_series(path: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{column: (times in s, values)}`` of a ROS 2 bag's JointState and number topics."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise _missing(path, "a ROS 2 bag", ROS_EXTRA, "ros") from None
    folder = Path(path).parent if Path(path).is_file() else Path(path)
    data: dict[str, tuple[list, list]] = {}

    def add(name: str, t: float, value: float) -> None:
        data.setdefault(name, ([], []))[0].append(t)
        data[name][1].append(float(value))
    try:
        with AnyReader([folder]) as reader:
            for connection, timestamp, raw in reader.messages():
                kind = connection.msgtype
                if kind not in _ROS_TYPES:
                    continue
                msg: Any = reader.deserialize(raw, kind)
                if kind == "sensor_msgs/msg/JointState":
                    t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                    for i, joint in enumerate(msg.name):
                        for field in ("position", "velocity", "effort"):
                            values = getattr(msg, field)
                            if i < len(values):
                                add(f"{connection.topic}/{joint}/{field}", t, values[i])
                elif kind == "std_msgs/msg/Float64MultiArray":
                    for i, value in enumerate(msg.data):
                        add(f"{connection.topic}/{i}", timestamp * 1e-9, value)
                else:
                    add(connection.topic, timestamp * 1e-9, msg.data)
    except (RecordingFormatError, MemoryError):
        raise
    except OSError as exc:
        if exc.errno == errno.EFBIG:          # unpacked past the bound of :func:`_ros_child`
            raise
        raise RecordingFormatError(f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from None
    except Exception as exc:  # noqa: BLE001 -- rosbags raises its own zoo on a damaged or foreign bag
        raise RecordingFormatError(f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from None
    return {name: _sorted(times, values) for name, (times, values) in data.items()}


#: The memory a bag's reader may take beyond what the process holds: a floor for the reader itself, and a few
#: times the bag's bytes for its messages held as numbers.  Compressed bags (zstd by file, by message, or
#: MCAP's zstd and lz4 chunks) are unpacked by the reader with no bound of its own: a bomb of a few MB would
#: ask for gigabytes.
BAG_MEMORY_FLOOR = 1 << 30
BAG_MEMORY_RATIO = 8


def _bag_bytes(path: str) -> int:
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    return sum(q.stat().st_size for q in folder.iterdir() if q.is_file() and q.suffix.lower() in (".db3", ".mcap"))


def _ros_child(path: str, extra: int, send: Any) -> None:
    """The bag reader's process: its memory bounded by ``extra`` bytes more than it holds at the start."""
    import faulthandler
    faulthandler.disable()
    from .mat_files import _limit_address_space
    _limit_address_space(extra)
    try:                 # a bag compressed by file is unpacked to a temporary file: bounded too (EFBIG, not a kill)
        import resource
        import signal
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (extra, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    except (ImportError, AttributeError, OSError, ValueError):
        pass
    try:
        send.send(("ok", _ros_series(path)))
    except MemoryError:
        send.send(("memory", ""))
    except OSError as exc:
        send.send(("memory", "") if exc.errno == errno.EFBIG else
                  ("refused", f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})"))
    except RecordingFormatError as exc:
        send.send(("refused", str(exc)))
    except Exception as exc:  # noqa: BLE001 -- said in the parent as the reader's error
        send.send(("refused", f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})"))


def _bounded_ros_series(path: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """:func:`_ros_series` in a process of its own whose memory is bounded by what the bag can honestly hold
    (:data:`BAG_MEMORY_FLOOR` + :data:`BAG_MEMORY_RATIO` x its bytes), where processes fork (elsewhere read
    here, unbounded)."""
    import multiprocessing
    if "fork" not in multiprocessing.get_all_start_methods():
        return _ros_series(path)
    extra = BAG_MEMORY_FLOOR + BAG_MEMORY_RATIO * _bag_bytes(path)
    ctx = multiprocessing.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_ros_child, args=(path, extra, send), daemon=True)
    child.start()
    send.close()
    try:
        message = receive.recv()
    except EOFError:                    # the child ended without a word: it crashed
        message = None
    finally:
        receive.close()
    child.join()
    if message is None:
        raise RecordingFormatError(f"{path}: a damaged ROS 2 bag: the reader crashed on it (exit status "
                                   f"{child.exitcode})")
    kind, payload = message
    if kind == "memory":
        raise RecordingFormatError(f"{path}: reading this bag needs more than the {extra} bytes a bag of "
                                   f"{_bag_bytes(path)} bytes may take ({BAG_MEMORY_RATIO} x its size + "
                                   f"{BAG_MEMORY_FLOOR >> 20} MiB, in memory or unpacked to a file): a decompression "
                                   "bomb or a damaged bag, refused")
    if kind == "refused":
        raise RecordingFormatError(payload)
    return payload


_ROS_TYPES = {"sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float64",
              "std_msgs/msg/Float32", "std_msgs/msg/Int32", "std_msgs/msg/Int16", "std_msgs/msg/Int64"}
