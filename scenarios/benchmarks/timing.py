"""Timing helpers shared by the benchmarks."""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

__all__ = ["median_time"]


def median_time(func: Callable[[], object], repeats: int = 5) -> float:
    """Median wall-clock seconds of ``func()`` over ``repeats`` calls (after one warm-up call)."""
    func()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
