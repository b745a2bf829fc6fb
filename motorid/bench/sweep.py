"""``motorid bench sweep``: the sweeps' batch engine against a per-run python-control loop, same workload.

Workload: ``--repetitions`` runs of ``--samples`` samples, run r driven by
``200 sin(10 t + alpha_r)`` with its own phase (so no run repeats another), simulated,
read by the 16667-count encoder and fitted with ``euler-ls`` and ``zoh-ls``.  The
baseline is the naive loop: ``control.forced_response`` of ``Motor.discretise(dt)``,
``floor`` to counts, differencing and ``numpy.linalg.lstsq`` per run.  Both produce
every estimate; they must agree to 1e-9 relative (exit status 1 otherwise).
"""
from __future__ import annotations

import argparse
import math
import time
from typing import Sequence

import numpy as np

from identify import fit_batch
from motorid.bench.flags import integer
from motorid.bench.timing import median_time
from motorsim.batch import encoder_counts_batch, simulate_batch, speed_batch
from motorsim.excitation import Sine
from motorsim.plant import Motor

__all__ = ["bench_sweep", "python_control_loop"]

_METHODS = ("euler-ls", "zoh-ls")


def python_control_loop(motor: Motor, duty: np.ndarray, sample_period: float, counts_per_rev: int) -> np.ndarray:
    """The baseline: per run, ``control.forced_response``, floored counts, differencing, ``lstsq``.

    Returns
    -------
    ndarray, shape (runs, 4)
        ``euler-ls`` a, b and ``zoh-ls`` a, b of each row of ``duty``.
    """
    import control
    dt, cpr = sample_period, counts_per_rev
    sysd = motor.discretise(dt)
    out = np.empty((len(duty), 4))
    for r, row in enumerate(duty):
        resp = control.forced_response(sysd, U=row)
        counts = np.floor(resp.outputs[0] * (cpr / (2 * math.pi)))
        speed = np.diff(counts * (2 * math.pi / cpr)) / dt
        A = np.column_stack([speed[:-1], row[1:-1]])
        (t1, t2), *_ = np.linalg.lstsq(A, speed[1:], rcond=None)
        a_zoh = -math.log(t1) / dt
        out[r] = (1 - t1) / dt, t2 / dt, a_zoh, a_zoh * t2 / (1 - t1)
    return out


def _parse(argv: Sequence[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="motorid bench sweep", description=__doc__.splitlines()[0])
    p.add_argument("--repetitions", type=integer(), default=200, metavar="N",
                   help="runs, each with its own phase (default 200)")
    p.add_argument("--samples", type=integer(2), default=10_000, metavar="N", help="samples per run (default 10000)")
    p.add_argument("--repeats", type=integer(), default=5, metavar="N",
                   help="timings of the batch engine to take the median of (default 5)")
    p.add_argument("--parallel", action="store_true",
                   help="also time the frequency-noise sweep (20 repetitions) on 1 worker, as many workers as "
                        "cores and twice as many: the parallel efficiency")
    args = p.parse_args(list(argv))
    if args.repetitions < 1 or args.samples < 10 or args.repeats < 1:
        p.error(f"--repetitions must be >= 1, --samples >= 10 and --repeats >= 1, got {args.repetitions}, "
                f"{args.samples}, {args.repeats}")
    return args


def bench_sweep(argv: Sequence[str]) -> int:
    """Time the batch engine and the loop on the same workload; exit 1 if their estimates differ."""
    args = _parse(argv)
    motor, dt, cpr, n, runs = Motor(25.0, 3.0), 0.005, 16667, args.samples, args.repetitions
    phases = np.linspace(0.0, 2 * math.pi, runs, endpoint=False)
    duty = np.stack([Sine(10.0, 200, ph).duty(n, dt) for ph in phases]).astype(float)

    def batch():
        angle, _ = simulate_batch(motor, duty, dt)
        counts = encoder_counts_batch(angle, cpr)
        return fit_batch(_METHODS, speed_batch(counts, cpr, dt), duty, dt)

    t_batch = median_time(batch, args.repeats)
    fits = batch()
    t0 = time.perf_counter()
    ref = python_control_loop(motor, duty, dt, cpr)
    t_loop = time.perf_counter() - t0
    ours = np.column_stack([fits["euler-ls"].a, fits["euler-ls"].b, fits["zoh-ls"].a, fits["zoh-ls"].b])
    diff = float(np.max(np.abs(ours - ref) / np.abs(ref)))
    total = runs * n
    print(f"workload                 {runs} runs x {n} samples: simulate + encoder + euler-ls + zoh-ls")
    print(f"max relative difference  {diff:.2e}  (all {4 * runs} estimates)")
    print(f"batch engine             {total / t_batch / 1e6:10.2f} M samples/s  ({t_batch * 1e3:.1f} ms, "
          f"median of {args.repeats})")
    print(f"python-control loop      {total / t_loop / 1e6:10.2f} M samples/s  ({t_loop * 1e3:.0f} ms)")
    print(f"ratio                    {t_loop / t_batch:10.1f} x")
    _oe_against_zoh_ls()
    same = _parallel_efficiency() if args.parallel else True
    return 0 if diff < 1e-9 and same else 1


def _oe_against_zoh_ls() -> None:
    """Time the ``frequency-noise`` sweep (one process) with ``zoh-ls`` alone and with ``oe`` alone."""
    import dataclasses
    import functools
    import os
    import tempfile

    from scenarios.scenario import load_scenario
    from scenarios.sweep import run_scenario
    scenario = load_scenario("frequency-noise")
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        for method in ("zoh-ls", "oe"):
            times[method] = median_time(functools.partial(
                run_scenario, dataclasses.replace(scenario, methods=(method,)), os.path.join(tmp, method),
                workers=1), 3)
    print(f"frequency-noise sweep    {scenario.n_points} points x {scenario.repetitions} repetitions, one process")
    print(f"  zoh-ls                 {times['zoh-ls']:8.2f} s")
    print(f"  oe                     {times['oe']:8.2f} s  ratio {times['oe'] / times['zoh-ls']:.1f} x  "
          "(goal <= 3 x)")


def _parallel_efficiency() -> bool:
    """Time ``frequency-noise`` on 1, cores and 2 x cores workers; True when the CSVs are identical.

    The three runs do the same work and alternate over two rounds (best of each kept), so a
    change in the machine's load hits every configuration alike.  A fresh worker pool is
    started in every timed run (its start is part of the figure).  Besides the wall-clock
    efficiency it prints the CPU seconds of this process and its workers, so the work the
    parallel run adds (start-up, transfer) shows apart from the CPU share the scheduler
    grants: with other sessions busy, Linux's autogroup scheduling shares the cores between
    sessions, not processes, and then no worker count buys a session more than its share.
    """
    import os
    import tempfile

    from scenarios.executors import available_cores
    from scenarios.scenario import load_scenario
    from scenarios.sweep import run_scenario
    scenario = load_scenario("frequency-noise")
    cores = available_cores()
    counts = (1, cores, 2 * cores)
    runs: dict[int, list[tuple[float, float, float]]] = {w: [] for w in counts}
    csvs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(2):
            for workers in counts:
                cpu0, t0 = _cpu_seconds(), time.perf_counter()
                summary = run_scenario(scenario, os.path.join(tmp, str(workers)), workers=workers)
                runs[workers].append((time.perf_counter() - t0, _cpu_seconds() - cpu0, _load_average()))
                csvs[workers] = summary.csv_path.read_bytes()
    print(f"frequency-noise sweep    {scenario.n_points} points x {len(scenario.methods)} methods x "
          f"{scenario.repetitions} repetitions on {cores} cores, best of 2 alternating rounds")
    best = {w: min(r) for w, r in runs.items()}
    for workers in counts:
        wall, cpu, _ = best[workers]
        note = "  (clamped to the cores)" if workers > cores else ""
        load = " ".join(f"{r[2]:.1f}" for r in runs[workers])
        print(f"  {workers:2d} worker(s)            {wall:8.2f} s  efficiency "
              f"{best[1][0] / (min(workers, cores) * wall):6.1%}  CPU {cpu:5.2f} s (work efficiency "
              f"{best[1][1] / cpu:6.1%}, {cpu / wall:.2f} cores obtained)  load average {load}{note}")
    print("goal: efficiency >= 85 % at as many workers as cores; more workers never slower")
    return len(set(csvs.values())) == 1


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and its reaped children (NaN without ``resource``)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return math.nan
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _load_average() -> float:
    """The 1-minute load average (NaN where the OS has none)."""
    import os
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
