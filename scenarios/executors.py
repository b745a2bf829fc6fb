"""Where a sweep's grid points run: this process, a process pool of warm workers, or any executor.

:func:`points_executor` gives the executor (a ``ProcessPoolExecutor`` of workers forked
from this warm process, see :func:`worker_context`, or the one a caller gives, e.g. Dask's
``Client(...).get_executor()``) and how many points to keep in flight;
:func:`results_in_order` runs jobs on it and yields their results in job order, so that
the CSV can be written as points finish without holding the grid in memory.
"""
from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import gc
import multiprocessing
import os
import signal
import sys
import threading
from typing import Any, Callable, Iterable, Iterator

__all__ = ["WORKER_PRELOAD", "available_cores", "usable_workers", "worker_context", "points_executor",
           "results_in_order", "interrupts_deferred"]

#: Ctrl-C and the signals ``motorid`` handles like it (those this platform has).
_DEFERRED_SIGNALS = (signal.SIGINT, *(getattr(signal, name) for name in ("SIGTERM", "SIGHUP")
                                      if hasattr(signal, name)))


def results_in_order(executor: concurrent.futures.Executor | None, function: Callable[..., Any],
                     jobs: Iterable[tuple], window: int) -> Iterator[Any]:
    """Results of ``function(*job)`` in job order, with at most ``window`` jobs in flight (None: here)."""
    if executor is None:
        for job in jobs:
            yield function(*job)
        return
    pending: collections.deque = collections.deque()
    for job in jobs:
        with interrupts_deferred():    # a submit may start the workers
            pending.append(executor.submit(function, *job))
        if len(pending) >= window:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


#: Modules a worker needs, imported once by the fork server so that workers start warm.
WORKER_PRELOAD = ("scenarios.sweep", "identify", "scipy.signal", "scipy.optimize")


def available_cores() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - no affinity API (macOS, Windows)
        return os.cpu_count() or 1


def usable_workers(workers: int | None) -> int:
    """Worker processes for a sweep: ``workers`` (default: every core) clamped to :func:`available_cores`.

    More CPU-bound processes than cores only add switching and memory, so a larger
    request is clamped (``motorid sweep`` says so).
    """
    cores = available_cores()
    return min(workers or cores, cores)


def worker_context() -> multiprocessing.context.BaseContext:
    """How sweep workers start: forked from this process once it has imported :data:`WORKER_PRELOAD`.

    Forking the warm parent costs milliseconds per worker, so the workers compute from the
    start (a fork server or spawn would import scipy and motorid again first: about a
    second, serial, a quarter of a 20-repetition ``frequency-noise`` sweep).  Fork is used
    only on Linux while this process runs no Python thread but the main one (a thread could
    hold a lock the child inherits locked; OpenBLAS's own threads are reset by its fork
    handler).  Otherwise the workers come from a fork server that has imported the same
    modules (spawn where there is none).
    """
    import importlib
    for module in WORKER_PRELOAD:
        importlib.import_module(module)
    if sys.platform.startswith("linux") and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    if "forkserver" not in multiprocessing.get_all_start_methods():  # pragma: no cover - Windows
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(WORKER_PRELOAD))
    return context


def _worker_signals() -> None:
    """In a worker: the default signal handlers, not the ones a forked worker inherits.

    The parent turns SIGTERM and SIGHUP into an orderly stop (:mod:`motorid.interrupts`)
    and terminates its workers itself; a worker that ran that handler would print a
    traceback.  Ctrl-C reaches the whole process group: the parent handles it.
    """
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def points_executor(workers: int | None, executor: concurrent.futures.Executor | None
                     ) -> Iterator[tuple[concurrent.futures.Executor | None, int]]:
    """The executor to run points on (None: this process) and how many points to keep in flight.

    A process pool made here (``workers`` > 1, no ``executor`` given) is shut down on exit.
    """
    if executor is not None:
        yield executor, 2 * (os.cpu_count() or 1)
        return
    workers = usable_workers(workers)
    if workers == 1:
        yield None, 2
        return
    own = concurrent.futures.ProcessPoolExecutor(workers, mp_context=worker_context(),
                                                 initializer=_worker_signals)
    # Forked workers share the parent's memory until they write to it; the garbage collector
    # writes to every object it scans, so the objects that exist now are kept out of its
    # reach while the workers start (the pool forks them all at the first submit).
    gc.freeze()
    try:
        try:
            own.submit(int).result()
        finally:
            gc.unfreeze()
        # A deep window keeps every worker busy while the oldest point (whose result the CSV
        # waits for) is a slow one; results are small.
        yield own, 8 * workers
    except BaseException:     # an error, Ctrl-C, SIGTERM: no point waits for the points in flight
        _stop_workers(own)
        raise
    finally:
        own.shutdown()


def _stop_workers(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """Cancel the queued points and terminate the worker processes (their points are abandoned)."""
    # terminated before the pool lets go of them: a worker still starting up would otherwise
    # find its pipe closed and print a traceback
    for process in list((getattr(pool, "_processes", None) or {}).values()):   # no public handle on them
        if process.is_alive():
            process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Within the block, Ctrl-C, SIGTERM and SIGHUP wait; on exit the first one received is delivered.

    For a step that must not be cut in half, such as starting a worker process (a worker
    whose start-up data was never sent prints a traceback).  Outside the main thread this
    does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def hold(signum, frame):
        received.append(signum)

    previous = {s: signal.signal(s, hold) for s in _DEFERRED_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if received:
            signal.raise_signal(received[0])
