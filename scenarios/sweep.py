"""Scenario sweeps: every grid point x estimator x repetition, in parallel, streamed to a tidy CSV.

:func:`run_point` does one grid point: all its repetitions at once through the
batch engine (:mod:`scenarios.batch`) when the setting is linear and every
sample arrives, else one :meth:`SimRig.run <motorsim.rig.SimRig.run>` and one
:func:`identify.fit` per repetition -- the path users take.  Estimators with a
batched implementation (``scenarios.batch.BATCHED_METHODS``) use it; any other
name from ``identify.available_methods()`` is fitted with ``identify.fit`` on
recordings of the same counts.  Where the setting has an input delay, every
method that takes ``input_delay`` is fitted with ``input_delay="auto"`` (one
recording at a time).  A fit that raises is a counted failure with its reason,
never a crash of the sweep.

:func:`run_scenario` spreads the grid points over a
``concurrent.futures.Executor`` (processes by default, or any executor given,
e.g. Dask's ``Client(...).get_executor()``), keeps at most a few points in
flight and writes each point's rows as soon as it and all points before it are
done, so memory does not grow with the grid.

Seeds never depend on the workers: repetition ``r`` of grid point ``i`` draws
from ``SeedSequence(seed, spawn_key=(i, r))``, which is
``SeedSequence(seed).spawn(n_points)[i].spawn(repetitions)[r]``.
"""
from __future__ import annotations

import argparse
import collections
import concurrent.futures
import contextlib
import csv
import dataclasses
import gc
import json
import math
import multiprocessing
import os
import sys
import time
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from identify import fit
from identify.uncertainty import cramer_rao_bound
from motorsim.checks import check_int
from motorsim.files import atomic_writer, make_output_dir, safe_file_name, write_atomically
from motorsim.recording import Recording
from motorsim.rig import bench_knobs

from .arguments import CommandError, print_to_stderr
from .batch import (
    BATCHED_METHODS,
    MethodOutcome,
    encoder_counts_batch,
    fit_batch,
    is_batchable,
    regression_batch,
    simulate_batch,
    speed_batch,
)
from .batch_output_error import output_error_batch
from .progress import ProgressBar
from .scenario import GridPoint, Scenario, Setting

__all__ = ["MethodOutcome", "PointResult", "SweepSummary", "run_point", "run_scenario", "CSV_COLUMNS",
           "SETTING_COLUMNS", "setting_column", "axis_column", "read_sweep_csv", "repetition_seed", "make_plots",
           "format_sweep_table",
           "add_sweep_arguments", "run_sweep", "available_cores", "usable_workers", "worker_context",
           "WORKER_PRELOAD"]

def setting_column(knob: str) -> str:
    """The CSV column of a bench knob: its name, except ``true_a`` and ``true_b`` for the motor's a and b."""
    return f"true_{knob}" if knob in ("a", "b") else knob


#: Columns of the tidy CSV, one row per grid point x estimator: every bench knob, then the excitation.
SETTING_COLUMNS = (*(setting_column(k.name) for k in bench_knobs()), "excitation", "frequency", "amplitude",
                   "n_samples")
STAT_COLUMNS = ("method", "repetitions", "successes", "failures", "failure_reasons",
                "mean_a", "bias_a_pct", "std_a", "rmse_a", "crb_a",
                "mean_b", "bias_b_pct", "std_b", "rmse_b", "crb_b")
CSV_COLUMNS = ("point", *SETTING_COLUMNS, *STAT_COLUMNS)

#: Repetitions are batched in chunks of about this many samples (bounded memory per worker).
_CHUNK_SAMPLES = 1 << 21


def axis_column(axis: str) -> str:
    """The CSV column holding grid axis ``axis`` (``"excitation.frequency"`` -> ``"frequency"``)."""
    section, _, key = axis.partition(".")
    if section == "excitation":
        return key if key in ("frequency", "amplitude") else "excitation"
    return setting_column(key)


def repetition_seed(seed: int, point: int, repetition: int) -> np.random.SeedSequence:
    """The seed of one repetition: ``SeedSequence(seed).spawn(...)[point].spawn(...)[repetition]``."""
    return np.random.SeedSequence(seed, spawn_key=(point, repetition))


@dataclasses.dataclass(frozen=True)
class PointResult:
    """All estimators' outcomes at one grid point.

    Attributes
    ----------
    point : GridPoint
    outcomes : tuple of MethodOutcome
        In the scenario's method order.
    crb : dict of str to float, or None
        Cramér-Rao standard errors of ``a`` and ``b`` (linear settings without jitter or
        drops, where ``identify.uncertainty.cramer_rao_bound`` applies), else None.
    samples_simulated : int
        Samples actually simulated (a noise-free setting is simulated once, its repetitions
        being identical).
    batched : bool
        Whether the batch engine ran this point.
    """

    point: GridPoint
    outcomes: tuple
    crb: dict | None
    samples_simulated: int
    batched: bool

    def rows(self) -> list[dict]:
        """The CSV rows of this point (see :data:`CSV_COLUMNS`)."""
        s = self.point.setting
        base = {"point": self.point.index, **{setting_column(k.name): getattr(s, k.name) for k in bench_knobs()},
                "excitation": s.excitation, "frequency": s.frequency, "amplitude": s.amplitude,
                "n_samples": s.n_samples}
        return [dict(base, **self._statistics(o)) for o in self.outcomes]

    def _statistics(self, outcome: MethodOutcome) -> dict:
        s = self.point.setting
        n = len(outcome.a)
        row = {"method": outcome.method, "repetitions": n, "successes": n - outcome.n_failed,
               "failures": outcome.n_failed, "failure_reasons": outcome.failure_summary()}
        for name, truth in (("a", s.a), ("b", s.b)):
            st = outcome.statistics(name, truth)
            row.update({f"mean_{name}": st["mean"], f"bias_{name}_pct": st["bias_pct"],
                        f"std_{name}": st["std"], f"rmse_{name}": st["rmse"],
                        f"crb_{name}": self.crb[name] if self.crb else math.nan})
        return row


def _crb(setting: Setting, duty: np.ndarray) -> dict | None:
    motor = setting.motor()
    if not (motor.is_linear and motor.input_delay == 0 and setting.jitter == 0 and setting.drop_rate == 0
            and not setting.record_speed):
        return None
    bound = cramer_rao_bound(setting.a, setting.b, duty, setting.sample_period,
                             counts_per_rev=setting.counts_per_rev, angle_noise=setting.angle_noise,
                             initial_speed=setting.initial_speed)
    return bound.stderr()


def _fit_or_reason(recording: Recording, method: str, auto_delay: bool = False) -> tuple[float, float, str]:
    """Fit; where the setting has an input delay, methods that take ``input_delay`` choose it ("auto")."""
    from identify.methods import method_options
    options = {"input_delay": "auto"} if auto_delay and "input_delay" in method_options(method) else {}
    try:
        est = fit(recording, method=method, **options)
    except Exception as exc:  # a failed fit is an outcome of the sweep, whatever the estimator raised
        return math.nan, math.nan, f"{type(exc).__name__}: {exc}".replace("\n", " ")
    return est.a, est.b, ""


def run_point(point: GridPoint, methods: Sequence[str], repetitions: int, seed: int, *,
              batch: bool = True) -> PointResult:
    """Run every repetition of one grid point and fit it with every method.

    Parameters
    ----------
    point : GridPoint
        The setting (and its index, which selects the seeds).
    methods : sequence of str
        Estimator names (``identify.available_methods()``).
    repetitions : int
        Monte Carlo repetitions, >= 1.
    seed : int
        The scenario's root seed.
    batch : bool
        Use the batch engine where the setting allows it (default).  ``False`` runs
        ``SimRig.run`` + ``identify.fit`` per repetition; both give the same estimates
        (to rounding, see ``tests/scenarios/test_sweep.py``).

    Returns
    -------
    PointResult
    """
    methods = _check_point_arguments(point, methods, repetitions)
    s = point.setting
    exp = s.experiment()
    # Without noise, jitter or drops every repetition is the same run: simulate it once.
    distinct = repetitions if s.needs_rng else 1
    fits = _Fits(methods, distinct, auto_delay=s.motor().input_delay > 0)
    batched = batch and _is_batchable(s)
    if batched:
        _run_batched(s, exp, fits, seed, point.index)
    else:
        _run_each(s, exp, fits, seed, point.index)
    copies = repetitions // distinct
    outcomes = tuple(MethodOutcome(m, np.tile(fits.a[m], copies), np.tile(fits.b[m], copies),
                                   tuple(fits.why[m]) * copies) for m in methods)
    return PointResult(point, outcomes, _crb(s, exp.duty()), distinct * exp.n_samples, batched)


def _check_point_arguments(point: GridPoint, methods: Sequence[str], repetitions: int) -> list[str]:
    from identify import available_methods
    if not isinstance(point, GridPoint):
        raise TypeError(f"point must be a GridPoint, got {type(point).__name__}")
    check_int("repetitions", repetitions, lo=1, allow_integral_float=False)
    methods = list(methods)
    unknown = [m for m in methods if m not in available_methods()]
    if not methods or unknown:
        raise ValueError(f"methods must be a non-empty list of names among {available_methods()}, got {methods!r}")
    return methods


def _is_batchable(s: Setting) -> bool:
    # a setting with an input delay is fitted with input_delay="auto", which the batch engine does not do
    return (not s.record_speed and s.motor().input_delay == 0
            and is_batchable(s.motor(), jitter=s.jitter, drop_rate=s.drop_rate))


class _Fits:
    """Estimates of a and b and failure reasons, per method and repetition (filled in place)."""

    def __init__(self, methods: Sequence[str], repetitions: int, auto_delay: bool = False):
        self.methods = list(methods)
        self.auto_delay = auto_delay
        self.a = {m: np.full(repetitions, np.nan) for m in methods}
        self.b = {m: np.full(repetitions, np.nan) for m in methods}
        self.why = {m: [""] * repetitions for m in methods}

    @property
    def repetitions(self) -> int:
        return len(self.why[self.methods[0]])

    def fit(self, r: int, recording: Recording, methods: Sequence[str]) -> None:
        """Fit repetition ``r`` with each of ``methods`` through ``identify.fit``."""
        for m in methods:
            self.a[m][r], self.b[m][r], self.why[m][r] = _fit_or_reason(recording, m, self.auto_delay)


def _run_each(s: Setting, exp, fits: _Fits, seed: int, index: int) -> None:
    """One ``SimRig.run`` and one ``identify.fit`` per repetition and method: the users' path."""
    for r in range(fits.repetitions):
        rng = np.random.default_rng(repetition_seed(seed, index, r))
        fits.fit(r, s.sim_rig(rng).run(exp), fits.methods)


def _run_batched(s: Setting, exp, fits: _Fits, seed: int, index: int) -> None:
    """All repetitions through the batch engine, in chunks of about ``_CHUNK_SAMPLES`` samples.

    Batched estimators fit whole chunks, ``oe`` too (:mod:`scenarios.batch_output_error`,
    rows it cannot fit fall back to ``identify.fit``); the others get one Recording per
    repetition built from the same counts.
    """
    duty, n = exp.duty(), exp.n_samples
    angle, _ = simulate_batch(s.motor(), duty, s.sample_period, initial_speed=s.initial_speed)
    batched = [m for m in fits.methods if m in BATCHED_METHODS]
    other = [m for m in fits.methods if m not in BATCHED_METHODS]
    chunk = max(1, _CHUNK_SAMPLES // n)
    for lo in range(0, fits.repetitions, chunk):
        hi = min(fits.repetitions, lo + chunk)
        rngs = [np.random.default_rng(repetition_seed(seed, index, r)) for r in range(lo, hi)]
        counts = encoder_counts_batch(np.broadcast_to(angle, (hi - lo, n)), s.counts_per_rev, s.angle_noise, rngs)
        counts += s.count_offset
        if batched:
            speed = speed_batch(counts, s.counts_per_rev, s.sample_period)
            for m, f in fit_batch(batched, speed, duty, s.sample_period).items():
                fits.a[m][lo:hi], fits.b[m][lo:hi] = f.a, f.b
                fits.why[m][lo:hi] = f.failure
        recordings = [_batch_recording(s, duty, row) for row in counts]
        rest = {j: list(other) for j in range(hi - lo)}
        if "oe" in other and _oe_batchable(recordings[0]):
            a, b = _output_error_rows(s, counts, duty)
            for j in map(int, np.flatnonzero(np.isfinite(a))):
                fits.a["oe"][lo + j], fits.b["oe"][lo + j] = a[j], b[j]
                rest[j].remove("oe")
        for j, methods in rest.items():
            if methods:
                fits.fit(lo + j, recordings[j], methods)


def _batch_recording(s: Setting, duty: np.ndarray, counts: np.ndarray) -> Recording:
    return Recording(time=np.arange(len(duty)) * s.sample_period, duty=duty, sample_period=s.sample_period,
                     counts=counts.astype(np.int64), counts_per_rev=s.counts_per_rev,
                     metadata={"source": "scenarios.batch"})


def _oe_batchable(recording: Recording) -> bool:
    """Whether ``oe`` would take its separable path: the shared duty excites, the segment is uniform."""
    import warnings

    from identify.data import as_recordings, check_excitation, prepare_segments
    from identify.variable_projection import is_separable
    recs = as_recordings(recording)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_excitation(recs, 2)
    except ValueError:
        return False
    segments = prepare_segments(recs, 0)
    return len(segments) == 1 and is_separable(segments, with_bias=False)


def _output_error_rows(s: Setting, counts: np.ndarray, duty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``oe`` of every row at once, started from ``zoh-ls``'s regression on the same counts.

    The fit's minimum does not depend on where it starts (the per-fit path starts
    unstartable rows on a grid of ``a``, here at the other rows' median: a test checks
    that the estimates agree).
    """
    speed = speed_batch(counts, s.counts_per_rev, s.sample_period)
    theta1, _, _ = regression_batch(speed, duty)
    with np.errstate(invalid="ignore", divide="ignore"):
        start = np.where((theta1 > 0) & (theta1 < 1), -np.log(theta1) / s.sample_period, np.nan)
    angle = counts * (2.0 * math.pi / s.counts_per_rev)
    a, b = output_error_batch(angle, duty, s.sample_period, start)
    # rows the regression could not start (noisy, fast sines): from the median of the fitted
    # rows, or from identify's grid start on the first row when none was fitted
    late = np.flatnonzero(~np.isfinite(start))
    if len(late):
        if np.any(np.isfinite(a)):
            a0 = float(np.nanmedian(a))
        else:
            from identify.data import as_recordings, prepare_segments
            from identify.start import grid_guess
            a0 = grid_guess(prepare_segments(as_recordings(_batch_recording(s, duty, counts[late[0]])), 0))[0]
        a[late], b[late] = output_error_batch(angle[late], duty, s.sample_period, np.full(len(late), a0))
    return a, b


def _run_point_job(point: GridPoint, methods: tuple, repetitions: int, seed: int) -> PointResult:
    """Module-level entry for executors (picklable)."""
    return run_point(point, methods, repetitions, seed)


def _in_order(executor: concurrent.futures.Executor | None, jobs: Iterable[tuple], window: int
              ) -> Iterator[PointResult]:
    """Results of ``_run_point_job(*job)`` in job order, with at most ``window`` jobs in flight."""
    if executor is None:
        for job in jobs:
            yield _run_point_job(*job)
        return
    from .interrupts import interrupts_deferred
    pending: collections.deque = collections.deque()
    for job in jobs:
        with interrupts_deferred():    # a submit may start the workers
            pending.append(executor.submit(_run_point_job, *job))
        if len(pending) >= window:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


def _format(value) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


@dataclasses.dataclass(frozen=True)
class SweepSummary:
    """What a sweep produced.

    Attributes
    ----------
    scenario : Scenario
    csv_path, json_path : Path
    n_points, n_rows : int
    samples_simulated : int
        Simulated samples over all points and repetitions.
    failures : dict of str to int
        Failed fits per method.
    elapsed : float
        Wall-clock seconds.
    """

    scenario: Scenario
    csv_path: Path
    json_path: Path
    n_points: int
    n_rows: int
    samples_simulated: int
    failures: dict
    elapsed: float


def run_scenario(scenario: Scenario, out_dir: str | os.PathLike, *, workers: int | None = None,
                 executor: concurrent.futures.Executor | None = None, progress: bool | None = None
                 ) -> SweepSummary:
    """Run a scenario and write ``sweep.csv`` and ``summary.json`` into ``out_dir``.

    Parameters
    ----------
    scenario : Scenario
    out_dir : path
        Created if needed.
    workers : int, optional
        Processes to use when no ``executor`` is given (default: every core; more than the
        cores is clamped to them, see :func:`usable_workers`; 1 runs in this process).
        Workers start warm, forked from this process or a fork server once motorid is imported
        (:func:`worker_context`).
    executor : concurrent.futures.Executor, optional
        Any executor (e.g. Dask's ``Client(...).get_executor()``); used as given, not shut down.
    progress : bool, optional
        Progress bar on stderr; default: only when stderr is a terminal.

    Returns
    -------
    SweepSummary

    Notes
    -----
    The CSV is the same byte for byte whatever the executor or the number of workers.

    Examples
    --------
    Two sine frequencies, the article's regression against output error, noise-free
    (so both repetitions are the same run):

    >>> import tempfile
    >>> from scenarios.scenario import scenario_from_dict
    >>> scenario = scenario_from_dict({"name": "tiny", "repetitions": 2, "methods": ["zoh-ls", "oe"],
    ...                                "bench": {"duration": 1.0},
    ...                                "grid": {"excitation.frequency": [10, 20]}})
    >>> with tempfile.TemporaryDirectory() as out:
    ...     summary = run_scenario(scenario, out, workers=1, progress=False)
    ...     rows = read_sweep_csv(summary.csv_path)
    >>> summary.n_points, summary.n_rows
    (2, 4)
    >>> for r in rows:
    ...     print(r["frequency"], r["method"], f"{r['mean_a']:.2f}", int(r["failures"]))
    10.0 zoh-ls 23.28 0
    10.0 oe 25.00 0
    20.0 zoh-ls 22.61 0
    20.0 oe 25.00 0
    """
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario must be a Scenario, got {type(scenario).__name__}")
    if workers is not None:
        check_int("workers", workers, lo=1, allow_integral_float=False)
    out = Path(out_dir)
    make_output_dir(out)
    jobs = ((p, scenario.methods, scenario.repetitions, scenario.seed) for p in scenario.points())
    t0 = time.perf_counter()
    tally = _Tally(scenario.methods)
    with _points_executor(workers, executor) as (pool, window), \
            ProgressBar(scenario.n_points, f"sweep {scenario.name}", enabled=progress) as bar:
        csv_path = _write_csv(out / "sweep.csv", _in_order(pool, jobs, window), tally, bar)
    elapsed = time.perf_counter() - t0
    json_path = _write_summary_json(out / "summary.json", scenario, tally, elapsed, csv_path.name)
    return SweepSummary(scenario, csv_path, json_path, scenario.n_points, tally.n_rows, tally.samples,
                        dict(tally.failures), elapsed)


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
    import threading
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

    The parent turns SIGTERM and SIGHUP into an orderly stop (:mod:`scenarios.interrupts`)
    and terminates its workers itself; a worker that ran that handler would print a
    traceback.  Ctrl-C reaches the whole process group: the parent handles it.
    """
    import signal
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _points_executor(workers: int | None, executor: concurrent.futures.Executor | None
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


class _Tally:
    """What the summary reports, accumulated row by row."""

    def __init__(self, methods: Sequence[str]):
        self.n_rows = 0
        self.samples = 0
        self.failures = collections.Counter({m: 0 for m in methods})
        self.worst = {m: 0.0 for m in methods}

    def add(self, result: PointResult) -> list[dict]:
        """Count a point's rows, failures and samples; return its rows."""
        rows = result.rows()
        for row in rows:
            self.n_rows += 1
            self.failures[row["method"]] += row["failures"]
            if math.isfinite(row["bias_a_pct"]):
                self.worst[row["method"]] = max(self.worst[row["method"]], abs(row["bias_a_pct"]))
        self.samples += result.samples_simulated
        return rows


def _write_csv(path: Path, results: Iterable[PointResult], tally: _Tally, bar: ProgressBar) -> Path:
    """Stream the rows of ``results`` to a temporary file that becomes ``path`` when complete.

    An interrupted or failed sweep leaves no CSV (and the previous one, if any, unchanged).
    """
    with atomic_writer(path) as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for result in results:
            for row in tally.add(result):
                writer.writerow([_format(row[c]) for c in CSV_COLUMNS])
            bar.update()
    return path


def _write_summary_json(path: Path, scenario: Scenario, tally: _Tally, elapsed: float, csv_name: str) -> Path:
    return write_atomically(path, json.dumps({
        "scenario": scenario.name, "description": scenario.description, "seed": scenario.seed,
        "repetitions": scenario.repetitions, "methods": list(scenario.methods),
        "grid": {axis: list(values) for axis, values in scenario.grid},
        "grid_columns": {axis: axis_column(axis) for axis in scenario.axes},
        "base": dict(scenario.base), "points": scenario.n_points, "rows": tally.n_rows,
        "samples_simulated": tally.samples, "elapsed_s": round(elapsed, 3),
        "failures": dict(tally.failures), "worst_abs_bias_a_pct": tally.worst, "csv": csv_name,
    }, indent=1))


def read_sweep_csv(path: str | os.PathLike) -> list[dict]:
    """Rows of a sweep CSV with numbers parsed (empty cells become nan, ``True``/``False`` bools)."""
    text_cols = {"excitation", "method", "failure_reasons"}
    with open(path, encoding="utf-8", newline="") as f:
        return [{k: (v if k in text_cols else _parse_cell(v)) for k, v in raw.items()} for raw in csv.DictReader(f)]


def _parse_cell(text: str) -> float | bool:
    if text in ("True", "False"):
        return text == "True"
    return float(text) if text != "" else math.nan


def make_plots(scenario: Scenario, csv_path: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """The PNGs of a sweep: bias and spread against frequency and heatmaps of |bias| of a and b.

    The bias plot is against frequency, or when frequency is not a grid axis, against the
    first numeric axis; the heatmaps span the first two numeric grid axes (other axes held
    at their first value).
    """
    from . import plots
    out = Path(out_dir)
    rows = read_sweep_csv(csv_path)
    columns = list(dict.fromkeys(axis_column(a) for a in scenario.axes))
    numeric = [c for c in columns if c != "excitation"]
    paths = []
    if numeric:
        x = "frequency" if "frequency" in numeric else numeric[0]
        others = [c for c in columns if c != x]
        paths.append(out / f"bias_vs_{x}.png")
        plots.plot_sweep_frequency(rows, paths[-1], others=others, x=x,
                                   title=f"{scenario.name}: bias and spread against {x}")
    if len(numeric) >= 2:
        x, y = numeric[0], numeric[1]
        fixed = {c: rows[0][c] for c in columns if c not in (x, y)}
        sub = [r for r in rows if all(r[c] == v for c, v in fixed.items())]
        note = ("; " + ", ".join(f"{c}={v:g}" if isinstance(v, float) else f"{c}={v}" for c, v in fixed.items())
                if fixed else "")
        for name in ("a", "b"):
            paths.append(out / f"heatmap_bias_{name}.png")
            plots.plot_sweep_heatmap(sub, x, y, paths[-1], value=f"bias_{name}_pct",
                                     value_label=f"|bias of {name}| [% of the true {name}]",
                                     title=f"{scenario.name}: |bias of {name}| in %{note}")
    return paths


def format_sweep_table(scenario: Scenario, rows: Sequence[dict]) -> str:
    """The sweep as a table: grid values, method, mean +- std and bias of a and b, the CRB, failures."""
    cols = list(dict.fromkeys(axis_column(a) for a in scenario.axes))
    def cell(v):
        return f"{v:g}" if isinstance(v, float) else str(v)
    widths = [max(len(c), *(len(cell(r[c])) for r in rows)) for c in cols]
    head = " ".join(f"{c:>{w}}" for c, w in zip(cols, widths)) + (
        f" {'method':<10} {'a mean ± std':>22} {'a bias %':>9} {'CRB a':>8} "
        f"{'b mean ± std':>22} {'b bias %':>9} {'CRB b':>8} {'fail':>5}")
    lines = [head, "-" * len(head)]

    def num(v, spec):
        return "-" if math.isnan(v) else format(v, spec)
    for r in rows:
        lines.append(" ".join(f"{cell(r[c]):>{w}}" for c, w in zip(cols, widths))
                     + f" {r['method']:<10} {num(r['mean_a'], '.4f'):>11} ± {num(r['std_a'], '.2g'):<8}"
                     f" {num(r['bias_a_pct'], '+.3f'):>9} {num(r['crb_a'], '.2g'):>8}"
                     f" {num(r['mean_b'], '.5f'):>11} ± {num(r['std_b'], '.2g'):<8}"
                     f" {num(r['bias_b_pct'], '+.3f'):>9} {num(r['crb_b'], '.2g'):>8} {int(r['failures']):>5d}")
    return "\n".join(lines)


def add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid sweep``."""
    parser.add_argument("scenario", nargs="?", metavar="NAME|FILE.toml",
                        help="a built-in scenario (see --list) or a scenario file")
    from .budget import add_max_memory_flag
    add_max_memory_flag(parser)
    parser.add_argument("--list", action="store_true", help="list the built-in scenarios and exit")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="folder for sweep.csv, summary.json and the PNGs (default sweep-output/NAME)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes (default: all cores; more are clamped to the cores; "
                             "1 runs in this process)")
    parser.add_argument("--repetitions", type=int, default=None, metavar="N",
                        help="Monte Carlo repetitions per grid point (default: the scenario's)")
    parser.add_argument("--methods", default=None, metavar="all|M,M,...",
                        help="estimators to compare instead of the scenario's (e.g. all, or oe,oe-friction)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run on a Dask cluster (scheduler address, or 'local' for a LocalCluster of "
                             "--workers processes; gives up after 10 s without a scheduler); the scheduler "
                             "runs code of its choosing here: use only one you trust; needs motorid[dask]")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no table")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")


def run_sweep(args: argparse.Namespace) -> int:
    """``motorid sweep``: the CLI glue around :func:`run_scenario`."""
    from .scenario import builtin_scenarios
    if args.list:
        for name, description in builtin_scenarios().items():
            print(f"{name:<16} {description}")
        return 0
    scenario = _scenario_from_args(args)
    from .budget import check_sweep
    check_sweep(scenario, args.max_memory)
    out = Path(args.out or Path("sweep-output") / safe_file_name(scenario.name, "scenario"))
    if args.workers and not args.dask and args.workers > usable_workers(args.workers):
        print(f"--workers {args.workers}: using {usable_workers(args.workers)}, the cores available "
              "(more processes than cores only slow a sweep down)", file=sys.stderr)
    if not args.quiet:
        from .sweep_time import estimate_sweep_time
        print_to_stderr(estimate_sweep_time(scenario, args.workers).describe(scenario))
    with _dask_executor(args.dask, args.workers) as executor:
        summary = run_scenario(scenario, out, workers=args.workers, executor=executor,
                               progress=False if args.quiet else None)
    if not args.quiet:
        print(f"{scenario.name}: {scenario.description}")
        print(f"{summary.n_points} points x {len(scenario.methods)} methods x {scenario.repetitions} repetitions, "
              f"{summary.samples_simulated:,} samples simulated in {summary.elapsed:.2f} s\n")
        rows = read_sweep_csv(summary.csv_path)
        print(format_sweep_table(scenario, rows) if len(rows) <= 200 else f"({len(rows)} rows: see the CSV)")
    paths = [] if args.no_plots else make_plots(scenario, summary.csv_path, out)
    print(f"\nwrote {summary.csv_path}, {summary.json_path}" + "".join(f", {p}" for p in paths))
    return 0


def _scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The scenario the flags name, with ``--repetitions`` and ``--methods`` applied."""
    from .scenario import load_scenario
    if not args.scenario:
        raise CommandError("sweep needs a scenario NAME or FILE.toml (see motorid sweep --list)")
    if args.workers is not None and args.workers < 1:
        raise CommandError(f"--workers must be >= 1, got {args.workers}")
    scenario = load_scenario(args.scenario)
    if args.repetitions is not None:
        scenario = scenario.with_repetitions(args.repetitions)
    if args.methods is not None:
        scenario = scenario.with_methods("all" if args.methods == "all"
                                         else [m.strip() for m in args.methods.split(",") if m.strip()])
    return scenario


#: Seconds ``--dask ADDRESS`` waits for the scheduler before giving up.
DASK_CONNECT_TIMEOUT = 10.0


def _connect_dask(client_class, address: str):
    """A Dask client on ``address``, or a one-line :class:`CommandError` within :data:`DASK_CONNECT_TIMEOUT` s."""
    try:
        return client_class(address, timeout=DASK_CONNECT_TIMEOUT)
    except (OSError, TimeoutError) as exc:
        raise CommandError(f"--dask {address}: no Dask scheduler answered within {DASK_CONNECT_TIMEOUT:g} s "
                           f"({type(exc).__name__}: {exc}); check the address (tcp://HOST:8786, tls://...) "
                           f"and that the scheduler runs") from None
    except Exception as exc:    # whatever a server that is not a Dask scheduler makes the client raise
        raise CommandError(f"--dask {address}: the server there does not speak Dask's protocol "
                           f"({type(exc).__name__}: {str(exc)[:200]})") from None


@contextlib.contextmanager
def _dask_executor(address: str | None, workers: int | None) -> Iterator[concurrent.futures.Executor | None]:
    """A Dask client's executor for ``--dask ADDRESS`` (``local``: a LocalCluster), else None."""
    if not address:
        yield None
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise CommandError("--dask needs Dask: pip install 'motorid[dask]'") from None
    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        client = _connect_dask(Client, address)
    try:
        yield client.get_executor()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
