"""Speed and memory goals of the benchmarks, and ``motorid bench --check``: the gate that runs them.

Each goal is declared once, as a :class:`Goal` next to the benchmark that measures it (its
module's ``GOALS``); the benchmark prints every figure with its goal, and its ``goal_figures()``
returns ``(goal, figure)`` pairs for the gate.  Figures are ratios against a baseline measured
in the same run (a slower machine slows both) or, where the goal is a budget on a user's file,
seconds; both in CPU time where the work is single-threaded (:mod:`motorid.bench.timing`), and
each over a small family of recordings, the worst kept.  ``motorid bench --check`` runs every
benchmark of :data:`GATED`, prints each figure with its goal and exits with status 1 when one is
missed (an open goal, :attr:`Goal.held`, only beyond the figure it holds): run it before a change
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
    held : float, optional
        For a goal not reached yet: the figure the code keeps meanwhile (what it measures now, with
        the margin of a busy machine).  Its line still says MISSED, but the gate fails only beyond
        ``held``, so a change that makes it worse is still caught.  None (default): the gate fails
        whenever the goal is missed.
    """

    name: str
    limit: float
    unit: str = "x"
    at_most: bool = True
    held: float | None = None

    def met(self, figure: float) -> bool:
        """Whether ``figure`` keeps the goal (a figure that is not a number never does)."""
        return self._within(figure, self.limit)

    def fails(self, figure: float) -> bool:
        """Whether ``figure`` fails the gate: the goal missed, and for an open goal its ``held`` figure too."""
        return not self.met(figure) and (self.held is None or not self._within(figure, self.held))

    def _within(self, figure: float, limit: float) -> bool:
        if not math.isfinite(figure):
            return False
        return figure <= limit if self.at_most else figure >= limit

    def line(self, figure: float) -> str:
        """``name  figure unit  goal <= limit unit: met`` (or ``MISSED``, with the figure an open goal holds)."""
        sign = "<=" if self.at_most else ">="
        status = "met" if self.met(figure) else "MISSED"
        if self.held is not None and not self.met(figure):
            status += f" (open; the gate fails {'above' if self.at_most else 'below'} {self.held:g} {self.unit})"
        return f"{self.name:72s} {figure:8.3g} {self.unit:1s}   goal {sign} {self.limit:g} {self.unit}: {status}"


def report(figures: Iterable[tuple[Goal, float]], stream: TextIO | None = None) -> int:
    """Print each figure with its goal; 1 when one fails the gate (:meth:`Goal.fails`), else 0."""
    out = sys.stdout if stream is None else stream
    failed = 0
    for goal, figure in figures:
        print(goal.line(figure), file=out)
        failed += goal.fails(figure)
    return 1 if failed else 0


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
        1 when a goal is missed (an open goal: beyond its ``held`` figure), or a benchmark gives no figure for a
        goal it declares; else 0.
    """
    out = sys.stdout if stream is None else stream
    unknown = [n for n in names if n not in GATED]
    if unknown:
        raise ValueError(f"names must be among {list(GATED)}, got {unknown}")
    status = opened = 0
    for name in names or list(GATED):
        module = GATED[name]
        print(f"[{name}]", file=out, flush=True)
        figures = (measure or _measure)(module)
        declared = getattr(importlib.import_module(module), "GOALS", ())
        measured = {goal for goal, _ in figures}
        figures += [(goal, math.nan) for goal in declared if goal not in measured]
        status |= report(figures, out)
        opened += sum(not goal.met(figure) and not goal.fails(figure) for goal, figure in figures)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    summary = "a goal was MISSED" if status else "every goal held" if opened else "all goals met"
    if opened and not status:
        summary += f", {opened} of them open (MISSED, within the figure held)"
    print(f"{summary} (load average {load:.1f})", file=out)
    return status
