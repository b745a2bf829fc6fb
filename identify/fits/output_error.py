"""Output error: fit ``a``, ``b`` by simulating the exact ZOH model of the *angle* against the counts.

The encoder counts are exact functions of the angle, and the angle is the
integral of the speed, so the model of the counts has no approximation: the
only errors left are the encoder's (quantisation, noise).  For each gap-free
segment ``s`` of each recording the model is::

    theta_k = theta0_s + f_k(a, b, d, omega0_s)          (exact ZOH, identify.fits.sensitivity)

with ``a``, ``b`` (and the optional constant acceleration ``d``, ``bias`` in the
code, ``fit_bias=True``) shared by all
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
bound (:func:`identify.checks.uncertainty.cramer_rao_bound`).
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Callable

import numpy as np

from motorsim.checks import check_bool, check_choice, check_int
from motorsim.recording import Recording

from ..checks.encoder_bootstrap import encoder_bootstrap_covariance, is_coarse
from ..checks.uncertainty import covariance_from_jacobian, robust_covariance
from ..checks.validation import keep_models, segment_fit_percent, segment_speeds
from ..comparison import LEVEL, MAX_AUTO_DELAY, Candidate, CandidateFit, choose_delay
from ..data import (
    DEFAULT_INPUT_DELAY,
    MIN_SEGMENT_SAMPLES,
    Segment,
    as_recordings,
    check_excitation,
    check_input_delay,
    first_rows,
    prepare_segments,
    residual_unit,
)
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..model_structures import ModelStructure
from ..sums import dot, sum_squares
from .sensitivity import phi_functions, zoh_response
from .start import grid_guess, initial_guess
from .variable_projection import (
    SeparableSolution,
    is_separable,
    regression_start,
    separable_candidate,
    solve_separable,
    static_gain_ceiling,
)

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

__all__ = ["fit_output_error", "select_delay", "solve_output_error", "OutputErrorProblem", "OutputErrorSolution",
           "MAX_AUTO_DELAY", "JACOBIANS"]

#: Rows on which a candidate's first Gauss--Newton steps run on long data (:func:`linear_candidate`).
COARSE_SAMPLES = 1000
#: Jacobians :func:`fit_output_error` offers.
JACOBIANS = ("analytic", "2-point", "3-point")


class OutputErrorProblem:
    """Residuals and Jacobian of the pooled output-error problem in ``(a, b[, bias])`` only.

    Each segment's initial speed (and, for angle, its offset) enters the model
    linearly, so for given ``(a, b, bias)`` it is solved exactly by a small least
    squares and projected out (variable projection, Golub & Pereyra 1973, with
    Kaufman's Jacobian, whose gradient ``J^T r`` is exact because the dropped term
    lies in the span of the projected columns).  The minimiser is therefore the
    joint one, and ``(J^T J)^{-1}`` of the projected Jacobian is the marginal
    covariance of the shared parameters (the Schur complement).

    Parameters
    ----------
    segments : list of Segment
        The data, at least one segment.
    with_bias : bool
        Also fit the constant acceleration ``bias`` (the model's ``d``).

    Attributes
    ----------
    n_global : int
        Shared parameters: 2 (``a``, ``b``) or 3 (and ``bias``).
    n_nuisance : int
        Projected-out parameters: each segment's initial speed and, for angle, its offset.
    n_rows : int
        Residuals (samples of all segments).
    """

    def __init__(self, segments: list[Segment], with_bias: bool):
        self.segments = segments
        self.with_bias = with_bias
        self.n_global = 3 if with_bias else 2
        self.rows = [len(s.time) for s in segments]
        self.n_rows = sum(self.rows)
        self.n_nuisance = sum(2 if s.kind == "angle" else 1 for s in segments)
        self._key: bytes | None = None
        self._value: tuple[np.ndarray, np.ndarray | None, np.ndarray] | None = None
        self._columns = [0, 1, 3] if with_bias else [0, 1]
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

    def _evaluate_batched(self, a, b, bias, jacobian: bool):
        resp = zoh_response(a, b, self.v_drive, self.v_time, 0.0, bias=bias, uniform=self.v_uniform,
                            sensitivities=jacobian)
        s0w = np.exp(-a * self.tau)                    # initial-speed column of each segment (speed)
        s0w_a = -self.tau * s0w
        if self.kind == "angle":
            h = self.v_steps
            p1, _, d1, _ = phi_functions(a * h)
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
        g = sens[:, self._columns].copy()
        g[:, 0] += self._per_row(w) * s0a
        if self.kind == "angle":
            g -= self._per_row(self._segment_sum(g) / self.lengths[:, None])
        coef = np.divide(self._segment_sum(s0[:, None] * g), ss[:, None], out=np.zeros((len(ss), g.shape[1])),
                         where=ss[:, None] > 0)
        g -= s0[:, None] * self._per_row(coef)
        return r, -g, w_start

    def unpack(self, x: np.ndarray) -> tuple[float, float, float]:
        """``(a, b, bias)`` from the parameter vector (``bias`` 0 when not fitted)."""
        a, b = x[0], x[1]
        bias = x[2] if self.with_bias else 0.0
        return a, b, bias

    def evaluate(self, x: np.ndarray, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Residuals, the Jacobian (None unless asked) and each segment's initial speed at ``x``.

        Cached for the last ``x``.
        """
        key = x.tobytes()
        if key == self._key and self._value is not None and (self._value[1] is not None or not jacobian):
            return self._value
        a, b, bias = self.unpack(x)
        if self.batched:
            value = self._evaluate_batched(a, b, bias, jacobian)
        else:
            value = self._evaluate_segments(a, b, bias, jacobian)
        self._key, self._value = key, value
        return value

    def _evaluate_segments(self, a, b, bias, jacobian: bool):
        r = np.empty(self.n_rows)
        J = np.empty((self.n_rows, self.n_global)) if jacobian else None
        w0 = np.empty(len(self.segments))
        row = 0
        for i, seg in enumerate(self.segments):
            n = len(seg.time)
            resp = zoh_response(a, b, seg.drive, seg.time, 0.0, bias=bias, uniform=seg.uniform,
                                sensitivities=jacobian)
            if seg.kind == "angle":
                err = seg.output - resp.angle
                s0 = resp.angle_initial_speed
                # project out the offset (centre), then solve for the initial speed
                err = err - err.mean()
                s0 = s0 - s0.mean()
            else:
                err = seg.output - resp.speed
                s0 = resp.speed_initial_speed
            ss = sum_squares(s0)
            w = dot(s0, err) / ss if ss > 0 else 0.0
            w0[i] = w
            r[row:row + n] = err - w * s0
            if J is not None:
                J[row:row + n] = -self._projected_sensitivity(seg, resp, w, s0, ss)
            row += n
        return r, J, w0

    def _projected_sensitivity(self, seg: Segment, resp, w: float, s0: np.ndarray, ss: float) -> np.ndarray:
        """Model sensitivity to the shared parameters with the segment's initial state projected out."""
        if seg.kind == "angle":
            g = resp.angle_sensitivity[:, self._columns]
            g[:, 0] += w * resp.angle_initial_speed_a   # a-sensitivity at the fitted initial speed
            g -= g.mean(axis=0)
        else:
            g = resp.speed_sensitivity[:, self._columns]
            g[:, 0] += w * resp.speed_initial_speed_a
        if ss > 0:
            g -= np.outer(s0, np.einsum("i,ij->j", s0, g) / ss)
        return g

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Residuals at ``x`` (rad or rad/s, segments concatenated)."""
        return self.evaluate(x, jacobian=False)[0]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Jacobian of :meth:`residuals` with respect to the shared parameters at ``x``."""
        J = self.evaluate(x, jacobian=True)[1]
        if J is None:  # pragma: no cover - evaluate(jacobian=True) always computes it
            raise RuntimeError("the Jacobian was not computed")
        return J

    def initial_speeds(self, x: np.ndarray) -> np.ndarray:
        """Fitted initial speed of each segment (rad/s) at ``x``."""
        return self.evaluate(x, jacobian=False)[2]


@dataclasses.dataclass(frozen=True)
class SolverResult:
    """What an optimiser found: ``x`` the parameters, ``fun`` the residuals, ``nfev`` its evaluations.

    The fields of ``scipy.optimize.OptimizeResult`` that a fit reads, kept without
    importing ``scipy.optimize`` (slow to import) where variable projection solves the fit.
    """

    x: np.ndarray
    fun: np.ndarray
    nfev: int


@dataclasses.dataclass(frozen=True)
class OutputErrorSolution:
    """A converged output-error fit: the optimiser's result and the problem it solved.

    Attributes
    ----------
    result : SolverResult
        ``x`` holds ``(a, b[, bias])``; ``fun`` the residuals.
    problem : OutputErrorProblem
        The segments and the model.
    """

    result: SolverResult
    problem: OutputErrorProblem
    separable: SeparableSolution | None = None

    def initial_speeds(self) -> np.ndarray:
        """Fitted initial speed of each segment in rad/s."""
        if self.separable is not None:
            return self.separable.initial_speeds
        return self.problem.initial_speeds(self.result.x)

    def covariance(self, noise_variance: float) -> np.ndarray:
        """``noise_variance (J^T J)^{-1}`` over the shared parameters (projected Jacobian)."""
        if self.separable is not None:
            return self.separable.covariance(noise_variance)
        return covariance_from_jacobian(self.problem.jacobian(self.result.x), noise_variance, self.problem.n_global)

    def model_outputs(self) -> list[np.ndarray]:
        """The fitted model's output (angle or speed, as each segment) on every segment."""
        a, b, bias = self.problem.unpack(self.result.x)
        if self.separable is not None:
            return [seg.output - r for seg, r in zip(self.problem.segments, self.separable.segment_residuals())]
        return [_segment_output(float(a), float(b), bias, seg, w)
                for seg, w in zip(self.problem.segments, self.initial_speeds())]


def _solve(problem: OutputErrorProblem, x0: np.ndarray, jac: str) -> OptimizeResult:
    jac_arg = problem.jacobian if jac == "analytic" else jac
    with np.errstate(over="ignore", invalid="ignore"):
        from scipy.optimize import least_squares  # imported when used: slow to import
        return least_squares(problem.residuals, x0, jac=jac_arg, method="lm", x_scale="jac",
                             xtol=1e-11, ftol=1e-11, gtol=1e-11, max_nfev=200 * len(x0))


def select_delay(recordings: Recording | list[Recording], max_delay: int = MAX_AUTO_DELAY, *,
                 with_bias: bool = False) -> int:
    """The input delay (samples) of the linear model chosen by :func:`identify.default.selection.select_model`.

    Every candidate delay is fitted on the same rows (each segment from row ``max_delay``) and
    the shortest whose fit is within the noise of the best is returned, so a delay that improves
    the residual by less than the noise can tell is not taken.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for :func:`fit_output_error`.
    max_delay : int
        Largest delay tried, >= 0 samples.
    with_bias : bool
        Fit the constant acceleration ``bias`` in every candidate.

    Returns
    -------
    int
    """
    recs = as_recordings(recordings)
    max_delay = check_int("max_delay", max_delay, lo=0, allow_integral_float=False)
    return choose_delay(recs, lambda segs, d, full: linear_candidate(recs, segs, d, with_bias, refine=full),
                        max_delay, LEVEL, "oe")


def linear_candidate(recs: list[Recording], segs: list[Segment], delay: int, with_bias: bool,
                refine: bool = True) -> CandidateFit:
    """The ``oe`` fit (with or without a bias) on ``segs``: what ``fit_output_error`` computes
    (with ``refine=False`` on long data, only its first steps: see :func:`identify.comparison.refine`)."""
    name = "bias" if with_bias else "linear"
    if is_separable(segs, False):
        ceiling = static_gain_ceiling(segs)
        for start in _separable_starts(recs, segs):
            found = separable_candidate(segs, start(), with_bias=with_bias, ceiling=ceiling,
                                        coarse_samples=COARSE_SAMPLES, refine=refine)
            if found is not None:
                a, b, bias, r, refined = found
                return CandidateFit(Candidate(name, delay, a, b, sum_squares(r)), r, bias, refined)
    try:
        solution = solve_output_error(recs, segs, delay, with_bias=with_bias)
    except NotIdentifiableError as exc:
        return CandidateFit(Candidate(name, delay, math.nan, math.nan, math.nan, note=str(exc)), None)
    r = np.asarray(solution.result.fun, float)
    x = solution.result.x
    return CandidateFit(Candidate(name, delay, float(x[0]), float(x[1]), sum_squares(r)), r,
                   float(x[2]) if with_bias else 0.0)


def structure_candidate(recs: list[Recording], segs: list[Segment], delay: int, structure: ModelStructure, *,
                        refine: bool = True, fix_bias: bool = False) -> CandidateFit:
    """``structure`` (``linear`` or ``bias``) as a candidate of the default's selection (:func:`linear_candidate`)."""
    return linear_candidate(recs, segs, delay, "bias" in structure.param_names, refine=refine)


def _separable_start(recs: list[Recording], segs: list[Segment]) -> float:
    """Starting pole of the separable iteration: ``zoh-ls``'s regression, else the general start value."""
    start = regression_start(segs)
    return initial_guess(recs, segs)[0] if start is None else start


def _separable_starts(recs: list[Recording], segs: list[Segment]) -> tuple[Callable[[], float], ...]:
    """The starting poles of the separable iteration in the order tried, each computed when asked for:
    :func:`_separable_start`, then the grid's best on the first :data:`COARSE_SAMPLES` rows
    (:func:`identify.fits.start.grid_guess`).  The regression's pole can be far off where the speed it
    differences is coarse or friction bends the response (389 1/s for a = 25 through friction on a
    1000-count encoder at 1 ms), and the iteration in ``a`` alone then fails; from the grid's pole it
    reaches the minimum the general Levenberg–Marquardt fit reaches (the same ``a`` to 1e-10 there), at a
    twentieth of its cost."""
    return (lambda: _separable_start(recs, segs), lambda: grid_guess(first_rows(segs, COARSE_SAMPLES))[0])


def solve_output_error(recordings: list[Recording], segments: list[Segment], input_delay: int, *,
                       with_bias: bool = False, jac: str = "analytic") -> OutputErrorSolution:
    """Levenberg–Marquardt on :class:`OutputErrorProblem`, from :func:`identify.fits.start.initial_guess`.

    Parameters
    ----------
    recordings : list of Recording
        The pooled runs (checked by :func:`identify.data.as_recordings`).
    segments : list of Segment
        The runs cut at gaps with the duty delayed by ``input_delay``.
    input_delay : int
        Input delay in samples (for the messages).
    with_bias : bool
        Also fit the constant acceleration ``bias``.
    jac : {"analytic", "2-point", "3-point"}
        The Jacobian.

    Returns
    -------
    OutputErrorSolution

    Raises
    ------
    NotIdentifiableError
        Too few samples, no convergence, or a fit that lands on ``a <= 0``.
    """
    if not segments:
        raise NotIdentifiableError(f"recording is too short: no gap-free stretch of at least "
                                   f"{MIN_SEGMENT_SAMPLES + input_delay} samples; record longer or fix the "
                                   "dropped samples")
    problem = OutputErrorProblem(segments, with_bias)
    if problem.n_rows - problem.n_nuisance <= problem.n_global + 1:
        raise NotIdentifiableError(f"recording is too short: {problem.n_rows} samples for "
                                   f"{problem.n_global + problem.n_nuisance} parameters "
                                   f"(a, b and the initial state of {len(segments)} segments); record longer")
    if jac == "analytic" and is_separable(segments, with_bias):
        for start in _separable_starts(recordings, segments):
            separable = solve_separable(segments, start())
            if separable is not None:
                result = SolverResult(np.array([separable.a, separable.b]), separable.residuals, separable.iterations)
                return OutputErrorSolution(result, problem, separable)
    a0, b0 = initial_guess(recordings, segments)
    x0 = np.array([a0, b0] + ([0.0] if with_bias else []))
    res = _solve(problem, x0, jac)
    a = float(res.x[0])
    if not (res.success or res.status == 0) or not np.all(np.isfinite(res.x)) or not a > 0:
        # one retry from the robust grid start before giving up
        x0[:2] = grid_guess(segments)
        res = _solve(problem, x0, jac)
        a = float(res.x[0])
    if res.status == 0 and np.all(np.isfinite(res.x)) and a > 0:
        raise NotIdentifiableError(f"output-error fit did not converge in {res.nfev} evaluations (last a = {a:.6g} "
                                   "1/s): the data barely constrain the model; record longer or excite more")
    if not np.all(np.isfinite(res.x)) or not a > 0:
        dt = recordings[0].sample_period
        theta1 = math.exp(-a * dt) if math.isfinite(a) and -a * dt < 700 else math.inf
        raise NotIdentifiableError(
            f"output-error fit landed on a = {a:.6g} 1/s, i.e. theta1 = exp(-a dt) = {theta1:.6g} not in (0, 1): "
            "no stable first-order model fits; check the sign of the input, that the motor moved, "
            "and try input_delay='auto' or oe-friction")
    return OutputErrorSolution(SolverResult(np.asarray(res.x), np.asarray(res.fun), int(res.nfev)), problem)


def _estimate(recs: list[Recording], solution: OutputErrorSolution, input_delay: int,
              covariance: str = "auto") -> Estimate:
    res, problem = solution.result, solution.problem
    r = res.fun
    dof = problem.n_rows - problem.n_global - problem.n_nuisance
    rss = sum_squares(r)
    s2 = rss / max(dof, 1)
    a, b, bias = problem.unpack(res.x)
    models = solution.model_outputs()
    cov, cov_method = _covariance(recs, solution, models, s2, covariance)
    extra: dict[str, float] = {"input_delay": input_delay}
    if problem.with_bias:
        extra["bias"] = float(bias)
    if solution.separable is not None:
        fit_percent = solution.separable.speed_fit_percent(problem.segments)
    else:
        fit_percent = segment_fit_percent(problem.segments, models)
    est = Estimate(method="oe", a=float(a), b=float(b), n_samples=problem.n_rows,
                   sample_period=recs[0].sample_period, residual_rms=math.sqrt(rss / problem.n_rows),
                   fit_percent=fit_percent, covariance=cov,
                   param_names=("a", "b", "bias") if problem.with_bias else ("a", "b"), extra=extra,
                   residual_unit=residual_unit(problem.segments), input_unit=recs[0].input_unit,
                   input_limit=recs[0].input_limit, structure="bias" if problem.with_bias else "linear",
                   covariance_method=cov_method, speed_residuals=_speed_residuals(recs, problem.segments, models))
    if solution.separable is not None:
        # the part checks ask for this model on every row; the separable fit's is the measured output less its
        # least-squares residual, as theirs (the other path's angle has no offset fitted)
        keep_models(est, recs, problem.segments, models)
    return est


def _speed_residuals(recs: list[Recording], segments: list[Segment], models: list[np.ndarray],
                     ) -> tuple[np.ndarray, ...]:
    """Measured minus model speed on every recording, row by row as :func:`identify.checks.validation.model_output`.

    The fit's initial speeds (and angle offsets) are least squares given ``a``, ``b`` and the bias,
    as ``model_output``'s are, so this is its residual without simulating the model again.
    """
    out = [np.full(len(r), np.nan) for r in recs]
    for seg, model in zip(segments, models):
        rows, measured, simulated = segment_speeds(seg, model)
        out[seg.recording][rows] = measured - simulated
    for r in out:
        r.setflags(write=False)
    return tuple(out)


def _covariance(recs: list[Recording], solution: OutputErrorSolution, models: list[np.ndarray],
                s2: float, method: str = "auto") -> tuple[np.ndarray, str]:
    """Refits of re-quantised model angles on a coarse encoder, else Gauss–Newton or Newey–West.

    ``method="gauss-newton"`` skips the choice and returns the fit's own covariance.
    """
    res, problem = solution.result, solution.problem
    segs = problem.segments
    cprs = [recs[s.recording].counts_per_rev for s in segs]
    steps = [2 * math.pi / c if c else None for c in cprs]
    placed = [m + float(np.mean(s.output - m)) if s.kind == "angle" else m for s, m in zip(segs, models)]
    if method == "auto" and is_coarse(segs, placed, steps):
        def refit(new: list[Segment]) -> np.ndarray | None:
            try:
                out = _solve(OutputErrorProblem(new, problem.with_bias), np.array(res.x, dtype=float), "analytic")
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):   # a refit that overflows failed too
                return None
            return out.x if out.status > 0 else None
        cov = encoder_bootstrap_covariance(segs, placed, steps, float(res.fun @ res.fun) / problem.n_rows, refit,
                                           problem.n_global)
        return cov, "encoder-bootstrap"
    if method == "gauss-newton":
        return solution.covariance(s2), "gauss-newton"
    # the Jacobian (a pass with sensitivities) only when the residuals are not white
    return robust_covariance(lambda: problem.jacobian(res.x), res.fun, s2, problem.n_global,
                             gauss_newton=lambda: solution.covariance(s2))


def _segment_output(a: float, b: float, bias: float, seg: Segment, initial_speed: float) -> np.ndarray:
    """The model's angle or speed (as the segment) from the fitted initial speed."""
    resp = zoh_response(a, b, seg.drive, seg.time, initial_speed, bias=bias, uniform=seg.uniform)
    return resp.angle if seg.kind == "angle" else resp.speed


def fit_output_error(recordings: Recording | list[Recording], *, input_delay: int | str = DEFAULT_INPUT_DELAY,
                     fit_bias: bool = False, jac: str = "analytic", covariance: str = "auto") -> Estimate:
    """Output-error fit of ``a``, ``b`` on the encoder angle (the default method, ``oe``).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled: one ``(a, b)``, an initial speed and encoder offset per gap-free segment.
    input_delay : int or "auto"
        Input delay in whole samples, or ``"auto"`` (default,
        :data:`identify.data.DEFAULT_INPUT_DELAY`): the shortest delay in ``0 ... MAX_AUTO_DELAY``
        whose fit is within the noise of the best (:func:`identify.default.selection.select_model`).
    fit_bias : bool
        Also fit a constant acceleration ``bias`` (the model's ``d``):
        ``d omega/dt = -a omega + b u + d``.  For a motor that never stops (a driver
        or load offset, an affine static map), where Coulomb friction is
        indistinguishable from it.  Default False.
    jac : {"analytic", "2-point", "3-point"}
        Jacobian: the analytic sensitivities (default) or finite differences
        (the baseline of ``motorid bench accuracy``).
    covariance : {"auto", "gauss-newton"}
        ``"auto"`` (default): intervals that hold when the noise model fails — an encoder
        bootstrap on a coarse encoder, Newey–West when the residuals are not white (a
        Ljung–Box test), else Gauss–Newton; ``estimate.covariance_method`` says which.
        ``"gauss-newton"``: the fit's own ``s^2 (J^T J)^-1``, which assumes white noise
        (cheaper: no test, no extra pass with sensitivities).

    Returns
    -------
    Estimate
        ``method = "oe"``, covariance over ``("a", "b")`` (``("a", "b", "bias")``
        with ``fit_bias``), ``input_delay`` (int, samples) and
        ``extra["bias"]`` in rad/s^2 with ``fit_bias``; ``residual_rms`` in rad
        (angle recordings) or rad/s (speed-only recordings).

    Raises
    ------
    NotIdentifiableError
        Too short, constant or zero input, stuck encoder, or a fit that lands on ``a <= 0``.

    Examples
    --------
    A noise-free 16667-count encoder on the article's motor and input:

    >>> from identify import fit_output_error
    >>> from motorsim.excitation import Sine
    >>> from motorsim.plant import Motor
    >>> from motorsim.rig import Experiment, SimRig
    >>> rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 5.0))
    >>> est = fit_output_error(rec)
    >>> print(f"a = {est.a:.2f} 1/s, b = {est.b:.3f} (rad/s^2)/duty, delay {est.input_delay}")
    a = 25.00 1/s, b = 3.000 (rad/s^2)/duty, delay 0
    """
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    fit_bias = check_bool("fit_bias", fit_bias)
    check_choice("jac", jac, JACOBIANS)
    check_choice("covariance", covariance, ("auto", "gauss-newton"))
    check_excitation(recs, 3 if fit_bias else 2)
    delay = select_delay(recs, with_bias=fit_bias) if input_delay == "auto" else int(input_delay)
    segments = prepare_segments(recs, delay)
    return _estimate(recs, solve_output_error(recs, segments, delay, with_bias=fit_bias, jac=jac), delay,
                     covariance)
