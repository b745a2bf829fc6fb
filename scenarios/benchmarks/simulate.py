"""``motorid bench simulate``: the exact ZOH simulation against python-control, answers compared.

The time grid is ``k * dt`` in floating point, as recordings hold it: its intervals
differ by rounding, which :func:`motorsim.simulate` absorbs (``motorsim.plant.RECURSION_RTOL``).
"""
from __future__ import annotations

import argparse
import math
import os
from typing import Sequence

import numpy as np

from .timing import interleaved_times

__all__ = ["bench_simulate"]


def bench_simulate(argv: Sequence[str]) -> int:
    """Throughput of ``motorsim.simulate`` vs ``control.forced_response``; exit 1 if they differ."""
    import control

    from motorsim import Motor, Sine, simulate
    p = argparse.ArgumentParser(prog="motorid bench simulate", description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=int, default=100_000, help="samples per run (default 100000)")
    p.add_argument("--repeats", type=int, default=5, help="alternating rounds to take the median of (default 5)")
    args = p.parse_args(list(argv))
    motor, dt, n = Motor(25.0, 3.0), 0.005, args.samples
    duty = Sine(10.0).duty(n, dt).astype(float)
    t = np.arange(n) * dt
    sysd = motor.discretise(dt)
    ours = simulate(motor, duty, t)
    ref = control.forced_response(sysd, U=duty)
    err = max(np.max(np.abs(ref.outputs[0] - ours.angle)) / np.max(np.abs(ours.angle)),
              np.max(np.abs(ref.outputs[1] - ours.speed)) / np.max(np.abs(ours.speed)))
    t_ours, t_ref = interleaved_times([lambda: simulate(motor, duty, t), lambda: control.forced_response(sysd, U=duty)],
                                      args.repeats)
    print(f"samples per run          {n}")
    print(f"max relative difference  {err:.2e}")
    print(f"motorsim.simulate        {n / t_ours / 1e6:10.2f} M samples/s  ({t_ours * 1e3:.2f} ms)")
    print(f"control.forced_response  {n / t_ref / 1e6:10.2f} M samples/s  ({t_ref * 1e3:.2f} ms)")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(f"ratio                    {t_ref / t_ours:10.1f} x  (goal >= 100 x; load average {load:.1f})")
    return 0 if err < 1e-9 else 1
