"""The exact response of the motor behind a driver that limits its current (``current-limit``).

``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d`` (:mod:`identify.fits.current_limit`). Over each held
sample the vector field is continuous and piecewise linear in ``omega`` (linear, or saturated on either side), so the
speed is an exponential (a ramp where ``(1 - s) a`` is 0) in each region, and the instants it crosses from one to the
next are solved in closed form (:func:`limit_interval`); at most two crossings per sample. The loop over the samples
is compiled by numba where it is installed (:func:`motorsim.compiled.numba_jit`), the same Python loop otherwise. Kept
apart from the fit so that the structure (:mod:`identify.model_structures.current_limit`) imports no estimator.

The fit's Jacobian is the response's exact forward sensitivities (:func:`limit_sensitivities`) to ``(a, b, L, s, d)``
and the initial speed: each piece of a held sample is differentiated at its own length.  The crossing instants move
with the parameters, but the field is continuous across the limit, so what the state gains by a later crossing it
loses in the next piece: the derivative at a fixed piece length is the whole derivative.
"""
from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..sums import sum_squares

if TYPE_CHECKING:
    from ..data import Segment

__all__ = ["limit_interval", "limit_run", "limit_run_python", "limit_response", "segment_model", "initial_speed_fit",
           "limit_sensitivities", "limit_sensitivity_run_python", "segment_sensitivities"]


def _phi(alpha: float, t: float) -> tuple[float, float]:
    """``(1 - exp(-alpha t)) / alpha`` and its integral from 0 to ``t`` (``t`` and ``t^2 / 2`` at ``alpha = 0``)."""
    x = alpha * t
    if abs(x) < 1e-4:
        return t * (1.0 - x / 2.0 + x * x / 6.0), t * t * (0.5 - x / 6.0 + x * x / 24.0)
    p1 = -math.expm1(-x) / alpha
    return p1, (t - p1) / alpha


def _dphi(alpha: float, t: float) -> tuple[float, float]:
    """The derivatives with respect to ``alpha`` of :func:`_phi`'s two functions at ``t`` (``alpha t >= 0``): ``t^2
    g1(alpha t)`` and ``t^3 g2(alpha t)``, their series below 0.1 (to ``x^11``: 1e-16 relative), the closed forms
    above."""
    x = alpha * t
    if abs(x) < 0.1:
        g1, g2, xj, f2, f3, sign = 0.0, 0.0, 1.0, 2.0, 6.0, -1.0
        for j in range(12):          # g1 = sum (-1)^(j+1) (j+1) x^j / (j+2)!,  g2 the same over (j+3)!
            g1 += sign * (j + 1) * xj / f2
            g2 += sign * (j + 1) * xj / f3
            xj *= x
            sign = -sign
            f2 *= j + 3
            f3 *= j + 4
    else:
        e, m = math.exp(-x), math.expm1(-x)
        g1 = (x * e + m) / (x * x)
        g2 = (-2.0 * x - (x + 2.0) * m) / (x * x * x)
    return t * t * g1, t * t * t * g2


def _first_region(ae: float, bu: float, limit: float, w: float) -> tuple[float, float, int]:
    """The speeds ``up`` and ``lo`` between which the torque is within the limit (linear where ``up <= w <= lo``)
    and the region the speed ``w`` starts in: 1 held at ``+limit``, -1 at ``-limit``, 0 linear."""
    if ae > 0.0:
        up, lo = (bu - limit) / ae, (bu + limit) / ae
        if w < up:
            return up, lo, 1
        if w > lo:
            return up, lo, -1
        return up, lo, 0
    return 0.0, 0.0, (1 if bu > limit else (-1 if bu < -limit else 0))


def limit_interval(ae: float, am: float, bu: float, limit: float, d: float, w: float, th: float,
                   h: float) -> tuple[float, float]:
    """Exact solution over ``h`` s of ``w' = sat_limit(bu - ae w) - am w + d`` from speed ``w``, angle ``th``.

    Returns the speed and the angle at the interval's end (module docstring: at most two crossings between the
    linear and the saturated regions; the field is continuous, so the motion keeps its direction across one).
    """
    up, lo, reg = _first_region(ae, bu, limit, w)
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


def _piece(reg: int, a: float, s: float, ae: float, am: float, u: float, bu: float, limit: float, d: float,
           dal: np.ndarray, dc: np.ndarray) -> tuple[float, float]:
    """The field ``c - alpha w`` of region ``reg`` (0 linear, 1 or -1 held at the limit): ``alpha``, ``c``, and
    their derivatives with respect to ``(a, b, L, s, d, w0)`` in ``dal``, ``dc``."""
    for i in range(6):
        dal[i] = 0.0
        dc[i] = 0.0
    dc[4] = 1.0
    if reg == 0:
        dal[0] = 1.0
        dc[1] = u
        return ae + am, bu + d
    dal[0] = 1.0 - s
    dal[3] = -a
    dc[2] = float(reg)
    return am, reg * limit + d


def _next_region(ae: float, reg: int, f: float, up: float, lo: float) -> tuple[float, int]:
    """The speed at which a motion of rate ``f`` in region ``reg`` leaves it and the region it enters (2: none)."""
    if ae > 0.0:
        if reg == 0 and f > 0.0:
            return lo, -1
        if reg == 0 and f < 0.0:
            return up, 1
        if reg == 1 and f > 0.0:
            return up, 0
        if reg == -1 and f < 0.0:
            return lo, 0
    return 0.0, 2


def limit_interval_sensitivity(a: float, s: float, u: float, b: float, limit: float, d: float, w: float, th: float,
                               h: float, dw: np.ndarray, dth: np.ndarray, dal: np.ndarray, dc: np.ndarray,
                               df: np.ndarray) -> tuple[float, float]:
    """:func:`limit_interval` (``ae = s a``, ``am = (1 - s) a``, ``bu = b u``) carrying the derivatives of the speed
    ``dw`` and the angle ``dth`` with respect to ``(a, b, L, s, d, w0)`` (updated in place; ``dal``, ``dc``, ``df``
    are scratch of the same length): each piece differentiated at its own length (module docstring)."""
    ae, am, bu = s * a, (1.0 - s) * a, b * u
    up, lo, reg = _first_region(ae, bu, limit, w)
    remaining = h
    for _ in range(4):
        alpha, c = _piece(reg, a, s, ae, am, u, bu, limit, d, dal, dc)
        f = c - alpha * w
        for i in range(6):
            df[i] = dc[i] - w * dal[i] - alpha * dw[i]
        target, nxt = _next_region(ae, reg, f, up, lo)
        tau = remaining
        crossed = False
        if nxt != 2:
            q = (target - w) / f
            if alpha * q < 1.0:
                tc = q if alpha == 0.0 else -math.log1p(-alpha * q) / alpha
                if tc < remaining:
                    tau, crossed = tc, True
        p1, p2 = _phi(alpha, tau)
        q1, q2 = _dphi(alpha, tau)
        th += w * tau + f * p2
        for i in range(6):
            dth[i] += dw[i] * tau + df[i] * p2 + f * q2 * dal[i]
            dw[i] += df[i] * p1 + f * q1 * dal[i]
        if crossed:
            w = target
            remaining -= tau
            reg = nxt
            continue
        w = w + f * p1
        return w, th
    return w, th


def limit_sensitivity_run_python(a: float, s: float, u: np.ndarray, b: float, limit: float, d: float, h: np.ndarray,
                                 speed: np.ndarray, angle: np.ndarray, sw: np.ndarray, sth: np.ndarray) -> None:
    """Fill ``speed[1:]``, ``angle[1:]`` and their sensitivities ``sw``, ``sth`` (rows as the samples, columns
    ``(a, b, L, s, d, w0)``) from ``speed[0]``, ``angle[0]`` and the rows ``sw[0]``, ``sth[0]``
    (:func:`limit_interval_sensitivity`)."""
    w, th = float(speed[0]), float(angle[0])
    dw, dth = sw[0].copy(), sth[0].copy()
    dal, dc, df = np.empty(6), np.empty(6), np.empty(6)
    for k in range(len(h)):
        w, th = limit_interval_sensitivity(a, s, u[k], b, limit, d, w, th, h[k], dw, dth, dal, dc, df)
        speed[k + 1] = w
        angle[k + 1] = th
        sw[k + 1] = dw
        sth[k + 1] = dth


def limit_run_python(ae: float, am: float, bu: np.ndarray, limit: float, d: float, h: np.ndarray,
                     speed: np.ndarray, angle: np.ndarray) -> None:
    """Fill ``speed[1:]`` and ``angle[1:]`` interval by interval from ``speed[0]``, ``angle[0]``: ``bu[k]`` (rad/s^2)
    held over ``h[k]`` s (:func:`limit_interval`)."""
    w, th = float(speed[0]), float(angle[0])
    for k in range(len(h)):
        w, th = limit_interval(ae, am, bu[k], limit, d, w, th, h[k])
        speed[k + 1] = w
        angle[k + 1] = th


def _rebound(function: Callable, **compiled: Callable) -> Callable:
    """``function``'s code with the callees it names replaced by their compiled ``compiled``: a plain module function
    for numba, which it caches on disk (a closure over the callees is compiled again in every process)."""
    import types
    return types.FunctionType(function.__code__, dict(function.__globals__, **compiled), function.__name__)


@functools.cache
def _compiled() -> Callable[..., None] | None:
    """:func:`limit_run_python` compiled by numba (None without numba or with ``MOTORID_NUMBA=0``)."""
    from motorsim.compiled import numba_jit
    jit = numba_jit()
    if jit is None:
        return None
    interval = jit(_rebound(limit_interval, _phi=jit(_phi), _first_region=jit(_first_region)))
    return jit(_rebound(limit_run_python, limit_interval=interval))


@functools.cache
def _compiled_sensitivity() -> Callable[..., None] | None:
    """:func:`limit_sensitivity_run_python` compiled by numba (None without numba or with ``MOTORID_NUMBA=0``)."""
    from motorsim.compiled import numba_jit
    jit = numba_jit()
    if jit is None:
        return None
    interval = jit(_rebound(limit_interval_sensitivity, _phi=jit(_phi), _dphi=jit(_dphi), _piece=jit(_piece),
                            _next_region=jit(_next_region), _first_region=jit(_first_region)))
    return jit(_rebound(limit_sensitivity_run_python, limit_interval_sensitivity=interval))


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


def limit_sensitivities(a: float, b: float, limit: float, share: float, bias: float, drive: np.ndarray,
                        time: np.ndarray, initial_speed: float = 0.0
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`limit_response` from angle 0 with the exact sensitivities of its angle and speed to ``(a, b, L, s, d,
    w0)`` (module docstring): ``(angle, speed, d angle, d speed)``, the last two one row per sample, one column per
    parameter."""
    t = np.asarray(time, dtype=float)
    n = len(t)
    speed, angle = np.empty(n), np.empty(n)
    sw, sth = np.zeros((n, 6)), np.zeros((n, 6))
    if n == 0:
        return angle, speed, sth, sw
    speed[0], angle[0] = initial_speed, 0.0
    sw[0, 5] = 1.0
    u = np.ascontiguousarray(np.asarray(drive, dtype=float)[:max(n - 1, 0)])
    kernel = _compiled_sensitivity()
    (limit_sensitivity_run_python if kernel is None else kernel)(
        float(a), float(share), u, float(b), float(limit), float(bias), np.ascontiguousarray(np.diff(t)), speed,
        angle, sw, sth)
    return angle, speed, sth, sw


def segment_sensitivities(theta: Sequence[float] | np.ndarray, seg: Segment, w0: float) -> tuple[np.ndarray,
                                                                                                np.ndarray]:
    """The model's output on ``seg`` from ``w0`` (:func:`segment_model`) and its sensitivities to ``(a, b, L, s, d,
    w0)`` (:func:`limit_sensitivities`)."""
    a, b, limit, share, d = (float(x) for x in theta)
    angle, speed, sth, sw = limit_sensitivities(a, b, limit, share, d, seg.drive, seg.time, w0)
    return (angle, sth) if seg.kind == "angle" else (speed, sw)


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
