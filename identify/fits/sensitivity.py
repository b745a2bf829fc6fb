"""Exact ZOH response of ``b/(s+a)`` and its analytic sensitivities (output error, CRB).

Over an interval of length ``h_k = t_{k+1} - t_k`` with the duty ``u_k`` held
(``x = a h_k``, see ``motorsim.plant``)::

    e_k = exp(-x)               omega_{k+1} = e_k omega_k + b p_k u_k
    p_k = h_k phi1(x)           theta_{k+1} = theta_k + p_k omega_k + b q_k u_k
    q_k = h_k^2 phi2(x)

with ``phi1(x) = (1 - e^-x)/x`` and ``phi2(x) = (x - 1 + e^-x)/x^2`` (evaluated
by their power series for small ``x``, so nothing cancels when ``a h`` is tiny).
Differentiating the recursions gives recursions for the sensitivities of angle
and speed with respect to ``a``, ``b`` and the initial speed ``omega_0``; they
share the factor ``e_k``, so all of them are first-order linear recursions,
solved without a Python loop per sample (:func:`motorsim.recursion.first_order_filter`
for a uniform clock, a blocked closed form ``x_k = E_k (x_0 + sum_j f_j / E_{j+1})`` for a
jittered one).  The angle at the first sample is taken as 0: callers fit or
project out an angle offset.

References: Ljung, *System Identification* (2nd ed., 1999), sec. 10.3
(output-error sensitivities); Soderstrom & Stoica, *System Identification*
(1989), sec. 7.5.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from motorsim.recursion import first_order_filter

__all__ = ["Response", "zoh_response", "phi_functions", "UNIFORM_RTOL", "first_order_scan",
           "project_out_initial_state"]

#: Relative spread of the sample intervals under which a clock counts as uniform (as
#: :class:`identify.data.Segment` decides): a float grid ``k * dt`` differs by rounding only.
UNIFORM_RTOL = 1e-9
_SERIES_BELOW = 0.05  # power series below; above, the closed forms lose < 1e-13 to cancellation
_SERIES_TERMS = 8     # 0.05**8 / 10! < 1e-16: series truncation below rounding
_BLOCK_EXPONENT = 200.0  # keep exp() of partial sums far from overflow in the blocked scan


def phi_functions(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``phi1, phi2`` and their derivatives with respect to ``x``, elementwise.

    Parameters
    ----------
    x : ndarray
        ``a h`` per interval (dimensionless).

    Returns
    -------
    phi1, phi2, dphi1, dphi2 : ndarray
        Same shape as ``x`` (see the module docstring).
    """
    x = np.asarray(x, dtype=float)
    p1 = np.empty_like(x)
    p2 = np.empty_like(x)
    d1 = np.empty_like(x)
    d2 = np.empty_like(x)
    small = np.abs(x) < _SERIES_BELOW
    if np.any(small):
        xs = x[small]
        s1 = np.zeros_like(xs)
        s2 = np.zeros_like(xs)
        t1 = np.zeros_like(xs)
        t2 = np.zeros_like(xs)
        for k in range(_SERIES_TERMS, -1, -1):  # Horner, highest term first
            c1 = (-1.0) ** k / math.factorial(k + 1)
            c2 = (-1.0) ** k / math.factorial(k + 2)
            s1 = s1 * xs + c1
            s2 = s2 * xs + c2
            if k >= 1:
                t1 = t1 * xs + k * c1
                t2 = t2 * xs + k * c2
        p1[small], p2[small], d1[small], d2[small] = s1, s2, t1, t2
    big = ~small
    if np.any(big):
        xb = x[big]
        em = np.exp(-xb)
        one_minus = -np.expm1(-xb)
        p1[big] = one_minus / xb
        p2[big] = (xb - one_minus) / xb**2
        d1[big] = (xb * em - one_minus) / xb**2
        d2[big] = one_minus / xb**2 - 2.0 * (xb - one_minus) / xb**3
    return p1, p2, d1, d2


def first_order_scan(decay: np.ndarray, forcing: np.ndarray, x0: np.ndarray, uniform: bool) -> np.ndarray:
    """``x[0] = x0``, ``x[k+1] = exp(-decay[k]) x[k] + forcing[k]`` for columns of ``forcing``.

    ``decay`` has shape (n-1,), ``forcing`` (n-1, m), ``x0`` (m,); returns (n, m).
    """
    n = len(decay) + 1
    m = forcing.shape[1]
    out = np.empty((n, m))
    out[0] = x0
    if n == 1:
        return out
    if uniform:
        e = math.exp(-decay[0])
        first_order_filter(e, forcing, x0, out=out[1:])
        return out
    s = np.concatenate([[0.0], np.cumsum(decay)])  # s[k] = a (t_k - t_0), increasing for a > 0
    start = 0
    while start < n - 1:
        stop = int(np.searchsorted(s, s[start] + _BLOCK_EXPONENT, side="right")) - 1
        stop = min(max(stop, start + 1), n - 1)
        rel = s[start + 1:stop + 1] - s[start]
        if stop == start + 1 or rel[-1] <= 0:
            # one long interval (or a non-positive a): step directly
            for k in range(start, stop):
                out[k + 1] = math.exp(-decay[k]) * out[k] + forcing[k]
        else:
            acc = np.cumsum(np.exp(rel)[:, None] * forcing[start:stop], axis=0)
            out[start + 1:stop + 1] = np.exp(-rel)[:, None] * (out[start] + acc)
        start = stop
    return out


@dataclasses.dataclass(frozen=True)
class Response:
    """Model angle and speed at the sample instants, and their sensitivities.

    Attributes
    ----------
    angle, speed : ndarray, shape (n,)
        rad (relative to the first sample) and rad/s.
    angle_sensitivity, speed_sensitivity : ndarray, shape (n, 4), or (n, 1)
        Derivatives with respect to ``(a, b, initial_speed, bias)``; of a response computed
        without sensitivities, the ``initial_speed`` column alone.
    angle_initial_speed_a, speed_initial_speed_a : ndarray, shape (n,)
        Derivative of the ``initial_speed`` column with respect to ``a`` (the response
        is linear in the initial speed, so this is all variable projection needs).
    """

    angle: np.ndarray
    speed: np.ndarray
    angle_sensitivity: np.ndarray
    speed_sensitivity: np.ndarray
    angle_initial_speed_a: np.ndarray
    speed_initial_speed_a: np.ndarray

    @property
    def angle_initial_speed(self) -> np.ndarray:
        """The angle's derivative with respect to the initial speed, shape (n,) (computed in either mode)."""
        return self.angle_sensitivity[:, 2 if self.angle_sensitivity.shape[1] == 4 else 0]

    @property
    def speed_initial_speed(self) -> np.ndarray:
        """The speed's derivative with respect to the initial speed, shape (n,) (computed in either mode)."""
        return self.speed_sensitivity[:, 2 if self.speed_sensitivity.shape[1] == 4 else 0]


def _interval_coefficients(a: float, t: np.ndarray, uniform: bool) -> tuple[Any, np.ndarray, Any, Any, Any, Any]:
    """``h``, ``x = a h``, ``p``, ``q``, ``dp/da`` and ``dq/da`` of every interval (module docstring).

    On a uniform clock the coefficients are evaluated once, as scalars (``x`` is
    still one entry per interval).
    """
    h = np.diff(t)
    if uniform and len(h):
        h = h[0]
        x = np.full(len(t) - 1, a * h)
        phis: Sequence[float | np.ndarray] = [float(f[0]) for f in phi_functions(np.array([a * h]))]
    else:
        x = a * h
        phis = phi_functions(x)
    p1, p2, d1, d2 = phis
    p = h * p1                  # (1 - e)/a
    q = h * h * p2              # (h - p)/a ; angle gain of the drive is b q
    dp = h * h * d1             # dp/da
    dq = h ** 3 * d2            # dq/da
    return h, x, p, q, dp, dq


def zoh_response(a: float, b: float, drive, time, initial_speed: float = 0.0, *,
                 bias: float = 0.0, uniform: bool | None = None, sensitivities: bool = True) -> Response:
    """Exact ZOH response of ``d omega/dt = -a omega + b v`` and its sensitivities.

    Parameters
    ----------
    a : float
        Pole in 1/s (any real; the power series keep ``a -> 0`` exact).
    b : float
        Gain per drive unit.
    drive : array_like, shape (n,)
        ``drive[k]`` held from ``time[k]`` to ``time[k+1]`` (last value unused).
    time : array_like, shape (n,)
        Strictly increasing sample instants in s.
    initial_speed : float
        Speed at ``time[0]`` in rad/s.
    bias : float
        Constant acceleration ``d`` in rad/s^2: ``d omega/dt = -a omega + b v + d``.
    uniform : bool, optional
        Whether ``time`` is uniformly spaced (detected when None: intervals within
        :data:`UNIFORM_RTOL` of the first).
    sensitivities : bool
        When False, only the angle, the speed and the ``initial_speed`` columns are
        computed (the sensitivities of shape (n, 1) hold that column alone, 32 bytes a sample
        less than four columns): what a residual evaluation needs.

    Returns
    -------
    Response
        Sensitivity columns ``(a, b, initial_speed, bias)``.
    """
    v = np.asarray(drive, dtype=float)[:-1]
    t = np.asarray(time, dtype=float)
    if uniform is None:
        steps = np.diff(t)
        uniform = len(steps) > 0 and bool(np.all(np.abs(steps - steps[0]) <= UNIFORM_RTOL * abs(steps[0])))
    h, x, p, q, dp, dq = _interval_coefficients(a, t, uniform)
    n = len(t)
    tau = a * (t - t[0]) if uniform else np.concatenate([[0.0], np.cumsum(x)])
    e_pow = np.exp(-tau)        # E_k = prod_{j<k} e_j
    # speed per unit b and per unit bias (zero initial speed): w[k+1] = e w[k] + p v
    if bias == 0 and not sensitivities:
        w_b = first_order_scan(x, (p * v)[:, None], np.zeros(1), uniform)[:, 0]
        w_d = np.zeros(n)
    else:
        w_bd = first_order_scan(x, np.column_stack([p * v, np.broadcast_to(p, v.shape)]), np.zeros(2), uniform)
        w_b, w_d = w_bd[:, 0], w_bd[:, 1]
    speed = b * w_b + bias * w_d + initial_speed * e_pow
    force = b * v + bias
    angle = np.zeros(n)
    angle[1:] = np.cumsum(p * speed[:-1] + q * force)
    th_0 = np.zeros(n)
    th_0[1:] = np.cumsum(p * e_pow[:-1])
    if not sensitivities:
        undefined = np.broadcast_to(np.nan, (n,))
        return Response(angle=angle, speed=speed, angle_sensitivity=th_0[:, None], speed_sensitivity=e_pow[:, None],
                        angle_initial_speed_a=undefined, speed_initial_speed_a=undefined)
    # d speed / d a: forcing (de/da) w + (dp/da) force, de/da = -h e
    e = np.exp(-x)
    w_a = first_order_scan(x, (-h * e * speed[:-1] + dp * force)[:, None], np.zeros(1), uniform)[:, 0]
    th_a = np.zeros(n)
    th_b = np.zeros(n)
    th_d = np.zeros(n)
    th_a[1:] = np.cumsum(p * w_a[:-1] + dp * speed[:-1] + dq * force)
    th_b[1:] = np.cumsum(p * w_b[:-1] + q * v)
    th_d[1:] = np.cumsum(p * w_d[:-1] + q)
    e_pow_a = -(t - t[0]) * e_pow
    th_0a = np.zeros(n)
    th_0a[1:] = np.cumsum(dp * e_pow[:-1] + p * e_pow_a[:-1])
    return Response(angle=angle, speed=speed,
                    angle_sensitivity=np.column_stack([th_a, th_b, th_0, th_d]),
                    speed_sensitivity=np.column_stack([w_a, w_b, e_pow, w_d]),
                    angle_initial_speed_a=th_0a, speed_initial_speed_a=e_pow_a)


def project_out_initial_state(s0: np.ndarray, offset: bool, *columns: np.ndarray) -> list[np.ndarray]:
    """``columns`` less their least-squares fit on a segment's initial state: the initial-speed column
    ``s0`` (a :class:`Response`'s ``[:, 2]`` sensitivity) and, when ``offset`` (angle data), a constant.

    What every fit with the initial state as a nuisance does to a segment's residual and regressors;
    a zero ``s0`` is no direction.

    Examples
    --------
    >>> s0 = np.array([0.0, 1.0, 2.0, 3.0])
    >>> [float(x) for x in project_out_initial_state(s0, True, 2 * s0 + 5)[0]]
    [0.0, 0.0, 0.0, 0.0]
    """
    if offset:
        s0 = s0 - s0.mean()
        columns = tuple(c - c.mean() for c in columns)
    ss = float(s0 @ s0)
    if ss == 0:
        return list(columns)
    return [c - s0 * (float(s0 @ c) / ss) for c in columns]
