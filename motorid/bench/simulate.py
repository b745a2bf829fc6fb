"""``motorid bench simulate``: the exact ZOH simulation against python-control, answers compared.

The time grid is ``k * dt`` in floating point, as recordings hold it: its intervals
differ by rounding, which :func:`motorsim.simulate` absorbs (``motorsim.plant.RECURSION_RTOL``).
"""
from __future__ import annotations

import argparse
import functools
import math
import os
from typing import Sequence

import numpy as np

from motorid.bench.flags import integer
from motorid.bench.goals import Goal, report
from motorid.bench.timing import cpu_clock, interleaved_rounds, interleaved_times, median_ratio

__all__ = ["bench_simulate", "goal_figures", "GOALS", "SPEED_GOAL"]

#: ``control.forced_response`` time over ``motorsim.simulate``'s on the same plant and input.
SPEED_GOAL = Goal("simulate: speed-up over control.forced_response, 10^5 samples (worst of 2)", 100.0, "x",
                  at_most=False)
GOALS = (SPEED_GOAL,)


def bench_simulate(argv: Sequence[str]) -> int:
    """Throughput of ``motorsim.simulate`` vs ``control.forced_response``; 1 if they differ or the goal is missed."""
    p = argparse.ArgumentParser(prog="motorid bench simulate", description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=integer(2), default=100_000, help="samples per run (default 100000)")
    p.add_argument("--repeats", type=integer(), default=5, help="alternating rounds to take the median of (default 5)")
    args = p.parse_args(list(argv))
    n = args.samples
    ratio, err = _speed_up(n, args.repeats, verbose=True)
    same = _friction_paths(n, args.repeats)
    missed = report([(SPEED_GOAL, ratio)]) if n == 100_000 else 0
    return 0 if err < 1e-9 and same and not missed else 1


def _family():
    """The inputs of the gate's figure: (sample period in s, excitation).  Two, not more: the linear simulation's
    work does not depend on the input, and one ``forced_response`` of 10^5 samples takes over a second."""
    from motorsim import PRBS, Sine
    return ((0.005, Sine(10.0)), (0.001, PRBS(200, -200, 16, 1)))


def goal_figures() -> list[tuple[Goal, float]]:
    """The speed-up over python-control at the goal's size, the least of two inputs (``motorid bench --check``).

    Each is the median over rounds of the two timed in alternation, in CPU time (both single-threaded);
    answers that differ by more than 1e-9 give no figure.
    """
    import control

    from motorsim import Motor, simulate
    motor, n, ratios = Motor(25.0, 3.0), 100_000, []
    for dt, excitation in _family():
        duty = excitation.duty(n, dt).astype(float)
        t = np.arange(n) * dt
        sysd = motor.discretise(dt)
        ours, ref = simulate(motor, duty, t), control.forced_response(sysd, U=duty)
        err = max(np.max(np.abs(ref.outputs[0] - ours.angle)) / np.max(np.abs(ours.angle)),
                  np.max(np.abs(ref.outputs[1] - ours.speed)) / np.max(np.abs(ours.speed)))
        rounds = interleaved_rounds([functools.partial(simulate, motor, duty, t),
                                     functools.partial(control.forced_response, sysd, U=duty)], 3, clock=cpu_clock)
        ratios.append(median_ratio(rounds, 1, 0) if err < 1e-9 else math.nan)
    return [(SPEED_GOAL, min(ratios))]


def _speed_up(n: int, repeats: int, verbose: bool) -> tuple[float, float]:
    """``forced_response`` time over ``simulate``'s and the largest relative difference of their answers."""
    import control

    from motorsim import Motor, Sine, simulate
    motor, dt = Motor(25.0, 3.0), 0.005
    duty = Sine(10.0).duty(n, dt).astype(float)
    t = np.arange(n) * dt
    sysd = motor.discretise(dt)
    ours = simulate(motor, duty, t)
    ref = control.forced_response(sysd, U=duty)
    err = max(np.max(np.abs(ref.outputs[0] - ours.angle)) / np.max(np.abs(ours.angle)),
              np.max(np.abs(ref.outputs[1] - ours.speed)) / np.max(np.abs(ours.speed)))
    t_ours, t_ref = interleaved_times([lambda: simulate(motor, duty, t), lambda: control.forced_response(sysd, U=duty)],
                                      repeats)
    if verbose:
        print(f"samples per run          {n}")
        print(f"max relative difference  {err:.2e}")
        print(f"motorsim.simulate        {n / t_ours / 1e6:10.2f} M samples/s  ({t_ours * 1e3:.2f} ms)")
        print(f"control.forced_response  {n / t_ref / 1e6:10.2f} M samples/s  ({t_ref * 1e3:.2f} ms)")
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
        print(f"ratio                    {t_ref / t_ours:10.1f} x  (goal >= {SPEED_GOAL.limit:g} x at 10^5 samples; "
              f"load average {load:.1f})")
    return t_ref / t_ours, float(err)


def _friction_paths(n: int, repeats: int) -> bool:
    """Time the friction loop in Python and compiled by numba (when installed); True when they agree."""
    from motorsim.compiled import compiled_kernel, friction_run_python
    rng = np.random.default_rng(0)
    h = np.full(n - 1, 0.005)
    force = 3.0 * (120 * np.sin(2.0 * np.arange(n - 1) * 0.005) + 5 * rng.standard_normal(n - 1))

    def run(kernel):
        speed, angle = np.zeros(n), np.zeros(n)
        kernel(25.0, force, 60.0, h, speed, angle, 60.0)
        return speed, angle

    kernel = compiled_kernel()
    if kernel is None:
        t_py, = interleaved_times([lambda: run(friction_run_python)], repeats)
        print(f"friction loop (Python)   {n / t_py / 1e6:10.2f} M samples/s  ({t_py * 1e3:.2f} ms); numba not "
              "loaded (MOTORID_NUMBA=0, or not installed)")
        return True
    t_py, t_nb = interleaved_times([lambda: run(friction_run_python), lambda: run(kernel)], repeats)
    slow, fast = run(friction_run_python), run(kernel)
    diff = max(float(np.max(np.abs(x - y))) / float(np.max(np.abs(x))) for x, y in zip(slow, fast))
    print(f"friction loop (Python)   {n / t_py / 1e6:10.2f} M samples/s  ({t_py * 1e3:.2f} ms)")
    print(f"friction loop (numba)    {n / t_nb / 1e6:10.2f} M samples/s  ({t_nb * 1e3:.2f} ms)  "
          f"ratio {t_py / t_nb:.1f} x, max relative difference {diff:.1e}")
    return diff < 1e-12
