"""``oe-current-limit``: output error of the motor behind a driver that limits its current.

The structure (:class:`identify.model_structures.current_limit.CurrentLimit`) is

``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d``,

``sat_L(x) = min(max(x, -L), L)``.  The motor's current, ``(V - k_e omega) / R``, makes the torque ``b u - s a omega``
(``s`` = ``emf_share``, the share of the pole ``a`` the back-EMF gives); the driver holds that current within its
limit, the torque within ``L`` (``current_limit``, rad/s^2); the rest of the pole, ``(1 - s) a``, is the shaft's
own viscous friction, which acts whatever the current.  Below the limit it is the linear motor ``b/(s + a)`` with
a constant acceleration ``d`` (a load, outside the driver's loop).  The limit acts where the torque asked for is
large: at steps and reversals of the drive, where the back-EMF has not yet caught up.

The exact zero-order-hold response: over each held sample the vector field is continuous and piecewise linear
in ``omega`` (linear, or saturated on either side), so the speed is an exponential (a ramp where ``a_m`` is 0) in
each region, and the instants it crosses from one to the next are solved in closed form
(:func:`limit_interval`); at most two crossings per sample.  The loop over the samples is compiled by numba where
it is installed (:func:`motorsim.compiled.numba_jit`), the same Python loop otherwise.

The fit is nonlinear least squares (:func:`scipy.optimize.least_squares`, bounded: ``a > 0``, ``L > 0``,
``0 < s <= 1``) on ``(a, b, L, s, d)`` and each segment's initial speed, the angle offset projected out, from
several starting limits; its covariance is :func:`identify.asymmetry.fit_mapped`'s (the encoder's rounding by the
linearised bootstrap where it dominates, else Gauss--Newton or Newey--West), the initial speeds projected out of
the Jacobian.
"""
from __future__ import annotations

import functools
import math
from typing import Callable, Sequence

import numpy as np

from motorsim.checks import check_choice
from motorsim.recording import Recording

from .data import (
    DEFAULT_INPUT_DELAY,
    Segment,
    as_recordings,
    check_excitation,
    check_input_delay,
    prepare_segments,
    residual_unit,
)
from .errors import NotIdentifiableError
from .estimate import Estimate
from .sums import sum_squares

__all__ = ["fit_output_error_current_limit", "limit_interval", "limit_run", "limit_response", "STRUCTURE",
           "FITTED", "START_QUANTILES", "START_SHARES"]

#: The structure's name.
STRUCTURE = "current-limit"
#: The parameters the fit estimates.
FITTED = ("a", "b", "current_limit", "emf_share", "bias")
#: Quantiles of the torque the linear model asks for (``|b u - a omega|`` along its run) the limit starts from.
START_QUANTILES = (0.6, 0.8, 0.95)
#: Back-EMF shares the fit starts from.
START_SHARES = (0.5, 0.9)
#: The smallest back-EMF share (the bound of the fit): a driver's current limit needs a back-EMF to act through.
MIN_SHARE = 0.01


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


def _residuals(x: np.ndarray, segments: Sequence[Segment]) -> np.ndarray:
    theta = x[:5]
    out = []
    for j, seg in enumerate(segments):
        r = seg.output - segment_model(theta, seg, float(x[5 + j]))
        out.append(r - r.mean() if seg.kind == "angle" else r)
    return np.concatenate(out)


def _starts(segments: Sequence[Segment], a: float, b: float, bias: float) -> list[np.ndarray]:
    """Start points: the linear model's ``a``, ``b``, ``bias``; limits at :data:`START_QUANTILES` of the torque it
    asks for along its run; shares :data:`START_SHARES`."""
    asked = []
    for seg in segments:
        angle, speed = limit_response(a, b, math.inf, 1.0, bias, seg.drive, seg.time, seg.initial_speed_guess())
        asked.append(np.abs(b * np.asarray(seg.drive, dtype=float) - a * speed))
    torque = np.concatenate(asked)
    torque = torque[torque > 0]
    if len(torque) < 3:
        return []
    return [np.array([a, b, float(np.quantile(torque, q)), s, bias]) for q in START_QUANTILES for s in START_SHARES]


def _fit(recs: list[Recording], delay: int, a: float, b: float, bias: float, covariance: str = "auto") -> Estimate:
    """The fit at ``delay`` from the linear model's ``a``, ``b``, ``bias`` and :func:`_starts`' limits and shares."""
    from scipy.optimize import least_squares

    from .encoder_bootstrap import linearised_encoder_bootstrap_covariance
    from .friction import ROUNDING_DOMINATED
    from .uncertainty import covariance_from_jacobian, robust_covariance
    from .validation import segment_fit_percent
    segments = prepare_segments(recs, delay)
    n = sum(len(s.time) for s in segments)
    p = len(FITTED)
    nuisance = sum(2 if s.kind == "angle" else 1 for s in segments)
    if not segments or n - nuisance <= p + 1:
        raise NotIdentifiableError(f"recording is too short for a current limit: {p} parameters and the initial "
                                   f"state of {len(segments)} segments; record longer")
    if not (math.isfinite(a) and a > 0 and math.isfinite(b) and b != 0):
        raise NotIdentifiableError(f"a current limit needs a stable linear start, got a = {a:.6g}, b = {b:.6g}")
    starts = _starts(segments, a, abs(b), bias)
    if not starts:
        raise NotIdentifiableError("a current limit needs a motor that moved: the drive asked for no torque")
    w0s = [seg.initial_speed_guess() for seg in segments]
    lower = np.array([1e-9, -np.inf, 1e-9, MIN_SHARE, -np.inf] + [-np.inf] * len(segments))
    upper = np.array([np.inf, np.inf, np.inf, 1.0, np.inf] + [np.inf] * len(segments))
    best = None
    for start in starts:
        x0 = np.concatenate([start, w0s])
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                found = least_squares(_residuals, np.clip(x0, lower + 1e-12, upper), bounds=(lower, upper),
                                      args=(segments,), x_scale="jac", xtol=1e-12, ftol=1e-14, gtol=1e-14,
                                      max_nfev=400)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            continue
        if np.all(np.isfinite(found.x)) and (best is None or found.cost < best.cost):
            best = found
    if best is None:
        raise NotIdentifiableError("no fit with a current limit converged: the data do not show one")
    x = best.x
    residual = _residuals(x, segments)
    rss = sum_squares(residual)
    J_all = -_jacobian(x, segments)          # d model / d x, the angle offsets projected out
    W, J = J_all[:, p:], J_all[:, :p]
    if W.shape[1]:
        J = J - W @ np.linalg.lstsq(W, J, rcond=None)[0]
    dof = max(n - nuisance - p, 1)
    s2 = rss / dof
    models, lo = [], 0
    for seg in segments:
        hi = lo + len(seg.time)
        models.append(seg.output - residual[lo:hi])
        lo = hi
    steps = [2 * math.pi / c if c else None for c in (recs[s.recording].counts_per_rev for s in segments)]
    variance = rss / n
    encoders = all(s.kind == "angle" and st for s, st in zip(segments, steps))
    if covariance == "gauss-newton":
        cov, how = covariance_from_jacobian(J, s2, p), "gauss-newton"
    elif encoders and variance <= ROUNDING_DOMINATED * max(st or 0.0 for st in steps) ** 2 / 12.0:
        cov = linearised_encoder_bootstrap_covariance(segments, models, steps, variance, -J, p)
        how = "linearised-encoder-bootstrap"
    else:
        cov, how = robust_covariance(J, residual, s2, p)
    a1, b1, limit, share, d = (float(v) for v in x[:5])
    return Estimate(method="oe-current-limit", a=a1, b=b1, n_samples=n, sample_period=recs[0].sample_period,
                    residual_rms=math.sqrt(rss / n), fit_percent=segment_fit_percent(segments, models),
                    covariance=cov, param_names=FITTED,
                    extra={"current_limit": limit, "emf_share": share, "bias": d, "input_delay": delay},
                    residual_unit=residual_unit(segments), input_unit=recs[0].input_unit,
                    input_limit=recs[0].input_limit, structure=STRUCTURE, covariance_method=how)


def _jacobian(x: np.ndarray, segments: Sequence[Segment]) -> np.ndarray:
    """Central differences of :func:`_residuals` (steps relative to each value)."""
    r0 = _residuals(x, segments)
    J = np.empty((len(r0), len(x)))
    for i in range(len(x)):
        h = 1e-6 * max(abs(float(x[i])), 1e-3)
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        if i == 3 and up[i] > 1.0:          # the share at its bound: one-sided
            up[i], h2 = x[i], h
            J[:, i] = (_residuals(up, segments) - _residuals(down, segments)) / h2
            continue
        J[:, i] = (_residuals(up, segments) - _residuals(down, segments)) / (2 * h)
    return J


def fit_output_error_current_limit(recordings: Recording | Sequence[Recording], *,
                                   input_delay: int | str = DEFAULT_INPUT_DELAY,
                                   covariance: str = "auto") -> Estimate:
    """Output-error fit of the motor behind a driver that limits its current (``oe-current-limit``).

    ``d omega/dt = sat_L(b u - s a omega) - (1 - s) a omega + d`` (module docstring), exact under the zero-order
    hold, on the encoder angle (or the speed column).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled: one set of parameters, an initial speed (and angle offset) per gap-free segment.
    input_delay : int or "auto"
        Whole samples, or ``"auto"`` (default): the delay ``oe`` with a bias chooses.
    covariance : {"auto", "gauss-newton"}
        As :func:`identify.asymmetry.fit_output_error_asymmetric`'s.

    Returns
    -------
    Estimate
        Structure ``current-limit``: ``a``, ``b`` (the linear motor's, below the limit), ``extra``
        ``current_limit`` (rad/s^2), ``emf_share`` and ``bias``; the covariance over
        ``("a", "b", "current_limit", "emf_share", "bias")``.

    Raises
    ------
    NotIdentifiableError
        Too short, a motor that did not move, or no fit converged.

    Examples
    --------
    A driver that holds the torque within 400 rad/s^2 at steps of the duty, noise-free:

    >>> import numpy as np
    >>> from identify import fit
    >>> from identify.model_structures import structure
    >>> from motorsim import Recording
    >>> t = np.arange(3000) * 0.002
    >>> duty = np.where(np.sin(2.5 * t) > 0, 180, -150)
    >>> truth = {"a": 25.0, "b": 3.0, "current_limit": 400.0, "emf_share": 0.8, "bias": 0.0}
    >>> angle = structure("current-limit").response(truth, duty, t).angle
    >>> est = fit(Recording(time=t, duty=duty, sample_period=0.002, angle=angle), "oe-current-limit", input_delay=0)
    >>> print(f"a = {est.a:.6f}, b = {est.b:.6f}, limit {est.extra['current_limit']:.4f}, "
    ...       f"share {est.extra['emf_share']:.6f}")
    a = 25.000000, b = 3.000000, limit 400.0000, share 0.800000
    """
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    check_choice("covariance", covariance, ("auto", "gauss-newton"))
    check_excitation(recs, 5)
    if input_delay == "auto":
        from .output_error import select_delay
        input_delay = select_delay(recs, with_bias=True)
    from .output_error import fit_output_error
    delay = int(input_delay)
    start = fit_output_error(recs, input_delay=delay, fit_bias=True, covariance="gauss-newton")
    return _fit(recs, delay, start.a, start.b, float(start.extra.get("bias", 0.0)), covariance)


def asked_torque(est: Estimate, recs: Sequence[Recording]) -> float:
    """The largest torque (rad/s^2) the fitted model's current asks for on the recordings, ``|b u - s a omega|`` along
    its own run: what its limit cuts."""
    delay = int(est.input_delay)
    v = est.values()
    theta = (v["a"], v["b"], v["current_limit"], v["emf_share"], v["bias"])
    top = 0.0
    for seg in prepare_segments(list(recs), delay):
        w0 = initial_speed_fit(theta, seg)
        _, speed = limit_response(*theta, seg.drive, seg.time, w0)
        asked = np.abs(theta[1] * np.asarray(seg.drive, dtype=float)[:-1] - theta[3] * theta[0] * speed[:-1])
        top = max(top, float(np.max(asked, initial=0.0)))
    return top
