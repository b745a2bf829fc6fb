"""scenarios: sweeps of the simulated bench -- grid x estimators x Monte Carlo repetitions.

A scenario (:mod:`scenarios.scenario`: a TOML file or a dict; ``builtin/*.toml`` holds the
shipped ones) is a base setting of the bench, a grid of values to sweep, the estimators to
compare and the repetitions per grid point.  :func:`run_sweep` runs one and writes the tidy
CSV (one row per grid point x estimator) and ``summary.json``: the batch paths of the
simulator and the estimators (:mod:`motorsim.batch`, :mod:`identify.fits.batch`) simulate and fit
every repetition of a point at once where they can, :mod:`scenarios.executors` spreads the points
over processes or any ``concurrent.futures`` executor (Dask's too), and
:mod:`scenarios.sweep_time` estimates a sweep's run time before it starts.  Usable from
Python without the command line; ``motorid sweep`` (:mod:`motorid.commands.sweep`) is the
command line around it.
"""
from __future__ import annotations

import concurrent.futures
import os
from typing import TYPE_CHECKING, Callable

from motorsim.checks import ParameterTypeError

if TYPE_CHECKING:
    from .scenario import Scenario
    from .sweep import SweepSummary

__all__ = ["run_sweep"]


def run_sweep(scenario: Scenario | str | os.PathLike, out_dir: str | os.PathLike, *, workers: int | None = None,
              executor: concurrent.futures.Executor | None = None,
              progress: Callable[[int], object] | None = None) -> SweepSummary:
    """Run a scenario sweep and write ``sweep.csv`` and ``summary.json`` into ``out_dir``.

    Parameters
    ----------
    scenario : Scenario, str or path
        A :class:`~scenarios.scenario.Scenario` (e.g. from
        :func:`~scenarios.scenario.scenario_from_dict`), the name of a built-in scenario
        (:func:`~scenarios.scenario.builtin_scenarios`) or a scenario TOML file.
    out_dir : path
        Created if needed.
    workers : int, optional
        Processes to use when no ``executor`` is given (default: every core; 1 runs in this
        process).
    executor : concurrent.futures.Executor, optional
        Any executor (e.g. Dask's ``Client(...).get_executor()``); used as given, not shut down.
    progress : callable, optional
        Called with the number of grid points done after each point.

    Returns
    -------
    SweepSummary
        The paths written, the counts of points, rows, simulated samples and failed fits,
        and the elapsed time; read the rows with :func:`scenarios.sweep.read_sweep_csv`.

    See Also
    --------
    scenarios.sweep.run_scenario : the same on a ``Scenario`` only.

    Examples
    --------
    A scenario file (in the current folder) sweeping two sine frequencies, ``zoh-ls`` against ``oe``, noise-free:

    >>> import pathlib
    >>> from scenarios.sweep import read_sweep_csv
    >>> _ = pathlib.Path("tiny.toml").write_text('''
    ... name = "tiny"
    ... repetitions = 1
    ... methods = ["zoh-ls", "oe"]
    ... [bench]
    ... duration = 1.0
    ... [grid]
    ... "excitation.frequency" = [10, 20]
    ... ''')
    >>> summary = run_sweep("tiny.toml", "tiny-out", workers=1)
    >>> [(r["frequency"], r["method"], round(r["mean_a"], 2)) for r in read_sweep_csv(summary.csv_path)]
    [(10.0, 'zoh-ls', 23.28), (10.0, 'oe', 25.0), (20.0, 'zoh-ls', 22.61), (20.0, 'oe', 25.0)]
    """
    from .scenario import Scenario, load_scenario
    from .sweep import run_scenario
    if not isinstance(scenario, Scenario):
        if not isinstance(scenario, (str, os.PathLike)):
            raise ParameterTypeError(f"scenario must be a Scenario, a built-in name or a path, "
                                     f"got {type(scenario).__name__}")
        scenario = load_scenario(scenario)
    return run_scenario(scenario, out_dir, workers=workers, executor=executor, progress=progress)
