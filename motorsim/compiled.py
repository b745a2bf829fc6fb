"""The friction simulation's per-sample loop, compiled by numba when it is installed.

Coulomb friction makes each interval's solution depend on the sign of the speed
(sticking at rest, a zero crossing inside the interval, a break-away at the static
level), so the exact simulation
has no vectorised form: :func:`friction_run` walks the samples.  With numba
(a dependency of motorid wherever it has wheels) the loop is compiled to machine code once a process
has spent about as long in the Python loop as numba takes to import and compile
(:data:`COMPILE_AFTER`; the kernel is cached on disk for later processes); without
numba (it cannot be imported), or with ``MOTORID_NUMBA=0`` in the environment, the Python loop
runs throughout.  Both give the same numbers to rounding (the tests run both).
"""
from __future__ import annotations

import functools
import math
import os
from typing import Callable

import numpy as np

__all__ = ["friction_run", "friction_run_python", "friction_interval", "compiled_kernel", "numba_jit",
           "COMPILE_AFTER"]


def friction_interval(a: float, force: float, c: float, w: float, th: float, h: float,
                      static: float) -> tuple[float, float]:
    """Exact solution over ``h`` s of ``w' = -a w + force - c sign(w)`` with sticking at rest.

    At rest the shaft stays put while ``|force| <= static`` (the static friction, ``>= c``) and
    breaks away in the direction of ``force`` otherwise; a speed that reaches zero inside the
    interval sticks there on the same rule.  ``static = c`` is plain Coulomb friction.

    Parameters
    ----------
    a : float
        Pole in 1/s.
    force : float
        ``b v + bias`` over the interval, rad/s^2.
    c : float
        Coulomb friction, rad/s^2.
    w, th : float
        Speed (rad/s) and angle (rad) at the interval's start.
    h : float
        Interval in s.
    static : float
        Static friction (the break-away level) in rad/s^2, ``>= c``.

    Returns
    -------
    w, th : float
        Speed and angle at the interval's end.
    """
    remaining = h
    while remaining > 0:
        if w == 0.0:
            if abs(force) <= static:
                return 0.0, th  # stuck for the rest of the interval
            s = 1.0 if force > 0 else -1.0
        else:
            s = 1.0 if w > 0 else -1.0
        target = (force - s * c) / a  # equilibrium of this branch
        # Does the branch reach zero speed (towards the opposite sign) within `remaining`?
        if w != 0.0 and target * s < 0:
            t_zero = math.log((w - target) / (0.0 - target)) / a
            if t_zero < remaining:
                th += target * t_zero + (w - target) * (-math.expm1(-a * t_zero)) / a
                w = 0.0
                remaining -= t_zero
                continue
        em = -math.expm1(-a * remaining)
        th += target * remaining + (w - target) * em / a
        w = target + (w - target) * (1.0 - em)
        return w, th
    return w, th


def friction_run_python(a: float, force: np.ndarray, c: float, h: np.ndarray, speed: np.ndarray,
                        angle: np.ndarray, static: float) -> None:
    """Fill ``speed[1:]`` and ``angle[1:]`` interval by interval from ``speed[0]``, ``angle[0]``.

    ``force[k]`` (rad/s^2) acts over ``h[k]`` s; ``static`` is the break-away level; see
    :func:`friction_interval`.
    """
    w, th = float(speed[0]), float(angle[0])
    for k in range(len(h)):
        w, th = friction_interval(a, force[k], c, w, th, h[k], static)
        speed[k + 1] = w
        angle[k + 1] = th


#: Python-loop intervals after which :func:`friction_run` compiles the loop: importing numba
#: and loading (or compiling) the kernel costs about as much as this many Python intervals
#: (~0.3 s), so a process never pays more than twice the better choice made in hindsight.
COMPILE_AFTER = 300_000
#: Intervals this process has run in the Python loop so far.
usage = {"python_intervals": 0}


def friction_run(a: float, force: np.ndarray, c: float, h: np.ndarray, speed: np.ndarray,
                 angle: np.ndarray, static: float) -> None:
    """:func:`friction_run_python`, by the compiled kernel once this process has run
    :data:`COMPILE_AFTER` intervals in Python and numba is available."""
    kernel = compiled_kernel() if usage["python_intervals"] >= COMPILE_AFTER else None
    if kernel is None:
        friction_run_python(a, force, c, h, speed, angle, static)
        usage["python_intervals"] += len(h)
    else:
        kernel(a, force, c, h, speed, angle, static)


def numba_jit() -> Callable[[Callable], Callable] | None:
    """``numba.njit(cache=True)``, or None without numba or with ``MOTORID_NUMBA=0`` (every compiled
    per-sample loop of the project asks here, so one switch turns them all off)."""
    if os.environ.get("MOTORID_NUMBA", "1") == "0":
        return None
    try:
        import numba
    except ImportError:
        return None
    return numba.njit(cache=True)


@functools.cache
def compiled_kernel() -> Callable[..., None] | None:
    """:func:`friction_run_python` compiled by numba (None without numba or with ``MOTORID_NUMBA=0``)."""
    jit = numba_jit()
    if jit is None:
        return None
    interval = jit(friction_interval)

    def run(a, force, c, h, speed, angle, static):
        w, th = speed[0], angle[0]
        for k in range(len(h)):
            w, th = interval(a, force[k], c, w, th, h[k], static)
            speed[k + 1] = w
            angle[k + 1] = th

    return jit(run)
