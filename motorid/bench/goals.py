"""Speed and memory goals of the benchmarks, and ``motorid bench --check``: the gate that runs them.

Each goal is declared once, as a :class:`Goal` next to the benchmark that measures it (its
module's ``GOALS``); the benchmark prints every figure with its goal, and its ``goal_figures()``
returns ``(goal, figure)`` pairs for the gate.  Figures are ratios against a baseline measured
in the same run (a slower machine slows both) or, where the goal is a wall-clock budget on a
user's file, seconds.  ``motorid bench --check`` runs every benchmark of :data:`GATED`, prints
each figure with its goal and exits with status 1 when one is missed: run it before a change
lands (``docs/develop.md``).  It is not part of ``make test``: timings are noisy, and the tests
never assert wall-clock times; the gate's logic is tested with made-up figures.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
import os
import sys
from typing import Callable, Iterable, Sequence, TextIO

__all__ = ["Goal", "GATED", "report", "run_check"]


@dataclasses.dataclass(frozen=True)
class Goal:
    """A figure a benchmark measures and the limit it must keep.

    Attributes
    ----------
    name : str
        What is measured, against what (one line).
    limit : float
        The goal.
    unit : str
        Unit of the figure (``x`` for a ratio, ``s``).
    at_most : bool
        True: the figure must be at most ``limit`` (a time); False: at least (a speed-up).
    """

    name: str
    limit: float
    unit: str = "x"
    at_most: bool = True

    def met(self, figure: float) -> bool:
        """Whether ``figure`` keeps the goal (a figure that is not a number never does)."""
        if not math.isfinite(figure):
            return False
        return figure <= self.limit if self.at_most else figure >= self.limit

    def line(self, figure: float) -> str:
        """``name  figure unit  goal <= limit unit: met`` (or ``MISSED``)."""
        sign = "<=" if self.at_most else ">="
        return (f"{self.name:72s} {figure:8.3g} {self.unit:1s}   goal {sign} {self.limit:g} {self.unit}: "
                f"{'met' if self.met(figure) else 'MISSED'}")


def report(figures: Iterable[tuple[Goal, float]], stream: TextIO | None = None) -> int:
    """Print each figure with its goal; 1 when a goal is missed, else 0."""
    out = sys.stdout if stream is None else stream
    missed = 0
    for goal, figure in figures:
        print(goal.line(figure), file=out)
        missed += not goal.met(figure)
    return 1 if missed else 0


#: The benchmarks the gate runs: name -> the module whose ``goal_figures()`` measures its goals.
GATED: dict[str, str] = {
    "simulate": "motorid.bench.simulate",
    "oe": "motorid.bench.output_error",
    "selection": "motorid.bench.selection",
    "frequency": "motorid.bench.frequency",
}


def _measure(module: str) -> list[tuple[Goal, float]]:
    return list(importlib.import_module(module).goal_figures())


def run_check(names: Sequence[str] = (), stream: TextIO | None = None,
              measure: Callable[[str], list[tuple[Goal, float]]] | None = None) -> int:
    """Run the gated benchmarks (``names``, default all of :data:`GATED`) and :func:`report` their goals.

    Parameters
    ----------
    names : sequence of str
        Keys of :data:`GATED`; empty: all.
    stream : file, optional
        Where to print (default standard output).
    measure : callable, optional
        ``measure(module) -> [(goal, figure), ...]`` (default: the module's ``goal_figures()``).

    Returns
    -------
    int
        1 when a goal is missed (or a benchmark gives no figure for a goal it declares), else 0.
    """
    out = sys.stdout if stream is None else stream
    unknown = [n for n in names if n not in GATED]
    if unknown:
        raise ValueError(f"names must be among {list(GATED)}, got {unknown}")
    status = 0
    for name in names or list(GATED):
        module = GATED[name]
        print(f"[{name}]", file=out, flush=True)
        figures = (measure or _measure)(module)
        declared = getattr(importlib.import_module(module), "GOALS", ())
        measured = {goal for goal, _ in figures}
        figures += [(goal, math.nan) for goal in declared if goal not in measured]
        status |= report(figures, out)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(f"{'all goals met' if status == 0 else 'a goal was MISSED'} (load average {load:.1f})", file=out)
    return status
