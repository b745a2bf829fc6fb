"""``oe-friction``: output error of ``d omega/dt = -a omega + b u - c sign(omega) + d``.

Real motors have Coulomb friction ``c`` and a duty dead zone; fitted with the
linear model their ``a`` and ``b`` drift with the input's frequency and
amplitude.  This fit simulates the friction model exactly, event by event
(zero crossings, and sticking at rest while ``|b u + d| <= c``; see
``motorsim.plant.simulate``), against the encoder angle, with the same
segments, offsets and initial speeds as :mod:`identify.output_error`.  The
simulation has kinks at the events, so the Jacobian is by finite differences
(trust-region reflective, ``a > 0`` and ``c >= 0`` as bounds).

When the speed never reverses or comes to rest, ``-c sign(omega)`` is a
constant and cannot be told from ``d``: the fit then reports the net constant
acceleration as ``d`` (linear model with offset, analytic Jacobian), sets
``c = 0`` and says so in a warning.
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
from scipy.optimize import least_squares

from motorsim.plant import Motor, simulate

from .errors import NotIdentifiableError
from .estimate import Estimate
from .output_error import (_check_delay, _fit, check_excitation, fit_output_error, fit_output_error_offset,
                           prepare_segments, select_delay)
from .regression import as_recordings
from .uncertainty import covariance_from_jacobian
from .validation import nrmse_fit

__all__ = ["fit_output_error_friction", "speed_reverses"]

#: Starting (c / (|b| max|u|), dead zone / max|u|) pairs; the first two have no dead zone.
_STARTS = ((0.05, 0.0), (0.2, 0.0), (0.05, 0.05), (0.2, 0.1))


def speed_reverses(recordings, *, rest_fraction: float = 0.02) -> bool:
    """Whether the speed changes sign or comes near rest (``|omega| < rest_fraction max|omega|``) anywhere."""
    speeds = []
    for r in as_recordings(recordings):
        w = r.measured_speed()
        speeds.append(w[np.isfinite(w)])
    w = np.concatenate(speeds)
    if len(w) == 0:
        return False
    top = float(np.max(np.abs(w)))
    return bool(np.any(w > 0) and np.any(w < 0)) or bool(np.any(np.abs(w) < rest_fraction * top))


@dataclasses.dataclass(frozen=True)
class _Start:
    a: float
    b: float


def _sparsity(segments, n_global):
    """Jacobian pattern: shared parameters touch every row, a segment's initial speed only its rows
    (so finite differences perturb all initial speeds at once)."""
    from scipy.sparse import lil_matrix
    rows = sum(len(s.time) for s in segments)
    pattern = lil_matrix((rows, n_global + len(segments)), dtype=int)
    pattern[:, :n_global] = 1
    row = 0
    for i, seg in enumerate(segments):
        pattern[row:row + len(seg.time), n_global + i] = 1
        row += len(seg.time)
    return pattern.tocsr()


def _simulate(a, b, c, d, seg, w0, dead_zone=0.0):
    motor = Motor(a, b, friction=c, bias=d, dead_zone=dead_zone)
    traj = simulate(motor, seg.drive, seg.time, initial_speed=w0)
    return traj.angle if seg.kind == "angle" else traj.speed


def fit_output_error_friction(recordings, *, delay: int | str = 0, fix_d: bool = False,
                              dead_zone: bool = True) -> Estimate:
    """Fit ``a``, ``b``, Coulomb friction ``c``, offset ``d`` and a duty dead zone by output error.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for ``oe``.
    delay : int or "auto"
        Input delay in samples (``"auto"``: chosen with the linear model).
    fix_d : bool
        Hold ``d = 0`` (no offset).
    dead_zone : bool
        Also fit a dead zone ``z >= 0`` in input units: the motor receives
        ``u - sign(u) z`` when ``|u| > z``, else nothing (default True).

    Returns
    -------
    Estimate
        ``method = "oe-friction"``; ``extra["c"]`` and ``extra["d"]`` in rad/s^2,
        ``extra["dead_zone"]`` in input units; covariance over
        ``("a", "b", "c", "d", "dead_zone")`` less what is fixed (``d`` with
        ``fix_d``, ``dead_zone`` when not fitted; only ``a, b, d`` when the speed
        never reverses).

    Raises
    ------
    NotIdentifiableError
        As for ``oe``, or when the fit lands on ``a <= 0``.
    """
    recs = as_recordings(recordings)
    delay = _check_delay(delay)
    if not isinstance(fix_d, bool):
        raise TypeError(f"fix_d must be a bool, got {fix_d!r}")
    if not isinstance(dead_zone, bool):
        raise TypeError(f"dead_zone must be a bool, got {dead_zone!r}")
    check_excitation(recs, 3 + (not fix_d) + dead_zone)
    if delay == "auto":
        delay = select_delay(recs)
    delay = delay or 0
    if not speed_reverses(recs):
        return _no_reversal(recs, delay, fix_d)
    segments = prepare_segments(recs, delay)
    lin, lin_problem = _fit(recs, segments, delay, False, "analytic")
    start = _Start(a=float(lin.x[0]), b=float(lin.x[1]))
    names = ("a", "b", "c") + (() if fix_d else ("d",)) + (("dead_zone",) if dead_zone else ())
    n_global = len(names)
    u_scale = float(np.max(np.abs(np.concatenate([s.drive for s in segments])))) or 1.0
    w0 = list(lin_problem.initial_speeds(lin.x))
    # friction and dead zone make the cost kinked and multi-modal: start from a few
    # (c, dead zone) guesses, as fractions of b max|u| and of max|u|, and keep the best
    starts = [np.concatenate([[start.a, start.b, fc * abs(start.b) * u_scale] + ([] if fix_d else [0.0])
                              + ([fz * u_scale] if dead_zone else []), w0])
              for fc, fz in _STARTS[: (len(_STARTS) if dead_zone else 2)]]
    rows = sum(len(s.time) for s in segments)

    def unpack(x):
        named = dict(zip(names, x[:n_global]))
        return named["a"], named["b"], named["c"], named.get("d", 0.0), named.get("dead_zone", 0.0)

    def residuals(x):
        a, b, c, d, z = unpack(x)
        out = np.empty(rows)
        row = 0
        for i, seg in enumerate(segments):
            n = len(seg.time)
            r = seg.output - _simulate(a, b, c, d, seg, x[n_global + i], z)
            out[row:row + n] = r - r.mean() if seg.kind == "angle" else r
            row += n
        return out

    lower = np.full(len(starts[0]), -np.inf)
    lower[0] = 1e-9
    lower[2] = 0.0
    if dead_zone:
        lower[n_global - 1] = 0.0
    if start.b == 0:
        raise NotIdentifiableError("oe-friction: the linear start has b = 0; the input does not move the motor")
    res = None
    sparsity = _sparsity(segments, n_global) if len(segments) > 1 else None
    for x0 in starts:
        with np.errstate(over="ignore", invalid="ignore"):
            trial = least_squares(residuals, x0, jac="2-point", method="trf", bounds=(lower, np.inf),
                                  x_scale="jac", xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=100,
                                  jac_sparsity=sparsity)
        if res is None or trial.cost < res.cost:
            res = trial
    a, b, c, d, z = (float(v) for v in unpack(res.x))
    if not (np.all(np.isfinite(res.x)) and a > 1e-8 and b != 0):
        raise NotIdentifiableError(f"oe-friction landed on a = {a:.6g} 1/s (theta1 = exp(-a dt) not in (0, 1)); "
                                   "check the sign of the input and that the motor moved")
    n_offsets = sum(1 for s in segments if s.kind == "angle")
    dof = rows - len(res.x) - n_offsets
    s2 = float(res.fun @ res.fun) / max(dof, 1)
    jac = res.jac.toarray() if hasattr(res.jac, "toarray") else res.jac
    cov = covariance_from_jacobian(jac, s2, n_global)
    meas, sim = [], []
    for i, seg in enumerate(segments):
        out = _simulate(a, b, c, d, seg, res.x[n_global + i], z)
        if seg.kind == "angle":
            meas.append(np.diff(seg.output) / np.diff(seg.time))
            sim.append(np.diff(out) / np.diff(seg.time))
        else:
            meas.append(seg.output)
            sim.append(out)
    kinds = {s.kind for s in segments}
    return Estimate(method="oe-friction", a=a, b=b, n_samples=rows, sample_period=recs[0].sample_period,
                    residual_rms=math.sqrt(float(res.fun @ res.fun) / rows),
                    fit_percent=nrmse_fit(np.concatenate(meas), np.concatenate(sim)), covariance=cov,
                    param_names=names, extra={"c": c, "d": d, "dead_zone": z, "input_delay": float(delay)},
                    residual_unit="rad" if kinds == {"angle"} else "rad/s", input_unit=recs[0].input_unit)


def _no_reversal(recs, delay, fix_d) -> Estimate:
    if fix_d:
        warnings.warn("oe-friction: the speed never reverses or rests, so Coulomb friction c acts as a constant; "
                      "with d fixed at 0 it cannot be separated from b u: fitting the linear model (c = 0)",
                      UserWarning, stacklevel=3)
        est = fit_output_error(recs, delay=delay)
        return dataclasses.replace(est, method="oe-friction", extra={**est.extra, "c": 0.0, "d": 0.0})
    warnings.warn("oe-friction: the speed never reverses or comes to rest, so Coulomb friction c is a constant "
                  "indistinguishable from the offset d: reporting c = 0 and d as the net constant acceleration "
                  "(d - c sign(omega))", UserWarning, stacklevel=3)
    est = fit_output_error_offset(recs, delay=delay)
    return dataclasses.replace(est, method="oe-friction", extra={**est.extra, "c": 0.0})
