"""Timing helpers shared by the benchmarks.

Two clocks: the wall clock (:func:`time.perf_counter`) and the process's CPU time
(:func:`time.process_time`, every thread of the process).  The gate's figures
(:mod:`motorid.bench.goals`) are CPU times where the work is single-threaded: on a
machine whose cores other processes share, a wall-clock time counts the waits for a
core, which have nothing to do with the code, while the CPU time of the same work
moves only by what the neighbours do to the caches.  Timed on :data:`cpu_clock`, every call
runs with BLAS on one thread (:func:`identify.sums.single_threaded_blas`, as every fit runs):
a BLAS helper thread that waits for a core spins, and its spinning is CPU time of the process
that the work did not need (the frequency response of 10^6 samples: 0.125 s on one thread,
0.128-0.174 s of CPU with OpenBLAS's two beside other work, 0.117 and 0.150 s in two runs of
the gate).
"""
from __future__ import annotations

import contextlib
import time
from typing import Callable, ContextManager, Sequence

import numpy as np

__all__ = ["median_time", "interleaved_times", "interleaved_rounds", "median_ratio", "least_time", "cpu_clock"]

#: The clock of the gate's figures: CPU seconds of this process, all threads.
cpu_clock: Callable[[], float] = time.process_time


def _single_threaded(clock: Callable[[], float]) -> ContextManager[None]:
    """BLAS on one thread while timing on :data:`cpu_clock` (module docstring); nothing changed on another clock."""
    if clock is not cpu_clock:
        return contextlib.nullcontext()
    from identify.sums import single_threaded_blas
    return single_threaded_blas()


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
    """The least seconds of ``func()`` on ``clock`` over ``repeats`` calls (after one warm-up call; on
    :data:`cpu_clock` with BLAS on one thread, as the module docstring says).

    The least, not the median: a busy machine only ever adds to a call's time (cache
    misses, a core shared with a neighbour), so the least is the steadiest figure of the work.
    """
    with _single_threaded(clock):
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
    hits all of them alike and the ratios within a round are fair.  On :data:`cpu_clock`,
    with BLAS on one thread (module docstring).
    """
    calls = []
    times = np.empty((repeats, len(funcs)))
    with _single_threaded(clock):
        for func in funcs:
            t0 = clock()
            func()                                        # warm-up, and the size of a batch
            calls.append(max(1, int(batch_seconds / max(clock() - t0, 1e-9))))
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
