"""Output error on a uniform clock by variable projection in the pole ``a`` alone.

For angle segments on a uniform clock with no ``bias``, the exact ZOH angle is
linear in everything but ``a``::

    theta_k = b B_k(a) + omega0_s W_k(a) + theta0_s            (segment s)

with ``W_k = (1 - exp(-a tau_k))/a`` (``tau_k = t_k - t_0``) the response to the
initial speed and ``B_k = (h S_k - w_k)/a`` the response to ``b = 1``, where
``S_k = sum_{j<k} u_j`` and ``w_{k+1} = e w_k + p u_k`` (``e = exp(-a h)``,
``p = (1 - e)/a``) is the speed per unit ``b`` -- the angle recursion of
``motorsim.plant`` summed in closed form.  For a given ``a`` the linear
parameters (``b`` shared, each segment's ``omega0_s`` and ``theta0_s``) are a
small least squares, and the residual ``r(a)`` is minimised over the scalar
``a`` by Gauss--Newton with Kaufman's Jacobian (Golub & Pereyra 2003, *Inverse
Problems* 19, R1, sec. 3): the step is ``(g . r) / |P g|^2`` with ``g = b dB/da +
omega0 dW/da`` and ``P`` the projection onto the complement of the linear
columns.  One evaluation costs two first-order filter passes (``w`` and ``dw/da``) and a
few vector operations, written into arrays allocated once.

The minimiser is the one of :class:`identify.fits.output_error.OutputErrorProblem`
(the same model and residual), so the estimates agree to rounding; the
projected Jacobian over ``(a, b)`` is returned for the covariance.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
from typing import Any, Iterator

import numpy as np

from motorsim.recursion import first_order_filter

from ..data import Segment, first_rows
from ..sums import dot
from .sensitivity import phi_functions

__all__ = ["SeparableSolution", "solve_separable", "separable_residual_sum", "separable_candidate", "is_separable",
           "regression_start", "static_gain_ceiling", "shared_work"]

#: Relative step in ``a`` after which the iteration stops.  Gauss--Newton converges
#: quadratically here (small residuals), so the error left after such a step is of
#: order its square, below rounding.
STEP_RTOL = 1e-8
#: Samples of the coarse phase: on long recordings the first steps, which need no
#: precision, run on about this many samples (the segments' beginnings) until a step
#: is below ``COARSE_RTOL``; the fit on all samples then starts within the coarse
#: fit's statistical error and needs one or two steps.
COARSE_SAMPLES = 20_000
COARSE_RTOL = 1e-5
#: Evaluations of an unrefined candidate's coarse steps (:func:`separable_candidate`).
COARSE_BUDGET = 4
#: Gauss--Newton iterations before giving up (the caller then falls back to Levenberg--Marquardt).
MAX_ITERATIONS = 30


def _dot(x: np.ndarray, y: np.ndarray) -> float:
    """``x . y``; long vectors by :func:`identify.sums.dot` (short ones stay on one BLAS thread)."""
    if len(x) < _BLAS_BELOW:
        return float(x.dot(y))
    return dot(x, y)


_BLAS_BELOW = 4096


#: Within :func:`shared_work`: what the candidates of one selection compute alike on the same rows, by key; each
#: entry holds the object it was made from (compared by identity, so a key is never a reused ``id``).  None outside.
_SHARED: dict[tuple, tuple[Any, Any]] | None = None


@contextlib.contextmanager
def shared_work() -> Iterator[None]:
    """Within it, candidates fitted on the same segments (the same list object) share their work: the regression's
    start and the coarse steps, which a refit of the same candidate
    (:func:`identify.default.comparison.refine`) would repeat from the same start and resumes instead.  The numbers
    are the ones each fit computes alone, bit for bit: the same operations on the same values.  Forgotten on exit."""
    global _SHARED
    outer = _SHARED
    if outer is None:
        _SHARED = {}
    try:
        yield
    finally:
        if outer is None:
            _SHARED = None


def _shared(key: tuple, made_from: Any) -> tuple[bool, Any]:
    """``(True, value)`` for ``key`` when :func:`shared_work` holds it for the very object ``made_from``."""
    entry = None if _SHARED is None else _SHARED.get(key)
    if entry is not None and entry[0] is made_from:
        return True, entry[1]
    return False, None


def _share(key: tuple, made_from: Any, value: Any) -> Any:
    """Keep ``value`` for ``key`` within :func:`shared_work` (nothing outside it); returns ``value``."""
    if _SHARED is not None:
        _SHARED[key] = (made_from, value)
    return value


def _mean(x: np.ndarray) -> float:
    return float(np.add.reduce(x)) / len(x)


def _coefficients(a: float, h: float) -> tuple[float, float, float]:
    """``e = exp(-a h)``, ``p = h phi1(a h)`` and ``dp/da = h^2 phi1'(a h)`` (scalars)."""
    x = a * h
    e = math.exp(-x)
    if abs(x) < 0.05:   # cancellation: the power series of identify.fits.sensitivity
        p1, _, d1, _ = (float(f[0]) for f in phi_functions(np.array([x])))
    else:
        one_minus = -math.expm1(-x)
        p1, d1 = one_minus / x, (x * e - one_minus) / (x * x)
    return e, h * p1, h * h * d1


def is_separable(segments: list[Segment], with_bias: bool) -> bool:
    """True when :func:`solve_separable` applies: angle segments on uniform clocks, no ``bias``."""
    return (not with_bias and len(segments) > 0
            and all(s.kind == "angle" and s.uniform and len(s.time) >= 3 for s in segments))


@dataclasses.dataclass(frozen=True)
class SeparableSolution:
    """A converged separable fit.

    Attributes
    ----------
    a, b : float
        Pole (1/s) and gain.
    initial_speeds : ndarray, shape (n_segments,)
        Fitted speed at each segment's first sample (rad/s).
    residuals : ndarray, shape (n_rows,)
        Measured minus model angle (rad), segments concatenated.
    normal_matrix : ndarray, shape (2, 2)
        ``J^T J`` of the Jacobian over ``(a, b)`` with each segment's initial speed and
        offset projected out (the marginal information of ``(a, b)``).
    iterations : int
        Model evaluations.
    """

    a: float
    b: float
    initial_speeds: np.ndarray
    residuals: np.ndarray
    normal_matrix: np.ndarray
    iterations: int
    segment_lengths: tuple[int, ...]

    def segment_residuals(self) -> list[np.ndarray]:
        """:attr:`residuals` cut into the segments."""
        if len(self.segment_lengths) == 1:
            return [self.residuals]
        return np.split(self.residuals, np.cumsum(self.segment_lengths)[:-1])

    def speed_fit_percent(self, segments: list[Segment]) -> float:
        """NRMSE fit (%) of the model's interval speed against the measured one, pooled over segments.

        :func:`identify.checks.validation.segment_fit_percent` of the fitted angles, from the
        residuals: the speeds' difference is the differenced residual over the interval.
        Each segment's interval is its mean (the clock is uniform within 1e-9 relative).
        """
        pieces = [(seg.output, r, float(seg.time[-1] - seg.time[0]) / (len(seg.time) - 1))
                  for seg, r in zip(segments, self.segment_residuals())]
        count = sum(len(y) - 1 for y, _, _ in pieces)
        if count < 2:
            return math.nan
        mean = sum(float(y[-1] - y[0]) / h for y, _, h in pieces) / count
        spread = error = 0.0
        for y, r, h in pieces:
            v = np.diff(y)
            v /= h
            v -= mean
            spread += _dot(v, v)
            np.subtract(r[1:], r[:-1], out=v)
            error += _dot(v, v) / (h * h)
        if spread == 0:
            return math.nan
        return 100.0 * (1.0 - math.sqrt(error / spread))

    def covariance(self, noise_variance: float) -> np.ndarray:
        """``noise_variance (J^T J)^{-1}`` over ``(a, b)``, ``inf`` when ``J^T J`` is singular.

        Scaled to unit diagonal first, like :func:`identify.checks.uncertainty.covariance_from_jacobian`
        (whose singular-value threshold 1e-13 is 1e-26 on the eigenvalues here).
        """
        m = self.normal_matrix
        if not (m[0, 0] > 0 and m[1, 1] > 0 and np.all(np.isfinite(m))):
            return np.full((2, 2), math.inf)
        s0, s1 = math.sqrt(m[0, 0]), math.sqrt(m[1, 1])
        c = float(m[0, 1]) / (s0 * s1)              # scaled: [[1, c], [c, 1]], eigenvalues 1 -+ |c|
        if 1 - abs(c) <= (1 + abs(c)) * 1e-26:
            return np.full((2, 2), math.inf)
        k = noise_variance / (1 - c * c)
        return np.array([[k / (s0 * s0), -k * c / (s0 * s1)], [-k * c / (s0 * s1), k / (s1 * s1)]])


class _Segment:
    """Per-segment constants and work arrays, allocated once per fit.

    Columns are kept in convenient scalings: ``B* = a B = h S - w`` with coefficient
    ``beta = b / a``, and ``D = -exp(-a tau)`` (``W = (1 + D)/a``) with coefficient
    ``gamma = omega0 / a``.  ``D`` is nonzero only while ``a tau < DECAYED`` (``k < K``):
    every product with a centred vector needs only those samples.
    """

    def __init__(self, seg: Segment, with_bias: bool = False, source: tuple[list[Segment], int] | None = None):
        n = len(seg.time)
        self.n = n
        # the segments list and the index this one's rows begin (its first ``n`` rows): within shared_work, the
        # columns at an ``a`` already evaluated on the same rows are taken as made (:func:`_columns`)
        self.source = source
        self.h = float(seg.time[1] - seg.time[0])
        self.u = seg.drive[:-1]
        self.h_sum = np.empty(n)                     # h S_k
        self.h_sum[0] = 0.0
        np.cumsum(self.u, out=self.h_sum[1:])
        self.h_sum *= self.h
        self.y = seg.output - seg.output.mean()      # centred: the offset is projected out
        self.b_col = np.empty(n)                     # B*, centred
        self.g = np.empty(n)                         # direction g, centred
        self.r = self.g                              # residual: only the last evaluation, which needs no g
        self.d_col = np.empty(0)                     # D on its first K samples
        self.d_mean = 0.0
        self.d_norm2 = 0.0                           # |D - mean(D)|^2 over all n samples
        self.factors = (0.0, 0.0, 0.0)               # p, dp/da, h e p of the last evaluation
        self.f_col = np.empty(n - 1)                 # u filtered by 1/(1 - e z^-1)
        self.g_col = np.empty(n - 1)                 # u filtered twice
        self.t_col: np.ndarray | None = None         # with a bias: the ramp T = tau, centred
        if with_bias:
            self.t_col = self.h * np.arange(n, dtype=float)
            self.t_col -= self.t_col.mean()
            self.t_norm2 = _dot(self.t_col, self.t_col)
            self.t_y = _dot(self.t_col, self.y)


#: ``a tau`` beyond which ``exp(-a tau)`` is below 1e-17 relative: treated as 0.
DECAYED = 40.0


def _columns(s: _Segment, a: float, direction: bool, keep: bool = False) -> None:
    """``B*`` (centred), ``D`` on its support, the filtered drive ``F`` and, with ``direction``, ``G``.

    Within :func:`shared_work`, with ``keep``, they are kept for the segment's rows and ``a`` (the first step of
    a candidate's coarse phase): the ``linear`` and ``bias`` candidates of a delay make their first step at the same
    start on the same rows (the same numbers, copied).  Only those: copies of every step's columns, or of a long
    run's, cost more in the cache than the passes they save."""
    h = s.h
    e, p, dp = _coefficients(a, h)
    source = s.source[0] if s.source is not None and _SHARED is not None else None
    key = None if s.source is None or source is None else ("columns", id(source), s.source[1], s.n, a)
    if key is not None:
        found, kept = _shared(key, source)
        if found:
            _restore_columns(s, kept, e, direction)
            if direction and kept[1] is None:
                _share(key, source, (kept[0], s.g_col.copy(), *kept[2:]))
            return
    s.factors = (p, dp, h * e * p)
    first_order_filter(e, s.u, out=s.f_col)      # F_k = e F_{k-1} + u_k (zero initial state)
    if direction:
        first_order_filter(e, s.f_col, out=s.g_col)
    b = s.b_col
    b[0] = 0.0
    np.multiply(s.f_col, -p, out=b[1:])
    b += s.h_sum                                     # B* = h S - p F_{k-1}
    b -= _mean(b)
    support = min(s.n, int(math.ceil(DECAYED / (a * h))) + 1)
    s.d_col = -np.exp(-a * h * np.arange(support))
    s.d_mean = float(s.d_col.sum()) / s.n
    centred = s.d_col - s.d_mean
    s.d_norm2 = _dot(centred, centred) + (s.n - support) * s.d_mean ** 2
    if key is not None and keep:
        _share(key, source, (s.f_col.copy(), s.g_col.copy() if direction else None, b.copy(), s.d_col,
                                  s.d_mean, s.d_norm2, s.factors))


def _restore_columns(s: _Segment, kept: tuple, e: float, direction: bool) -> None:
    """:func:`_columns`' results kept for these rows and ``a`` (their ``G`` filtered from ``F`` where only the
    residual had been formed there), written into ``s``."""
    f_col, g_col, b_col, s.d_col, s.d_mean, s.d_norm2, s.factors = kept
    np.copyto(s.f_col, f_col)
    np.copyto(s.b_col, b_col)
    if direction:
        if g_col is None:
            first_order_filter(e, s.f_col, out=s.g_col)
        else:
            np.copyto(s.g_col, g_col)


def _dot_d(s: _Segment, x: np.ndarray) -> float:
    """``x . (D - mean D)`` for a centred ``x`` (only ``D``'s support counts)."""
    return _dot(x[:len(s.d_col)], s.d_col)


def _direction(s: _Segment, beta: float, gamma: float) -> np.ndarray:
    """The part of ``d model/d a`` outside the span of ``1``, ``D``, ``B*``, centred, in ``s.g``.

    At fixed ``b`` and ``omega0``, ``d model/da = -beta (B*/a + dw/da) - gamma D (1/a + tau)``
    with ``dw/da_k = dp F_{k-1} - h e p G_{k-2}``; the ``B*`` and ``D/a`` terms are
    projected out anyway, so ``g = -beta dw/da - gamma tau D`` (:func:`_normal_matrix`
    adds the ``B*`` term back for the Jacobian over ``b``).
    """
    _, dp, hep = s.factors
    g = s.g
    g[0] = 0.0
    np.multiply(s.f_col, -beta * dp, out=g[1:])
    s.g_col *= beta * hep                            # G is not needed after this
    g[2:] += s.g_col[:-1]
    support = len(s.d_col)
    g[:support] -= (gamma * s.h) * np.arange(support) * s.d_col
    g -= _mean(g)
    return g


@dataclasses.dataclass
class _Point:
    """Everything one evaluation at ``a`` yields (sums over segments where shared)."""

    a: float
    beta: float
    gammas: np.ndarray
    step: float = math.nan                           # Gauss--Newton step in a
    gg: float = 0.0                                  # <g, g>' (1 and D projected out)
    gb: float = 0.0                                  # <g, B*>'
    bb: float = 0.0                                  # <B*, B*>'
    delta: float = 0.0                               # with a bias: coefficient of the ramp T (bias / a)
    gt: float = 0.0                                  # <g, T>'
    bt: float = 0.0                                  # <B*, T>'
    tt: float = 0.0                                  # <T, T>'

    @property
    def b(self) -> float:
        return self.beta * self.a


def _evaluate(segs: list[_Segment], a: float, direction: bool = True, keep: bool = False) -> _Point:
    """Linear parameters at ``a`` and, with ``direction``, the Gauss--Newton step; else the residuals in ``r``.

    Per segment the offset is removed by centring and ``D`` by one Gram--Schmidt step;
    ``b`` is shared, so its column ``B~ = B* - (B*.D/D.D) D`` is projected out across
    segments, and so is the ramp ``T~`` when the segments carry one (a bias).  ``keep``: the columns kept within
    :func:`shared_work` (:func:`_columns`).
    """
    ramp = segs[0].t_col is not None
    point = _Point(a, math.nan, np.full(len(segs), math.nan))
    by = ty = 0.0
    parts = []
    for s in segs:
        _columns(s, a, direction, keep)
        dd = s.d_norm2
        bd = _dot_d(s, s.b_col) / dd
        yd = _dot_d(s, s.y) / dd
        by += _dot(s.b_col, s.y) - bd * yd * dd
        point.bb += _dot(s.b_col, s.b_col) - bd * bd * dd
        td = 0.0
        if s.t_col is not None:
            td = _dot_d(s, s.t_col) / dd
            ty += s.t_y - td * yd * dd
            point.tt += s.t_norm2 - td * td * dd
            point.bt += _dot(s.b_col, s.t_col) - bd * td * dd
        parts.append((bd, yd, td))
    det = point.bb * point.tt - point.bt ** 2 if ramp else point.bb
    if not det > (1e-12 * point.bb * point.tt if ramp else 0.0):
        return point                                 # B* (or T) in the span of the others: not identifiable here
    if ramp:
        point.beta = (by * point.tt - ty * point.bt) / det
        point.delta = (ty * point.bb - by * point.bt) / det
    else:
        point.beta = by / point.bb
    beta, delta = point.beta, point.delta
    point.gammas = np.array([yd - beta * bd - delta * td for bd, yd, td in parts])
    if not direction:
        for s, gamma in zip(segs, point.gammas):
            r = s.r
            np.multiply(s.b_col, -beta, out=r)
            r += s.y
            if s.t_col is not None:
                r -= delta * s.t_col
            r[:len(s.d_col)] -= gamma * s.d_col
            r += gamma * s.d_mean                    # r = y - beta B* [- delta T] - gamma (D - mean D)
        return point
    gr = 0.0
    for s, gamma, (bd, _, td) in zip(segs, point.gammas, parts):
        g = _direction(s, beta, gamma)
        gd = _dot_d(s, g)
        g_b = _dot(g, s.b_col)
        # g . r with r = y - beta B* [- delta T] - gamma (D - mean D) (g is centred)
        gr += _dot(g, s.y) - beta * g_b - gamma * gd
        point.gg += _dot(g, g) - gd * gd / s.d_norm2
        point.gb += g_b - gd * bd
        if s.t_col is not None:
            g_t = _dot(g, s.t_col)
            gr -= delta * g_t
            point.gt += g_t - gd * td
    if ramp:        # |P g|^2 less its part along the shared columns B~ and T~
        explained = (point.gb ** 2 * point.tt - 2 * point.gb * point.gt * point.bt
                     + point.gt ** 2 * point.bb) / det
    else:
        explained = point.gb ** 2 / point.bb
    curvature = point.gg - explained
    point.step = gr / curvature if curvature > 0 else math.nan   # nan: no descent direction, give up
    return point


def _normal_matrix(point: _Point) -> np.ndarray:
    """``J^T J`` over ``(a, b)`` with each segment's ``omega0`` and offset projected out.

    The columns are ``d model/da = g - (beta/a) B*`` (up to the span of ``1``, ``D``) and
    ``d model/db = B*/a``.
    """
    a, c = point.a, point.beta / point.a
    aa = point.gg - 2 * c * point.gb + c * c * point.bb
    ab = (point.gb - c * point.bb) / a
    return np.array([[aa, ab], [ab, point.bb / a ** 2]])


def static_gain_ceiling(segments: list[Segment]) -> float:
    """The pole (1/s) beyond which the model equals its limit ``a -> inf`` to rounding.

    That limit is a static gain with no lag: the angle ``theta_k = theta_0 + (b/a) h S_k``
    plus a step after the first sample.  The last term to vanish is the lag
    ``-(b/a^2) u_{k-1}``, ``1/(a h)`` relative to the gain's, so the ceiling is
    ``a h = 1/eps`` (machine epsilon) on the shortest sample period.
    """
    return 1.0 / (np.finfo(float).eps * min(float(seg.time[1] - seg.time[0]) for seg in segments))


def regression_start(segments: list[Segment]) -> float | None:
    """``a`` from ``zoh-ls``'s regression on the segments' angle increments, or None.

    ``Delta_{k+1} = theta_1 Delta_k + c u_k`` (``Delta_k = theta_k - theta_{k-1}``) by a
    2 x 2 normal-equation solve pooled over segments, ``a = -log(theta_1)/h``: a start
    value only (biased by the averaging and the encoder's noise, a few per cent).
    """
    found, start = _shared(("start", id(segments)), segments)
    if found:
        return start
    return _share(("start", id(segments)), segments, _regression_start(segments))


def _regression_start(segments: list[Segment]) -> float | None:
    s11 = s12 = s22 = t1 = t2 = 0.0
    for seg in segments:
        d = np.diff(seg.output)
        x, y, u = d[:-1], d[1:], seg.drive[1:-1]
        s11 += _dot(x, x)
        s12 += _dot(x, u)
        s22 += _dot(u, u)
        t1 += _dot(x, y)
        t2 += _dot(u, y)
    det = s11 * s22 - s12 * s12
    if not det > 0:
        return None
    theta1 = (t1 * s22 - t2 * s12) / det
    if not 0 < theta1 < 1:
        return None
    return -math.log(theta1) / float(segments[0].time[1] - segments[0].time[0])


def solve_separable(segments: list[Segment], a0: float, *, ceiling: float = math.inf) -> SeparableSolution | None:
    """Gauss--Newton on ``a`` with ``b``, the initial speeds and offsets projected out.

    Parameters
    ----------
    segments : list of Segment
        Angle segments on uniform clocks (:func:`is_separable`).
    a0 : float
        Starting pole in 1/s, > 0.
    ceiling : float, optional
        Pole in 1/s at which to stop when Gauss--Newton climbs past it: the solution is
        then the fit *at* the ceiling, not a minimum.  :func:`static_gain_ceiling` is
        where the model equals its limit ``a -> inf`` (a static gain) to rounding, so
        stopping there gives that limit's residual without following ``a`` to overflow
        (what ranking candidate input delays needs).

    Returns
    -------
    SeparableSolution or None
        None when the iteration leaves ``a > 0`` or does not converge (the caller
        then uses the general Levenberg--Marquardt fit and its diagnostics).
    """
    solved = _solve_pole(segments, a0, ceiling, with_bias=False)
    if solved is None:
        return None
    segs, a, point, count = solved
    # the Jacobian at the last step's start is within STEP_RTOL of the final one: enough for a covariance
    normal = _normal_matrix(point)
    final = _evaluate(segs, a, direction=False)
    if not (math.isfinite(final.b) and np.all(np.isfinite(final.gammas))):
        return None
    return SeparableSolution(a=a, b=final.b, initial_speeds=final.gammas * a,
                             residuals=segs[0].r if len(segs) == 1 else np.concatenate([s.r for s in segs]),
                             normal_matrix=normal,
                             iterations=count + 1, segment_lengths=tuple(s.n for s in segs))


def separable_residual_sum(segments: list[Segment], a0: float, *, with_bias: bool = False,
                           ceiling: float = math.inf) -> float | None:
    """The least residual sum of squares (rad^2) of the output-error fit, by :func:`solve_separable`'s
    iteration; with ``with_bias``, of the model with a constant acceleration ``bias`` too.

    On a uniform clock the bias's angle is ``(bias/a) (tau - W)``: the ramp ``tau`` from the
    segment's start, shared by all segments, plus a multiple of the initial-speed column ``W``,
    which each segment's own initial speed absorbs.  So the bias adds one linear column that
    does not depend on ``a``, projected out like ``b``'s, and the iteration stays in ``a``
    alone.  Only the residual is returned (what ranking candidate input delays needs); the
    fit itself with a bias is :func:`identify.fits.output_error.fit_output_error`'s.

    Parameters
    ----------
    segments : list of Segment
        Angle segments on uniform clocks (:func:`is_separable` without a bias).
    a0 : float
        Starting pole in 1/s, > 0.
    with_bias : bool
        Fit the bias too.
    ceiling : float, optional
        As for :func:`solve_separable`.

    Returns
    -------
    float or None
        None when the iteration fails.
    """
    solved = _solve_pole(segments, a0, ceiling, with_bias=with_bias)
    if solved is None:
        return None
    segs, a, _, _ = solved
    final = _evaluate(segs, a, direction=False)
    if not math.isfinite(final.beta):
        return None
    return sum(_dot(s.r, s.r) for s in segs)


def separable_candidate(segments: list[Segment], a0: float, *, with_bias: bool = False, ceiling: float = math.inf,
                        coarse_samples: int = COARSE_SAMPLES,
                        refine: bool = True) -> tuple[float, float, float, np.ndarray, bool] | None:
    """``(a, b, bias, residuals, refined)`` of the output-error fit by :func:`solve_separable`'s iteration.

    What scoring a candidate model needs (:mod:`identify.default.selection`): the fit's parameters and its
    residual vector (rad, segments concatenated), with or without the bias column (see
    :func:`separable_residual_sum`), no covariance.  None when the iteration fails.  The first
    steps run on about ``coarse_samples`` rows when the data hold four times as many (as
    :func:`solve_separable` does with :data:`COARSE_SAMPLES`); the last ones on all rows.  With
    ``refine=False`` the coarse steps are all: the residuals are those on all rows at the coarse
    ``a``, whose sum of squares bounds the fit's from above (``refined`` says which was done).
    """
    if not refine and sum(len(seg.time) for seg in segments) >= 4 * coarse_samples:
        coarse = _coarse_steps(segments, float(a0), with_bias, ceiling, coarse_samples, COARSE_BUDGET)
        if coarse is not None:
            return _candidate(_work_segments(segments, with_bias), coarse[0], False)
    solved = _solve_pole(segments, a0, ceiling, with_bias=with_bias, coarse_samples=coarse_samples, share=True)
    if solved is None:
        return None
    return _candidate(solved[0], solved[1], True)


def _candidate(segs: list[_Segment], a: float, refined: bool) -> tuple[float, float, float, np.ndarray, bool] | None:
    final = _evaluate(segs, a, direction=False)
    if not (math.isfinite(final.beta) and math.isfinite(final.delta)):
        return None
    return a, final.b, final.delta * a, np.concatenate([s.r for s in segs]), refined


def _coarse_steps(segments: list[Segment], a0: float, with_bias: bool, ceiling: float, coarse_samples: int,
                  budget: int | None, share: bool = True) -> tuple[float, _Point, int] | None:
    """The coarse phase: :func:`_iterate` on the first ``coarse_samples`` rows from ``a0`` to :data:`COARSE_RTOL`,
    within ``budget`` evaluations when given.  Within :func:`shared_work` (and ``share``) the same phase from the same
    start on the same segments is made once: a later call resumes where an earlier one stopped at its budget (each
    step depends on its ``a`` alone, so the steps are the ones an unbroken run makes).  Only the phase's result is
    kept, not its work arrays: arrays held between fits cost more in the cache than making them again."""
    segs = _work_segments(segments, with_bias, coarse_samples)
    if not share:
        return _iterate(segs, a0, COARSE_RTOL, ceiling, budget=budget, keep_first=True)
    key = ("coarse", id(segments), with_bias, a0, ceiling, coarse_samples)
    found, done = _shared(key, segments)
    if found:
        if done is None or done[3] or (budget is not None and done[2] >= budget):
            return None if done is None else done[:3]
        coarse = _iterate(segs, done[0], COARSE_RTOL, ceiling, budget=budget, evaluations=done[2])
    else:
        coarse = _iterate(segs, a0, COARSE_RTOL, ceiling, budget=budget, keep_first=True)
    if coarse is None:
        return _share(key, segments, None)
    a, point, count = coarse
    # finished: converged or at the ceiling (an unbroken run stops there too), not only at the budget
    finished = a == ceiling or abs(point.step) <= COARSE_RTOL * abs(a)
    _share(key, segments, (a, point, count, finished))
    return coarse


def _work_segments(segments: list[Segment], with_bias: bool, rows: int | None = None) -> list[_Segment]:
    """The work segments of ``segments`` (their first ``rows`` in all, :func:`identify.data.first_rows`), each
    knowing where its rows come from (:func:`_columns` shares what it computes on them within :func:`shared_work`)."""
    kept = segments if rows is None else first_rows(segments, rows)
    return [_Segment(s, with_bias, (segments, i)) for i, s in enumerate(kept)]


def _solve_pole(segments: list[Segment], a0: float, ceiling: float, with_bias: bool,
                coarse_samples: int = COARSE_SAMPLES, share: bool = False
                ) -> tuple[list[_Segment], float, _Point, int] | None:
    """Gauss--Newton in ``a`` (coarse phase on long recordings first): the work segments, ``a``, the
    last point and the evaluations, or None.  ``share``: the coarse phase shared within :func:`shared_work`."""
    evaluations = 0
    if sum(len(seg.time) for seg in segments) >= 4 * coarse_samples:
        coarse = _coarse_steps(segments, float(a0), with_bias, ceiling, coarse_samples, None, share)
        if coarse is not None:
            a0, evaluations = coarse[0], coarse[2]
    segs = _work_segments(segments, with_bias) if share else [_Segment(s, with_bias) for s in segments]
    fine = _iterate(segs, float(a0), STEP_RTOL, ceiling)
    if fine is None:
        return None
    a, point, count = fine
    return segs, a, point, evaluations + count


def _iterate(segs: list[_Segment], a: float, rtol: float, ceiling: float = math.inf,
             budget: int | None = None, evaluations: int = 0, keep_first: bool = False
             ) -> tuple[float, _Point, int] | None:
    """Gauss--Newton steps from ``a`` until one is below ``rtol`` relative, or ``a`` passes ``ceiling``
    (then ``a = ceiling``): ``(a, last point, evaluations)``.  With a ``budget``, the ``a`` reached
    after that many evaluations is returned even when not converged.  ``evaluations``: those made before
    ``a`` (a run resumed), counted towards :data:`MAX_ITERATIONS` and the budget.  ``keep_first``: the first step's
    columns kept within :func:`shared_work` (a coarse phase's start, which the other candidates of its delay share)."""
    keep = keep_first and evaluations == 0
    while True:
        if not (a > 0 and math.isfinite(a)) or evaluations == MAX_ITERATIONS:
            return None
        point = _evaluate(segs, a, keep=keep)
        keep = False
        evaluations += 1
        if not math.isfinite(point.step):
            return None
        a += point.step
        if a >= ceiling:
            return ceiling, point, evaluations
        if abs(point.step) <= rtol * abs(a) or evaluations == budget:
            break
    return (a, point, evaluations) if a > 0 else None
