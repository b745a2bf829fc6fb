"""``motorid bench startup``: how long ``motorid`` takes to start, against ``import control``.

All in one run, as subprocesses started the same way and timed interleaved (round by round,
so a change in the machine's load hits every command alike), medians over ``--repeats``:

- ``python -c "import control"``: the baseline, what python-control costs to import;
- ``motorid --help``: goal at most 0.25 x the baseline;
- ``motorid identify small.csv`` (a 2 s, 400-sample simulated run, ``oe``): goal at most
  0.5 x the baseline plus the fit itself, measured in-process after a warm-up;
- ``python -c "pass"``: the interpreter alone, for reference.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from motorid.bench.flags import integer
from motorid.bench.timing import median_time

__all__ = ["bench_startup"]

ROOT = Path(__file__).resolve().parents[2]


def _wall(cmd: list[str], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _small_run(folder: Path) -> Path:
    from motorsim import Experiment, Motor, SimRig, Sine, write_recording
    return write_recording(SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 2.0)),
                           folder / "small.csv")


def bench_startup(argv: Sequence[str]) -> int:
    """Start-up times of ``motorid --help`` and ``motorid identify small.csv`` against ``import control``."""
    p = argparse.ArgumentParser(prog="motorid bench startup", description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=integer(), default=5, help="rounds to take the median of (default 5)")
    args = p.parse_args(list(argv))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    motorid = [sys.executable, "-m", "motorid.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        small = _small_run(Path(tmp))
        commands = {"python -c pass": [sys.executable, "-c", "pass"],
                    "import control": [sys.executable, "-c", "import control"],
                    "motorid --help": [*motorid, "--help"],
                    "motorid identify small.csv": [*motorid, "identify", str(small)]}
        times: dict[str, list[float]] = {name: [] for name in commands}
        for cmd in commands.values():               # warm the file cache once
            _wall(cmd, env)
        for _ in range(max(args.repeats, 1)):
            for name, cmd in commands.items():
                times[name].append(_wall(cmd, env))
        # the same work `motorid identify FILE` does after start-up: read and screen the file,
        # fit with the command's default automatic input delay, confirm no outliers
        from motorid.screening import read_and_fit
        fit_time = median_time(lambda: read_and_fit([str(small)], "oe", {"input_delay": "auto"}),
                               max(args.repeats, 1))
    med = {name: statistics.median(t) for name, t in times.items()}
    base = med["import control"]
    print(f"{'command':<28}{'median':>10}   ratio to import control")
    for name, value in med.items():
        print(f"{name:<28}{value * 1e3:8.0f} ms   {value / base:5.2f} x")
    help_ratio = med["motorid --help"] / base
    identify_ratio = (med["motorid identify small.csv"] - fit_time) / base
    print(f"read + fit (in-process)      {fit_time * 1e3:8.0f} ms")
    print(f"goal --help                  <= 0.25 x: {help_ratio:.2f} x  {'met' if help_ratio <= 0.25 else 'MISSED'}")
    print(f"goal identify minus the fit  <= 0.50 x: {identify_ratio:.2f} x  "
          f"{'met' if identify_ratio <= 0.5 else 'MISSED'}")
    return 0
