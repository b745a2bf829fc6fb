"""``pem-disturbance``: prediction error with a torque-disturbance model, consistent under feedback.

In a closed loop the controller feeds the measured output back into the duty, so a torque
disturbance on the shaft (a load that comes and goes, a cogging, a rough gearbox) reaches
the duty too.  An output-error fit (``oe``, ``oe-friction``) then treats the disturbance's
response as noise independent of the input, which it is not: its ``a`` and ``b`` are biased,
by tens of percent in a position loop (Ljung, *System Identification*, 2nd ed. (1999),
sec. 13.4: the direct prediction-error method is consistent under feedback only with a noise
model that can describe the true disturbance).

This estimator predicts each sample from the past with a Kalman filter on the motor with the
disturbance as a state::

    d omega/dt = -a omega + b u - c sign(omega) + bias + delta,
    delta_{k+1} = phi delta_k + eta_k,  var(eta) = Q,       (delta held over each sample)
    y_k = angle_k (or speed_k) + e_k,   var(e) = R,

where ``delta`` enters exactly where the input does.  The exact zero-order-hold step of the
family (:func:`identify.fits.friction_kernel.event_interval` for an interval in which friction
stops the shaft) moves the state; the Kalman gain, from a diffuse start through the Riccati
recursion at ``Q/R`` and held once that has settled (:data:`STEADY`), corrects it with each
innovation.  The parameters ``a, b, c, bias, phi``
and ``log(Q/R)`` minimise the sum of squared innovations (the quadratic prediction-error
criterion; only the ratio ``Q/R`` shapes the predictor).  The covariance is
:func:`identify.checks.uncertainty.robust_covariance` of the innovations (Gauss–Newton when they are
white, else Newey–West).

With ``phi = 1`` the disturbance is a random walk (its start is then the bias, which is held where
it starts), with ``Q = 0`` there is none (the fit is then an output-error fit with a filter that
settles on the measured trajectory).  Without
friction (``friction=False``) ``c = 0``.

The fit's Jacobian is analytic (:func:`filter_pass_sensitivities`): the filter's pass differentiated term by
term, through the gain's Riccati recursion, the log-determinant and friction's event steps, one pass for every
column instead of one pass per column of a finite difference, and without its error (which moved the standard
errors by up to 6e-5 of themselves on ``motorid bench selection``'s torque-loop recordings). The filter's passes
are compiled by numba (a dependency where it has wheels); without it, or with ``MOTORID_NUMBA=0``, the same
functions run in Python, slower, with the same numbers.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, Sequence

import numpy as np

from motorsim.checks import ParameterError, check_real
from motorsim.compiled import numba_jit
from motorsim.plant import first_order_coefficients
from motorsim.recording import Recording

from ..checks.uncertainty import robust_covariance
from ..checks.validation import segment_fit_percent
from ..data import Segment, as_recordings, check_excitation, check_input_delay, prepare_segments, residual_unit
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..sums import sum_squares
from .friction_kernel import _COMPLEX_STEP, _event_value, event_interval
from .start import initial_guess

__all__ = ["fit_prediction_error", "solve_prediction_error", "PredictionErrorFit", "innovations", "PARAMETERS",
           "filter_pass", "covariance_step", "initial_covariance", "gain_step", "next_covariance",
           "compiled_filter_pass", "compiled_steps", "with_compiled",
           "filter_pass_sensitivities", "compiled_sensitivity_pass",
           "DIFFUSE", "STEADY", "START_POLES", "START_LOG_RATIOS"]

#: The fitted parameters, in order (``friction`` left out when ``friction=False``).
PARAMETERS = ("a", "b", "friction", "bias", "disturbance_pole", "log_disturbance_ratio")
#: The initial state's variance, in units of what one measurement tells of it (a diffuse start).
DIFFUSE = 1e2
#: Relative change of the filter's covariance in one step below which its gain is held (the steady state).
STEADY = 1e-13


def filter_pass(u: np.ndarray, y: np.ndarray, speed_kind: bool, e: float, p: float, q: float, a: float,
                h: float, b: float, c: float, bias: float, phi: float, ratio: float, w0: float,
                eps: np.ndarray) -> float:
    """Innovations of the Kalman predictor over one uniform segment, each over its standard deviation
    (in units of the measurement's), into ``eps``; returns the sum of the logarithms of their variances
    (module docstring).

    The filter starts from a diffuse state (the first measurement, the speed ``w0`` and no disturbance,
    each with a variance :data:`DIFFUSE` times what one sample can tell): its gain settles as the data
    pin the state, so a segment's initial state costs no parameter.  The variances are in units of the
    measurement's (``R = 1``); ``ratio`` is ``Q/R``.

    The covariance's recursion does not depend on the data: once a step changes none of its six numbers
    by more than :data:`STEADY` of their size, the gain is the steady one and the rest of the pass
    skips the recursion (the innovations then differ from the full recursion's by about ``STEADY``).
    """
    n = len(u)
    th = y[0] if not speed_kind else 0.0
    w = w0 if not speed_kind else y[0]
    d = 0.0
    # the covariance of (angle, speed, disturbance), symmetric: six numbers
    p00, p01, p02, p11, p12, p22 = initial_covariance(h, speed_kind)
    log_det = 0.0
    settled = steady = False
    s_var = k0 = k1 = k2 = scale = 1.0
    g0 = g1 = g2 = 0.0
    for k in range(n):
        if not steady:
            s_var, g0, g1, g2, k0, k1, k2, scale = gain_step(p00, p01, p02, p11, p12, speed_kind)
            # once settled, this gain and this variance hold for the rest of the segment
            log_det += (n - k if settled else 1) * math.log(s_var)
            steady = settled
        ek = y[k] - (w if speed_kind else th)
        eps[k] = ek * scale
        th += k0 * ek
        w += k1 * ek
        d += k2 * ek
        force = b * u[k] + bias + d
        _, _, w_next, d_angle = _friction_mode(w, force, c, a, h, e, p, q)
        th += d_angle
        w = w_next
        d = phi * d
        if steady:
            continue
        p00, p01, p02, p11, p12, p22, settled = next_covariance(p00, p01, p02, p11, p12, p22, g0, g1, g2, k0, k1, k2,
                                                                e, p, q, phi, ratio, speed_kind)
    return log_det


def initial_covariance(h: float, speed_kind: bool) -> tuple[float, float, float, float, float, float]:
    """The filter's covariance of (angle, speed, disturbance) at a segment's start (six numbers of the symmetric
    ``P``, in units of the measurement's variance): the first measurement known to one sample's noise, the speed
    and the disturbance diffuse (:data:`DIFFUSE` times what one sample can tell of them)."""
    p00 = 1.0 if not speed_kind else 0.0
    p11 = DIFFUSE / (h * h) if not speed_kind else 1.0
    return p00, 0.0, 0.0, p11, 0.0, DIFFUSE / (h * h) / (h * h)


def gain_step(p00: float, p01: float, p02: float, p11: float, p12: float,
              speed_kind: bool) -> tuple[float, float, float, float, float, float, float, float]:
    """The Kalman gain of one measurement (the angle, or the speed): the innovation's variance ``s = H P H^T + 1``,
    ``g = P H^T``, the gain ``k = g / s`` and ``1 / sqrt(s)``, which scales the innovation; every pass's gain."""
    s_var = (p11 if speed_kind else p00) + 1.0
    g0, g1, g2 = (0.0, p11, p12) if speed_kind else (p00, p01, p02)
    return s_var, g0, g1, g2, g0 / s_var, g1 / s_var, g2 / s_var, 1.0 / math.sqrt(s_var)


def next_covariance(p00: float, p01: float, p02: float, p11: float, p12: float, p22: float, g0: float, g1: float,
                    g2: float, k0: float, k1: float, k2: float, e: float, p: float, q: float, phi: float, ratio: float,
                    speed_kind: bool) -> tuple[float, float, float, float, float, float, bool]:
    """The covariance one sample on (:func:`covariance_step`) and whether it has settled (:func:`_settled`: the
    gain is then held for the rest of the segment)."""
    n00, n01, n02, n11, n12, n22 = covariance_step(p00, p01, p02, p11, p12, p22, g0, g1, g2, k0, k1, k2, e, p, q,
                                                   phi, ratio, speed_kind)
    return n00, n01, n02, n11, n12, n22, _settled(n00, n01, n02, n11, n12, n22, p00, p01, p02, p11, p12, p22)


def covariance_step(p00: float, p01: float, p02: float, p11: float, p12: float, p22: float, g0: float, g1: float,
                    g2: float, k0: float, k1: float, k2: float, e: float, p: float, q: float, phi: float, ratio: float,
                    speed_kind: bool) -> tuple[float, float, float, float, float, float]:
    """One step of the filter's covariance (the six numbers of the symmetric ``P``): the measurement update
    with the gain ``k = g / s``, then the time update ``F P F^T + Q`` of the linear part,
    ``F = [[1, p, q], [0, e, p], [0, 0, phi]]``, ``Q`` the disturbance's ``ratio`` (the angle's row left as
    it is when the speed is measured)."""
    m00 = p00 - g0 * k0
    m01 = p01 - g0 * k1
    m02 = p02 - g0 * k2
    m11 = p11 - g1 * k1
    m12 = p12 - g1 * k2
    m22 = p22 - g2 * k2
    r00 = m00 + p * m01 + q * m02
    r01 = m01 + p * m11 + q * m12
    r02 = m02 + p * m12 + q * m22
    r11 = e * m11 + p * m12
    r12 = e * m12 + p * m22
    r22 = phi * m22
    n00, n01, n02 = p00, p01, p02
    if not speed_kind:
        n00 = r00 + p * r01 + q * r02
        n01 = e * r01 + p * r02
        n02 = phi * r02
    return n00, n01, n02, e * r11 + p * r12, phi * r12, phi * r22 + ratio


def _coefficient_derivatives(a: float, h: float, e: float, p: float, q: float) -> tuple[float, float, float]:
    """``de/da, dp/da, dq/da`` of :func:`motorsim.plant.first_order_coefficients` (a power series for small
    ``a h``, as :mod:`identify.fits.friction_response` has them)."""
    x = a * h
    if abs(x) < 1e-5:
        return -h * e, h * h * (-0.5 + x / 3.0), h * h * h * (-1.0 / 6.0 + x / 12.0)
    dp = (h * e - p) / a
    return -h * e, dp, (-dp - q) / a


def _covariance_derivative(dp00: float, dp01: float, dp02: float, dp11: float, dp12: float, dp22: float,
                           p00: float, p01: float, p02: float, p11: float, p12: float, p22: float,
                           g0: float, g1: float, g2: float, k0: float, k1: float, k2: float,
                           dg0: float, dg1: float, dg2: float, dk0: float, dk1: float, dk2: float,
                           e: float, p: float, q: float, phi: float, de: float, dpp: float, dq: float,
                           dphi: float, dratio: float, speed_kind: bool) -> tuple[float, float, float, float, float,
                                                                                   float]:
    """The derivative of :func:`covariance_step` along one parameter: ``dP`` (six numbers) from the step's
    inputs and their derivatives (``dpp`` is ``dp/d``, the step's ``p``; ``de``, ``dq``, ``dphi``, ``dratio``
    those of the others), term by term."""
    m01 = p01 - g0 * k1
    m02 = p02 - g0 * k2
    m11 = p11 - g1 * k1
    m12 = p12 - g1 * k2
    m22 = p22 - g2 * k2
    d00 = dp00 - dg0 * k0 - g0 * dk0
    d01 = dp01 - dg0 * k1 - g0 * dk1
    d02 = dp02 - dg0 * k2 - g0 * dk2
    d11 = dp11 - dg1 * k1 - g1 * dk1
    d12 = dp12 - dg1 * k2 - g1 * dk2
    d22 = dp22 - dg2 * k2 - g2 * dk2
    r01 = m01 + p * m11 + q * m12
    r02 = m02 + p * m12 + q * m22
    r11 = e * m11 + p * m12
    r12 = e * m12 + p * m22
    r22 = phi * m22
    s00 = d00 + dpp * m01 + p * d01 + dq * m02 + q * d02
    s01 = d01 + dpp * m11 + p * d11 + dq * m12 + q * d12
    s02 = d02 + dpp * m12 + p * d12 + dq * m22 + q * d22
    s11 = de * m11 + e * d11 + dpp * m12 + p * d12
    s12 = de * m12 + e * d12 + dpp * m22 + p * d22
    s22 = dphi * m22 + phi * d22
    n00, n01, n02 = dp00, dp01, dp02
    if not speed_kind:
        n00 = s00 + dpp * r01 + p * s01 + dq * r02 + q * s02
        n01 = de * r01 + e * s01 + dpp * r02 + p * s02
        n02 = dphi * r02 + phi * s02
    return (n00, n01, n02, de * r11 + e * s11 + dpp * r12 + p * s12, dphi * r12 + phi * s12,
            dphi * r22 + phi * s22 + dratio)


def _covariance_derivatives(dcov: np.ndarray, dk: np.ndarray, p00: float, p01: float, p02: float, p11: float,
                            p12: float, p22: float, g0: float, g1: float, g2: float, k0: float, k1: float, k2: float,
                            e: float, p: float, q: float, phi: float, de: float, dpp: float, dq: float,
                            speed_kind: bool) -> None:
    """:func:`covariance_step`'s derivatives along ``a``, ``phi`` and ``ratio`` (the rows of ``dcov``), in place
    (``dk``: the gain's derivatives, a column per parameter)."""
    for i in range(3):
        j = 0 if i == 0 else 3 + i
        dg0, dg1, dg2 = (0.0, dcov[i, 3], dcov[i, 4]) if speed_kind else (dcov[i, 0], dcov[i, 1], dcov[i, 2])
        along_a = 1.0 if i == 0 else 0.0            # e, p, q move with a alone; phi and ratio are their own
        along_phi = 1.0 if i == 1 else 0.0
        along_ratio = 1.0 if i == 2 else 0.0
        dcov[i, 0], dcov[i, 1], dcov[i, 2], dcov[i, 3], dcov[i, 4], dcov[i, 5] = _covariance_derivative(
            dcov[i, 0], dcov[i, 1], dcov[i, 2], dcov[i, 3], dcov[i, 4], dcov[i, 5],
            p00, p01, p02, p11, p12, p22, g0, g1, g2, k0, k1, k2, dg0, dg1, dg2, dk[0, j], dk[1, j], dk[2, j],
            e, p, q, phi, de * along_a, dpp * along_a, dq * along_a, along_phi, along_ratio, speed_kind)


def _gain_derivatives(dcov: np.ndarray, dk: np.ndarray, dscale: np.ndarray, dlog_det: np.ndarray, k0: float,
                      k1: float, k2: float, s_var: float, scale: float, weight: float, speed_kind: bool) -> None:
    """The gain's, the scale's (``1/sqrt(s_var)``) and the log-determinant's derivatives along ``a``, ``phi`` and
    ``ratio`` from the covariance's (``dcov``, a row each), in place (``weight``: the log-determinant's count of
    this variance)."""
    for i in range(3):
        j = 0 if i == 0 else 3 + i              # a, phi, ratio
        dg0, dg1, dg2 = (0.0, dcov[i, 3], dcov[i, 4]) if speed_kind else (dcov[i, 0], dcov[i, 1], dcov[i, 2])
        ds = dcov[i, 3] if speed_kind else dcov[i, 0]
        dk[0, j] = (dg0 - k0 * ds) / s_var
        dk[1, j] = (dg1 - k1 * ds) / s_var
        dk[2, j] = (dg2 - k2 * ds) / s_var
        dscale[j] = -0.5 * scale * ds / s_var
        dlog_det[j] += weight * ds / s_var


def _moving_step_sensitivities(sw: np.ndarray, sth: np.ndarray, dforce: np.ndarray, w: float, g: float, s: float,
                               e: float, p: float, q: float, de: float, dpp: float, dq: float) -> None:
    """The speed's and the angle's derivatives carried through a moving interval (``g`` the force less friction
    of sign ``s``), in place."""
    for j in range(6):
        dg = dforce[j] - (s if j == 2 else 0.0)
        sth[j] += p * sw[j] + q * dg
        sw[j] = e * sw[j] + p * dg
    sth[0] += dpp * w + dq * g
    sw[0] += de * w + dpp * g


def _event_step_sensitivities(sw: np.ndarray, sth: np.ndarray, dforce: np.ndarray, dw: np.ndarray, dth: np.ndarray,
                              w: float, force: float, c: float, a: float, h: float, s: float) -> None:
    """The speed's and the angle's derivatives ``sw``, ``sth`` carried through an event interval (the speed reaches
    zero inside it), in place: the event step's partials with respect to ``(w, force, c, a)`` by complex step
    (into ``dw``, ``dth``), ``dforce`` the force's derivatives."""
    stick = abs(force) <= c
    for i in range(4):
        arg = w if i == 0 else force if i == 1 else c if i == 2 else a
        step = _COMPLEX_STEP * max(abs(arg), 1.0)
        zw = complex(w, step) if i == 0 else complex(w, 0.0)
        zf = complex(force, step) if i == 1 else complex(force, 0.0)
        zc = complex(c, step) if i == 2 else complex(c, 0.0)
        za = complex(a, step) if i == 3 else complex(a, 0.0)
        cw, cth = _event_value(zw, zf, zc, za, h, s, stick)
        dw[i] = cw.imag / step
        dth[i] = cth.imag / step
    for j in range(6):
        f_w = dw[1] * dforce[j] + (dw[3] if j == 0 else dw[2] if j == 2 else 0.0)
        f_th = dth[1] * dforce[j] + (dth[3] if j == 0 else dth[2] if j == 2 else 0.0)
        sth[j] += dth[0] * sw[j] + f_th
        sw[j] = dw[0] * sw[j] + f_w


def filter_pass_sensitivities(u: np.ndarray, y: np.ndarray, speed_kind: bool, e: float, p: float, q: float, a: float,
                              h: float, b: float, c: float, bias: float, phi: float, ratio: float, w0: float,
                              eps: np.ndarray, jac: np.ndarray, dlog_det: np.ndarray) -> float:
    """:func:`filter_pass` with the derivatives of its innovations (each over its standard deviation) and of its
    log-determinant with respect to ``(a, b, c, bias, phi, ratio)``, into ``jac`` (shape ``(6, len(u))``) and
    ``dlog_det`` (6): the same recursion differentiated term by term (the state's, the covariance's and the
    gain's derivatives carried along; the gain's held with the gain once the covariance has settled; an event
    interval's step differentiated through the event time by complex step, as the friction response's).  The
    innovations and the log-determinant are :func:`filter_pass`'s, the same operations in the same order."""
    n = len(u)
    de, dpp, dq = _coefficient_derivatives(a, h, e, p, q)
    th = y[0] if not speed_kind else 0.0
    w = w0 if not speed_kind else y[0]
    d = 0.0
    p00, p01, p02, p11, p12, p22 = initial_covariance(h, speed_kind)
    # the derivatives of the covariance along a, phi and ratio (rows), six numbers each; of the state along all six
    dcov = np.zeros((3, 6))
    sth = np.zeros(6)
    sw = np.zeros(6)
    sd = np.zeros(6)
    dk = np.zeros((3, 6))           # rows: the gain's three numbers; columns: the six parameters
    dscale = np.zeros(6)
    dforce = np.zeros(6)
    dw = np.zeros(4)
    dth = np.zeros(4)
    for j in range(6):
        dlog_det[j] = 0.0
    log_det = 0.0
    settled = steady = False
    s_var = k0 = k1 = k2 = scale = 1.0
    g0 = g1 = g2 = 0.0
    for k in range(n):
        if not steady:
            s_var, g0, g1, g2, k0, k1, k2, scale = gain_step(p00, p01, p02, p11, p12, speed_kind)
            weight = (n - k if settled else 1)
            log_det += weight * math.log(s_var)
            _gain_derivatives(dcov, dk, dscale, dlog_det, k0, k1, k2, s_var, scale, weight, speed_kind)
            steady = settled
        ek = y[k] - (w if speed_kind else th)
        eps[k] = ek * scale
        _innovation_sensitivities(jac, k, sth, sw, sd, dk, dscale, ek, scale, k0, k1, k2, speed_kind)
        th += k0 * ek
        w += k1 * ek
        d += k2 * ek
        force = b * u[k] + bias + d
        for j in range(6):
            dforce[j] = sd[j]
        dforce[1] += u[k]
        dforce[3] += 1.0
        s, event, w_next, d_angle = _friction_mode(w, force, c, a, h, e, p, q)
        if c > 0.0 and s == 0.0:                        # stuck: the speed is 0 whatever the parameters
            for j in range(6):
                sw[j] = 0.0
        elif event:
            _event_step_sensitivities(sw, sth, dforce, dw, dth, w, force, c, a, h, s)
        else:
            _moving_step_sensitivities(sw, sth, dforce, w, force - s * c, s, e, p, q, de, dpp, dq)
        th += d_angle
        w = w_next
        for j in range(6):
            sd[j] = phi * sd[j]
        sd[4] += d
        d = phi * d
        if steady:
            continue
        # the derivatives first: they are taken at this step's covariance
        _covariance_derivatives(dcov, dk, p00, p01, p02, p11, p12, p22, g0, g1, g2, k0, k1, k2, e, p, q, phi, de, dpp,
                                dq, speed_kind)
        p00, p01, p02, p11, p12, p22, settled = next_covariance(p00, p01, p02, p11, p12, p22, g0, g1, g2, k0, k1, k2,
                                                                e, p, q, phi, ratio, speed_kind)
    return log_det


def _innovation_sensitivities(jac: np.ndarray, k: int, sth: np.ndarray, sw: np.ndarray, sd: np.ndarray,
                              dk: np.ndarray, dscale: np.ndarray, ek: float, scale: float, k0: float, k1: float,
                              k2: float, speed_kind: bool) -> None:
    """:func:`filter_pass_sensitivities`' innovation ``k``: its derivatives into ``jac[:, k]``, and the state's
    derivatives corrected by it (in place)."""
    for j in range(6):
        dek = -(sw[j] if speed_kind else sth[j])
        jac[j, k] = dek * scale + ek * dscale[j]
        sth[j] += dk[0, j] * ek + k0 * dek
        sw[j] += dk[1, j] * ek + k1 * dek
        sd[j] += dk[2, j] * ek + k2 * dek


def _friction_mode(w: float, force: float, c: float, a: float, h: float, e: float, p: float,
                   q: float) -> tuple[float, bool, float, float]:
    """One interval's step of :func:`filter_pass` and :func:`filter_pass_sensitivities`: the sign of the friction
    (0: stuck), whether it is an event interval, the speed at its end and the angle it adds."""
    s = 0.0
    event = False
    if c > 0.0:
        if w == 0.0:
            s = (1.0 if force > 0 else -1.0) if abs(force) > c else 0.0
        else:
            s = 1.0 if w > 0 else -1.0
        if s == 0.0:
            d_angle, w_next = 0.0, 0.0
        else:
            end = e * w + p * (force - s * c)
            if w != 0.0 and s * end < 0.0:
                w_next, d_angle = event_interval(w, force, c, a, h, s, c)
                event = True
            else:
                w_next, d_angle = end, p * w + q * (force - s * c)
    else:
        s = 1.0 if w > 0 else -1.0                  # only c's column uses it (friction left out: not fitted)
        w_next, d_angle = e * w + p * force, p * w + q * force
    return s, event, w_next, d_angle


def _settled(n00: float, n01: float, n02: float, n11: float, n12: float, n22: float, p00: float, p01: float,
             p02: float, p11: float, p12: float, p22: float) -> bool:
    """Whether one step changed none of the covariance's six numbers by more than :data:`STEADY` of their size."""
    return (abs(n00 - p00) <= STEADY * abs(n00) and abs(n01 - p01) <= STEADY * abs(n01)
            and abs(n02 - p02) <= STEADY * abs(n02) and abs(n11 - p11) <= STEADY * abs(n11)
            and abs(n12 - p12) <= STEADY * abs(n12) and abs(n22 - p22) <= STEADY * abs(n22))


def with_compiled(function: Callable[..., Any], jit: Callable[..., Any], **names: Any) -> Callable[..., Any]:
    """``function`` compiled by ``jit``, the globals ``names`` it calls replaced by theirs (compiled: numba calls
    only compiled functions)."""
    import types
    return jit(types.FunctionType(function.__code__, dict(function.__globals__, **names), function.__name__))


@functools.cache
def compiled_steps() -> dict[str, Callable[..., Any]]:
    """The steps every filter pass shares (its start, gain, covariance and friction steps) compiled by numba, by the
    name the passes call them; empty without numba or with ``MOTORID_NUMBA=0``."""
    jit = numba_jit()
    if jit is None:
        return {}
    return dict(initial_covariance=jit(initial_covariance), gain_step=jit(gain_step),
                next_covariance=with_compiled(next_covariance, jit, covariance_step=jit(covariance_step),
                                              _settled=jit(_settled)),
                _friction_mode=with_compiled(_friction_mode, jit, event_interval=jit(event_interval)))


@functools.cache
def compiled_filter_pass() -> Callable[..., float] | None:
    """:func:`filter_pass` compiled by numba (cached on disk); None without numba or with ``MOTORID_NUMBA=0``."""
    jit = numba_jit()
    if jit is None:
        return None
    return with_compiled(filter_pass, jit, **compiled_steps())


@functools.cache
def compiled_sensitivity_pass() -> Callable[..., float] | None:
    """:func:`filter_pass_sensitivities` compiled by numba (cached on disk); None without numba or with
    ``MOTORID_NUMBA=0``."""
    jit = numba_jit()
    if jit is None:
        return None
    return with_compiled(
        filter_pass_sensitivities, jit, **compiled_steps(),
        _covariance_derivatives=with_compiled(_covariance_derivatives, jit,
                                              _covariance_derivative=jit(_covariance_derivative)),
        _gain_derivatives=jit(_gain_derivatives), _moving_step_sensitivities=jit(_moving_step_sensitivities),
        _coefficient_derivatives=jit(_coefficient_derivatives),
        _event_step_sensitivities=with_compiled(_event_step_sensitivities, jit, _event_value=jit(_event_value)),
        _innovation_sensitivities=jit(_innovation_sensitivities))


#: Start values of the disturbance's pole per sample and of ``log(Q/R)`` tried before the fit (the
#: criterion has a local minimum at a white disturbance that a start near it falls into).
START_POLES = (0.0, 0.9, 0.99, 0.999)
START_LOG_RATIOS = tuple(float(v) for v in range(-10, 45, 5))
#: The largest log-ratio (and log-scale) the innovations take: a Levenberg-Marquardt step far beyond any start
#: (a jittered clock's misfit) would overflow a float's exponent; held there, its criterion is simply worse.
LOG_RATIO_LIMIT = 700.0


class _Problem:
    """The pooled innovations of every segment at a parameter vector: ``a, b, [c], bias, [phi], log(Q/R)``
    (``c`` with friction, ``phi`` unless the disturbance's pole is held)."""

    def __init__(self, segments: Sequence[Segment], friction: bool, h: float, pole: float | None = None,
                 disturbance: bool = True):
        self.segments = list(segments)
        self.friction = friction
        self.disturbance = disturbance
        self.pole = pole if disturbance else 0.0
        self.h = h
        self.n_rows = sum(len(s.time) for s in self.segments)
        self.kernel = compiled_filter_pass() or filter_pass
        self.w0 = [s.initial_speed_guess() for s in self.segments]

    @property
    def n_plant(self) -> int:
        """Parameters of the motor: ``a, b, [c], bias``."""
        return 4 if self.friction else 3

    @property
    def pole_index(self) -> int | None:
        return None if self.pole is not None else self.n_plant

    def unpack(self, x: np.ndarray) -> tuple[float, float, float, float, float, float]:
        """``a, b, c, bias, phi, log(Q/R)``."""
        v = [float(value) for value in x]
        c = v[2] if self.friction else 0.0
        bias = v[self.n_plant - 1]
        phi = self.pole if self.pole is not None else v[self.n_plant]
        return v[0], v[1], c, bias, phi, v[-1] if self.disturbance else -math.inf

    def pack(self, a: float, b: float, c: float, bias: float, phi: float, lr: float) -> np.ndarray:
        noise = ([phi] if self.pole is None else []) + [lr] if self.disturbance else []
        return np.array([a, b] + ([c] if self.friction else []) + [bias] + noise, dtype=float)

    def innovations(self, x: np.ndarray) -> np.ndarray:
        """Each innovation over its standard deviation, all scaled by the geometric mean of those deviations
        (so that their sum of squares is the Gaussian likelihood's criterion, with the scale of the noise
        concentrated out)."""
        a, b, c, bias, phi, lr = self.unpack(x)
        out = np.empty(self.n_rows)
        row = 0
        h = self.h
        e, p, q = first_order_coefficients(a, h)
        log_det = 0.0
        for seg, w0 in zip(self.segments, self.w0):
            n = len(seg.time)
            log_det += self.kernel(seg.drive, seg.output, seg.kind == "speed", e, p, q, a, h, b, c, bias, phi,
                                   math.exp(min(lr, LOG_RATIO_LIMIT)), float(w0), out[row:row + n])
            row += n
        return out * math.exp(min(0.5 * log_det / max(self.n_rows, 1), LOG_RATIO_LIMIT))

    def jacobian(self, x: np.ndarray, factors: np.ndarray | None = None,
                 keep: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`innovations` at ``x`` and their derivatives with respect to ``x``'s entries, analytic
        (:func:`filter_pass_sensitivities`): shape ``(n_rows, len(x))``, in Fortran order (what MINPACK takes).
        ``keep`` (default all) chooses ``x``'s entries and ``factors`` multiplies each kept column (a change of
        coordinates' ``dx/dz``)."""
        a, b, c, bias, phi, lr = self.unpack(x)
        h = self.h
        kernel = compiled_sensitivity_pass() or filter_pass_sensitivities
        out = np.empty(self.n_rows)
        full = np.empty((6, self.n_rows))
        dlog = np.zeros(6)
        part = np.empty(6)
        row = 0
        e, p, q = first_order_coefficients(a, h)
        ratio = math.exp(min(lr, LOG_RATIO_LIMIT))
        log_det = 0.0
        for seg, w0 in zip(self.segments, self.w0):
            n = len(seg.time)
            log_det += kernel(seg.drive, seg.output, seg.kind == "speed", e, p, q, a, h, b, c, bias, phi, ratio,
                              float(w0), out[row:row + n], full[:, row:row + n], part)
            dlog += part
            row += n
        half = 0.5 / max(self.n_rows, 1)
        level = half * log_det
        scale = math.exp(min(level, LOG_RATIO_LIMIT))
        # x's entries among (a, b, c, bias, phi, ratio); the last is log(ratio): d ratio / d log(ratio) = ratio
        columns = [0, 1] + ([2] if self.friction else []) + [3]
        chain = [1.0] * len(columns)
        if self.disturbance:
            if self.pole is None:
                columns.append(4)
                chain.append(1.0)
            columns.append(5)
            chain.append(ratio if lr < LOG_RATIO_LIMIT else 0.0)
        keep = range(len(columns)) if keep is None else keep
        jac = np.empty((len(keep), self.n_rows))
        for i, m in enumerate(keep):       # d r / d theta = (d eps + eps d level) * scale
            j = columns[m]
            factor = scale * chain[m] * (1.0 if factors is None else float(factors[i]))
            np.multiply(full[j], factor, out=jac[i])
            if level < LOG_RATIO_LIMIT:
                jac[i] += (factor * half * dlog[j]) * out
        out *= scale
        return out, jac.T


@dataclasses.dataclass
class PredictionErrorFit:
    """A solved :class:`_Problem`: the parameters, the scaled innovations, their Jacobian and the criterion."""

    problem: _Problem
    x: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray

    @property
    def cost(self) -> float:
        """The sum of the squared scaled innovations."""
        return sum_squares(self.residuals)

    def values(self) -> dict[str, float]:
        a, b, c, bias, phi, lr = self.problem.unpack(self.x)
        return {"a": a, "b": b, "friction": c, "bias": bias, "disturbance_pole": phi, "log_disturbance_ratio": lr}


def solve_prediction_error(recordings: Sequence[Recording], segments: Sequence[Segment], *, friction: bool,
                           disturbance_pole: float | None = None, disturbance: bool = True,
                           start: tuple[float, float, float, float] | None = None,
                           noise_start: tuple[float, float] | None = None) -> PredictionErrorFit:
    """Fit the model of the module docstring to ``segments`` (the recordings cut at gaps, the duty delayed).

    Parameters
    ----------
    recordings : sequence of Recording
        The runs the segments come from (one sample period).
    segments : sequence of Segment
    friction : bool
        Fit Coulomb friction (else ``c = 0``).
    disturbance_pole : float, optional
        Hold the disturbance's pole per sample at this value (1: a random walk) instead of fitting it.
    disturbance : bool
        False: no disturbance at all (``Q = 0``; the predictor is then the model simulated from a state the
        filter settles, an output-error fit), to test whether the data show one.
    start : (a, b, c, bias), optional
        Start values of the motor's parameters (default: the regression start of
        :func:`identify.fits.start.initial_guess`).
    noise_start : (phi, log(Q/R)), optional
        Start values of the disturbance's (a neighbouring fit's); default: the best of a grid
        (:data:`START_POLES` x :data:`START_LOG_RATIOS`).
    """
    h = recordings[0].sample_period
    problem = _Problem(segments, friction, h, disturbance_pole, disturbance)
    if start is None:
        a0, b0 = initial_guess(recordings, segments)
        a0 = float(min(max(a0, 1e-3 / h), 0.5 / h)) if math.isfinite(a0) and a0 > 0 else 0.05 / h
        drive = np.concatenate([s.drive for s in segments])
        c0 = abs(b0) * float(np.percentile(np.abs(drive), 10)) if friction else 0.0
        start = (a0, b0, c0, 0.0)
    a0, b0, c0, bias0 = start
    if friction and not c0 > 0:
        c0 = 1e-3 * abs(b0) * float(np.max(np.abs(np.concatenate([s.drive for s in segments]))))
    best, best_cost = None, math.inf
    poles = START_POLES if disturbance_pole is None else (disturbance_pole,)
    ratios = START_LOG_RATIOS
    if noise_start is not None:
        poles = (noise_start[0],) if disturbance_pole is None else poles
        ratios = (noise_start[1],)
    for phi in poles if disturbance else (0.0,):
        for lr in ratios if disturbance else (0.0,):
            x = problem.pack(a0, b0, c0, bias0, phi, lr)
            r = problem.innovations(x)
            cost = sum_squares(r)
            if cost < best_cost:
                best, best_cost = x, cost
    assert best is not None
    x, r, jac = _solve(problem, best)
    return PredictionErrorFit(problem, x, r, jac)


def innovations(estimate: Estimate, recording: Recording) -> np.ndarray:
    """The scaled one-step prediction errors of a ``pem-disturbance`` estimate on ``recording``.

    Parameters
    ----------
    estimate : Estimate
        A fit by this method (its ``extra`` holds ``disturbance_pole`` and ``log_disturbance_ratio``).
    recording : Recording
        A run at the estimate's sample period.
    """
    segs = prepare_segments([recording], estimate.input_delay)
    values = estimate.values()
    friction = float(values.get("friction", 0.0)) > 0
    problem = _Problem(segs, friction, recording.sample_period)
    return problem.innovations(problem.pack(estimate.a, estimate.b, float(values.get("friction", 0.0)),
                                            float(values.get("bias", 0.0)), float(values["disturbance_pole"]),
                                            float(values["log_disturbance_ratio"])))


def fit_prediction_error(recordings: Recording | Sequence[Recording], *, input_delay: int = 0,
                         friction: bool = True, disturbance_pole: float | None = None) -> Estimate:
    """Estimate ``a``, ``b`` (and Coulomb friction, a bias) with a torque-disturbance model (module docstring).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Runs at one sample period, open or closed loop (pooled over gap-free segments).
    input_delay : int
        Input delay in samples, >= 0.
    friction : bool
        Fit Coulomb friction ``c`` (else ``c = 0``).
    disturbance_pole : float, optional
        Hold the disturbance's pole per sample (in [0, 1]; 1 makes it a random walk) instead of fitting it.

    Returns
    -------
    Estimate
        ``method = "pem-disturbance"``, ``structure`` ``"friction"`` or ``"bias"``; ``extra`` holds the
        disturbance's pole per sample (``disturbance_pole``) and ``log(Q/R)`` (``log_disturbance_ratio``);
        ``residual_rms`` is the scaled innovations'; ``fit_percent`` the model's simulated speed against
        the measured one.  With the pole at 1 the bias is the disturbance's
        starting level, not a parameter: it stays at its start (0) and its variance is ``inf``.

    Raises
    ------
    NotIdentifiableError
        When the recording is too short or the input does not excite the motor.

    Examples
    --------
    >>> import numpy as np
    >>> from motorsim import Encoder, Experiment, Motor, Multisine, SimRig
    >>> rig = SimRig(Motor(25.0, 3.0), Encoder(1000), rng=np.random.default_rng(0))
    >>> rec = rig.run(Experiment(Multisine((3.0, 17.0, 70.0), (80, 60, 40), (0, 1, 2)), 0.002, 4.0))
    >>> est = fit_prediction_error(rec, friction=False)
    >>> abs(est.a / 25 - 1) < 0.01, abs(est.b / 3 - 1) < 0.01
    (True, True)
    """
    recs = as_recordings(recordings)
    delay = check_input_delay(input_delay)
    if delay == "auto":
        raise ParameterError("input_delay must be an integer number of samples for pem-disturbance, got 'auto'")
    if not isinstance(friction, (bool, np.bool_)):
        raise ParameterError(f"friction must be True or False, got {friction!r}")
    if disturbance_pole is not None:
        disturbance_pole = check_real("disturbance_pole", disturbance_pole)
        if not 0.0 <= disturbance_pole <= 1.0:
            raise ParameterError(f"disturbance_pole must be in [0, 1], got {disturbance_pole!r}")
    segs = prepare_segments(recs, int(delay))
    if not segs:
        raise NotIdentifiableError("recording is too short for pem-disturbance: no gap-free stretch long enough")
    check_excitation(recs)
    return estimate_from(recs, solve_prediction_error(recs, segs, friction=bool(friction),
                                                      disturbance_pole=disturbance_pole), int(delay))


def estimate_from(recs: Sequence[Recording], fit: PredictionErrorFit, input_delay: int) -> Estimate:
    """The :class:`Estimate` of a solved fit."""
    problem = fit.problem
    names = ("a", "b", "friction", "bias") if problem.friction else ("a", "b", "bias")
    cov, cov_method = _covariance(fit)
    values = fit.values()
    if not problem.friction:
        values.pop("friction")
    r = fit.residuals
    est = Estimate(method="pem-disturbance", a=values.pop("a"), b=values.pop("b"), n_samples=problem.n_rows,
                   sample_period=problem.h, residual_rms=float(np.sqrt(np.mean(r ** 2))), fit_percent=math.nan,
                   covariance=cov, param_names=names, covariance_method=cov_method, extra=values,
                   residual_unit=residual_unit(problem.segments), input_unit=recs[0].input_unit,
                   input_limit=recs[0].input_limit, structure="friction" if problem.friction else "bias",
                   input_delay=input_delay)
    # the fit of the model simulated on the data, as every estimator reports it (the one-step predictions
    # would fit far better: the filter follows the disturbance)
    shape = est.model_structure()
    models = [shape.segment_output(est.values(), seg) for seg in problem.segments]
    return dataclasses.replace(est, fit_percent=segment_fit_percent(problem.segments, models))


def _covariance(fit: PredictionErrorFit) -> tuple[np.ndarray, str]:
    """:func:`robust_covariance` of the motor's parameters, the noise parameters at a bound held fixed.

    A pole at 1 makes the disturbance a random walk, whose mean (the bias) is then no parameter: its
    variance is ``inf``.
    """
    problem, x, jac = fit.problem, fit.x, fit.jacobian
    keep = problem.n_plant
    _, _, _, _, phi, _ = problem.unpack(x)
    use = [j for j in range(len(x)) if np.all(np.isfinite(jac[:, j])) and np.any(jac[:, j] != 0)]
    if phi >= 1.0 - 1e-6:
        use = [j for j in use if j != keep - 1]
    if problem.pole_index is not None and not 1e-6 < phi < 1.0 - 1e-6:
        use = [j for j in use if j != problem.pole_index]
    lead = [j for j in use if j < keep]
    r = fit.residuals
    s2 = sum_squares(r) / max(len(r) - len(use), 1)
    cov_used, method = robust_covariance(jac[:, use], r, s2, len(lead))
    cov = np.diag(np.full(keep, math.inf))
    for i, ji in enumerate(lead):
        for m, jm in enumerate(lead):
            cov[ji, jm] = cov_used[i, m]
    return cov, method


def _solve(problem: _Problem, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimise the criterion from ``x0``: the parameters, the residuals and their Jacobian.

    Levenberg–Marquardt (MINPACK, through :func:`scipy.optimize.least_squares`) in coordinates that keep
    ``a > 0``, ``c > 0`` and ``0 < phi < 1`` without bounds (logarithms and a logistic), with the analytic
    Jacobian of :meth:`_Problem.jacobian` (:func:`filter_pass_sensitivities`) carried to those coordinates and back
    by the chain rule.  With the pole held at 1
    the bias is held at its start: it is then the disturbance's starting level, which the filter's diffuse
    start already takes, so the criterion hardly depends on it and its step would only stall the others'
    (its Jacobian column is returned as zeros).
    """
    from scipy.optimize import least_squares  # imported when used: slow to import
    positive = [0] + ([2] if problem.friction else [])
    pole = problem.pole_index
    held = [problem.n_plant - 1] if problem.pole is not None and problem.pole >= 1.0 else []
    free = np.array([j for j in range(len(x0)) if j not in held], dtype=int)

    def to_x(z_free: np.ndarray) -> np.ndarray:
        z = np.array(z0, dtype=float)
        z[free] = z_free
        x = np.array(z, dtype=float)
        x[positive] = np.exp(np.clip(z[positive], -700.0, 700.0))
        if pole is not None:
            x[pole] = 1.0 / (1.0 + math.exp(-min(max(float(z[pole]), -700.0), 700.0)))
        return x

    def residuals(z: np.ndarray) -> np.ndarray:
        x = to_x(z)
        if not (x[0] * problem.h < 2.0 and (not problem.disturbance or abs(x[-1]) < 80.0)):
            return np.full(problem.n_rows, 1e6)
        return problem.innovations(x)

    def dx_dz(x: np.ndarray) -> np.ndarray:
        scale = np.ones(len(x))
        scale[positive] = x[positive]
        if pole is not None:
            scale[pole] = x[pole] * (1.0 - x[pole])
        return scale

    def jacobian(z: np.ndarray) -> np.ndarray:
        x = to_x(z)
        if not (x[0] * problem.h < 2.0 and (not problem.disturbance or abs(x[-1]) < 80.0)):
            return np.zeros((problem.n_rows, len(free)))
        return problem.jacobian(x, dx_dz(x)[free], [int(j) for j in free])[1]

    z0 = np.array(x0, dtype=float)
    z0[positive] = np.log(np.maximum(x0[positive], 1e-12))
    if pole is not None:
        phi0 = min(max(float(x0[pole]), 1e-6), 1.0 - 1e-6)
        z0[pole] = math.log(phi0 / (1.0 - phi0))
    res = least_squares(residuals, z0[free], jac=jacobian, method="lm", x_scale="jac")
    x = to_x(res.x)
    scale = dx_dz(x)                             # dx/dz of each coordinate
    jac = np.zeros((len(res.fun), len(x)))
    with np.errstate(divide="ignore", invalid="ignore"):
        jac[:, free] = np.where(scale[free] > 0, res.jac / np.where(scale[free] > 0, scale[free], 1.0), 0.0)
    return x, res.fun, jac
