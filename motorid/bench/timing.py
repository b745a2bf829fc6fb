"""Timing helpers shared by the benchmarks.

Two clocks: the wall clock (:func:`time.perf_counter`) and the process's CPU time
(:func:`time.process_time`, every thread of the process).  The gate's figures
(:mod:`motorid.bench.goals`) are CPU times where the work is single-threaded: on a
machine whose cores other processes share, a wall-clock time counts the waits for a
core, which have nothing to do with the code, while the CPU time of the same work
moves only by what the neighbours do to the caches.
"""
from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np

__all__ = ["median_time", "interleaved_times", "interleaved_rounds", "median_ratio", "least_time", "cpu_clock"]

#: The clock of the gate's figures: CPU seconds of this process, all threads.
cpu_clock: Callable[[], float] = time.process_time


def median_time(func: Callable[[], object], repeats: int = 5) -> float:
    """Median wall-clock seconds of ``func()`` over ``repeats`` calls (after one warm-up call)."""
    func()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def least_time(func: Callable[[], object], repeats: int = 3, clock: Callable[[], float] = cpu_clock) -> float:
    """The least seconds of ``func()`` on ``clock`` over ``repeats`` calls (after one warm-up call).

    The least, not the median: a busy machine only ever adds to a call's time (cache
    misses, a core shared with a neighbour), so the least is the steadiest figure of the work.
    """
    func()
    times = []
    for _ in range(repeats):
        t0 = clock()
        func()
        times.append(clock() - t0)
    return float(min(times))


def interleaved_rounds(funcs: Sequence[Callable[[], object]], repeats: int = 5, batch_seconds: float = 0.02,
                       clock: Callable[[], float] = time.perf_counter) -> np.ndarray:
    """Seconds per call of each function in each round, timed in alternation: shape ``(repeats, len(funcs))``.

    Each round times every function once in turn, a short one over as many calls as
    fill about ``batch_seconds``, so a change in the machine's load between rounds
    hits all of them alike and the ratios within a round are fair.
    """
    calls = []
    for func in funcs:
        t0 = clock()
        func()                                            # warm-up, and the size of a batch
        calls.append(max(1, int(batch_seconds / max(clock() - t0, 1e-9))))
    times = np.empty((repeats, len(funcs)))
    for r in range(repeats):
        for i, (func, k) in enumerate(zip(funcs, calls)):
            t0 = clock()
            for _ in range(k):
                func()
            times[r, i] = (clock() - t0) / k
    return times


def interleaved_times(funcs: Sequence[Callable[[], object]], repeats: int = 5, batch_seconds: float = 0.02,
                      clock: Callable[[], float] = time.perf_counter) -> list[float]:
    """Median seconds per call of each function, timed in alternation (:func:`interleaved_rounds`)."""
    return [float(t) for t in np.median(interleaved_rounds(funcs, repeats, batch_seconds, clock), axis=0)]


def median_ratio(rounds: np.ndarray, numerator: int, denominator: int) -> float:
    """The median over rounds of one function's time over another's in the same round (:func:`interleaved_rounds`).

    A ratio within a round pairs two timings taken seconds apart; the median of those ratios
    is steadier than the ratio of two medians when the machine's state drifts between rounds.
    """
    return float(np.median(rounds[:, numerator] / rounds[:, denominator]))
