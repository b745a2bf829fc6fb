"""``motorid bench parse``: reading a large recording against ``pandas.read_csv`` on the same file.

Each reader runs in a fresh Python process (``--repeats`` times, the median reported), which
imports its libraries, then reads the file once; its peak memory is the process's peak
resident set size (``VmHWM``, reset before the read) above its resident set before the read,
so import costs are left out.
Goals: parse time at most 1.5 times that of ``pandas.read_csv`` (default settings), peak
memory at most 3 times the file's size. Exit status 1 when a goal is missed or the readers
disagree on the number of rows.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np

from motorid.arguments import CommandError
from motorid.bench.flags import integer
from motorsim.files import open_input

__all__ = ["bench_parse", "TIME_GOAL", "MEMORY_GOAL"]

#: Largest parse time allowed, relative to ``pandas.read_csv`` on the same file.
TIME_GOAL = 1.5
#: Largest peak memory allowed, relative to the file's size.
MEMORY_GOAL = 3.0

_CHILD = r"""
import json, resource, sys, time
kind, path = sys.argv[1], sys.argv[2]

def status(key):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(key)) * 1024

def start():
    # Linux: reset the peak (VmHWM) to the current resident set, so the imports' own peak is left out.
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return status("VmRSS:")
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

def peak():
    try:
        return status("VmHWM:")
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

if kind == "pandas":
    import pandas
    read = lambda: len(pandas.read_csv(path, comment="#"))
else:
    try:   # the reader's own library, imported before the measurement as pandas is for pandas
        import pyarrow.csv  # noqa: F401
    except ImportError:
        pass
    from motorsim.reading import read_recording
    if kind == "careful":
        import motorsim.reading as reading
        reading._read_columns_fast = lambda *args: None
    read = lambda: len(read_recording(path))
before = start()
t0 = time.perf_counter()
rows = read()
seconds = time.perf_counter() - t0
print(json.dumps({"seconds": seconds, "peak_bytes": peak() - before, "rows": rows}))
"""


def _measure(kind: str, path: Path, repeats: int) -> dict:
    """Median time and peak memory of ``repeats`` fresh processes reading ``path`` with ``kind``."""
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    runs = []
    for _ in range(repeats):
        out = subprocess.run([sys.executable, "-c", _CHILD, kind, str(path)], capture_output=True, text=True,
                             env=env)
        if out.returncode != 0:
            last = (out.stderr.strip().splitlines() or ["no message"])[-1]
            raise CommandError(f"--file {path}: the {kind} reader could not read it as a recording ({last})")
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return {"seconds": float(np.median([r["seconds"] for r in runs])),
            "peak_bytes": float(np.median([r["peak_bytes"] for r in runs])), "rows": runs[0]["rows"]}


def _write_sample(path: Path, rows: int) -> None:
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine, write_recording
    rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(0))
    write_recording(rig.run(Experiment(Sine(10.0), 0.005, rows * 0.005)), path)


def bench_parse(argv: Sequence[str]) -> int:
    """Time and peak memory of ``read_recording`` against ``pandas.read_csv``; exit 1 if a goal is missed."""
    p = argparse.ArgumentParser(prog="motorid bench parse", description=__doc__.splitlines()[0])
    p.add_argument("--file", help="a recording to read (default: a simulated one of --rows rows)")
    p.add_argument("--rows", type=integer(), default=2_000_000,
                   help="rows of the simulated recording (default 2000000)")
    p.add_argument("--repeats", type=integer(), default=3, help="fresh processes per reader, median taken (default 3)")
    p.add_argument("--careful", action="store_true",
                   help="also time the line-by-line parser used to name the line of a bad file (slow)")
    args = p.parse_args(list(argv))
    try:
        import pandas  # noqa: F401
    except ImportError:
        print("motorid bench parse needs pandas (pip install pandas)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.file) if args.file else Path(tmp) / "big.csv"
        if args.file:     # a FIFO or a device would block every reader: only a regular file is read
            open_input(path, what="--file", max_bytes=2**62).close()
        else:
            _write_sample(path, args.rows)
        size = path.stat().st_size
        kinds = ["pandas", "motorid"] + (["careful"] if args.careful else [])
        results = {kind: _measure(kind, path, args.repeats if kind != "careful" else 1) for kind in kinds}
    ref, ours = results["pandas"], results["motorid"]
    print(f"file                     {size / 1e6:.1f} MB, {ours['rows']} rows")
    if hasattr(os, "getloadavg"):   # the times depend on what else the machine runs
        print(f"machine                  {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} (1 min)")
    for kind, label in (("pandas", "pandas.read_csv"), ("motorid", "read_recording"),
                        ("careful", "careful parser (bad files)")):
        if kind in results:
            r = results[kind]
            print(f"{label:<26} {r['seconds']:7.2f} s   peak {r['peak_bytes'] / 1e6:7.1f} MB "
                  f"({r['peak_bytes'] / size:.2f} x file)")
    time_ratio, memory_ratio = ours["seconds"] / ref["seconds"], ours["peak_bytes"] / size
    print(f"time vs pandas           {time_ratio:7.2f} x   (goal <= {TIME_GOAL})")
    print(f"peak memory vs file      {memory_ratio:7.2f} x   (goal <= {MEMORY_GOAL})")
    ok = time_ratio <= TIME_GOAL and memory_ratio <= MEMORY_GOAL and ref["rows"] == ours["rows"]
    return 0 if ok else 1
