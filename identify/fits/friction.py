"""``oe-friction``: output error of ``d omega/dt = -a omega + b u - c sign(omega) + d``.

In the code (and in :class:`~identify.estimate.Estimate`) the friction ``c`` is
named ``friction`` and the constant acceleration ``d`` is named ``bias``.

Real motors have Coulomb friction ``c`` and a duty dead zone; fitted with the
linear model their ``a`` and ``b`` drift with the input's frequency and
amplitude.  This fit simulates the friction model exactly, event by event
(zero crossings, and sticking at rest while ``|b u + d| <= c``), with the
response of :mod:`identify.fits.friction_response` (one compiled pass with numba, else vectorised),
against the encoder angle, with the same segments, offsets and initial speeds as
:mod:`identify.fits.output_error`.  Its Jacobian is analytic, differentiated through
the event times: the exact model's exact derivative wherever the stick/slip
pattern does not change, so no smoothed friction law and no final polish are
needed.  Each segment's angle offset is projected out (variable projection);
the rest are found by Levenberg–Marquardt on the (tiny) normal equations with steps
projected onto the bounds (``a > 0``, ``c >= 0``, dead zone ``>= 0``), started from an
instrumental-variable regression of the measured speed on its own past, the duty, the
signs of duty and speed and a constant (exact for the ZOH model between reversals; the
encoder's noise does not bias it).  A good start matters: the cost is kinked and has
local minima where friction and dead zone trade off; from this start a fit takes a
handful of evaluations.  When the regression fails (too few moving samples), the
linear output-error fit with a small friction guess is the start.  On long data
(:data:`PREFIX_MIN_ROWS`) the first iterations run on the first quarter of every segment
(:func:`_prefix_start`), and the fit stops once a step would move the parameters by less
than :data:`~identify.fits.friction_solver.FINAL_STEP` standard errors, taking that step without evaluating it: on the
10 000-sample runs of ``motorid bench accuracy`` two evaluations on all rows (and three on
a quarter) instead of five or six.  Stick/slip kinks leave nearby local minima
a fraction of a standard error apart, so this can land on a neighbour of the minimum that
iterating to rounding would reach (a test bounds the difference: at most one residual
variance of cost).

When the speed never reverses or comes to rest, ``-c sign(omega)`` is a
constant and cannot be told from ``d``: the fit then reports the net constant
acceleration as ``d`` (linear model with bias, analytic Jacobian), sets
``c = 0`` and says so in a warning.

The covariance (``covariance_method`` in the estimate and its JSON): when every
segment is an encoder's angle and the residuals are mostly its rounding (variance at
most :data:`identify.fits.oe_common.ROUNDING_DOMINATED` times ``step^2/12``), ``"linearised-encoder-bootstrap"``
(:func:`identify.checks.encoder_bootstrap.linearised_encoder_bootstrap_covariance`): the shaft
sticks for many samples around each reversal, and the rounding error then stays put, a
correlation over whole stuck intervals that Gauss–Newton and Newey–West intervals miss.
It costs one product with the Jacobian over 64 encoder phases, no model evaluation.
Otherwise ``"gauss-newton"`` or ``"newey-west"`` (:func:`identify.checks.uncertainty.robust_covariance`).
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import TYPE_CHECKING, Sequence

import numpy as np

from motorsim.checks import ParameterError, check_bool
from motorsim.plant import first_order_coefficients
from motorsim.recording import Recording

from ..checks.validation import segment_fit_percent
from ..comparison import BLOCKS, LEVEL, STOP_FACTOR, STRUCTURES, Candidate, CandidateFit, choose_delay
from ..data import (
    DEFAULT_INPUT_DELAY,
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
from ..sums import sum_squares
from .friction_response import FRICTION_PARAMETERS, FrictionResponse, friction_response
from .friction_solver import levenberg_marquardt, reachable_cost
from .oe_common import fit_covariance, segment_models
from .output_error import MAX_AUTO_DELAY, fit_output_error, linear_candidate, select_delay
from .stiction import GATE_ROWS, StaticProfile, profile_static_level, stiction_evident
from .variable_projection import is_separable, separable_candidate, static_gain_ceiling

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

__all__ = ["fit_output_error_friction", "speed_reverses", "segments_reverse", "friction_candidate", "FrictionScan",
           "solve_friction", "friction_parameter_names", "FrictionProblem"]



def speed_reverses(recordings: Recording | list[Recording], *, rest_fraction: float = 0.02) -> bool:
    """Whether the speed changes sign or comes near rest (``|omega| < rest_fraction max|omega|``) anywhere.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        The runs.
    rest_fraction : float
        Share of the largest speed below which the motor counts as at rest.
    """
    return _reverses([r.measured_speed() for r in as_recordings(recordings)], rest_fraction)


def segments_reverse(segments: Sequence[Segment], *, rest_fraction: float = 0.02) -> bool:
    """:func:`speed_reverses` on the rows of ``segments`` (their measured speed: the differenced angle
    over each interval, or the speed)."""
    return _reverses([np.diff(s.output) / np.diff(s.time) if s.kind == "angle" else s.output for s in segments],
                     rest_fraction)


def _reverses(speeds: Sequence[np.ndarray], rest_fraction: float) -> bool:
    w = np.concatenate([np.asarray(x, dtype=float)[np.isfinite(x)] for x in speeds]) if speeds else np.zeros(0)
    if len(w) == 0:
        return False
    top = float(np.max(np.abs(w)))
    return bool(np.any(w > 0) and np.any(w < 0)) or bool(np.any(np.abs(w) < rest_fraction * top))


class FrictionProblem:
    """Residuals and analytic Jacobian of the friction model on pooled segments.

    The parameter vector holds the shared parameters ``names`` (``a``, ``b``,
    ``friction``, then ``bias`` and ``dead_zone`` when fitted) followed by each
    segment's initial speed; each angle segment's offset enters linearly and is
    projected out (residual and Jacobian columns centred: variable projection,
    Golub & Pereyra 1973).  Each segment keeps the modes of its last evaluation as
    the start of the next (:func:`identify.fits.friction_response.friction_response`).
    ``static`` is the static friction (the break-away level, not a fitted column: see
    :mod:`identify.fits.stiction`), 0 for none; set it with :meth:`at_level`.
    """

    def __init__(self, segments: list[Segment], names: tuple[str, ...]):
        self.segments = segments
        self.names = names
        self.static = 0.0
        self.n_global = len(names)
        self.n_rows = sum(len(s.time) for s in segments)
        self.columns = [FRICTION_PARAMETERS.index(n) for n in names]
        self.modes: list[np.ndarray | None] = [None] * len(segments)
        n_params = self.n_global + len(segments) + sum(1 for s in segments if s.kind == "angle")   # with offsets
        self.dof = max(self.n_rows - n_params, 1)
        self._key: bytes | None = None
        self._value: tuple[np.ndarray, np.ndarray | None] | None = None

    def unpack(self, x: np.ndarray) -> tuple[float, float, float, float, float]:
        """``(a, b, friction, bias, dead_zone)`` from ``x`` (0 for what is not fitted)."""
        named = dict(zip(self.names, x[:self.n_global]))
        return named["a"], named["b"], named["friction"], named.get("bias", 0.0), named.get("dead_zone", 0.0)

    def at_level(self, static: float) -> None:
        """Set the static friction (rad/s^2; the friction level when smaller) for the evaluations that follow."""
        if static != self.static:
            self.static = float(static)
            self._key = None

    def _response(self, x: np.ndarray, i: int, sensitivities: bool) -> FrictionResponse:
        seg = self.segments[i]
        resp = friction_response(*self.unpack(x), seg.drive, seg.time, float(x[self.n_global + i]),
                                 uniform=seg.uniform, sensitivities=sensitivities, modes=self.modes[i],
                                 static_friction=self.static)
        self.modes[i] = resp.modes
        return resp

    def evaluate(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals (measured minus model, angle segments centred) and, if asked, their Jacobian."""
        key = x.tobytes()
        if key == self._key and self._value is not None and (self._value[1] is not None or not jacobian):
            return self._value
        r = np.empty(self.n_rows)
        one = len(self.segments) == 1          # its columns are the whole Jacobian, in this order
        J = np.zeros((self.n_rows, len(x))) if jacobian and not one else None
        row = 0
        for i, seg in enumerate(self.segments):
            n = len(seg.time)
            resp = self._response(x, i, jacobian)
            model, sens = ((resp.angle, resp.angle_sensitivity) if seg.kind == "angle"
                           else (resp.speed, resp.speed_sensitivity))
            err = np.subtract(seg.output, model, out=r[row:row + n])
            if seg.kind == "angle":
                err -= err.mean()
            if jacobian and sens is not None:
                cols = sens[:, self.columns + [len(FRICTION_PARAMETERS) - 1]]    # a copy
                if seg.kind == "angle":
                    np.subtract(cols.mean(axis=0), cols, out=cols)      # centred, negated
                else:
                    np.negative(cols, out=cols)
                if one:
                    J = cols
                else:
                    assert J is not None
                    J[row:row + n, :self.n_global] = cols[:, :-1]
                    J[row:row + n, self.n_global + i] = cols[:, -1]
            row += n
        self._key, self._value = key, (r, J)
        return r, J

    def reachable_cost(self, r: np.ndarray, J: np.ndarray | None) -> float:
        """The residual sum a full Gauss–Newton step from residuals ``r`` with Jacobian ``J`` would reach."""
        return math.inf if J is None else reachable_cost(r, J)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Residuals at ``x`` (rad or rad/s, segments concatenated)."""
        return self.evaluate(x, False)[0]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Jacobian of :meth:`residuals` at ``x``."""
        J = self.evaluate(x, True)[1]
        if J is None:  # pragma: no cover - evaluate(jacobian=True) always computes it
            raise RuntimeError("the Jacobian was not computed")
        return J

    def lower_bounds(self) -> np.ndarray:
        """``a > 0``, ``friction >= 0``, ``dead_zone >= 0``; the rest free."""
        lower = np.full(self.n_global + len(self.segments), -np.inf)
        lower[0] = 1e-9
        lower[2] = 0.0
        if "dead_zone" in self.names:
            lower[self.n_global - 1] = 0.0
        return lower


def fit_output_error_friction(recordings: Recording | list[Recording], *,
                              input_delay: int | str = DEFAULT_INPUT_DELAY,
                              fix_bias: bool = False, dead_zone: bool = True,
                              static_friction: bool = False) -> Estimate:
    """Fit ``a``, ``b``, Coulomb friction ``c``, bias ``d`` and a duty dead zone by output error.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for ``oe``.
    input_delay : int or "auto"
        Input delay in samples, or ``"auto"`` (default, :data:`identify.data.DEFAULT_INPUT_DELAY`): chosen by
        this friction model's own fits in
        ``0 ... 10``, the shortest delay within the noise of the best, see
        :func:`identify.default.selection.select_model`).
    fix_bias : bool
        Hold the bias ``d = 0``.
    dead_zone : bool
        Also fit a dead zone ``z >= 0`` in input units: the motor receives
        ``u - sign(u) z`` when ``|u| > z``, else nothing (default True).
    static_friction : bool
        Also fit a static friction ``c_s >= c`` (stiction: the force the shaft at rest needs to break
        away) by a profile over the levels the data apply (:mod:`identify.fits.stiction`); needs
        ``dead_zone=False`` (default False).  The estimate's structure is then ``stiction``, its
        ``extra["static_friction"]`` the level, and the profile's bracket of levels (and the ``a`` and
        ``b`` fitted across it) its :attr:`~identify.Estimate.model_range`.  With ``input_delay="auto"``
        the delay is chosen by the fit without stiction.

    Returns
    -------
    Estimate
        ``method = "oe-friction"``; ``extra["friction"]`` and ``extra["bias"]`` in
        rad/s^2, ``extra["dead_zone"]`` in input units, ``extra["input_delay"]`` in
        samples; covariance over ``("a", "b", "friction", "bias", "dead_zone")`` less
        what is fixed (``bias`` with ``fix_bias``, ``dead_zone`` when not fitted;
        only ``a, b, bias`` when the speed never reverses).

    Raises
    ------
    NotIdentifiableError
        As for ``oe``, or when the fit lands on ``a <= 0``.
    """
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    fix_bias = check_bool("fix_bias", fix_bias)
    dead_zone = check_bool("dead_zone", dead_zone)
    if check_bool("static_friction", static_friction) and dead_zone:
        raise ParameterError("static_friction=True fits no dead zone: pass dead_zone=False, got dead_zone=True")
    check_excitation(recs, 3 + (not fix_bias) + dead_zone)
    if input_delay == "auto":     # ranked by this model itself (the shortest delay within the noise of the best)
        delay = _select_delay(recs, "dead-zone" if dead_zone else "friction", fix_bias)
    else:
        delay = int(input_delay)
    if not speed_reverses(recs):
        return _no_reversal(recs, delay, fix_bias)
    segments = prepare_segments(recs, delay)
    names = friction_parameter_names(fix_bias=fix_bias, dead_zone=dead_zone)
    problem, res = solve_friction(recs, segments, names, delay)
    profile = None
    if static_friction:
        res, profile = profile_static_level(problem, res, levenberg_marquardt)
    a, b, friction, bias, zone = (float(v) for v in problem.unpack(res.x))
    placed = segment_models(segments, res.fun)        # model (+ offset)
    cov, cov_method = fit_covariance(recs, segments, placed, res.fun, res.jac, problem.dof, problem.n_global)
    extra = {"friction": friction, "bias": bias, "dead_zone": zone, "input_delay": delay}
    est = Estimate(method="oe-friction", structure="dead-zone" if dead_zone else "friction", a=a, b=b,
                   n_samples=problem.n_rows, sample_period=recs[0].sample_period,
                   residual_rms=math.sqrt(sum_squares(res.fun) / problem.n_rows),
                   fit_percent=segment_fit_percent(segments, placed),
                   covariance=cov, param_names=names, covariance_method=cov_method, extra=extra,
                   residual_unit=residual_unit(segments), input_unit=recs[0].input_unit,
                   input_limit=recs[0].input_limit)
    return est if profile is None else _with_profile(est, profile)


def _with_profile(est: Estimate, profile: StaticProfile) -> Estimate:
    """The estimate of the ``stiction`` structure: the static level, and the profile's bracket as its model range
    (the level's, and ``a``'s and ``b``'s over the levels in the bracket).  The bracket's ends are forces
    ``|b u + d|`` at the fitted ``b``; as forces of the motor they are as uncertain as ``b``, so each end is
    carried to the far end of ``b``'s interval."""
    extra = {k: v for k, v in est.extra.items() if k != "dead_zone"}
    extra["static_friction"] = profile.level
    low_b, high_b = (abs(x / est.b) if math.isfinite(x) else math.inf for x in est.confidence_interval()["b"])
    low_b, high_b = min(low_b, high_b, 1.0), max(low_b, high_b, 1.0)
    ranges = {"static_friction": (max(profile.low * low_b, est.extra["friction"]), profile.high * high_b)}
    if profile.ranges["a"] != (est.a, est.a) or profile.ranges["b"] != (est.b, est.b):
        ranges.update(profile.ranges)
    return dataclasses.replace(est, structure="stiction", extra=extra, model_range=ranges)


def _select_delay(recs: list[Recording], structure: str, fix_bias: bool) -> int:
    """The shortest input delay whose friction fit is within the noise of the best (:func:`comparison.choose`);
    the linear model's with a bias when the speed never reverses (friction is then a constant)."""
    if not speed_reverses(recs):
        return select_delay(recs, with_bias=not fix_bias)
    # the scan's fits start from the neighbouring delay's and stop early when they cannot win; refined: in full
    scan = FrictionScan()
    return choose_delay(recs, lambda segs, d, refine: friction_candidate(recs, segs, d, structure, fix_bias,
                                                                         scan=None if refine else scan),
                        MAX_AUTO_DELAY, LEVEL, "oe-friction")


def friction_parameter_names(*, fix_bias: bool = False, dead_zone: bool = True) -> tuple[str, ...]:
    """The shared parameters ``oe-friction`` fits: ``a, b, friction``, then ``bias`` unless fixed, ``dead_zone``."""
    return ("a", "b", "friction") + (() if fix_bias else ("bias",)) + (("dead_zone",) if dead_zone else ())


def solve_friction(recordings: list[Recording], segments: list[Segment], names: tuple[str, ...],
                   input_delay: int, *, thorough: bool = False) -> tuple[FrictionProblem, OptimizeResult]:
    """The friction model's least-squares fit on ``segments``: the problem and the optimiser's result.

    What :func:`fit_output_error_friction` does once the delay is fixed and the speed is known to
    reverse, without the covariance: the model selection (:mod:`identify.default.selection`) scores every
    candidate by this fit's residuals, the same fit the estimate it returns is made from.

    The cost is kinked and has local minima where friction and dead zone trade off.  The fit starts
    from the instrumental-variable regression, one Levenberg–Marquardt run; from the linear fit too
    (with a little friction, a dead zone of a tenth of the input, much friction) only when that lands
    worse than the linear model it contains, when the regression's ``a`` is far from the linear one,
    or always with ``thorough``; the least residual wins.  The linear fit it is checked against is the
    variable projection in ``a`` started from the friction fit's pole (a few cheap evaluations).

    Raises
    ------
    NotIdentifiableError
        When the fit lands on ``a <= 0``, ``b = 0`` or a non-finite value.
    """
    if not segments:
        raise NotIdentifiableError("recording is too short: no gap-free stretch long enough for the delay")
    problem = FrictionProblem(segments, names)
    x0 = _regression_start(problem)
    results = []
    if x0 is not None:
        with np.errstate(over="ignore", invalid="ignore"):
            results.append(levenberg_marquardt(problem, _prefix_start(problem, x0)))
    near = float(results[0].x[0]) if results and np.isfinite(results[0].x[0]) else None
    linear = _linear_fit(recordings, segments, input_delay, "bias" in names, near)
    if linear is not None and (thorough or not results or _suspicious(results[0], x0, linear)):
        # the kinked cost has local minima where friction and dead zone trade off: when the regression's
        # start lands worse than the linear model it contains (c = 0, no dead zone), start from that model
        for start in _linear_starts(problem, linear):
            with np.errstate(over="ignore", invalid="ignore"):
                results.append(levenberg_marquardt(problem, start))
    if not results:
        raise NotIdentifiableError("oe-friction: neither the regression nor the linear fit gives a start; "
                                   "the input does not move the motor")
    res = min(results, key=_cost)
    a, b = float(res.x[0]), float(res.x[1])
    if not (np.all(np.isfinite(res.x)) and a > 1e-8 and b != 0):
        raise NotIdentifiableError(f"oe-friction landed on a = {a:.6g} 1/s (theta1 = exp(-a dt) not in (0, 1)); "
                                   "check the sign of the input and that the motor moved")
    return problem, res


class FrictionScan:
    """What the friction candidates of one model selection share as it goes through the delays.

    Each structure's last fit (the neighbouring delay's: its parameters are the start of the next
    delay's fit, and the general structure's fit at a delay starts the simpler one's there) and the
    least residual sum fitted so far, from which a candidate that cannot come near it is stopped early
    (:func:`friction_candidate`).

    Parameters
    ----------
    best : float
        The least residual sum already fitted on the same rows (the linear candidates'), inf if none.
    level : float
        Level of the selection's test (:data:`identify.comparison.LEVEL`).
    """

    def __init__(self, best: float = math.inf, level: float = LEVEL):
        self.best = best
        self.level = level
        self.starts: dict[str, tuple[tuple[str, ...], np.ndarray, list[Segment]]] = {}
        self.linear: dict[tuple[int, bool], tuple[list[Segment], _LinearFit | None]] = {}

    def linear_fit(self, recs: list[Recording], segs: list[Segment], delay: int, with_bias: bool,
                   near: float | None) -> _LinearFit | None:
        """:func:`_linear_fit` on ``segs``, made once per delay and bias: the structures fitted at one delay
        (the same rows) check themselves against the same linear fit, which only its start (``near``, the
        first structure's pole) would tell from another's."""
        kept = self.linear.get((delay, with_bias))
        if kept is not None and kept[0] is segs:
            return kept[1]
        linear = _linear_fit(recs, segs, delay, with_bias, near)
        self.linear[(delay, with_bias)] = (segs, linear)
        return linear

    def bound(self, structure: str) -> float:
        """The residual sum above which a candidate of ``structure`` cannot be within :data:`STOP_FACTOR` times the
        noise of the best: its statistic is at least its relative excess over the best residual sum (the
        batch-means variance is at most ``|Delta|^2`` times the best's residual sum, by Cauchy–Schwarz)."""
        if not math.isfinite(self.best):
            return math.inf
        n_params = STRUCTURES[structure].n_params
        k = max(max(s.n_params for s in STRUCTURES.values()) + 1 - n_params, 1)   # the largest k it is tested with
        far = STOP_FACTOR * k * float(_f_quantile(k, BLOCKS - k, 1.0 - self.level))
        return self.best * (1.0 + far)

    def start(self, structure: str, names: tuple[str, ...], segs: list[Segment]) -> tuple[np.ndarray, bool] | None:
        """This structure's last fit, else another structure's, its dead zone dropped or added at 0; and whether
        it was fitted on ``segs`` themselves (another structure at the same delay)."""
        for source in (structure, *[s for s in self.starts if s != structure]):
            if source not in self.starts:
                continue
            fitted_names, x, fitted_on = self.starts[source]
            if len(x) - len(fitted_names) != len(segs):
                continue
            shared = dict(zip(fitted_names, x[:len(fitted_names)]))
            return np.concatenate([[shared.get(n, 0.0) for n in names], x[len(fitted_names):]]), fitted_on is segs
        return None


def _f_quantile(k: int, m: int, p: float) -> float:
    from scipy.special import fdtri  # the F quantile, lighter than scipy.stats
    return float(fdtri(k, m, p))


def friction_candidate(recs: list[Recording], segs: list[Segment], delay: int, structure: str,
                       fix_bias: bool, *, scan: FrictionScan | None = None) -> CandidateFit:
    """A friction structure's fit on ``segs`` at ``delay``, scored as a candidate of the model selection.

    With ``scan`` (the candidates of one selection, :class:`FrictionScan`) the fit starts from the
    better (lower residual sum) of the regression's start and the neighbouring delay's fit, makes one
    Levenberg–Marquardt run, and stops early (at that start itself, or at any point of the run) when even
    its Gauss–Newton step could not bring it within
    :data:`STOP_FACTOR` times the noise of the best residual sum so far (:meth:`FrictionScan.bound`):
    such a candidate comes back with ``refined=False`` and its residuals where it stopped (a residual
    sum that bounds its full fit's from above), and ``friction_candidate`` without ``scan`` fits it fully.
    """
    names = friction_parameter_names(fix_bias=fix_bias, dead_zone=structure == "dead-zone")
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            if scan is None:
                _, res = solve_friction(recs, segs, names, delay)
            else:
                res = _scanned_fit(recs, segs, names, delay, structure, scan)
    except (NotIdentifiableError, np.linalg.LinAlgError) as exc:
        return CandidateFit(Candidate(structure, delay, math.nan, math.nan, math.nan, note=str(exc)), None)
    r = np.asarray(res.fun, float)
    fitted = CandidateFit(Candidate(structure, delay, float(res.x[0]), float(res.x[1]), sum_squares(r)), r,
                          refined=res.status != 3, start=tuple(float(v) for v in res.x))
    if scan is not None and fitted.refined:
        scan.starts[structure] = (names, np.asarray(res.x, float), segs)
        scan.best = min(scan.best, fitted.candidate.residual_sum)
    return fitted


def _scanned_fit(recs: list[Recording], segs: list[Segment], names: tuple[str, ...], delay: int, structure: str,
                 scan: FrictionScan) -> OptimizeResult:
    """:func:`solve_friction` from the better of the regression's start and the neighbour's fit, with the bound;
    from another structure's fit on the same rows alone, where there is one."""
    if not segs:
        raise NotIdentifiableError("recording is too short: no gap-free stretch long enough for the delay")
    problem = FrictionProblem(segs, names)
    bound = scan.bound(structure)
    lower = problem.lower_bounds()
    found = scan.start(structure, names, segs)
    if found is not None and found[1]:
        # another structure's minimum on these very rows (the dead zone dropped or added at 0): the start, as it
        # is, the regression's and the prefix's rough starts no nearer
        x0 = found[0]
        res = levenberg_marquardt(problem, x0, bound=bound)
        return res if res.status == 3 else _checked_scanned(recs, segs, names, delay, scan, res, x0)
    starts = [x for x in (None if found is None else found[0], _regression_start(problem)) if x is not None]
    if not starts:
        return solve_friction(recs, segs, names, delay)[1]
    costs = [float(np.sum(problem.residuals(np.maximum(x, lower)) ** 2)) for x in starts]
    x0 = starts[int(np.nanargmin(np.where(np.isfinite(costs), costs, np.nan)))] if np.any(np.isfinite(costs)) \
        else starts[-1]
    if math.isfinite(bound) and problem.n_rows >= PREFIX_MIN_ROWS:
        # the bound at the start itself, before the prefix's iterations: the test the solver makes at its first
        # point (what it is on data too short for a prefix), so a candidate far from the best costs one evaluation
        x = np.maximum(x0, lower)
        r, J = problem.evaluate(x, True)
        if problem.reachable_cost(r, J) > bound:
            from scipy.optimize import OptimizeResult  # imported when used: slow to import
            return OptimizeResult(x=x, fun=r, jac=J, cost=0.5 * sum_squares(r), status=3)
    res = levenberg_marquardt(problem, _prefix_start(problem, x0), bound=bound)
    return res if res.status == 3 else _checked_scanned(recs, segs, names, delay, scan, res, x0)


def _checked_scanned(recs: list[Recording], segs: list[Segment], names: tuple[str, ...], delay: int,
                     scan: FrictionScan, res: OptimizeResult, x0: np.ndarray) -> OptimizeResult:
    """A scanned fit ``res`` from ``x0``, refitted by :func:`solve_friction` when the linear model it contains
    beats it or ``x0`` was far from that model's pole; refused when it landed on ``a <= 0``."""
    near = float(res.x[0]) if np.isfinite(res.x[0]) else None
    linear = scan.linear_fit(recs, segs, delay, "bias" in names, near)
    if linear is not None and _suspicious(res, x0, linear):
        return solve_friction(recs, segs, names, delay)[1]
    if not (np.all(np.isfinite(res.x)) and res.x[0] > 1e-8 and res.x[1] != 0):
        raise NotIdentifiableError(f"oe-friction landed on a = {float(res.x[0]):.6g} 1/s")
    return res


def structure_candidate(recs: list[Recording], segs: list[Segment], delay: int, structure: ModelStructure, *,
                        refine: bool = True, fix_bias: bool = False,
                        starts: Sequence[tuple[float, ...]] = ()) -> CandidateFit:
    """``structure`` (``friction``, ``dead-zone`` or ``stiction``) as a candidate of the default's selection
    (:func:`friction_candidate`, or :func:`stiction_candidate` from the first of ``starts``, a friction
    candidate's fit at the same delay, when given; always fitted fully, ``refine`` has no effect)."""
    if structure.options.get("static_friction"):
        return stiction_candidate(recs, segs, delay, structure.name, fix_bias, starts[0] if starts else None)
    return friction_candidate(recs, segs, delay, structure.name, fix_bias)


def stiction_candidate(recs: list[Recording], segs: list[Segment], delay: int, name: str, fix_bias: bool,
                       start: Sequence[float] | None = None) -> CandidateFit:
    """The friction model with a static level (:mod:`identify.fits.stiction`) fitted on ``segs`` at ``delay``, scored
    as a candidate of the model selection (``name``: the structure's), its friction fit started from ``start``
    (the friction structure's fit on the same rows) when given.  With a start, the level is fitted only where
    :func:`identify.fits.stiction.stiction_evident` finds one worth it on the first rows; elsewhere the candidate
    comes back unfitted, with a note saying why."""
    names = friction_parameter_names(fix_bias=fix_bias, dead_zone=False)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            problem = FrictionProblem(segs, names)
            if start is not None and len(start) == problem.n_global + len(segs):
                x = np.asarray(start, float)
                if not stiction_evident(FrictionProblem(first_rows(segs, GATE_ROWS), names), x, levenberg_marquardt):
                    # nothing calls for a static level: not a candidate (its fit would be the friction fit's)
                    return CandidateFit(Candidate(name, delay, math.nan, math.nan, math.nan, note=(
                        f"no static level above the friction fits the first {GATE_ROWS} rows better beyond the "
                        "noise")), None)
                res = levenberg_marquardt(problem, x)
            else:
                problem, res = solve_friction(recs, segs, names, delay)
            res, _ = profile_static_level(problem, res, levenberg_marquardt)
    except (NotIdentifiableError, np.linalg.LinAlgError) as exc:
        return CandidateFit(Candidate(name, delay, math.nan, math.nan, math.nan, note=str(exc)), None)
    r = np.asarray(res.fun, float)
    return CandidateFit(Candidate(name, delay, float(res.x[0]), float(res.x[1]), sum_squares(r)), r)


def _regression_start(problem: FrictionProblem) -> np.ndarray | None:
    """A starting vector from one instrumental-variable regression on the measured speed.

    Over an interval where the speed keeps its sign ``s``, the exact ZOH step is linear in the
    regressors ``(omega_k, u_k, sign(u_k), s, 1)``: ``omega_{k+1} = e omega_k + p (b (u_k - z sign u_k)
    + d - c s)``.  For angle data the speed averaged over each interval is used; it obeys the same
    step with the force split over ``u_k`` and ``u_{k+1}`` (the two coefficients sum to ``p``; the
    dead zone's ``sign u`` enters as the mean of the two signs, which nearly always agree).  Rows
    near rest or across a reversal are left out, and rows inside the dead zone once it is known.
    The iterations of the output-error fit remove what is left of the approximations.
    Returns None when the regression does not give ``0 < e < 1`` and ``b != 0``.
    """
    dead_zone = "dead_zone" in problem.names
    fit_bias = "bias" in problem.names
    h = float(np.median(np.concatenate([np.diff(s.time) for s in problem.segments])))
    zone = 0.0
    parts = [_regression_rows(seg, dead_zone, fit_bias) for seg in problem.segments]
    X_all, Z_all, y_all, keep_all, duty_all = (np.asarray(parts[0][i]) if len(parts) == 1 else
                                               np.concatenate([part[i] for part in parts]) for i in range(5))
    n_u = parts[0][5]
    for _ in range(2 if dead_zone else 1):
        keep = keep_all & (duty_all > 1.5 * zone) if zone > 0 else keep_all
        rows = np.flatnonzero(keep)        # take: several times faster than a boolean index of 2-D rows
        X, Z, y = X_all.take(rows, axis=0), Z_all.take(rows, axis=0), y_all[rows]
        if len(y) <= 2 * X.shape[1]:
            return None
        try:
            beta = np.linalg.solve(Z.T @ X, Z.T @ y)
        except np.linalg.LinAlgError:
            return None
        e = float(beta[0])
        gain = float(np.sum(beta[1:1 + n_u]))          # p b
        if not (0.0 < e < 1.0) or gain == 0.0:
            return None
        a = -math.log(e) / h
        p = first_order_coefficients(a, h)[1]
        if dead_zone:
            zone = max(0.0, -float(beta[1 + n_u]) / gain)
    rest = 1 + n_u + dead_zone
    friction = max(0.0, -float(beta[rest]) / p)
    shared = [a, gain / p, friction] + ([float(beta[rest + 1]) / p] if fit_bias else []) + ([zone] if dead_zone else [])
    return np.concatenate([shared, [s.initial_speed_guess() for s in problem.segments]])


def _regression_rows(seg: Segment, dead_zone: bool,
                     fit_bias: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Regressors, instruments and targets of :func:`_regression_start` for one segment, the rows to
    keep (both speeds away from rest, no reversal), the smallest ``|duty|`` of each row (rows inside a
    dead zone are left out once it is known) and the number of duty columns.  The instrument of
    ``omega_k`` is ``omega_{k-2}``: the encoder's error in it is independent of the errors in
    ``omega_k`` and ``omega_{k+1}``, so the noise does not bias ``e``."""
    lag = 2
    if seg.kind == "angle":
        w = np.diff(seg.output) / np.diff(seg.time)
        duties = [seg.drive[lag:-2], seg.drive[lag + 1:-1]]
    else:
        w = seg.output
        duties = [seg.drive[lag:-1]]
    now, nxt, instrument = w[lag:-1], w[lag + 1:], w[:-lag - 1]
    top = float(np.max(np.abs(now), initial=0.0))
    keep = ((np.sign(now) == np.sign(nxt)) & (np.sign(instrument) == np.sign(now))
            & (np.abs(now) > 0.02 * top) & (np.abs(nxt) > 0.02 * top))
    # element by element (signs and their half-sums, minima: exact), not through a stacked array of the duties
    smallest_duty = np.abs(duties[0]) if len(duties) == 1 else np.minimum(np.abs(duties[0]), np.abs(duties[1]))
    signs = [] if not dead_zone else [np.sign(duties[0])] if len(duties) == 1 else [
        (np.sign(duties[0]) + np.sign(duties[1])) / 2.0]
    rest = duties + signs + [np.sign(now)]
    rest += [np.ones_like(now)] if fit_bias else []
    X = np.column_stack([now] + rest)
    Z = np.column_stack([instrument] + rest)
    return X, Z, nxt, keep, smallest_duty, len(duties)


@dataclasses.dataclass(frozen=True)
class _LinearFit:
    """The linear model (with a bias when fitted) on the same rows: what the friction fit must beat."""

    a: float
    b: float
    bias: float
    cost: float
    initial_speeds: np.ndarray


def _linear_fit(recs: list[Recording], segments: list[Segment], delay: int, with_bias: bool,
                near: float | None) -> _LinearFit | None:
    """The ``oe`` fit of the linear model on ``segments``, None when it fails: by variable projection in ``a``
    from ``near`` (the friction fit's pole: the linear one when friction is slight) where the clock is
    uniform, else :func:`identify.fits.output_error.linear_candidate`; the initial speeds are then the data's."""
    speeds = np.array([s.initial_speed_guess() for s in segments])
    if near is not None and near > 0 and is_separable(segments, False):
        found = separable_candidate(segments, near, with_bias=with_bias, ceiling=static_gain_ceiling(segments))
        if found is not None:
            a, b, bias, r, _ = found
            return _LinearFit(a, b, bias, sum_squares(r), speeds)
    fitted = linear_candidate(recs, segments, delay, with_bias)
    if fitted.residuals is None:
        return None
    c = fitted.candidate
    return _LinearFit(c.a, c.b, fitted.bias, c.residual_sum, speeds)


def _cost(res: OptimizeResult) -> float:
    """The fit's residual sum (inf when not finite or ``a`` left its bound)."""
    cost = sum_squares(res.fun)
    return cost if math.isfinite(cost) and np.all(np.isfinite(res.x)) and res.x[0] > 1e-8 else math.inf


def _suspicious(res: OptimizeResult, x0: np.ndarray | None, linear: _LinearFit) -> bool:
    """A fit from the regression's start that the linear model it contains beats, or a start far from it."""
    far = x0 is None or not (linear.a / 3 <= x0[0] <= 3 * linear.a)
    return far or _cost(res) > linear.cost * (1 + 1e-9)


def _linear_starts(problem: FrictionProblem, linear: _LinearFit) -> list[np.ndarray]:
    """Starts from the linear fit: a little friction; a dead zone of a tenth of the input; much friction."""
    a0, b0 = linear.a, linear.b
    if b0 == 0 or not a0 > 0:
        return []
    u_scale = float(np.max(np.abs(np.concatenate([s.drive for s in problem.segments])))) or 1.0
    bias = [linear.bias] if "bias" in problem.names else []
    dead = "dead_zone" in problem.names
    guesses = [(0.05, 0.02), (0.0, 0.1), (0.15, 0.0)] if dead else [(0.05, 0.0), (0.15, 0.0)]
    speeds = linear.initial_speeds
    return [np.concatenate([[a0, b0, c * abs(b0) * u_scale], bias, [z * u_scale] if dead else [], speeds])
            for c, z in guesses]


#: Rows from which the first iterations run on the first :data:`PREFIX_SHARE` of every segment.
PREFIX_MIN_ROWS = 8000
#: Share of every segment (its first rows) that the first iterations of a long fit use.
PREFIX_SHARE = 0.25
#: Sign changes of the measured speed the prefix needs (reversals or rests to tell friction apart).
PREFIX_REVERSALS = 4
#: Standard errors of the prefix's fit (as :data:`~identify.fits.friction_solver.FINAL_STEP`) below which its step
#: is its last.
PREFIX_STEP = 10.0
#: Largest ratio of the mean square residual on all rows to the prefix's at the prefix's parameters.
PREFIX_MISFIT = 4.0


def _prefix_start(problem: FrictionProblem, x0: np.ndarray) -> np.ndarray:
    """The start refined by the fit on the first rows of every segment, on long data.

    Far from the minimum each iteration only needs the rough direction; the first
    :data:`PREFIX_SHARE` of every segment gives it at that share of the cost, to within
    :data:`PREFIX_STEP` of its standard errors (a few of the whole data's), and the fit on
    all rows then takes one or two iterations.  Returns ``x0`` on short data, when the prefix
    has fewer than :data:`PREFIX_REVERSALS` sign changes of the speed, when its fit fails,
    or when its parameters leave a mean square residual on all rows more than
    :data:`PREFIX_MISFIT` times the prefix's own (the rest of the data is not what the
    prefix saw; the whole fit then starts where it would without the prefix).  That check is
    the whole fit's first evaluation: when it passes, its residuals and Jacobian stay cached.
    """
    if problem.n_rows < PREFIX_MIN_ROWS:
        return x0
    heads = [dataclasses.replace(s, time=s.time[:n], drive=s.drive[:n], output=s.output[:n])
             for s in problem.segments for n in [max(math.ceil(PREFIX_SHARE * len(s.time)), min(len(s.time), 10))]]
    changes = sum(int(np.count_nonzero(np.diff(np.sign(np.diff(s.output) if s.kind == "angle" else s.output))))
                  for s in heads)
    if changes < PREFIX_REVERSALS:
        return x0
    head = FrictionProblem(heads, problem.names)
    with np.errstate(over="ignore", invalid="ignore"):
        res = levenberg_marquardt(head, x0, final_step=PREFIX_STEP)
        if not np.all(np.isfinite(res.x)):
            return x0
        # the residuals alone first (the response is the same with or without its sensitivities): a prefix
        # that is refused then costs no Jacobian
        r = problem.evaluate(res.x, False)[0]
        misfit = sum_squares(r) / problem.n_rows
        if misfit > PREFIX_MISFIT * sum_squares(res.fun) / head.n_rows:
            return x0
        problem.evaluate(res.x, True)
    return res.x


def _no_reversal(recs: list[Recording], input_delay: int, fix_bias: bool) -> Estimate:
    if fix_bias:
        warnings.warn("oe-friction: the speed never reverses or rests, so Coulomb friction c acts as a constant; "
                      "with the bias d fixed at 0 it cannot be separated from b u: fitting the linear model (c = 0)",
                      UserWarning, stacklevel=3)
        est = fit_output_error(recs, input_delay=input_delay)
        return dataclasses.replace(est, method="oe-friction", structure="friction",
                                   extra={**est.extra, "friction": 0.0, "bias": 0.0})
    warnings.warn("oe-friction: the speed never reverses or comes to rest, so Coulomb friction c is a constant "
                  "indistinguishable from the bias d: reporting c = 0 and d as the net constant acceleration "
                  "(d - c sign(omega))", UserWarning, stacklevel=3)
    est = fit_output_error(recs, input_delay=input_delay, fit_bias=True)
    return dataclasses.replace(est, method="oe-friction", structure="friction", extra={**est.extra, "friction": 0.0})
