"""Timing helpers shared by the benchmarks."""
from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np

__all__ = ["median_time", "interleaved_times"]


def median_time(func: Callable[[], object], repeats: int = 5) -> float:
    """Median wall-clock seconds of ``func()`` over ``repeats`` calls (after one warm-up call)."""
    func()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def interleaved_times(funcs: Sequence[Callable[[], object]], repeats: int = 5, batch_seconds: float = 0.02
                      ) -> list[float]:
    """Median seconds per call of each function, timed in alternation.

    Each round times every function once in turn, a short one over as many calls as
    fill about ``batch_seconds``, so a change in the machine's load between rounds
    hits all of them alike and the ratios of the results are fair.
    """
    calls = []
    for func in funcs:
        t0 = time.perf_counter()
        func()                                            # warm-up, and the size of a batch
        calls.append(max(1, int(batch_seconds / max(time.perf_counter() - t0, 1e-9))))
    times: list[list[float]] = [[] for _ in funcs]
    for _ in range(repeats):
        for func, k, out in zip(funcs, calls, times):
            t0 = time.perf_counter()
            for _ in range(k):
                func()
            out.append((time.perf_counter() - t0) / k)
    return [float(np.median(t)) for t in times]
