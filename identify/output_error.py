"""Output error: fit ``a``, ``b`` by simulating the exact ZOH model of the *angle* against the counts.

The encoder counts are exact functions of the angle, and the angle is the
integral of the speed, so the model of the counts has no approximation: the
only errors left are the encoder's (quantisation, noise).  For each gap-free
segment ``s`` of each recording the model is::

    theta_k = theta0_s + f_k(a, b, d, omega0_s)          (exact ZOH, identify.sensitivity)

with ``a``, ``b`` (and the optional constant acceleration ``d``) shared by all
segments and recordings, and each segment's initial speed ``omega0_s`` and
encoder offset ``theta0_s`` its own (after a dropped sample the duty applied
during the gap is unknown, so it is not invented: the next segment restarts).
``theta0_s`` enters linearly and is eliminated exactly by projecting the
residual and the Jacobian onto the complement of the constant (variable
projection, Golub & Pereyra 1973).  The remaining parameters are found by
Levenberg–Marquardt (``scipy.optimize.least_squares(method="lm")``) with the
analytic sensitivities, started from ``zoh-ls``.  Recordings that hold only
speed are fitted against the speed, with no offset to project.

The covariance is ``s^2 (J^T J)^{-1}`` with ``s^2`` the residual variance
(Ljung, *System Identification*, 2nd ed., eq. 9.18), restricted to the
parameters of interest; for white measurement noise it attains the Cramér–Rao
bound (:func:`identify.uncertainty.cramer_rao_bound`).
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares

from motorsim.recording import Recording

from .errors import NotIdentifiableError
from .estimate import Estimate
from .regression import as_recordings
from .sensitivity import zoh_response
from .uncertainty import covariance_from_jacobian
from .validation import nrmse_fit

__all__ = ["fit_output_error", "fit_output_error_offset", "prepare_segments", "Segment",
           "check_excitation", "select_delay", "model_output", "model_residuals", "MAX_AUTO_DELAY"]

#: Largest input delay in samples that ``delay="auto"`` tries.
MAX_AUTO_DELAY = 10
_MIN_SEGMENT = 4          # samples; shorter segments carry almost no information
_SATURATION_SHARE = 0.5   # warn when the duty sits at its limit for more than this share


@dataclasses.dataclass(frozen=True)
class Segment:
    """One gap-free stretch of a recording, ready for the output-error model.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Sample instants in s.
    drive : ndarray, shape (n,)
        Input reaching the motor (delayed duty), held from ``time[k]`` to ``time[k+1]``.
    output : ndarray, shape (n,)
        Measured angle in rad (``kind == "angle"``) or speed in rad/s.
    kind : str
        ``"angle"`` or ``"speed"``.
    uniform : bool
        Whether ``time`` is uniformly spaced.
    recording : int
        Index of the recording the segment comes from.
    start : int
        Row of the recording where the segment starts.
    """

    time: np.ndarray
    drive: np.ndarray
    output: np.ndarray
    kind: str
    uniform: bool
    recording: int
    start: int

    def initial_speed_guess(self) -> float:
        """Speed near the first sample from the data (rad/s)."""
        if self.kind == "speed":
            return float(self.output[0])
        m = min(3, len(self.time) - 1)
        return float((self.output[m] - self.output[0]) / (self.time[m] - self.time[0]))


def _uniform(t: np.ndarray) -> bool:
    h = np.diff(t)
    return len(h) > 0 and bool(np.all(np.abs(h - h[0]) <= 1e-9 * h[0]))


def prepare_segments(recordings: Sequence[Recording], delay: int = 0, skip: int = 0) -> list[Segment]:
    """Split recordings at gaps into segments, delaying the duty by ``delay`` samples.

    Within a segment the duty ``delay`` samples earlier is unknown for the first
    ``delay`` rows, so each segment starts at row ``max(delay, skip)``.
    """
    out = []
    for i, rec in enumerate(recordings):
        row = 0
        angle_all = rec.measured_angle()
        for seg in rec.segments():
            n = len(seg)
            first = max(delay, skip)
            if n - first >= _MIN_SEGMENT:
                sl = slice(first, n)
                drive = seg.duty[first - delay:n - delay] if delay else seg.duty[sl]
                if angle_all is not None:
                    output, kind = angle_all[row:row + n][sl], "angle"
                else:
                    output, kind = seg.speed[sl], "speed"
                t = seg.time[sl]
                ok = np.isfinite(output)
                if kind == "speed" and not np.all(ok):
                    raise ValueError(f"recordings[{i}] has non-finite speed values")
                out.append(Segment(time=t, drive=np.asarray(drive, float), output=np.asarray(output, float),
                                   kind=kind, uniform=_uniform(t), recording=i, start=row + first))
            row += n
    return out


def check_excitation(recordings: Sequence[Recording], n_params: int = 2) -> None:
    """Raise :class:`NotIdentifiableError` (or warn) when the data cannot determine a and b.

    Checks, in order: enough samples, a duty that changes, an encoder that moves,
    and (warning only) a duty saturated for most of the run.
    """
    total = sum(len(r) for r in recordings)
    if total < 3 * n_params + 4:
        raise NotIdentifiableError(f"recording is too short: {total} samples for {n_params} parameters; "
                                   f"record at least {3 * n_params + 4} (a few time constants) samples")
    duty = np.concatenate([r.duty for r in recordings])
    if np.all(duty == 0):
        raise NotIdentifiableError("input is zero throughout: it is not persistently exciting; "
                                   "use a sine, multisine or PRBS")
    if np.all(duty == duty[0]):
        raise NotIdentifiableError(f"input is constant (duty = {duty[0]:g} throughout): it is not persistently "
                                   "exciting, a and b cannot be separated; use a sine, multisine or PRBS")
    for i, r in enumerate(recordings):
        ang = r.measured_angle()
        y = ang if ang is not None else r.speed
        if np.all(y == y[0]):
            what = "encoder count" if r.counts is not None else ("angle" if ang is not None else "speed")
            raise NotIdentifiableError(f"recordings[{i}]: the {what} never changes (stuck at {y[0]:g}): the "
                                       "encoder is stuck or the motor did not move; check the wiring and "
                                       "that the duty exceeds the motor's dead zone")
        if r.input_unit == "duty":
            limit = float(r.metadata.get("duty_limit", 255))
            share = float(np.mean(np.abs(r.duty) >= limit)) if limit > 0 else 0.0
            if share > _SATURATION_SHARE:
                warnings.warn(f"recordings[{i}]: the duty sits at its limit +-{limit:g} for {100 * share:.0f} % of "
                              "the samples; the motor sees a square wave and the estimate rests on few "
                              "transitions: lower the amplitude", UserWarning, stacklevel=3)


class _Problem:
    """Residuals and Jacobian of the pooled output-error problem in ``(a, b[, d])`` only.

    Each segment's initial speed (and, for angle, its offset) enters the model
    linearly, so for given ``(a, b, d)`` it is solved exactly by a small least
    squares and projected out (variable projection, Golub & Pereyra 1973, with
    Kaufman's Jacobian, whose gradient ``J^T r`` is exact because the dropped term
    lies in the span of the projected columns).  The minimiser is therefore the
    joint one, and ``(J^T J)^{-1}`` of the projected Jacobian is the marginal
    covariance of the shared parameters (the Schur complement).
    """

    def __init__(self, segments: list[Segment], with_offset: bool):
        self.segments = segments
        self.with_offset = with_offset
        self.n_global = 3 if with_offset else 2
        self.rows = [len(s.time) for s in segments]
        self.n_rows = sum(self.rows)
        self.n_nuisance = sum(2 if s.kind == "angle" else 1 for s in segments)
        self.n_params = self.n_global
        self._key = None
        self._value = None
        kinds = {seg.kind for seg in segments}
        self.batched = len(segments) > 1 and len(kinds) == 1
        if self.batched:
            self._prepare_batch(kinds.pop())

    def _prepare_batch(self, kind: str) -> None:
        """Concatenate the segments into one virtual run, simulated in a single scan.

        Between segments the virtual clock advances by the median interval with the
        segment's last duty held: that only changes the state a segment *starts*
        from, i.e. adds multiples of its initial-speed column and a constant to its
        angle, which the per-segment projection removes anyway.  So the residuals and
        the projected Jacobian equal the segment-by-segment ones (a test checks it).
        """
        segs = self.segments
        self.kind = kind
        self.lengths = np.array(self.rows)
        self.starts = np.concatenate([[0], np.cumsum(self.lengths)[:-1]])
        inner = [np.diff(seg.time) for seg in segs]
        h_gap = float(np.median(np.concatenate(inner)))
        steps = np.concatenate([np.concatenate([h, [h_gap]]) for h in inner])[:-1]
        self.v_time = np.concatenate([[0.0], np.cumsum(steps)])
        self.v_drive = np.concatenate([seg.drive for seg in segs])
        self.v_output = np.concatenate([seg.output for seg in segs])
        self.v_uniform = bool(np.all(np.abs(steps - steps[0]) <= 1e-9 * steps[0]))
        self.v_steps = steps
        # time since the segment's own start, and a mask of intervals inside segments
        self.tau = np.concatenate([seg.time - seg.time[0] for seg in segs])
        inside = np.ones(len(steps), bool)
        inside[self.starts[1:] - 1] = False
        self.inside = inside

    def _segment_sum(self, x):
        return np.add.reduceat(x, self.starts, axis=0)

    def _per_row(self, per_segment):
        return np.repeat(per_segment, self.lengths, axis=0)

    def _evaluate_batched(self, a, b, d, jacobian: bool):
        from .sensitivity import _phi
        cols = [0, 1, 3] if self.with_offset else [0, 1]
        resp = zoh_response(a, b, self.v_drive, self.v_time, 0.0, offset=d, uniform=self.v_uniform,
                            sensitivities=jacobian)
        s0w = np.exp(-a * self.tau)                    # initial-speed column of each segment (speed)
        s0w_a = -self.tau * s0w
        if self.kind == "angle":
            h = self.v_steps
            p1, _, d1, _ = _phi(a * h)
            p = np.where(self.inside, h * p1, 0.0)
            dp = np.where(self.inside, h * h * d1, 0.0)

            def segmented_cumsum(f):
                c = np.concatenate([[0.0], np.cumsum(f)])
                return c - self._per_row(c[self.starts])
            s0 = segmented_cumsum(p * s0w[:-1])
            s0a = segmented_cumsum(dp * s0w[:-1] + p * s0w_a[:-1])
            err = self.v_output - resp.angle
            err = err - self._per_row(self._segment_sum(err) / self.lengths)
            s0 = s0 - self._per_row(self._segment_sum(s0) / self.lengths)
            sens = resp.angle_sensitivity
        else:
            s0, s0a = s0w, s0w_a
            err = self.v_output - resp.speed
            sens = resp.speed_sensitivity
        ss = self._segment_sum(s0 * s0)
        w = np.divide(self._segment_sum(s0 * err), ss, out=np.zeros_like(ss), where=ss > 0)
        r = err - self._per_row(w) * s0
        w_start = resp.speed[self.starts] + w             # carried-in speed plus the fitted correction
        if not jacobian:
            return r, None, w_start
        g = sens[:, cols].copy()
        g[:, 0] += self._per_row(w) * s0a
        if self.kind == "angle":
            g -= self._per_row(self._segment_sum(g) / self.lengths[:, None])
        coef = np.divide(self._segment_sum(s0[:, None] * g), ss[:, None], out=np.zeros((len(ss), g.shape[1])),
                         where=ss[:, None] > 0)
        g -= s0[:, None] * self._per_row(coef)
        return r, -g, w_start

    def unpack(self, x):
        a, b = x[0], x[1]
        d = x[2] if self.with_offset else 0.0
        return a, b, d

    def evaluate(self, x, jacobian: bool = True):
        """Residuals (and, when asked, the Jacobian) at ``x``; cached for the last ``x``."""
        key = x.tobytes()
        if key == self._key and (self._value[1] is not None or not jacobian):
            return self._value
        a, b, d = self.unpack(x)
        if self.batched:
            self._key, self._value = key, self._evaluate_batched(a, b, d, jacobian)
            return self._value
        r = np.empty(self.n_rows)
        J = np.empty((self.n_rows, self.n_global)) if jacobian else None
        w0 = np.empty(len(self.segments))
        cols = [0, 1, 3] if self.with_offset else [0, 1]
        row = 0
        for i, seg in enumerate(self.segments):
            n = len(seg.time)
            resp = zoh_response(a, b, seg.drive, seg.time, 0.0, offset=d, uniform=seg.uniform,
                                sensitivities=jacobian)
            if seg.kind == "angle":
                err = seg.output - resp.angle
                s0 = resp.angle_sensitivity[:, 2]
                # project out the offset (centre), then solve for the initial speed
                err = err - err.mean()
                s0 = s0 - s0.mean()
            else:
                err = seg.output - resp.speed
                s0 = resp.speed_sensitivity[:, 2]
            ss = float(s0 @ s0)
            w = float(s0 @ err) / ss if ss > 0 else 0.0
            w0[i] = w
            r[row:row + n] = err - w * s0
            if jacobian:
                if seg.kind == "angle":
                    g = resp.angle_sensitivity[:, cols]
                    g[:, 0] += w * resp.angle_initial_speed_a   # a-sensitivity at the fitted initial speed
                    g -= g.mean(axis=0)
                else:
                    g = resp.speed_sensitivity[:, cols]
                    g[:, 0] += w * resp.speed_initial_speed_a
                if ss > 0:
                    g -= np.outer(s0, (s0 @ g) / ss)
                J[row:row + n] = -g
            row += n
        self._key, self._value = key, (r, J, w0)
        return self._value

    def residuals(self, x):
        return self.evaluate(x, jacobian=False)[0]

    def jacobian(self, x):
        return self.evaluate(x, jacobian=True)[1]

    def initial_speeds(self, x) -> np.ndarray:
        """Fitted initial speed of each segment (rad/s) at ``x``."""
        return self.evaluate(x, jacobian=False)[2]

    @property
    def n_offsets(self) -> int:
        """Projected-out nuisance parameters (initial speeds and angle offsets)."""
        return self.n_nuisance


def _initial_guess(recs, segments, delay) -> tuple[float, float]:
    """``zoh-ls``'s regression (without its fit score), else the log-grid start."""
    from .regression import least_squares as ls_solve, regression_rows
    try:
        A, y = regression_rows(recs)
        (t1, t2), _, _ = ls_solve(A, y)
        dt = recs[0].sample_period
        if 0 < t1 < 1:
            a = -math.log(t1) / dt
            b = a * t2 / (1.0 - t1)
            if math.isfinite(a) and math.isfinite(b) and b != 0:
                return a, b
    except NotIdentifiableError:
        pass
    return _grid_guess(segments)


def _grid_guess(segments) -> tuple[float, float]:
    """Best ``a`` on a log grid with ``b`` and initial states solved linearly (robust start)."""
    dt = float(np.median(np.concatenate([np.diff(s.time) for s in segments])))
    span = max(s.time[-1] - s.time[0] for s in segments)
    best = (math.inf, 1.0, 1.0)
    for a in np.geomspace(0.5 / span, 2.0 / dt, 40):
        cols, ys = [], []
        for i, seg in enumerate(segments):
            resp = zoh_response(a, 1.0, seg.drive, seg.time, 0.0, uniform=seg.uniform)
            sens = resp.angle_sensitivity if seg.kind == "angle" else resp.speed_sensitivity
            block = np.zeros((len(seg.time), 1 + 2 * len(segments)))
            block[:, 0] = sens[:, 1]
            block[:, 1 + 2 * i] = sens[:, 2]
            if seg.kind == "angle":
                block[:, 2 + 2 * i] = 1.0
            cols.append(block)
            ys.append(seg.output)
        A, y = np.vstack(cols), np.concatenate(ys)
        keep = np.linalg.norm(A, axis=0) > 0
        sol, *_ = np.linalg.lstsq(A[:, keep], y, rcond=None)
        rss = float(np.sum((y - A[:, keep] @ sol) ** 2))
        if rss < best[0] and sol[0] != 0:
            best = (rss, float(a), float(sol[0]))
    return best[1], best[2]


def _solve(problem: _Problem, x0: np.ndarray, jac: str):
    jac_arg = problem.jacobian if jac == "analytic" else jac
    with np.errstate(over="ignore", invalid="ignore"):
        return least_squares(problem.residuals, x0, jac=jac_arg, method="lm", x_scale="jac",
                             xtol=1e-11, ftol=1e-11, gtol=1e-11, max_nfev=200 * len(x0))


def select_delay(recordings, max_delay: int = MAX_AUTO_DELAY, *, with_offset: bool = False) -> int:
    """The integer input delay (samples) whose output-error fit leaves the least residual.

    Every candidate is fitted on the same rows (each segment from row ``max_delay``),
    so the residual sums compare like with like.
    """
    recs = as_recordings(recordings)
    if isinstance(max_delay, bool) or not isinstance(max_delay, (int, np.integer)) or max_delay < 0:
        raise ValueError(f"max_delay must be an integer >= 0, got {max_delay!r}")
    best = (math.inf, 0)
    for delay in range(int(max_delay) + 1):
        segs = prepare_segments(recs, delay, skip=max_delay)
        if not segs:
            break
        try:
            res = _fit(recs, segs, delay, with_offset, "analytic")
        except NotIdentifiableError:
            continue
        rss = float(res[0].fun @ res[0].fun)
        if rss < best[0]:
            best = (rss, delay)
    return best[1]


def _fit(recs, segments, delay, with_offset, jac):
    if not segments:
        raise NotIdentifiableError(f"recording is too short: no gap-free stretch of at least "
                                   f"{_MIN_SEGMENT + delay} samples; record longer or fix the dropped samples")
    problem = _Problem(segments, with_offset)
    if problem.n_rows - problem.n_offsets <= problem.n_params + 1:
        raise NotIdentifiableError(f"recording is too short: {problem.n_rows} samples for "
                                   f"{problem.n_params + problem.n_offsets} parameters "
                                   f"(a, b and the initial state of {len(segments)} segments); record longer")
    a0, b0 = _initial_guess(recs, segments, delay)
    x0 = np.array([a0, b0] + ([0.0] if with_offset else []))
    res = _solve(problem, x0, jac)
    a = float(res.x[0])
    dt = recs[0].sample_period
    if not (res.success or res.status == 0) or not np.all(np.isfinite(res.x)) or not a > 0:
        # one retry from the robust grid start before giving up
        a0, b0 = _grid_guess(segments)
        x0[:2] = a0, b0
        res = _solve(problem, x0, jac)
        a = float(res.x[0])
    if res.status == 0 and np.all(np.isfinite(res.x)) and a > 0:
        raise NotIdentifiableError(f"output-error fit did not converge in {res.nfev} evaluations (last a = {a:.6g} "
                                   "1/s): the data barely constrain the model; record longer or excite more")
    if not np.all(np.isfinite(res.x)) or not a > 0:
        theta1 = math.exp(-a * dt) if math.isfinite(a) and -a * dt < 700 else math.inf
        raise NotIdentifiableError(
            f"output-error fit landed on a = {a:.6g} 1/s, i.e. theta1 = exp(-a dt) = {theta1:.6g} not in (0, 1): "
            "no stable first-order model fits; check the sign of the input, that the motor moved, "
            "and try --delay auto or oe-friction")
    return res, problem


def _finish(method, recs, res, problem, delay, names) -> Estimate:
    r = res.fun
    dof = problem.n_rows - problem.n_params - problem.n_offsets
    s2 = float(r @ r) / max(dof, 1)
    J = problem.jacobian(res.x)
    k = problem.n_global
    cov = covariance_from_jacobian(J, s2, k)
    a, b, d = problem.unpack(res.x)
    w0 = problem.initial_speeds(res.x)
    kinds = {s.kind for s in problem.segments}
    extra = {"input_delay": float(delay)}
    if problem.with_offset:
        extra["d"] = float(d)
    est = Estimate(method=method, a=float(a), b=float(b), n_samples=problem.n_rows,
                   sample_period=recs[0].sample_period, residual_rms=math.sqrt(float(r @ r) / problem.n_rows),
                   fit_percent=math.nan, covariance=cov, param_names=names, extra=extra,
                   residual_unit="rad" if kinds == {"angle"} else ("rad/s" if kinds == {"speed"} else "mixed"),
                   input_unit=recs[0].input_unit)
    fit = _fit_percent_states(est, problem, w0, d)
    return dataclasses.replace(est, fit_percent=fit)


def _fit_percent_states(est, problem, w0, d) -> float:
    """NRMSE fit of the model's speed (with the fitted initial states) against the measured speed."""
    meas, sim = [], []
    for seg, w in zip(problem.segments, w0):
        resp = zoh_response(est.a, est.b, seg.drive, seg.time, w, offset=d, uniform=seg.uniform)
        if seg.kind == "angle":
            dtk = np.diff(seg.time)
            meas.append(np.diff(seg.output) / dtk)
            sim.append(np.diff(resp.angle) / dtk)
        else:
            meas.append(seg.output)
            sim.append(resp.speed)
    return nrmse_fit(np.concatenate(meas), np.concatenate(sim))


def _check_delay(delay):
    if delay == "auto" or delay is None:
        return delay
    if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or delay < 0:
        raise ValueError(f"delay must be 'auto' or an integer >= 0 samples, got {delay!r}")
    return int(delay)


def fit_output_error(recordings, *, delay: int | str = 0, jac: str = "analytic") -> Estimate:
    """Output-error fit of ``a``, ``b`` on the encoder angle (the default method, ``oe``).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled: one ``(a, b)``, an initial speed and encoder offset per gap-free segment.
    delay : int or "auto"
        Input delay in whole samples (default 0); ``"auto"`` picks it in
        ``0 ... MAX_AUTO_DELAY`` by the least residual.
    jac : {"analytic", "2-point", "3-point"}
        Jacobian: the analytic sensitivities (default) or finite differences
        (the baseline of ``motorid bench accuracy``).

    Returns
    -------
    Estimate
        ``method = "oe"``, covariance over ``("a", "b")``, ``extra["input_delay"]``;
        ``residual_rms`` in rad (angle recordings) or rad/s (speed-only recordings).

    Raises
    ------
    NotIdentifiableError
        Too short, constant or zero input, stuck encoder, or a fit that lands on ``a <= 0``.
    """
    return _fit_method("oe", recordings, delay=delay, jac=jac, with_offset=False)


def fit_output_error_offset(recordings, *, delay: int | str = 0, jac: str = "analytic") -> Estimate:
    """Output error with a constant acceleration ``d``: ``d omega/dt = -a omega + b u + d``.

    For a motor that never stops (a driver or load offset, an affine static map),
    where Coulomb friction is indistinguishable from ``d``.  Same parameters as
    :func:`fit_output_error`; ``extra["d"]`` in rad/s^2 and its covariance.
    """
    return _fit_method("oe-offset", recordings, delay=delay, jac=jac, with_offset=True)


def _fit_method(method, recordings, *, delay, jac, with_offset) -> Estimate:
    recs = as_recordings(recordings)
    delay = _check_delay(delay)
    if jac not in ("analytic", "2-point", "3-point"):
        raise ValueError(f"jac must be one of 'analytic', '2-point', '3-point', got {jac!r}")
    check_excitation(recs, 3 if with_offset else 2)
    if delay == "auto":
        delay = select_delay(recs, with_offset=with_offset)
    segments = prepare_segments(recs, delay or 0)
    res, problem = _fit(recs, segments, delay or 0, with_offset, jac)
    names = ("a", "b", "d") if with_offset else ("a", "b")
    return _finish(method, recs, res, problem, delay or 0, names)


def _segment_model(estimate: Estimate, seg: Segment) -> np.ndarray:
    """The estimate's native output (angle or speed) on one segment, initial state fitted."""
    d = float(estimate.extra.get("d", 0.0))
    c = float(estimate.extra.get("c", 0.0))
    zone = float(estimate.extra.get("dead_zone", 0.0))
    n = len(seg.time)
    if c > 0 or zone > 0:
        # friction model: not linear in the initial speed, so fit it (one parameter) from the data's guess
        from motorsim.plant import Motor, simulate
        motor = Motor(estimate.a, estimate.b, friction=c, bias=d, dead_zone=zone)

        def run(w0):
            traj = simulate(motor, seg.drive, seg.time, initial_speed=float(w0[0]))
            if seg.kind == "angle":
                return traj.angle + float(np.mean(seg.output - traj.angle))
            return traj.speed
        w0 = least_squares(lambda w: seg.output - run(w), [seg.initial_speed_guess()], xtol=1e-10).x
        return run(w0)
    resp = zoh_response(estimate.a, estimate.b, seg.drive, seg.time, 0.0, offset=d, uniform=seg.uniform)
    if seg.kind == "angle":
        A = np.column_stack([resp.angle_sensitivity[:, 2], np.ones(n)])
        coef, *_ = np.linalg.lstsq(A, seg.output - resp.angle, rcond=None)
        return resp.angle + A @ coef
    s0 = resp.speed_sensitivity[:, 2]
    return resp.speed + float(s0 @ (seg.output - resp.speed) / (s0 @ s0)) * s0


def model_output(estimate: Estimate, recording: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The estimate's speed on ``recording`` with each segment's initial state fitted.

    Returns ``(measured, simulated)`` speed in rad/s, aligned row by row (``nan``
    where undefined): for angle recordings both are the average speed over each
    interval (differenced angle), for speed-only recordings the speed itself.
    Held-out validation uses this: the initial speed and offset of the test data
    are unknown, and (with ``a``, ``b``, ``d`` fixed) the linear model is linear in
    them, so they are solved exactly by least squares (the friction model starts
    from the measured speed instead).
    """
    delay = int(estimate.extra.get("input_delay", 0))
    n = len(recording)
    meas = np.full(n, np.nan)
    sim = np.full(n, np.nan)
    for seg in prepare_segments([recording], delay):
        model = _segment_model(estimate, seg)
        if seg.kind == "angle":
            rows = slice(seg.start + 1, seg.start + len(seg.time))
            meas[rows] = np.diff(seg.output) / np.diff(seg.time)
            sim[rows] = np.diff(model) / np.diff(seg.time)
        else:
            rows = slice(seg.start, seg.start + len(seg.time))
            meas[rows] = seg.output
            sim[rows] = model
    return meas, sim


def model_residuals(estimate: Estimate, recording: Recording) -> tuple[np.ndarray, np.ndarray, str]:
    """Residuals in the recording's native output, the input aligned with them, and their unit.

    Angle recordings give angle residuals in rad (what the encoder measures; the
    differenced speed would add a lag-one correlation of its own), speed-only
    recordings speed residuals in rad/s.  Segments are concatenated.
    """
    delay = int(estimate.extra.get("input_delay", 0))
    res, inp, kinds = [], [], set()
    for seg in prepare_segments([recording], delay):
        res.append(seg.output - _segment_model(estimate, seg))
        inp.append(seg.drive)
        kinds.add(seg.kind)
    if not res:
        raise NotIdentifiableError("recording is too short to validate: no gap-free stretch of "
                                   f"{_MIN_SEGMENT + delay} samples")
    unit = "rad" if kinds == {"angle"} else ("rad/s" if kinds == {"speed"} else "mixed")
    return np.concatenate(res), np.concatenate(inp), unit
