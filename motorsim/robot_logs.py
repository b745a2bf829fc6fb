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

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .recording import RecordingFormatError

__all__ = ["is_robot_log", "read_log_table", "WPILIB_UNITS", "ROS_EXTRA", "WPILIB_EXTRA"]

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
    if Path(path).suffix.lower() == ".wpilog":
        series, units, keep = _wpilog_series(path)
    else:
        series, units, keep = _ros_series(path), {}, None
        units = {name: unit for name in series for suffix, unit in (("/position", "rad"), ("/velocity", "rad/s"))
                 if name.endswith(suffix) and name.count("/") >= 2}
    return _table(path, series, units, base, keep)


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


def _wpilog_series(path: str) -> tuple[dict, dict, tuple[np.ndarray, np.ndarray] | None]:
    """``{name: (times in s, values)}``, the units the entries' metadata state, the SysId test marks."""
    try:
        from wpiutil.log import DataLogReader
    except ImportError:
        raise _missing(path, "a WPILib data log", WPILIB_EXTRA, "wpilib") from None
    reader = DataLogReader(path)
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
    except RecordingFormatError:
        raise
    except Exception as exc:  # noqa: BLE001 -- rosbags raises its own zoo on a damaged or foreign bag
        raise RecordingFormatError(f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from None
    return {name: _sorted(times, values) for name, (times, values) in data.items()}


_ROS_TYPES = {"sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float64",
              "std_msgs/msg/Float32", "std_msgs/msg/Int32", "std_msgs/msg/Int16", "std_msgs/msg/Int64"}
