"""How long a sweep will take, said before it starts: one simulated run and one fit per method, timed.

The estimate is ``points x repetitions x (run + sum of the fits) / workers``: every repetition
of the first grid point is taken as typical, so grids whose settings change the run length or
the estimators' work (duration, dead zone) are estimated from their first point only, and
batched estimators (``euler-ls``, ``zoh-ls`` on linear settings) run faster than estimated.
"""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from .scenario import Scenario

__all__ = ["SweepTime", "estimate_sweep_time"]


@dataclasses.dataclass(frozen=True)
class SweepTime:
    """An estimated sweep duration.

    Attributes
    ----------
    seconds : float
        Estimated wall-clock time of the whole sweep in s.
    run : float
        One simulated run of the first grid point in s.
    fits : dict of str to float
        One fit per method on that run in s (nan for a fit that failed).
    workers : int
        Parallel workers assumed.
    """

    seconds: float
    run: float
    fits: dict[str, float]
    workers: int

    def describe(self, scenario: Scenario) -> str:
        """One line for stderr: the size of the sweep, the estimate and what it rests on."""
        fits = ", ".join(f"{m} {t * 1e3:.0f} ms" for m, t in self.fits.items())
        return (f"sweep {scenario.name}: {scenario.n_points} points x {len(scenario.methods)} methods x "
                f"{scenario.repetitions} repetitions, estimated {_duration(self.seconds)} on {self.workers} "
                f"worker{'s' if self.workers > 1 else ''} (one run {self.run * 1e3:.0f} ms; one fit: {fits})")


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def estimate_sweep_time(scenario: Scenario, workers: int | None = None) -> SweepTime:
    """Time one run of the first grid point and one fit per method on it; scale to the sweep.

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
    import scipy.optimize  # noqa: F401  (loaded here so that no fit below is timed with its import)
    import scipy.signal  # noqa: F401  (likewise: the estimators import it on first use)

    from identify import fit
    from identify.methods import method_function
    point = next(iter(scenario.points()))
    setting = point.setting
    t0 = time.perf_counter()
    recording = setting.sim_rig(np.random.default_rng(0)).run(setting.experiment())
    run = time.perf_counter() - t0
    fits = {}
    for method in scenario.methods:
        method_function(method)                      # import the estimator's module outside the timing
        t0 = time.perf_counter()
        try:
            fit(recording, method=method)
            fits[method] = time.perf_counter() - t0
        except ValueError:
            fits[method] = float("nan")
    n_workers = max(1, min(workers or os.cpu_count() or 1, scenario.n_points))
    per_repetition = run + sum(t for t in fits.values() if t == t)
    seconds = scenario.n_points * scenario.repetitions * per_repetition / n_workers
    return SweepTime(seconds, run, fits, n_workers)
