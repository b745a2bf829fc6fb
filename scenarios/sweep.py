"""Scenario sweeps: every grid point x estimator x repetition, in parallel, streamed to a tidy CSV.

:func:`run_point` does one grid point: all its repetitions at once through the
batch engine (simulated by :mod:`motorsim.batch`, fitted by :mod:`identify.fits.batch`) when the
setting is linear and every sample arrives, else one :meth:`SimRig.run <motorsim.rig.SimRig.run>`
and one :func:`identify.fit` per repetition -- the path users take.  Estimators with a
batched implementation (``identify.BATCHED_METHODS``, and ``oe``) use it; any other
name from ``identify.available_methods()`` is fitted with ``identify.fit`` on
recordings of the same counts.  Where the setting has an input delay, every
method that takes ``input_delay`` is fitted with ``input_delay="auto"`` (one
recording at a time); where it has none, at ``input_delay=0``.  A fit that raises is a counted failure with its reason,
never a crash of the sweep.

:func:`run_scenario` (also :func:`scenarios.run_sweep`) spreads the grid points over a
``concurrent.futures.Executor`` (processes by default, or any executor given,
e.g. Dask's ``Client(...).get_executor()``; :mod:`scenarios.executors`), keeps at
most a few points in flight and writes each point's rows as soon as it and all
points before it are done, so memory does not grow with the grid.  The command
line around it (``motorid sweep``: flags, table, figures) is
:mod:`motorid.commands.sweep`.

Seeds never depend on the workers: repetition ``r`` of grid point ``i`` draws
from ``SeedSequence(seed, spawn_key=(i, r))``, which is
``SeedSequence(seed).spawn(n_points)[i].spawn(repetitions)[r]``.
"""
from __future__ import annotations

import collections
import concurrent.futures
import csv
import dataclasses
import json
import math
import os
import re
import time
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from identify import (
    BATCHED_METHODS,
    BatchFit,
    cramer_rao_bound,
    fit,
    fit_batch,
    fit_output_error_batch,
    output_error_batchable,
)
from motorsim.batch import encoder_counts_batch, is_batchable, simulate_batch, speed_batch, unbatchable_parts
from motorsim.checks import ParameterError, ParameterTypeError, check_int
from motorsim.files import atomic_writer, make_output_dir, write_atomically
from motorsim.recording import Recording
from motorsim.rig import bench_knobs

from .executors import points_executor, results_in_order
from .scenario import PLANT_PARAMETERS, GridPoint, Scenario, Setting

__all__ = ["MethodOutcome", "PointResult", "SweepSummary", "run_point", "run_scenario", "CSV_COLUMNS",
           "SETTING_COLUMNS", "setting_column", "axis_column", "read_sweep_csv", "repetition_seed", "runs_batched"]


def setting_column(knob: str) -> str:
    """The CSV column of a bench knob: its name, except ``true_a`` and ``true_b`` for the motor's a and b."""
    return f"true_{knob}" if knob in ("a", "b") else knob


#: The setting's columns beside the bench knobs: the plant's structure and the structures' further parameters.
_PLANT_COLUMNS = ("structure", *PLANT_PARAMETERS)
#: Columns of the tidy CSV, one row per grid point x estimator: every bench knob, the plant's structure and
#: parameters, then the excitation.
SETTING_COLUMNS = (*(setting_column(k.name) for k in bench_knobs()), *_PLANT_COLUMNS, "excitation", "frequency",
                   "amplitude", "n_samples")
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
class MethodOutcome(BatchFit):
    """One estimator's results over the repetitions of one grid point (the fields of
    :class:`identify.BatchFit`: ``method``, ``a``, ``b``, ``failure``), with their failures summarised."""

    @property
    def n_failed(self) -> int:
        """Failed repetitions."""
        return sum(1 for f in self.failure if f)

    def failure_summary(self, top: int = 3) -> str:
        """The most common reasons with their counts, ``reason (n) | ...``.

        Reasons are grouped by their words with every number masked as ``#`` (``cond 3.1e+08`` and
        ``cond 2.7e+08`` are one reason); a group shows its first message as it was.
        """
        first: dict[str, str] = {}
        counts: collections.Counter[str] = collections.Counter()
        for reason in self.failure:
            if reason:
                key = _NUMBER.sub("#", reason)
                first.setdefault(key, reason)
                counts[key] += 1
        return " | ".join(f"{first[key]} ({n})" for key, n in counts.most_common(top))

    def statistics(self, name: str, truth: float) -> dict[str, float]:
        """Mean, bias in % of ``truth``, standard deviation (ddof 1) and RMSE of parameter ``name``."""
        x = getattr(self, name)
        x = x[np.isfinite(x)]
        if len(x) == 0:
            return {"mean": math.nan, "bias_pct": math.nan, "std": math.nan, "rmse": math.nan}
        # Deviations from the first value first, so identical repetitions give a std of exactly 0.
        d = x - x[0]
        mean = float(x[0] + np.mean(d))
        return {"mean": mean, "bias_pct": 100.0 * (mean - truth) / truth,
                "std": float(np.std(d, ddof=1)) if len(x) > 1 else math.nan,
                "rmse": float(np.sqrt(np.mean((x - truth) ** 2)))}


#: A number in a message (integer, decimal, exponent, sign), masked when reasons are grouped.
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


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
        drops, where ``identify.checks.uncertainty.cramer_rao_bound`` applies), else None.
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
                **{name: getattr(s, name) for name in _PLANT_COLUMNS}, "excitation": s.excitation,
                "frequency": s.frequency, "amplitude": s.amplitude,
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
    # the bound of the first-order motor: for that plant alone (an electrical lag is linear but not it)
    if not (motor.is_linear and not unbatchable_parts(motor) and motor.input_delay == 0 and setting.jitter == 0
            and setting.drop_rate == 0
            and not setting.record_speed):
        return None
    bound = cramer_rao_bound(setting.a, setting.b, duty, setting.sample_period,
                             counts_per_rev=setting.counts_per_rev, angle_noise=setting.angle_noise,
                             initial_speed=setting.initial_speed)
    return bound.stderr()


def _fit_or_reason(recording: Recording, method: str, auto_delay: bool = False) -> tuple[float, float, str]:
    """Fit; where the setting has an input delay, methods that take ``input_delay`` choose it ("auto"), where it
    has none they are fitted at 0 (as the batch engine fits every row)."""
    from identify import method_options
    options = {"input_delay": "auto" if auto_delay else 0} if "input_delay" in method_options(method) else {}
    try:
        est = fit(recording, method=method, outliers="keep", **options)
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
    batched = batch and runs_batched(s)
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
        raise ParameterTypeError(f"point must be a GridPoint, got {type(point).__name__}")
    check_int("repetitions", repetitions, lo=1, allow_integral_float=False)
    methods = list(methods)
    unknown = [m for m in methods if m not in available_methods()]
    if not methods or unknown:
        raise ParameterError(f"methods must be a non-empty list of names among {available_methods()}, got {methods!r}")
    return methods


def runs_batched(s: Setting) -> bool:
    """Whether :func:`run_point` runs this setting's repetitions together through the batch engine.

    A setting with an input delay is fitted with ``input_delay="auto"``, which the batch engine
    does not do, so it runs one repetition at a time.
    """
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

    Batched estimators fit whole chunks (:mod:`identify.fits.batch`), ``oe`` too (rows it cannot fit
    fall back to ``identify.fit``); the others get one Recording per
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
        if "oe" in other and output_error_batchable(recordings[0]):
            a, b = fit_output_error_batch(counts, duty, s.sample_period, s.counts_per_rev)
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


def _run_point_job(point: GridPoint, methods: tuple, repetitions: int, seed: int) -> PointResult:
    """Module-level entry for executors (picklable)."""
    return run_point(point, methods, repetitions, seed)


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
                 executor: concurrent.futures.Executor | None = None,
                 progress: Callable[[int], object] | None = None) -> SweepSummary:
    """Run a scenario and write ``sweep.csv`` and ``summary.json`` into ``out_dir``.

    Parameters
    ----------
    scenario : Scenario
    out_dir : path
        Created if needed.
    workers : int, optional
        Processes to use when no ``executor`` is given (default: every core; more than the
        cores is clamped to them, see :func:`scenarios.executors.usable_workers`; 1 runs in
        this process).  Workers start warm, forked from this process or a fork server once
        motorid is imported (:func:`scenarios.executors.worker_context`).
    executor : concurrent.futures.Executor, optional
        Any executor (e.g. Dask's ``Client(...).get_executor()``); used as given, not shut down.
    progress : callable, optional
        Called with the number of grid points done after each point (``motorid sweep``
        passes its progress bar's ``set``); default: nothing is reported.

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
    ...     summary = run_scenario(scenario, out, workers=1)
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
        raise ParameterTypeError(f"scenario must be a Scenario, got {type(scenario).__name__}")
    if workers is not None:
        check_int("workers", workers, lo=1, allow_integral_float=False)
    out = Path(out_dir)
    make_output_dir(out)
    jobs = ((p, scenario.methods, scenario.repetitions, scenario.seed) for p in scenario.points())
    t0 = time.perf_counter()
    tally = _Tally(scenario.methods)
    with points_executor(workers, executor) as (pool, window):
        csv_path = _write_csv(out / "sweep.csv", results_in_order(pool, _run_point_job, jobs, window), tally,
                              progress)
    elapsed = time.perf_counter() - t0
    json_path = _write_summary_json(out / "summary.json", scenario, tally, elapsed, csv_path.name)
    return SweepSummary(scenario, csv_path, json_path, scenario.n_points, tally.n_rows, tally.samples,
                        dict(tally.failures), elapsed)


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


def _write_csv(path: Path, results: Iterable[PointResult], tally: _Tally,
               progress: Callable[[int], object] | None) -> Path:
    """Stream the rows of ``results`` to a temporary file that becomes ``path`` when complete.

    An interrupted or failed sweep leaves no CSV (and the previous one, if any, unchanged).
    """
    with atomic_writer(path) as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for done, result in enumerate(results, 1):
            for row in tally.add(result):
                writer.writerow([_format(row[c]) for c in CSV_COLUMNS])
            if progress is not None:
                progress(done)
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
    text_cols = {"excitation", "method", "failure_reasons", "structure"}
    with open(path, encoding="utf-8", newline="") as f:
        return [{k: (v if k in text_cols else _parse_cell(v)) for k, v in raw.items()} for raw in csv.DictReader(f)]


def _parse_cell(text: str) -> float | bool:
    if text in ("True", "False"):
        return text == "True"
    return float(text) if text != "" else math.nan


