"""``motorid bench NAME``: speed and accuracy benchmarks.

Benchmarks print their figures and ratios against a baseline measured in the
same run; tests never assert wall-clock times.  ``_BENCHMARKS`` maps a name to
``"module:function"`` where ``function(argv: list[str]) -> int`` parses its own
flags; add a benchmark by adding one line.
"""
from __future__ import annotations

import argparse
import importlib
import time

import numpy as np

__all__ = ["bench_simulate", "median_time"]

_BENCHMARKS = {
    "simulate": ("scenarios.bench:bench_simulate",
                 "motorsim.simulate against control.forced_response of the same ZOH model"),
    "sweep": ("scenarios.batch:bench_sweep",
              "the sweeps' batch engine against a per-run control.forced_response + lstsq loop"),
    "accuracy": ("scenarios.benchmarks_accuracy:bench_accuracy",
                 "oe/oe-friction against the truth on an independent integrator, Monte Carlo vs the "
                 "Cramér–Rao bound, oe fit time vs a finite-difference Jacobian"),
    "serial": ("scenarios.bench_serial:bench_serial",
               "frames decoded/s by the host reader vs the 200 000/s goal; 60 s at 1 kHz through the pty"),
    "firmware": ("hardware.sim.bench_firmware:main",
                 "the Arduino firmware under simavr: size, sample rates per baud, encoder ceiling, speed"),
}


def median_time(func, repeats: int = 5) -> float:
    """Median wall-clock seconds of ``func()`` over ``repeats`` calls (after one warm-up call)."""
    func()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_simulate(argv: list[str]) -> int:
    """Throughput of the exact ZOH simulation vs python-control, with the answers compared."""
    import control

    from motorsim import Motor, Sine, simulate
    p = argparse.ArgumentParser(prog="motorid bench simulate")
    p.add_argument("--samples", type=int, default=100_000)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    motor, dt, n = Motor(25.0, 3.0), 0.005, args.samples
    duty = Sine(10.0).duty(n, dt).astype(float)
    t = np.arange(n) * dt
    sysd = motor.discretise(dt)
    ours = simulate(motor, duty, t)
    ref = control.forced_response(sysd, U=duty)
    err = max(np.max(np.abs(ref.outputs[0] - ours.angle)) / np.max(np.abs(ours.angle)),
              np.max(np.abs(ref.outputs[1] - ours.speed)) / np.max(np.abs(ours.speed)))
    t_ours = median_time(lambda: simulate(motor, duty, t), args.repeats)
    t_ref = median_time(lambda: control.forced_response(sysd, U=duty), args.repeats)
    print(f"samples per run          {n}")
    print(f"max relative difference  {err:.2e}")
    print(f"motorsim.simulate        {n / t_ours / 1e6:10.2f} M samples/s  ({t_ours * 1e3:.2f} ms)")
    print(f"control.forced_response  {n / t_ref / 1e6:10.2f} M samples/s  ({t_ref * 1e3:.2f} ms)")
    print(f"ratio                    {t_ref / t_ours:10.1f} x")
    return 0 if err < 1e-9 else 1


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    names = ", ".join(f"{k} ({v[1]})" for k, v in _BENCHMARKS.items())
    parser.add_argument("name", choices=list(_BENCHMARKS), metavar="NAME", help=f"one of: {names}")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="the benchmark's own flags (see NAME --help)")


def run_bench(args: argparse.Namespace) -> int:
    module, _, func = _BENCHMARKS[args.name][0].partition(":")
    return getattr(importlib.import_module(module), func)(list(args.options))
