"""Scenario sweeps: every grid point x estimator x repetition, in parallel, streamed to a tidy CSV.

:func:`run_point` does one grid point: all its repetitions at once through the
batch engine (:mod:`scenarios.batch`) when the setting is linear and every
sample arrives, else one :meth:`SimRig.run <motorsim.rig.SimRig.run>` and one
:func:`identify.fit` per repetition -- the path users take.  Estimators with a
batched implementation (``scenarios.batch.BATCHED_METHODS``) use it; any other
name from ``identify.available_methods()`` is fitted with ``identify.fit`` on
recordings of the same counts.  A fit that raises is a counted failure with
its reason, never a crash of the sweep.

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
import csv
import dataclasses
import json
import math
import multiprocessing
import os
import time
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from identify import fit
from identify.uncertainty import cramer_rao_bound
from motorsim.recording import Recording

from .batch import (BATCHED_METHODS, MethodOutcome, encoder_counts_batch, fit_batch, is_batchable,
                    simulate_batch, speed_batch)
from .progress import ProgressBar
from .scenario import GridPoint, Scenario, Setting

__all__ = ["MethodOutcome", "PointResult", "SweepSummary", "run_point", "run_scenario", "CSV_COLUMNS",
           "axis_column", "read_sweep_csv", "repetition_seed", "make_plots", "format_sweep_table",
           "add_sweep_arguments", "run_sweep"]

#: Columns of the tidy CSV, one row per grid point x estimator.
SETTING_COLUMNS = ("true_a", "true_b", "friction", "bias", "dead_zone", "input_delay", "sample_period",
                   "counts_per_rev", "angle_noise", "jitter", "drop_rate", "duration", "duty_limit",
                   "initial_speed", "excitation", "frequency", "amplitude", "n_samples")
STAT_COLUMNS = ("method", "repetitions", "successes", "failures", "failure_reasons",
                "mean_a", "bias_a_pct", "std_a", "rmse_a", "crb_a",
                "mean_b", "bias_b_pct", "std_b", "rmse_b", "crb_b")
CSV_COLUMNS = ("point", *SETTING_COLUMNS, *STAT_COLUMNS)

#: Repetitions are batched in chunks of about this many samples (bounded memory per worker).
_CHUNK_SAMPLES = 1 << 21


def axis_column(axis: str) -> str:
    """The CSV column holding grid axis ``axis`` (``"excitation.frequency"`` -> ``"frequency"``)."""
    section, _, key = axis.partition(".")
    if section == "motor" and key in ("a", "b"):
        return f"true_{key}"
    if section == "excitation":
        return key if key in ("frequency", "amplitude") else "excitation"
    return key


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
        exc = s.excitation_object()
        amps = getattr(exc, "amplitudes", ())
        base = {"point": self.point.index, "true_a": s.a, "true_b": s.b, "friction": s.friction, "bias": s.bias,
                "dead_zone": s.dead_zone, "input_delay": s.input_delay, "sample_period": s.sample_period,
                "counts_per_rev": s.counts_per_rev, "angle_noise": s.angle_noise, "jitter": s.jitter,
                "drop_rate": s.drop_rate, "duration": s.duration, "duty_limit": s.duty_limit,
                "initial_speed": s.initial_speed, "excitation": s.excitation, "frequency": s.frequency,
                "amplitude": float(amps[0]) if len(amps) == 1 else math.nan, "n_samples": s.n_samples}
        out = []
        for o in self.outcomes:
            row = dict(base, method=o.method, repetitions=len(o.a), successes=len(o.a) - o.n_failed,
                       failures=o.n_failed, failure_reasons=o.failure_summary())
            for name, truth in (("a", s.a), ("b", s.b)):
                st = o.statistics(name, truth)
                row.update({f"mean_{name}": st["mean"], f"bias_{name}_pct": st["bias_pct"],
                            f"std_{name}": st["std"], f"rmse_{name}": st["rmse"],
                            f"crb_{name}": self.crb[name] if self.crb else math.nan})
            out.append(row)
        return out


def _crb(setting: Setting, duty: np.ndarray) -> dict | None:
    motor = setting.motor()
    if not (motor.is_linear and motor.input_delay == 0 and setting.jitter == 0 and setting.drop_rate == 0):
        return None
    bound = cramer_rao_bound(setting.a, setting.b, duty, setting.sample_period,
                             counts_per_rev=setting.counts_per_rev, angle_noise=setting.angle_noise,
                             initial_speed=setting.initial_speed)
    return bound.stderr()


def _fit_or_reason(recording: Recording, method: str) -> tuple[float, float, str]:
    try:
        est = fit(recording, method=method)
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
    from identify import available_methods
    if not isinstance(point, GridPoint):
        raise TypeError(f"point must be a GridPoint, got {type(point).__name__}")
    if isinstance(repetitions, bool) or not isinstance(repetitions, int) or repetitions < 1:
        raise ValueError(f"repetitions must be an integer >= 1, got {repetitions!r}")
    methods = list(methods)
    unknown = [m for m in methods if m not in available_methods()]
    if not methods or unknown:
        raise ValueError(f"methods must be a non-empty list of names among {available_methods()}, got {methods!r}")
    s = point.setting
    exp = s.experiment()
    duty = exp.duty()
    n = exp.n_samples
    # Without noise, jitter or drops every repetition is the same run: simulate it once.
    distinct = repetitions if s.needs_rng else 1
    a = {m: np.full(distinct, np.nan) for m in methods}
    b = {m: np.full(distinct, np.nan) for m in methods}
    why = {m: [""] * distinct for m in methods}
    batched = batch and is_batchable(s.motor(), jitter=s.jitter, drop_rate=s.drop_rate)
    if batched:
        angle, _ = simulate_batch(s.motor(), duty, s.sample_period, initial_speed=s.initial_speed)
        time_s = np.arange(n) * s.sample_period
        batched_methods = [m for m in methods if m in BATCHED_METHODS]
        other = [m for m in methods if m not in BATCHED_METHODS]
        chunk = max(1, _CHUNK_SAMPLES // n)
        for lo in range(0, distinct, chunk):
            hi = min(distinct, lo + chunk)
            rngs = [np.random.default_rng(repetition_seed(seed, point.index, r)) for r in range(lo, hi)]
            counts = encoder_counts_batch(np.broadcast_to(angle, (hi - lo, n)), s.counts_per_rev,
                                          s.angle_noise, rngs)
            fits = fit_batch(batched_methods, speed_batch(counts, s.counts_per_rev, s.sample_period),
                             duty, s.sample_period) if batched_methods else {}
            for m, f in fits.items():
                a[m][lo:hi], b[m][lo:hi] = f.a, f.b
                why[m][lo:hi] = f.failure
            for j in (range(hi - lo) if other else ()):
                rec = Recording(time=time_s, duty=duty, sample_period=s.sample_period,
                                counts=counts[j].astype(np.int64), counts_per_rev=s.counts_per_rev,
                                metadata={"source": "scenarios.batch"})
                for m in other:
                    a[m][lo + j], b[m][lo + j], why[m][lo + j] = _fit_or_reason(rec, m)
    else:
        for r in range(distinct):
            rng = np.random.default_rng(repetition_seed(seed, point.index, r))
            rec = s.sim_rig(rng).run(exp)
            for m in methods:
                a[m][r], b[m][r], why[m][r] = _fit_or_reason(rec, m)
    copies = repetitions // distinct
    outcomes = tuple(MethodOutcome(m, np.tile(a[m], copies), np.tile(b[m], copies), tuple(why[m]) * copies)
                     for m in methods)
    return PointResult(point, outcomes, _crb(s, duty), distinct * n, batched)


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
    pending: collections.deque = collections.deque()
    for job in jobs:
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
        Processes to use when no ``executor`` is given (default ``os.cpu_count()``; 1 runs
        in this process).
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
    """
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario must be a Scenario, got {type(scenario).__name__}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path, json_path = out / "sweep.csv", out / "summary.json"
    jobs = ((p, scenario.methods, scenario.repetitions, scenario.seed) for p in scenario.points())
    own = None
    if executor is None:
        workers = workers or os.cpu_count() or 1
        if workers > 1:
            # spawn: no fork of a threaded parent; workers import motorid afresh.
            own = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))
        window = 2 * workers
    else:
        window = 2 * (os.cpu_count() or 1)
    t0 = time.perf_counter()
    n_rows = samples = 0
    failures = collections.Counter({m: 0 for m in scenario.methods})
    worst = {m: 0.0 for m in scenario.methods}
    tmp = csv_path.with_name(csv_path.name + ".part")
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as f, \
                ProgressBar(scenario.n_points, f"sweep {scenario.name}", enabled=progress) as bar:
            writer = csv.writer(f, lineterminator="\n")
            writer.writerow(CSV_COLUMNS)
            for result in _in_order(own or executor, jobs, window):
                for row in result.rows():
                    writer.writerow([_format(row[c]) for c in CSV_COLUMNS])
                    n_rows += 1
                    failures[row["method"]] += row["failures"]
                    if math.isfinite(row["bias_a_pct"]):
                        worst[row["method"]] = max(worst[row["method"]], abs(row["bias_a_pct"]))
                samples += result.samples_simulated
                f.flush()
                bar.update()
        os.replace(tmp, csv_path)
    finally:
        if own is not None:
            own.shutdown()
        if tmp.exists():
            tmp.unlink()
    elapsed = time.perf_counter() - t0
    summary = SweepSummary(scenario, csv_path, json_path, scenario.n_points, n_rows, samples, dict(failures),
                           elapsed)
    json_path.write_text(json.dumps({
        "scenario": scenario.name, "description": scenario.description, "seed": scenario.seed,
        "repetitions": scenario.repetitions, "methods": list(scenario.methods),
        "grid": {axis: list(values) for axis, values in scenario.grid},
        "grid_columns": {axis: axis_column(axis) for axis in scenario.axes},
        "base": dict(scenario.base), "points": scenario.n_points, "rows": n_rows,
        "samples_simulated": samples, "elapsed_s": round(elapsed, 3),
        "failures": dict(failures), "worst_abs_bias_a_pct": worst, "csv": csv_path.name,
    }, indent=1), encoding="utf-8")
    return summary


def read_sweep_csv(path: str | os.PathLike) -> list[dict]:
    """Rows of a sweep CSV with numbers parsed (empty cells become nan)."""
    text_cols = {"excitation", "method", "failure_reasons"}
    rows = []
    with open(path, encoding="utf-8", newline="") as f:
        for raw in csv.DictReader(f):
            rows.append({k: (v if k in text_cols else (float(v) if v != "" else math.nan)) for k, v in raw.items()})
    return rows


def make_plots(scenario: Scenario, csv_path: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """The PNGs of a sweep: bias and spread against frequency (or, when frequency is not a grid
    axis, against the first numeric axis) and heatmaps of |bias| of a and b over the first two numeric grid axes (other axes held at
    their first value)."""
    from . import plots
    out = Path(out_dir)
    rows = read_sweep_csv(csv_path)
    columns = list(dict.fromkeys(axis_column(a) for a in scenario.axes))
    numeric = [c for c in columns if c != "excitation"]
    paths = []
    if numeric:
        x = "frequency" if "frequency" in numeric else numeric[0]
        others = [c for c in columns if c != x]
        paths.append(plots.plot_sweep_frequency(rows, out / f"bias_vs_{x}.png", others=others, x=x,
                                                title=f"{scenario.name}: bias and spread against {x}"))
    if len(numeric) >= 2:
        x, y = numeric[0], numeric[1]
        fixed = {c: rows[0][c] for c in columns if c not in (x, y)}
        sub = [r for r in rows if all(r[c] == v for c, v in fixed.items())]
        note = ("; " + ", ".join(f"{c}={v:g}" if isinstance(v, float) else f"{c}={v}" for c, v in fixed.items())
                if fixed else "")
        for name in ("a", "b"):
            paths.append(plots.plot_sweep_heatmap(sub, x, y, out / f"heatmap_bias_{name}.png",
                                                  value=f"bias_{name}_pct",
                                                  title=f"{scenario.name}: |bias of {name}| in %{note}"))
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
    parser.add_argument("--list", action="store_true", help="list the built-in scenarios and exit")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="where sweep.csv, summary.json and the PNGs go (default sweep-output/NAME)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes (default: all cores; 1 runs in this process)")
    parser.add_argument("--repeats", type=int, default=None, metavar="N",
                        help="Monte Carlo repetitions per grid point (default: the scenario's)")
    parser.add_argument("--methods", default=None, metavar="all|M,M,...",
                        help="estimators to compare instead of the scenario's (e.g. all, or oe,oe-friction)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run on a Dask cluster (scheduler address, or 'local' for a LocalCluster of "
                             "--workers processes); needs motorid[dask]")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no table")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")


def run_sweep(args: argparse.Namespace) -> int:
    """``motorid sweep``: the CLI glue around :func:`run_scenario`."""
    from .cli import CommandError
    from .scenario import builtin_scenarios, load_scenario
    if args.list:
        for name, description in builtin_scenarios().items():
            print(f"{name:<16} {description}")
        return 0
    if not args.scenario:
        raise CommandError("sweep needs a scenario NAME or FILE.toml (see motorid sweep --list)")
    if args.workers is not None and args.workers < 1:
        raise CommandError(f"--workers must be >= 1, got {args.workers}")
    scenario = load_scenario(args.scenario)
    if args.repeats is not None:
        scenario = scenario.with_repetitions(args.repeats)
    if args.methods is not None:
        scenario = scenario.with_methods("all" if args.methods == "all"
                                         else [m.strip() for m in args.methods.split(",") if m.strip()])
    out = Path(args.out or Path("sweep-output") / scenario.name)
    client = cluster = None
    executor = None
    if args.dask:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise CommandError("--dask needs Dask: pip install 'motorid[dask]'") from None
        if args.dask == "local":
            cluster = LocalCluster(n_workers=args.workers or os.cpu_count() or 1, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
            client = Client(cluster)
        else:
            client = Client(args.dask)
        executor = client.get_executor()
    try:
        summary = run_scenario(scenario, out, workers=args.workers, executor=executor,
                               progress=False if args.quiet else None)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    if not args.quiet:
        print(f"{scenario.name}: {scenario.description}")
        print(f"{summary.n_points} points x {len(scenario.methods)} methods x {scenario.repetitions} repetitions, "
              f"{summary.samples_simulated:,} samples simulated in {summary.elapsed:.2f} s\n")
        rows = read_sweep_csv(summary.csv_path)
        if len(rows) <= 200:
            print(format_sweep_table(scenario, rows))
        else:
            print(f"({len(rows)} rows: see the CSV)")
    paths = [] if args.no_plots else make_plots(scenario, summary.csv_path, out)
    print(f"\nwrote {summary.csv_path}, {summary.json_path}" + "".join(f", {p}" for p in paths))
    return 0
