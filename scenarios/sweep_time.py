"""How long a sweep will take, said before it starts: a probe of each method on a few grid points, timed.

The probe is the sweep's own work: :func:`scenarios.sweep.run_point` with one repetition, one
method at a time, on up to :data:`PROBE_POINTS` grid points spread over the grid (the first, the
last and evenly between: grids whose settings change the work, such as friction, a dead zone or
an input delay chosen by search, are seen at both ends). A point's cost is the probed cost of
one repetition times the repetitions it really runs (one when the setting is noise-free; where the
batch engine runs the repetitions together, what a second repetition adds is timed too), and
the estimate is the mean point cost times the points, shared by the workers (as many as the
cores that the machine's load leaves free, :func:`effective_workers`), plus the workers'
start-up.
"""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from .scenario import Scenario

__all__ = ["SweepTime", "estimate_sweep_time", "effective_workers", "PROBE_POINTS", "WORKER_STARTUP"]

#: Grid points the probe runs (spread over the grid).
PROBE_POINTS = 4

#: Seconds the worker processes take to start (forked from a warm process), added once when workers > 1.
WORKER_STARTUP = 0.1


def effective_workers(workers: int) -> float:
    """Workers' share of the machine: ``workers``, at most the cores other processes leave free.

    The 1-minute load average, less this process, counts the cores others are using; on a
    shared machine two workers on two busy cores run at the speed of about one.
    """
    cores = os.cpu_count() or 1
    try:
        busy = max(0.0, os.getloadavg()[0] - 1.0)
    except (AttributeError, OSError):            # no load average on this platform
        busy = 0.0
    return max(1.0, min(float(workers), cores - busy))


@dataclasses.dataclass(frozen=True)
class SweepTime:
    """An estimated sweep duration.

    Attributes
    ----------
    seconds : float
        Estimated wall-clock time of the whole sweep in s.
    run : float
        Mean time in s of one simulated run on the probed points.
    fits : dict of str to float
        Per method, the mean time in s of one repetition (run and fit) on the probed points.
    workers : int
        Parallel workers assumed.
    points_probed : int
        Grid points the probe ran.
    """

    seconds: float
    run: float
    fits: dict[str, float]
    workers: int
    points_probed: int = 1

    def describe(self, scenario: Scenario) -> str:
        """One line for stderr: the size of the sweep, the estimate and what it rests on."""
        fits = ", ".join(f"{m} {t * 1e3:.0f} ms" for m, t in self.fits.items())
        return (f"sweep {scenario.name}: {scenario.n_points} points x {len(scenario.methods)} methods x "
                f"{scenario.repetitions} repetitions, estimated {_duration(self.seconds)} on {self.workers} "
                f"worker{'s' if self.workers > 1 else ''} (probed on {self.points_probed} "
                f"point{'s' if self.points_probed > 1 else ''}: one run {self.run * 1e3:.0f} ms; "
                f"one repetition: {fits})")


def _duration(seconds: float) -> str:
    if seconds < 1:
        return f"{seconds:.2f} s"
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _probe_indices(n_points: int) -> list[int]:
    """Up to :data:`PROBE_POINTS` grid indices, spread from the first to the last."""
    return sorted({int(round(x)) for x in np.linspace(0, n_points - 1, min(n_points, PROBE_POINTS))})


def estimate_sweep_time(scenario: Scenario, workers: int | None = None) -> SweepTime:
    """Probe each method on a few grid points with the sweep's own code; scale to the sweep.

    Parameters
    ----------
    scenario : Scenario
        The sweep.
    workers : int, optional
        Parallel workers (default: the number of CPUs), at most the number of points.

    Returns
    -------
    SweepTime
    """
    import scipy.optimize  # noqa: F401  (loaded here so that no probe below is timed with its import)
    import scipy.signal  # noqa: F401  (likewise: the estimators import it on first use)

    from identify import method_function

    from .sweep import run_point, runs_batched
    for method in scenario.methods:
        method_function(method)                      # import the estimator's module outside the timing
    points = [scenario.point(i) for i in _probe_indices(scenario.n_points)]   # by index: the grid is not walked
    runs: list[float] = []
    per_method: dict[str, list[float]] = {m: [] for m in scenario.methods}
    point_costs = []
    for point in points:
        setting = point.setting
        t0 = time.perf_counter()
        setting.sim_rig(np.random.default_rng(0)).run(setting.experiment())
        runs.append(time.perf_counter() - t0)
        distinct = scenario.repetitions if setting.needs_rng else 1
        batched = distinct > 1 and runs_batched(setting)
        one = two = 0.0
        for method in scenario.methods:
            t0 = time.perf_counter()
            run_point(point, [method], 1, scenario.seed)
            seconds = time.perf_counter() - t0
            per_method[method].append(seconds)
            one += seconds
            if batched:             # repetitions run together: time a second one to see what it adds
                t0 = time.perf_counter()
                run_point(point, [method], 2, scenario.seed)
                two += time.perf_counter() - t0
        point_costs.append(one + (distinct - 1) * max(two - one, 0.0) if batched else one * distinct)
    n_workers = max(1, min(workers or os.cpu_count() or 1, scenario.n_points))
    startup = WORKER_STARTUP if n_workers > 1 else 0.0
    seconds = startup + scenario.n_points * float(np.mean(point_costs)) / effective_workers(n_workers)
    fits = {m: float(np.mean(t)) for m, t in per_method.items()}
    return SweepTime(seconds, float(np.mean(runs)), fits, n_workers, len(points))
