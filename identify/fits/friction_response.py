"""Exact ZOH response of the Coulomb-friction motor and its analytic sensitivities, without a loop per sample.

The model (``motorsim.plant``) is ``d omega/dt = -a omega + b v - c sign(omega) + d`` with
``v`` the duty after the dead zone ``z`` (``v = u - sign(u) z`` when ``|u| > z``, else 0) and
sticking at rest while ``|b v + d| <= c``.  Every sample interval is in one of three *modes*:

* moving with sign ``s`` throughout: the linear ZOH step with the constant force
  ``G = b v + d - s c`` (``omega' = e omega + p G``, ``theta' = theta + p omega + q G``,
  ``e = exp(-a h)``, ``p = (1 - e)/a``, ``q = (h - p)/a``);
* stuck at rest: nothing moves;
* an *event*: the speed reaches zero at ``t_z = ln((omega - T)/(-T))/a`` (``T = G/a``)
  and then sticks or restarts the other way from rest.

Given the modes, the speed obeys ``omega_{k+1} = M_k omega_k + f_k`` with ``M_k = e_k``
except at the few event and sticking intervals, so the whole run is a first-order
linear scan (:func:`motorsim.recursion.first_order_filter` on a uniform clock, a blocked
closed form on a jittered one), a short Python loop over the *events* only, which replaces the scan's
step there by the exact nonlinear one, and the scan again with those steps put in
its forcing.  On a uniform clock ``e, p, q`` are computed once.  The modes are found in one
scan: simulate with guessed modes (the previous evaluation's, what a fit passes, or the
linear response's), read the modes off the result.  Before the first disagreement the
trajectory is exact; from there the intervals are stepped one at a time from their exact
state until that walk and the scan are both at rest at the same sample, after which the
past no longer matters and the scan is exact again up to its next disagreement.  Only a
walk that meets no common rest within :data:`WALK_LIMIT` samples scans the rest again.
(A fixed-point iteration of whole scans, which this replaced, took up to hundreds of scans
where wrong modes followed one another.)

Sensitivities: between events the derivatives with respect to ``(a, b, c, d, z,
omega_0)`` obey the same linear recursions (same ``M_k``), differentiated term by
term; at an event the step is differentiated *through the event time* ``t_z``
(exactly, by complex-step differentiation of the closed-form event step, Squire &
Trapp 1998, which has no cancellation), and a stuck interval has zero derivatives.
Being linear, the corrections at the events form one lower-bidiagonal system (one
LAPACK call instead of a loop), and a second scan spreads them.
With numba (a dependency where it has wheels), on at least
:data:`~identify.fits.friction_kernel.KERNEL_MIN_ROWS` samples or once the process has loaded it
(:func:`~identify.fits.friction_kernel.kernel_for`), the same response, modes and sensitivities come
from one compiled pass over the samples instead (:mod:`identify.fits.friction_kernel`: no walk in
Python); the two agree to rounding (a test compares them).

This is the exact derivative of the exact model wherever the modes do not change,
i.e. everywhere except on a set of measure zero — unlike a smoothed friction law,
the fit needs no final polish and the fitted model is the one ``motorsim.simulate``
integrates (a test checks both against it and against finite differences).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .friction_kernel import event_interval, kernel_for
from .sensitivity import first_order_scan

__all__ = ["FrictionResponse", "friction_response", "FRICTION_PARAMETERS"]

#: Columns of the sensitivities, in order.
FRICTION_PARAMETERS = ("a", "b", "friction", "bias", "dead_zone", "initial_speed")
_REST = 1e-10            # |omega| below this share of the speed scale counts as at rest
_COMPLEX_STEP = 1e-30    # relative complex step: exact derivatives to rounding


@dataclasses.dataclass(frozen=True)
class FrictionResponse:
    """Model angle and speed at the sample instants, their sensitivities and the modes.

    Attributes
    ----------
    angle, speed : ndarray, shape (n,)
        rad (relative to the first sample) and rad/s.
    angle_sensitivity, speed_sensitivity : ndarray, shape (n, 6) or None
        Derivatives with respect to :data:`FRICTION_PARAMETERS` (None when not asked).
    modes : ndarray of int, shape (n - 1,)
        Per interval: +1 / -1 moving with that sign, 0 stuck, +2 / -2 an event
        from that sign; pass back as ``modes`` to start the next evaluation.
    passes : int
        Scans over the samples used (1 but where the mode search scanned again, :data:`WALK_LIMIT`).
    """

    angle: np.ndarray
    speed: np.ndarray
    angle_sensitivity: np.ndarray | None
    speed_sensitivity: np.ndarray | None
    modes: np.ndarray
    passes: int


def _event_step(w, force, c, a, h, s, stick):
    """Speed and angle increment over an interval whose speed reaches zero (module docstring)."""
    target = (force - s * c) / a
    t_zero = np.log((w - target) / (-target)) / a
    d_angle = target * t_zero + w / a           # (w - T)(1 - exp(-a t_z)) = w at the zero
    rest = h - t_zero
    target2 = (force + s * c) / a                # restarting the other way from rest
    grown = 1.0 - np.exp(-a * rest)
    w_end = np.where(stick, 0.0 * w, target2 * grown)
    d_angle = d_angle + np.where(stick, 0.0 * w, target2 * (rest - grown / a))
    return w_end, d_angle


def _event_partials(w, force, c, a, h, s, stick):
    """Values and derivatives of :func:`_event_step` with respect to ``(w, force, c, a)``, by complex step."""
    args = [np.asarray(w, float), np.asarray(force, float), np.full(len(w), c), np.full(len(w), a)]
    w_end, d_angle = _event_step(args[0], args[1], args[2], args[3], h, s, stick)
    dw = np.empty((len(w), 4))
    dth = np.empty((len(w), 4))
    for j in range(4):
        step = _COMPLEX_STEP * np.maximum(np.abs(args[j]), 1.0)
        perturbed = [x.astype(complex) for x in args]
        perturbed[j] = perturbed[j] + 1j * step
        cw, cth = _event_step(perturbed[0], perturbed[1], perturbed[2], perturbed[3], h, s, stick)
        dw[:, j] = np.imag(cw) / step
        dth[:, j] = np.imag(cth) / step
    return w_end, d_angle, dw, dth


class _Intervals:
    """Per-interval constants of one evaluation: ``h, e, p, q`` and their ``a``-derivatives, the drive.

    On a uniform clock the constants are computed once and broadcast (read-only views).
    """

    def __init__(self, a, b, friction, bias, dead_zone, duty, time, uniform, static):
        u = np.asarray(duty, dtype=float)[:-1]
        h = np.diff(np.asarray(time, dtype=float))
        m = len(h)
        moving = np.abs(u) > dead_zone
        sign_u = np.sign(u)
        self.v = np.where(moving, u - sign_u * dead_zone, 0.0)
        self.v_zone = np.where(moving, -sign_u, 0.0)        # dv / d dead_zone
        self.force = b * self.v + bias
        self.a, self.b, self.c = a, b, friction
        self.static = max(static, friction)                 # the break-away level
        self.uniform = bool(uniform) and m > 0
        once = h[:1] if self.uniform else h
        self.h, self.e, self.p, self.q, self.dp, self.dq = (
            np.broadcast_to(x, (m,)) if self.uniform else x for x in _interval_constants(a, once))
        self.decay = a * self.h
        self.cum = np.concatenate([[0.0], np.cumsum(self.decay)])
        scale = (abs(b) * float(np.max(np.abs(self.v), initial=0.0)) + abs(bias) + friction) / max(a, 1e-12)
        self.rest = _REST * max(scale, 1e-300)


def _interval_constants(a: float, h: np.ndarray) -> tuple[np.ndarray, ...]:
    """``h, e = exp(-a h), p = (1 - e)/a, q = (h - p)/a, dp/da, dq/da`` (power series for small ``a h``)."""
    x = a * h
    e = np.exp(-x)
    one_minus = -np.expm1(-x)
    small = np.abs(x) < 1e-5
    xs = np.where(small, 1.0, x)
    a_s = np.where(small, 1.0, a)
    p = np.where(small, h * (1 - x / 2 + x * x / 6), one_minus / a_s)
    q = np.where(small, h ** 2 * (0.5 - x / 6 + x * x / 24), (h - p) / a_s)
    dp = np.where(small, h ** 2 * (-0.5 + x / 3), h * (xs * e - one_minus) / xs ** 2 * h)
    dq = np.where(small, h ** 3 * (-1 / 6 + x / 12), (-dp - q) / a_s)
    return h, e, p, q, dp, dq


def _uniform_constants(a: float, h: float) -> tuple[np.ndarray, ...]:
    """:func:`_interval_constants` of one interval ``h``, in floats where it is a handful of numpy calls on
    one-element arrays (the same operations, so the same bits; the power series of small ``a h`` as there)."""
    x = a * h
    if abs(x) < 1e-5:
        return _interval_constants(a, np.array([h]))
    e = float(np.exp(-x))
    one_minus = float(-np.expm1(-x))
    p = one_minus / a
    dp = h * (x * e - one_minus) / (x * x) * h
    q = (h - p) / a
    return tuple(np.array([v]) for v in (h, e, p, q, dp, (-dp - q) / a))


def _modes_of(iv: _Intervals, w: np.ndarray) -> np.ndarray:
    """The mode of every interval from the speed at its start (see :class:`FrictionResponse`)."""
    w0 = w[:-1]
    rest = np.abs(w0) <= iv.rest
    s = np.where(rest, np.where(np.abs(iv.force) > iv.static, np.sign(iv.force), 0.0), np.sign(w0))
    end = iv.e * w0 + iv.p * (iv.force - s * iv.c)
    event = ~rest & (s * end < 0)
    return (s * np.where(event, 2, 1)).astype(np.int8)


#: Samples the mode search walks one at a time from a wrong mode before it scans the rest again from there (when
#: neither the walk nor the scan has come to rest, the two trajectories cannot be joined).  A Python step costs
#: about a hundredth of a scan of 10^4 samples: on the bench's friction family 256 gave at most 13 scans an
#: evaluation and the shortest fits (2000: at most 4, but a run that seldom rests walks long; 64: up to 60).
WALK_LIMIT = 256


def _special_intervals(modes: np.ndarray) -> np.ndarray:
    """The intervals the scan replaces by an exact step: the events and the first of each stuck stretch."""
    after_stuck = np.concatenate([[False], modes[:-1] == 0])
    return np.flatnonzero((np.abs(modes) == 2) | ((modes == 0) & ~after_stuck))


def _suffix(iv: _Intervals, start: int) -> _Intervals:
    """The intervals from ``start`` on (views)."""
    out = object.__new__(_Intervals)
    out.__dict__.update(iv.__dict__)
    for name in ("v", "v_zone", "force", "h", "e", "p", "q", "dp", "dq", "decay", "cum"):
        setattr(out, name, getattr(iv, name)[start:])
    return out


def _exact_step(iv: _Intervals, k: int, w: float) -> tuple[int, float, float]:
    """Interval ``k`` from the speed ``w`` at its start, its mode read off ``w`` (as :func:`_modes_of`): the mode,
    the end speed and the angle increment, by the formulas of :func:`_trajectory`."""
    force, c = float(iv.force[k]), iv.c
    e, p, q = float(iv.e[k]), float(iv.p[k]), float(iv.q[k])
    rest = abs(w) <= iv.rest
    if rest:
        s = (1.0 if force > 0 else -1.0) if abs(force) > iv.static else 0.0
    else:
        s = 1.0 if w > 0 else -1.0
    g = force - s * c
    end = e * w + p * g
    if not rest and s * end < 0:
        w_next, d_angle = event_interval(w, force, c, iv.a, float(iv.h[k]), s, iv.static)
        return int(2 * s), w_next, d_angle
    if s == 0.0:
        return 0, 0.0, 0.0
    return int(s), end, p * w + q * g


def _searched(iv: _Intervals, guess: np.ndarray, w_start: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Speed, angle increments and modes of every interval, the modes found in one scan from ``guess``: the
    scan is exact up to its first interval whose mode its own speed contradicts; from there the intervals are
    stepped one at a time, each from its exact state, until both that walk and the scan are at rest at the same
    sample (the past then no longer matters: the scan is exact again from there, up to its next contradiction).
    Only where the two do not meet within :data:`WALK_LIMIT` samples is the rest scanned again, from the walk's
    state.  Returns ``(speed, angle increments, modes, scans)``."""
    m = len(iv.h)
    speed = np.empty(m + 1)
    speed[0] = w_start
    d_angle = np.empty(m)
    modes = np.empty(m, dtype=np.int8)
    start, scans = 0, 0
    while True:
        sub = iv if start == 0 else _suffix(iv, start)
        w, dth, _ = _trajectory(sub, guess[start:], float(speed[start]))
        scans += 1
        read = _modes_of(sub, w)
        n = len(read)
        resting = np.abs(w) <= iv.rest
        done = 0                    # intervals of this scan settled (relative to start); speed[start + done] is set
        for k in np.flatnonzero(read != guess[start:]).tolist():
            if k < done:            # walked over already
                continue
            speed[start + done + 1:start + k + 1] = w[done + 1:k + 1]
            d_angle[start + done:start + k] = dth[done:k]
            modes[start + done:start + k] = read[done:k]
            j, wj = k, float(w[k])
            while True:             # one interval at a time from the exact state
                modes[start + j], wj, d_angle[start + j] = _exact_step(iv, start + j, wj)
                j += 1
                speed[start + j] = wj
                if j == n or (abs(wj) <= iv.rest and resting[j]) or j - k >= WALK_LIMIT:
                    break
            done = j
            if j == n:
                return speed, d_angle, modes, scans
            if not resting[j] or abs(wj) > iv.rest:     # not rejoined: scan the rest again from here
                break
        else:                       # the scan is exact from `done` to the end
            speed[start + done + 1:] = w[done + 1:]
            d_angle[start + done:] = dth[done:]
            modes[start + done:] = read[done:]
            return speed, d_angle, modes, scans
        start += done
        guess = np.concatenate([guess[:start], read[done:]])


def _trajectory(iv: _Intervals, modes: np.ndarray, w_start: float):
    """Speed and angle for given modes; the event steps exact (module docstring)."""
    s = np.sign(modes).astype(float)
    moving = modes != 0
    g = iv.force - s * iv.c
    f = np.where(moving, iv.p * g, 0.0)
    special = _special_intervals(modes)
    start = np.array([w_start])
    base = first_order_scan(iv.decay, f[:, None], start, iv.uniform)[:, 0]
    decay = _special_decay(iv, special)
    x_at = np.empty(len(special))
    x_next = np.empty(len(special))
    th_at = np.zeros(len(special))
    acc = 0.0
    a, c = iv.a, iv.c
    for j, (m_k, b_k, b_next, dec, force, h) in enumerate(zip(
            modes[special].tolist(), base[special].tolist(), base[special + 1].tolist(),
            decay.tolist(), iv.force[special].tolist(), iv.h[special].tolist())):
        x_k = b_k + acc * dec
        if m_k == 0:
            w_next, d_angle = 0.0, 0.0
        else:
            w_next, d_angle = event_interval(x_k, force, c, a, h, 1.0 if m_k > 0 else -1.0, iv.static)
        x_at[j], x_next[j], th_at[j] = x_k, w_next, d_angle
        acc = w_next - b_next
    w = _rescanned(iv, f[:, None], start, special, x_at[:, None], x_next[:, None])[:, 0]
    d_angle_all = np.where(moving, iv.p * w[:-1] + iv.q * g, 0.0)
    d_angle_all[special] = th_at
    return w, d_angle_all, special


def _rescanned(iv: _Intervals, forcing: np.ndarray, start: np.ndarray, special: np.ndarray,
               x_at: np.ndarray, x_next: np.ndarray) -> np.ndarray:
    """The scan again with each special interval's step replaced: from ``x_at`` to ``x_next``.

    ``forcing`` is overwritten: on a special interval ``k`` it becomes ``x_next - e_k x_at``, so
    that the linear step ``e_k x_k + forcing_k`` lands on ``x_next`` (``x_k = x_at`` to rounding).
    """
    forcing[special] = x_next - iv.e[special][:, None] * x_at
    return first_order_scan(iv.decay, forcing, start, iv.uniform)


def _special_decay(iv: _Intervals, special: np.ndarray) -> np.ndarray:
    """``prod e`` from just after the previous special interval to the start of each special one."""
    previous_end = np.concatenate([[0], special[:-1] + 1])
    return np.exp(-(iv.cum[special] - iv.cum[previous_end]))


def friction_response(a: float, b: float, friction: float, bias: float, dead_zone: float, duty, time,
                      initial_speed: float = 0.0, *, uniform: bool | None = None, sensitivities: bool = True,
                      modes: np.ndarray | None = None, static_friction: float = 0.0) -> FrictionResponse:
    """Exact ZOH response of the friction motor and its sensitivities (module docstring).

    Parameters
    ----------
    a : float
        Pole in 1/s, > 0.
    b : float
        Gain per input unit, (rad/s^2)/duty.
    friction : float
        Coulomb friction ``c`` in rad/s^2, >= 0.
    bias : float
        Constant acceleration ``d`` in rad/s^2.
    dead_zone : float
        Dead zone in input units, >= 0.
    duty : array_like, shape (n,)
        Input held from ``time[k]`` to ``time[k+1]`` (already delayed; last value unused).
    time : array_like, shape (n,)
        Strictly increasing sample instants in s.
    initial_speed : float
        Speed at ``time[0]`` in rad/s.
    uniform : bool, optional
        Whether ``time`` is uniformly spaced (detected when None).
    sensitivities : bool
        Also compute the derivatives (default True).
    modes : ndarray, optional
        The modes the scan starts from (a previous response's ``modes``).
    static_friction : float
        Static friction (stiction) in rad/s^2: the force ``|b v + d|`` the shaft at rest needs to break away,
        and below which a speed reaching zero sticks; the friction level when smaller (default 0: none).
        It moves only those decisions, so the response is piecewise constant in it and has no column for it.

    Returns
    -------
    FrictionResponse
    """
    t = np.asarray(time, dtype=float)
    if uniform is None:
        steps = np.diff(t)
        uniform = len(steps) > 0 and bool(np.all(np.abs(steps - steps[0]) <= 1e-12 * abs(steps[0])))
    kernel = kernel_for(len(t))
    if kernel is not None:
        return _compiled(kernel, (a, b, friction, bias, dead_zone), np.asarray(duty, dtype=float)[:-1], t, uniform,
                         float(initial_speed), sensitivities, max(float(static_friction), friction))
    iv = _Intervals(a, b, friction, bias, dead_zone, duty, t, uniform, float(static_friction))
    if modes is None or len(modes) != len(iv.h):
        lin = first_order_scan(iv.decay, (iv.p * iv.force)[:, None], np.array([initial_speed]), uniform)[:, 0]
        modes = _modes_of(iv, lin)
    w, d_angle, modes, passes = _searched(iv, np.asarray(modes, dtype=np.int8), float(initial_speed))
    special = _special_intervals(modes)
    angle = np.concatenate([[0.0], np.cumsum(d_angle)])
    if not sensitivities:
        return FrictionResponse(angle, w, None, None, modes, passes)
    s_ang, s_spd = _sensitivities(iv, modes, w, special)
    return FrictionResponse(angle, w, s_ang, s_spd, modes, passes)


def _compiled(kernel, params: tuple[float, float, float, float, float], u: np.ndarray, t: np.ndarray, uniform: bool,
              initial_speed: float, sensitivities: bool, static: float) -> FrictionResponse:
    """The response by the compiled one-pass kernel (:mod:`identify.fits.friction_kernel`): the interval
    constants and the rest threshold as :class:`_Intervals` has them, the rest in the kernel."""
    a, b, friction, bias, dead_zone = params
    constants = _uniform_constants(a, float(t[1] - t[0])) if uniform and len(t) > 1 else \
        _interval_constants(a, np.diff(t))
    top = max(float(np.max(np.abs(u), initial=0.0)) - dead_zone, 0.0)
    rest = _REST * max((abs(b) * top + abs(bias) + friction) / max(a, 1e-12), 1e-300)
    n = len(u) + 1
    speed, angle = np.empty(n), np.empty(n)
    shape = (n, len(FRICTION_PARAMETERS)) if sensitivities else (1, len(FRICTION_PARAMETERS))
    s_spd, s_ang = np.empty(shape), np.empty(shape)
    modes = np.empty(n - 1, dtype=np.int8)
    kernel(np.ascontiguousarray(u), *constants, a, b, friction, bias, dead_zone, initial_speed, rest,
           sensitivities, speed, angle, s_spd, s_ang, modes, static)
    if not sensitivities:
        return FrictionResponse(angle, speed, None, None, modes, 1)
    return FrictionResponse(angle, speed, s_ang, s_spd, modes, 1)


def _sensitivities(iv: _Intervals, modes: np.ndarray, w: np.ndarray, special: np.ndarray):
    """Angle and speed derivatives with respect to :data:`FRICTION_PARAMETERS` (module docstring)."""
    s = np.sign(modes).astype(float)
    moving = modes != 0
    p = np.where(moving, iv.p, 0.0)
    w0 = w[:-1]
    g = iv.force - s * iv.c
    fw = _force_columns(iv, s, p)                       # forcing of the speed's sensitivities
    fw[:, 0] = np.where(moving, iv.dp * g - iv.h * iv.e * w0, 0.0)
    fth = _force_columns(iv, s, np.where(moving, iv.q, 0.0))      # of the angle increments'
    fth[:, 0] = np.where(moving, iv.dp * w0 + iv.dq * g, 0.0)
    mult_th = p                                         # d(angle increment)/d(speed at start)
    is_event = np.abs(modes[special]) == 2
    events = special[is_event]
    mult = np.zeros(len(special))                       # stuck: nothing carries over
    forcing = np.zeros((len(special), len(FRICTION_PARAMETERS)))
    if len(events):
        dw, ev_fw, dth, ev_fth = _event_columns(iv, w0, s, events)
        fth[events] = ev_fth
        mult_th[events] = dth[:, 0]
        mult[is_event] = dw[:, 0]
        forcing[is_event] = ev_fw
    x0 = np.zeros(len(FRICTION_PARAMETERS))
    x0[-1] = 1.0
    base = first_order_scan(iv.decay, fw, x0, iv.uniform)
    x_at, x_next = _special_states(mult, forcing, _special_decay(iv, special), base[special], base[special + 1])
    s_spd = _rescanned(iv, fw, x0, special, x_at, x_next)
    s_ang = np.zeros_like(s_spd)
    np.cumsum(mult_th[:, None] * s_spd[:-1] + fth, axis=0, out=s_ang[1:])
    return s_ang, s_spd


def _force_columns(iv: _Intervals, s: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """``gain`` times the derivatives of the force ``G = b v + d - s c`` with respect to the parameters
    (the ``a`` column left for the caller, the initial speed's is zero)."""
    out = np.empty((len(gain), len(FRICTION_PARAMETERS)))
    out[:, 1] = gain * iv.v
    out[:, 2] = -gain * s
    out[:, 3] = gain
    out[:, 4] = (iv.b * gain) * iv.v_zone
    out[:, 5] = 0.0
    return out


def _event_columns(iv: _Intervals, w0: np.ndarray, s: np.ndarray, events: np.ndarray):
    """At the event intervals: the end speed's derivative with respect to the start speed and its forcing
    columns, and the same for the angle increment (through the event time, :func:`_event_partials`)."""
    k = len(events)
    stick = np.abs(iv.force[events]) <= iv.static
    _, _, dw, dth = _event_partials(w0[events], iv.force[events], iv.c, iv.a, iv.h[events], s[events], stick)
    d_force = np.zeros((k, len(FRICTION_PARAMETERS)))  # d(b v + d)/dparam
    d_force[:, 1] = iv.v[events]
    d_force[:, 3] = 1.0
    d_force[:, 4] = iv.b * iv.v_zone[events]
    columns = []
    for partial in (dw, dth):
        col = partial[:, 1:2] * d_force
        col[:, 2] += partial[:, 2]
        col[:, 0] += partial[:, 3]
        columns.append(col)
    return dw, columns[0], dth, columns[1]


def _special_states(mult: np.ndarray, forcing: np.ndarray, decay: np.ndarray, base_at: np.ndarray,
                    base_next: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States at the start and at the end of each special interval ``j`` (rows), given the plain scan.

    The scan's state at a special interval is off by the previous special interval's jump
    ``acc`` decayed over the moving stretch between them; the step there is
    ``x_next = mult x_at + forcing``.  So ``acc_j = mult_j decay_j acc_{j-1} + (mult_j base_at_j
    + forcing_j - base_next_j)``: one lower-bidiagonal system, solved by forward substitution
    (LAPACK ``dtbtrs``, the same arithmetic as a loop over the special intervals).
    """
    k = len(mult)
    if k == 0:
        return np.zeros_like(base_at), np.zeros_like(base_at)
    from scipy.linalg.lapack import dtbtrs  # imported when used (start-up time)
    carry = mult * decay
    bands = np.zeros((2, k))
    bands[1, :-1] = -carry[1:]
    rhs = np.asfortranarray(mult[:, None] * base_at + forcing - base_next)
    acc, info = dtbtrs(bands, rhs, uplo="L", diag="U")
    if info != 0:  # pragma: no cover - a unit-diagonal triangular system is never singular
        raise np.linalg.LinAlgError(f"dtbtrs failed with info = {info}")
    x_at = base_at.copy()
    x_at[1:] += acc[:-1] * decay[1:, None]
    return x_at, mult[:, None] * x_at + forcing
