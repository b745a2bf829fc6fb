"""``motorid import``: a lab's own file (text table, MATLAB ``.mat``, ROS 2 bag, WPILib ``.wpilog``) to format v1.

The column flags (``--time t:ms --input u:V --speed y:deg/s``, or ``--angle``/``--counts``
with ``--counts-per-rev``) are shared with ``motorid identify``, which reads foreign files
directly when they are given.  Units and the timing rule: :mod:`motorsim.units`.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import warnings

import numpy as np

from motorid.arguments import CommandError, print_to_stderr
from motorsim.columns import import_recording
from motorsim.reading import read_recording
from motorsim.recording import FORMAT_HEADER, MAX_COUNTS_PER_REV, Recording, RecordingFormatError
from motorsim.units import ANGLE_UNITS, INPUT_UNITS, SPEED_UNITS, TIME_UNITS
from motorsim.writing import write_recording

__all__ = ["add_column_arguments", "column_flags_given", "import_from_args", "read_motorid_recording",
           "add_import_arguments", "run_import"]

_QUANTITIES = ("time", "input", "speed", "angle", "counts")


def _units(units) -> str:
    return ", ".join(u for u in units if u not in ("μs",)).replace("%", "%%")   # argparse formats help with %


def add_column_arguments(parser: argparse.ArgumentParser, required: bool) -> None:
    """``--time``, ``--input``, ``--speed``, ``--angle``, ``--counts``, ``--counts-per-rev``."""
    group = parser.add_argument_group("columns of a foreign file (NAME or 0-based INDEX, then :UNIT)")
    group.add_argument("--time", required=required, metavar="COL[:UNIT]",
                       help=f"time column; unit {_units(TIME_UNITS)} (default s)")
    group.add_argument("--input", required=required, metavar="COL[:UNIT]",
                       help=f"input column; unit {_units(INPUT_UNITS)}, required unless the file states it "
                            "(a header such as u_pct, a log's metadata); kept as the metadata input_unit, values "
                            "unchanged")
    group.add_argument("--speed", metavar="COL[:UNIT]",
                       help=f"measured speed column; unit {_units(SPEED_UNITS)}, required unless the file states "
                            "it (speed_rpm, w [rad/s], a log's metadata); kept as the metadata speed_unit, results "
                            "are also shown in it")
    group.add_argument("--angle", metavar="COL[:UNIT]",
                       help=f"measured angle column; unit {_units(ANGLE_UNITS)} (default rad)")
    group.add_argument("--counts", metavar="COL", help="encoder counts column (needs --counts-per-rev)")
    group.add_argument("--counts-per-rev", dest="import_counts_per_rev", type=int, metavar="N",
                       help="encoder resolution of --counts (or --angle COL:counts), counts/rev")
    group.add_argument("--input-shift", dest="input_shift", type=int, default=0, metavar="ROWS",
                       help="move the input column ROWS rows earlier: a log that writes each command just after "
                            "the state it answers needs 1 (default 0)")
    group.add_argument("--input-limit", dest="input_limit", type=float, metavar="LIMIT",
                       help="largest input magnitude the drive accepts, in the input's unit (e.g. 12 for "
                            "u:V, 100 for u:%%); kept as the metadata input_limit, carried into the model "
                            "and checked by control design (default for duty: 255)")


def column_flags_given(args: argparse.Namespace) -> bool:
    """True when any column flag was given (the files are then foreign, not format v1).

    Without one, ``--counts-per-rev`` and ``--input-limit`` (which only describe a foreign file's
    columns) are refused: a format-v1 recording states its own, and they would be ignored.
    """
    if any(getattr(args, q, None) is not None for q in _QUANTITIES):
        return True
    for flag, name in (("--counts-per-rev", "import_counts_per_rev"), ("--input-limit", "input_limit"),
                       ("--input-shift", "input_shift")):
        given = getattr(args, name, None)
        if given is not None and not (name == "input_shift" and given == 0):
            raise CommandError(f"{flag} describes a foreign file's columns (with --time, --input, ...); a format-v1 "
                               f"recording states its own in its header, got {flag} {getattr(args, name)!r} alone")
    return False


def import_from_args(path: str, args: argparse.Namespace) -> Recording:
    """Import ``path`` with the column flags; a non-uniform clock is said on stderr."""
    if args.time is None or args.input is None:
        raise CommandError("a foreign file needs --time COL[:UNIT] and --input COL[:UNIT]")
    if args.speed is None and args.angle is None and args.counts is None:
        raise CommandError("a foreign file needs one of --speed, --angle, --counts")
    cpr = args.import_counts_per_rev
    if cpr is not None:
        if not 1 <= cpr <= MAX_COUNTS_PER_REV:
            raise CommandError(f"--counts-per-rev must be an encoder's counts per revolution, in 1..."
                               f"{MAX_COUNTS_PER_REV}, got {cpr!r}")
        if args.counts is None and args.angle is None:
            raise CommandError(f"--counts-per-rev {cpr} describes a counts column (--counts COL, or --angle "
                               "COL:counts); a speed column needs none: leave it out")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        rec = import_recording(path, time=args.time, input=args.input, speed=args.speed, angle=args.angle,
                               counts=args.counts, counts_per_rev=args.import_counts_per_rev,
                               input_shift=getattr(args, "input_shift", 0))
    for w in caught:
        print_to_stderr(f"motorid: note: {path}: {w.message}")
    _say_gaps(path, rec)
    limit = getattr(args, "input_limit", None)
    if limit is not None:
        check_input_limit(limit, rec.input_unit)
        largest = float(np.max(np.abs(rec.duty)))
        if largest > limit * (1 + 1e-9):
            raise CommandError(f"--input-limit {limit:g} {rec.input_unit} is below the input {path} records (its "
                               f"largest magnitude {largest:g} {rec.input_unit}): a drive applies no more than its "
                               "limit; give the drive's real limit")
        rec = dataclasses.replace(rec, metadata={**rec.metadata, "input_limit": f"{limit:g}"})
    return rec


def check_input_limit(limit: float, unit: str, flag: str = "--input-limit") -> float:
    """``limit`` if it is a drive's limit: a number in ``1e-100...1e12`` (the inputs a fit takes, and a
    recording's largest magnitude); else :class:`CommandError` naming ``flag``.  Beyond them the top speed,
    the reference and a controller's gains underflow to 0 or overflow, and a design says nothing true."""
    from identify.data import INPUT_SCALE_LIMIT
    from motorsim.recording import MAX_MAGNITUDE
    if not (math.isfinite(limit) and 1 / INPUT_SCALE_LIMIT <= limit <= MAX_MAGNITUDE):
        raise CommandError(f"{flag} must be a number in {1 / INPUT_SCALE_LIMIT:g}...{MAX_MAGNITUDE:g} {unit} (a "
                           f"drive's largest input), got {limit!r}")
    return limit


def _say_gaps(path: str, rec: Recording) -> None:
    """Say where the time column jumps over whole sample periods: each gap splits the run into segments fitted
    apart (an hour's pause is a pause between runs, not 360 000 samples lost)."""
    import numpy as np
    steps = np.diff(np.asarray(rec.seq, dtype=np.int64)) - 1
    gaps = np.flatnonzero(steps > 0)
    if not len(gaps):
        return
    k = int(gaps[np.argmax(steps[gaps])])
    longest = int(steps[k]) * rec.sample_period
    print_to_stderr(f"motorid: note: {path}: the time column has {len(gaps)} gap(s), {int(steps[gaps].sum())} sample "
                    f"periods of {rec.sample_period:g} s with no row, the longest {longest:.6g} s after t = "
                    f"{float(rec.time[k]):.6g} s: read as {len(gaps) + 1} segments fitted apart (a pause or rows "
                    "lost, never samples made up)")


def _is_motorid_recording(path: str) -> bool:
    """Whether ``path`` starts with the format's header; True for anything but a regular file (a FIFO is
    never opened here: the reader's own refusal stands)."""
    import stat
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return True
        with open(path, encoding="utf-8-sig", errors="replace") as fh:     # a BOM is the reader's to say
            return fh.readline().strip().startswith(FORMAT_HEADER)
    except OSError:
        return True                   # the reader says what is wrong with the path


def _sysid_log(path: str) -> Recording:
    """A robot log given with no column flags: SysId's own (one motor's ``voltage-M`` and ``velocity-M`` entries,
    their units stated) read so and said; any other refused naming its columns and the flags to give."""
    from motorsim.robot_logs import read_log_table
    try:
        names, _, units = read_log_table(path, None)
    except RecordingFormatError as exc:
        raise CommandError(str(exc)) from None
    motors = {n.removeprefix("voltage-") for n in names if n.startswith("voltage-")}
    pairs = [m for m in sorted(motors) if f"velocity-{m}" in names and f"voltage-{m}" in units
             and f"velocity-{m}" in units]
    if len(pairs) != 1:
        shown = ", ".join(n for n in names if n != "time_s")
        raise CommandError(f"{path} is a robot log, not a motorid recording: name its columns with --time time_s "
                           f"--input NAME[:UNIT] and --speed or --angle NAME[:UNIT] (its columns: {shown})")
    motor = pairs[0]
    print_to_stderr(f"motorid: note: {path}: read as SysId's log of motor {motor!r}: --time time_s --input "
                    f"voltage-{motor} --speed velocity-{motor} (give the flags to choose others)")
    flags = argparse.Namespace(time="time_s", input=f"voltage-{motor}", speed=f"velocity-{motor}", angle=None,
                               counts=None, import_counts_per_rev=None, input_shift=0, input_limit=None)
    return import_from_args(path, flags)


def read_motorid_recording(path: str, check_samples: bool = True) -> Recording:
    """A recording (format v1); a file that is not one is refused naming the column flags and ``motorid import``;
    a robot log is read as SysId's where it is one (:func:`_sysid_log`)."""
    from motorsim.robot_logs import is_robot_log
    if is_robot_log(path):
        return _sysid_log(path)
    try:
        return read_recording(path, check_samples=check_samples)
    except RecordingFormatError as exc:
        if _is_motorid_recording(path):
            raise
        raise CommandError(f"{exc}: {path} is not a motorid recording; name its columns with --time COL[:UNIT] "
                           "--input COL[:UNIT] and one of --speed, --angle, --counts (e.g. --time t:ms --input u:V "
                           "--speed y:deg/s), or convert it once with motorid import FILE --time ... --out "
                           "recording.csv") from None


def add_import_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid import``."""
    parser.add_argument("file", metavar="FILE", help="text table (CSV, TSV, whitespace; header or none), .mat, a ROS 2 "
                                                     "bag (its folder, .db3 or .mcap) or a WPILib .wpilog")
    add_column_arguments(parser, required=True)
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="path of the recording (format v1)")


def run_import(args: argparse.Namespace) -> int:
    """Import the file and write it as a recording."""
    rec = import_from_args(args.file, args)
    path = write_recording(rec, args.out)
    limit = "" if rec.input_limit is None else f", limit +-{rec.input_limit:g} {rec.input_unit}"
    print_to_stderr(f"wrote {len(rec)} samples (sample period {rec.sample_period:.6g} s, input in "
                    f"{rec.input_unit}{limit}) to {path}")
    return 0
