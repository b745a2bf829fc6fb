"""The friction response and its sensitivities in one pass over the samples, compiled by numba.

:func:`identify.fits.friction_response.friction_response` finds each interval's mode (moving,
stuck, a zero crossing) by a vectorised scan and walks the intervals whose mode the scan got
wrong one at a time in Python; with many events (heavy friction, a multisine that stops the
shaft often) each scan carries a short Python loop over the events.  Walked sample by sample,
the mode of every interval is simply read off the state at its start, so one pass gives the speed, the angle, the modes
and the derivatives with respect to :data:`~identify.fits.friction_response.FRICTION_PARAMETERS`
together, by the same formulas (the moving step and its derivatives, the event step
differentiated through the event time by complex step, a stuck interval carrying nothing).
Compiled by numba (a dependency where it has wheels) that pass costs about as much as one of the
vectorised scans; in Python it would be far slower than the vectorised path, so without
numba (or with ``MOTORID_NUMBA=0``) :func:`compiled_response` returns None and the caller
keeps the vectorised path.  Both give the same numbers to rounding (tests compare them).
"""
from __future__ import annotations

import cmath
import contextlib
import functools
import math
from typing import Callable

import numpy as np

from motorsim.compiled import numba_jit

__all__ = ["response_pass", "event_interval", "compiled_response", "kernel_for", "KERNEL_MIN_ROWS"]

#: Rows from which :func:`identify.fits.friction_response.friction_response` takes the compiled pass (when
#: numba is installed) before the process has loaded it: below, loading it costs more than the work it
#: saves; once loaded, every length takes it.
KERNEL_MIN_ROWS = 200

_COMPLEX_STEP = 1e-30


def _event_value(w: complex, force: complex, c: complex, a: complex, h: float, s: float,
                 stick: bool) -> tuple[complex, complex]:
    """End speed and angle increment of an event interval (the complex-step form of the event step)."""
    target = (force - s * c) / a
    t_zero = cmath.log((w - target) / (-target)) / a
    d_angle = target * t_zero + w / a
    if stick:
        return 0.0 * w, d_angle
    rest = h - t_zero
    target2 = (force + s * c) / a
    grown = 1.0 - cmath.exp(-a * rest)
    return target2 * grown, d_angle + target2 * (rest - grown / a)


def event_interval(w: float, force: float, c: float, a: float, h: float, s: float,
                   static: float) -> tuple[float, float]:
    """End speed and angle increment of an event interval in floats (a plain step when it is not one: a mode
    the mode search of :mod:`identify.fits.friction_response` is about to correct); at the zero the shaft
    sticks while ``|force| <= static`` (the static friction, ``>= c``)."""
    target = (force - s * c) / a
    ratio = (w - target) / (-target) if target != 0 else 0.0
    if not ratio >= 1.0:
        e = math.exp(-a * h)
        return target + (w - target) * e, target * h + (w - target) * (1.0 - e) / a
    t_zero = math.log(ratio) / a
    d_angle = target * t_zero + w / a
    if abs(force) <= static:
        return 0.0, d_angle
    rest = h - t_zero
    target2 = (force + s * c) / a
    grown = -math.expm1(-a * rest)
    return target2 * grown, d_angle + target2 * (rest - grown / a)


def _moving_sensitivities(sw: np.ndarray, sth: np.ndarray, col: np.ndarray, e: float, p: float, q: float, dp: float,
                          dq: float, h: float, w: float, g: float, v: float, s: float, b_zone: float) -> None:
    """One moving interval: the speed's and the angle's sensitivities ``sw``, ``sth`` carried over, in place
    (``g`` the force less friction, ``b_zone`` the force's derivative with respect to the dead zone)."""
    col[0] = dp * g - h * e * w
    col[1] = v
    col[2] = -s
    col[3] = 1.0
    col[4] = b_zone
    for j in range(6):
        dg = col[j] if 0 < j < 5 else 0.0
        sth[j] += p * sw[j] + q * dg
        sw[j] = e * sw[j] + p * dg
    sth[0] += dp * w + dq * g
    sw[0] += col[0]


def _event_sensitivities(sw: np.ndarray, sth: np.ndarray, col: np.ndarray, dw: np.ndarray, dth: np.ndarray,
                         w: float, force: float, c: float, a: float, h: float, s: float, v: float, b: float,
                         v_zone: float, static: float) -> None:
    """One event interval: the sensitivities carried through the event time, in place (the event step's
    partials with respect to ``(w, force, c, a)`` by complex step into ``dw``, ``dth``)."""
    stick = abs(force) <= static
    for j in range(4):
        arg = w if j == 0 else force if j == 1 else c if j == 2 else a
        step = _COMPLEX_STEP * max(abs(arg), 1.0)
        cw, cth = _event_value(complex(w, step if j == 0 else 0.0), complex(force, step if j == 1 else 0.0),
                               complex(c, step if j == 2 else 0.0), complex(a, step if j == 3 else 0.0), h, s, stick)
        dw[j] = cw.imag / step
        dth[j] = cth.imag / step
    col[0] = dw[3]
    col[1] = dw[1] * v
    col[2] = dw[2]
    col[3] = dw[1]
    col[4] = dw[1] * b * v_zone
    for j in range(6):
        f_w = col[j] if j < 5 else 0.0
        f_th = (dth[3] if j == 0 else dth[1] * v if j == 1 else dth[2] if j == 2 else dth[1] if j == 3
                else dth[1] * b * v_zone if j == 4 else 0.0)
        sth[j] += dth[0] * sw[j] + f_th
        sw[j] = dw[0] * sw[j] + f_w


def response_pass(u: np.ndarray, h: np.ndarray, e: np.ndarray, p: np.ndarray, q: np.ndarray, dp: np.ndarray,
                  dq: np.ndarray, a: float, b: float, c: float, d: float, z: float, w0: float, rest: float,
                  sens: bool, speed: np.ndarray, angle: np.ndarray, s_spd: np.ndarray, s_ang: np.ndarray,
                  modes: np.ndarray, static: float) -> None:
    """Fill ``speed``, ``angle`` (from 0), ``modes`` and, with ``sens``, ``s_spd`` and ``s_ang`` (module docstring).

    ``u``: the duty of every interval (``len(h)``); ``h, e, p, q, dp, dq``: the interval constants of the
    friction response (``e = exp(-a h)`` and the rest, with their ``a``-derivatives), one per interval or
    a single one for all (a uniform clock); ``rest``: the speed below which the shaft counts as at rest;
    ``static``: the force the shaft at rest needs to break away (the static friction, ``>= c``; ``c`` without
    stiction).  The static level moves only the decisions to stick, so it has no sensitivity column.
    """
    m = len(u)
    one = len(e) == 1
    w = w0
    th = 0.0
    speed[0] = w
    angle[0] = 0.0
    sw = np.zeros(6)
    sth = np.zeros(6)
    sw[5] = 1.0
    if sens:
        s_spd[0, :] = sw
        s_ang[0, :] = sth
    col = np.zeros(6)
    dw = np.zeros(4)
    dth = np.zeros(4)
    for k in range(m):
        i = 0 if one else k
        uk = u[k]
        if abs(uk) > z:
            sgn_u = 1.0 if uk > 0 else (-1.0 if uk < 0 else 0.0)
            v = uk - sgn_u * z
            v_zone = -sgn_u
        else:
            v = 0.0
            v_zone = 0.0
        force = b * v + d
        if abs(w) <= rest:
            s = (1.0 if force > 0 else -1.0) if abs(force) > static else 0.0
        else:
            s = 1.0 if w > 0 else -1.0
        end = e[i] * w + p[i] * (force - s * c)
        event = abs(w) > rest and s * end < 0
        modes[k] = int(s) * (2 if event else 1)
        if s == 0.0:                                    # stuck: nothing moves, nothing carries over
            w_next, d_angle = 0.0, 0.0
            if sens:
                sw[:] = 0.0
        elif not event:                                 # moving with sign s throughout
            g = force - s * c
            w_next = end
            d_angle = p[i] * w + q[i] * g
            if sens:
                _moving_sensitivities(sw, sth, col, e[i], p[i], q[i], dp[i], dq[i], h[i], w, g, v, s, b * v_zone)
        else:                                           # the speed reaches zero inside the interval
            w_next, d_angle = event_interval(w, force, c, a, h[i], s, static)
            if sens:
                _event_sensitivities(sw, sth, col, dw, dth, w, force, c, a, h[i], s, v, b, v_zone, static)
        w = w_next
        th += d_angle
        speed[k + 1] = w
        angle[k + 1] = th
        if sens:
            s_spd[k + 1, :] = sw
            s_ang[k + 1, :] = sth


@functools.cache
def compiled_response() -> Callable[..., None] | None:
    """:func:`response_pass` compiled by numba (cached on disk); None without numba or with ``MOTORID_NUMBA=0``."""
    jit = numba_jit()
    if jit is None:
        return None
    import types

    def compiled(function, names=()):
        """``function`` compiled, the helpers it calls by ``names`` replaced by their compiled forms."""
        scope = dict(function.__globals__, **{n: helpers[n] for n in names})
        return jit(types.FunctionType(function.__code__, scope, function.__name__))
    helpers: dict[str, Callable[..., object]] = {"_event_value": jit(_event_value),
                                                 "event_interval": jit(event_interval)}
    helpers["_moving_sensitivities"] = jit(_moving_sensitivities)
    helpers["_event_sensitivities"] = compiled(_event_sensitivities, ("_event_value",))
    return compiled(response_pass, tuple(helpers))


#: Set (by :func:`without_loading`) while friction responses must not be the reason numba is imported.
_NO_LOADING = False


@contextlib.contextmanager
def without_loading():
    """Within it, :func:`kernel_for` gives the compiled pass only where the process has loaded it already: a short
    fit that a linear recording also makes (the default's check of its screen) does not import numba and its
    compiler, about 130 MB, for a few milliseconds of Python loop."""
    global _NO_LOADING
    before, _NO_LOADING = _NO_LOADING, True
    try:
        yield
    finally:
        _NO_LOADING = before


def kernel_for(rows: int) -> Callable[..., None] | None:
    """The compiled pass for a run of ``rows`` samples, or None: without numba, with ``MOTORID_NUMBA=0``, or
    for a run shorter than :data:`KERNEL_MIN_ROWS` (or any run within :func:`without_loading`) before the process
    has loaded the kernel (it does not pay for importing numba; once loaded, short runs such as the model output's
    initial-speed windows take it)."""
    if (rows < KERNEL_MIN_ROWS or _NO_LOADING) and not compiled_response.cache_info().currsize:
        return None
    return compiled_response()
