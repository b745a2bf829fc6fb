"""motorid: the command line that identifies a and b of a PWM-driven DC motor.

``motorid COMMAND`` (or ``python -m motorid COMMAND``) simulates the bench, imports a lab's
files, identifies, designs an experiment or a controller, runs the real bench live, sweeps
scenarios and benchmarks.  :mod:`motorid.cli` is the entry point and its command table;
:mod:`motorid.commands` holds one module per command; the pieces only the app uses sit
here: the figures (:mod:`motorid.plots`), progress on stderr (:mod:`motorid.progress`),
signal handling (:mod:`motorid.interrupts`), memory budgets (:mod:`motorid.budget`) and the
screening of ``identify``'s files (:mod:`motorid.screening`); :mod:`motorid.bench` holds
the benchmarks.  The app builds on the four library packages -- :mod:`motorsim`,
:mod:`identify`, :mod:`hardware`, :mod:`scenarios` -- and none of them imports it.

``motorid.__version__`` is the installed distribution's version (``unknown`` when run
from a source tree that is not installed).
"""
from __future__ import annotations

__all__ = ["__version__"]


def __getattr__(name: str) -> str:
    # read when asked, so that importing the app does not load importlib.metadata
    if name == "__version__":
        from importlib import metadata
        try:
            return metadata.version("motorid")
        except metadata.PackageNotFoundError:
            return "unknown"
    raise AttributeError(f"module 'motorid' has no attribute {name!r}")
