"""The exact response of the motor behind a driver that limits its current (``current-limit``).

``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d`` (:mod:`identify.fits.current_limit`). Over each held
sample the vector field is continuous and piecewise linear in ``omega`` (linear, or saturated on either side), so the
speed is an exponential (a ramp where ``(1 - s) a`` is 0) in each region, and the instants it crosses from one to the
next are solved in closed form (:func:`limit_interval`); at most two crossings per sample. The loop over the samples
is compiled by numba where it is installed (:func:`motorsim.compiled.numba_jit`), the same Python loop otherwise. Kept
apart from the fit so that the structure (:mod:`identify.model_structures.current_limit`) imports no estimator.
"""
from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..sums import sum_squares

if TYPE_CHECKING:
    from ..data import Segment

__all__ = ["limit_interval", "limit_run", "limit_run_python", "limit_response", "segment_model", "initial_speed_fit"]


def _phi(alpha: float, t: float) -> tuple[float, float]:
    """``(1 - exp(-alpha t)) / alpha`` and its integral from 0 to ``t`` (``t`` and ``t^2 / 2`` at ``alpha = 0``)."""
    x = alpha * t
    if abs(x) < 1e-4:
        return t * (1.0 - x / 2.0 + x * x / 6.0), t * t * (0.5 - x / 6.0 + x * x / 24.0)
    p1 = -math.expm1(-x) / alpha
    return p1, (t - p1) / alpha


def limit_interval(ae: float, am: float, bu: float, limit: float, d: float, w: float, th: float,
                   h: float) -> tuple[float, float]:
    """Exact solution over ``h`` s of ``w' = sat_limit(bu - ae w) - am w + d`` from speed ``w``, angle ``th``.

    Returns the speed and the angle at the interval's end (module docstring: at most two crossings between the
    linear and the saturated regions; the field is continuous, so the motion keeps its direction across one).
    """
    if ae > 0.0:
        up, lo = (bu - limit) / ae, (bu + limit) / ae      # linear where up <= w <= lo
        if w < up:
            reg = 1
        elif w > lo:
            reg = -1
        else:
            reg = 0
    else:
        up = lo = 0.0
        reg = 1 if bu > limit else (-1 if bu < -limit else 0)
    remaining = h
    for _ in range(4):
        if reg == 0:
            alpha, c = ae + am, bu + d
        else:
            alpha, c = am, reg * limit + d
        f = c - alpha * w                   # the speed's rate here: w(t) = w + f phi1(t)
        target, nxt = 0.0, 2
        if ae > 0.0:
            if reg == 0 and f > 0.0:
                target, nxt = lo, -1
            elif reg == 0 and f < 0.0:
                target, nxt = up, 1
            elif reg == 1 and f > 0.0:
                target, nxt = up, 0
            elif reg == -1 and f < 0.0:
                target, nxt = lo, 0
        if nxt != 2:
            q = (target - w) / f
            if alpha * q < 1.0:
                tc = q if alpha == 0.0 else -math.log1p(-alpha * q) / alpha
                if tc < remaining:
                    p1, p2 = _phi(alpha, tc)
                    th += w * tc + f * p2
                    w = target
                    remaining -= tc
                    reg = nxt
                    continue
        p1, p2 = _phi(alpha, remaining)
        th += w * remaining + f * p2
        w = w + f * p1
        return w, th
    return w, th


def limit_run_python(ae: float, am: float, bu: np.ndarray, limit: float, d: float, h: np.ndarray,
                     speed: np.ndarray, angle: np.ndarray) -> None:
    """Fill ``speed[1:]`` and ``angle[1:]`` interval by interval from ``speed[0]``, ``angle[0]``: ``bu[k]`` (rad/s^2)
    held over ``h[k]`` s (:func:`limit_interval`)."""
    w, th = float(speed[0]), float(angle[0])
    for k in range(len(h)):
        w, th = limit_interval(ae, am, bu[k], limit, d, w, th, h[k])
        speed[k + 1] = w
        angle[k + 1] = th


@functools.cache
def _compiled() -> Callable[..., None] | None:
    """:func:`limit_run_python` compiled by numba (None without numba or with ``MOTORID_NUMBA=0``)."""
    from motorsim.compiled import numba_jit
    jit = numba_jit()
    if jit is None:
        return None
    phi = jit(_phi)
    interval = jit(_interval_source(phi))

    def run(ae, am, bu, limit, d, h, speed, angle):
        w, th = speed[0], angle[0]
        for k in range(len(h)):
            w, th = interval(ae, am, bu[k], limit, d, w, th, h[k])
            speed[k + 1] = w
            angle[k + 1] = th

    return jit(run)


def _interval_source(phi: Callable) -> Callable:
    """:func:`limit_interval` calling ``phi`` (the compiled :func:`_phi`), for numba to compile."""
    globals_ = dict(limit_interval.__globals__, _phi=phi)
    import types
    return types.FunctionType(limit_interval.__code__, globals_, "limit_interval")


def limit_run(ae: float, am: float, bu: np.ndarray, limit: float, d: float, h: np.ndarray, speed: np.ndarray,
              angle: np.ndarray) -> None:
    """:func:`limit_run_python`, compiled where numba is installed."""
    kernel = _compiled()
    (limit_run_python if kernel is None else kernel)(float(ae), float(am), np.ascontiguousarray(bu, dtype=float),
                                                     float(limit), float(d), np.ascontiguousarray(h, dtype=float),
                                                     speed, angle)


def limit_response(a: float, b: float, limit: float, share: float, bias: float, drive: np.ndarray,
                   time: np.ndarray, initial_speed: float = 0.0, initial_angle: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Angle and speed at ``time`` of the motor behind the current limit (module docstring), ``drive[k]`` held from
    ``time[k]`` to ``time[k + 1]``, from ``initial_speed`` and ``initial_angle``."""
    t = np.asarray(time, dtype=float)
    n = len(t)
    speed, angle = np.empty(n), np.empty(n)
    if n == 0:
        return angle, speed
    speed[0], angle[0] = initial_speed, initial_angle
    u = np.asarray(drive, dtype=float)[:max(n - 1, 0)]
    limit_run(share * a, (1.0 - share) * a, b * u, limit, bias, np.diff(t), speed, angle)
    return angle, speed


def segment_model(theta: Sequence[float] | np.ndarray, seg: Segment, w0: float) -> np.ndarray:
    """The model's output on ``seg`` from initial speed ``w0``, ``theta = (a, b, L, s, d)`` (an angle from 0: its
    offset is the caller's)."""
    a, b, limit, share, d = (float(x) for x in theta)
    angle, speed = limit_response(a, b, limit, share, d, seg.drive, seg.time, w0)
    return angle if seg.kind == "angle" else speed


def initial_speed_fit(theta: Sequence[float] | np.ndarray, seg: Segment, w0: float | None = None) -> float:
    """The initial speed that fits ``seg`` best (a few secant-Newton steps on the least-squares cost)."""
    w = seg.initial_speed_guess() if w0 is None else float(w0)
    angle = seg.kind == "angle"

    def residual(x: float) -> np.ndarray:
        r = seg.output - segment_model(theta, seg, x)
        return r - r.mean() if angle else r

    r = residual(w)
    for _ in range(8):
        dw = 1e-6 * max(1.0, abs(w))
        g = (residual(w + dw) - r) / dw
        gg = float(g @ g)
        if gg <= 0 or not math.isfinite(gg):
            break
        step = -float(g @ r) / gg
        trial = residual(w + step)
        if not sum_squares(trial) <= sum_squares(r):
            break
        w, r = w + step, trial
        if abs(step) <= 1e-12 * max(1.0, abs(w)):
            break
    return w
