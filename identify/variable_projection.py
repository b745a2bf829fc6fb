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
columns.  One evaluation costs two ``lfilter`` passes (``w`` and ``dw/da``) and a
few vector operations, written into arrays allocated once.

The minimiser is the one of :class:`identify.output_error.OutputErrorProblem`
(the same model and residual), so the estimates agree to rounding; the
projected Jacobian over ``(a, b)`` is returned for the covariance.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import OptimizeResult
from scipy.signal import lfilter

from .data import Segment
from .sensitivity import phi_functions

__all__ = ["SeparableSolution", "solve_separable", "is_separable"]

#: Relative step in ``a`` after which the iteration stops.  Gauss--Newton converges
#: quadratically here (small residuals), so the error left after such a step is of
#: order its square, below rounding.
STEP_RTOL = 1e-8
#: Gauss--Newton iterations before giving up (the caller then falls back to Levenberg--Marquardt).
MAX_ITERATIONS = 30


def _dot(x: np.ndarray, y: np.ndarray) -> float:
    """``x . y`` by numpy's own loop: a multi-threaded BLAS ``dot`` is many times slower on a busy machine."""
    return float(np.einsum("i,i->", x, y))


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
        return np.split(self.residuals, np.cumsum(self.segment_lengths)[:-1])

    def optimize_result(self) -> OptimizeResult:
        """The solution as ``scipy.optimize.least_squares`` reports one (``x = (a, b)``, ``fun``, ``nfev``)."""
        return OptimizeResult(x=np.array([self.a, self.b]), fun=self.residuals, nfev=self.iterations, status=1,
                              success=True, message="relative step in a below STEP_RTOL")

    def covariance(self, noise_variance: float) -> np.ndarray:
        """``noise_variance (J^T J)^{-1}`` over ``(a, b)``, ``inf`` when ``J^T J`` is singular.

        Scaled to unit diagonal first, like :func:`identify.uncertainty.covariance_from_jacobian`
        (whose singular-value threshold 1e-13 is 1e-26 on the eigenvalues here).
        """
        scale = np.sqrt(np.diag(self.normal_matrix))
        if not (np.all(scale > 0) and np.all(np.isfinite(self.normal_matrix))):
            return np.full((2, 2), math.inf)
        scaled = self.normal_matrix / np.outer(scale, scale)
        eig = np.linalg.eigvalsh(scaled)
        if eig[0] <= eig[-1] * 1e-26:
            return np.full((2, 2), math.inf)
        return noise_variance * np.linalg.inv(scaled) / np.outer(scale, scale)


class _Segment:
    """Per-segment constants and work arrays (allocated once per fit)."""

    def __init__(self, seg: Segment):
        n = len(seg.time)
        self.n = n
        self.h = float(seg.time[1] - seg.time[0])
        self.u = np.ascontiguousarray(seg.drive[:-1], dtype=float)
        self.tau = seg.time - seg.time[0]
        self.h_sum = np.empty(n)                     # h S_k
        self.h_sum[0] = 0.0
        np.cumsum(self.u, out=self.h_sum[1:])
        self.h_sum *= self.h
        self.y = seg.output - seg.output.mean()      # centred: the offset is projected out
        self.w_col = np.empty(n)                     # W, centred
        self.w_da = np.empty(n)                      # dW/da
        self.b_col = np.empty(n)                     # B, centred
        self.b_da = np.empty(n)                      # dB/da
        self.speed = np.empty(n)                     # w per unit b
        self.work = np.empty(n)


def _columns(s: _Segment, a: float) -> None:
    """Fill ``W``, ``dW/da``, ``B``, ``dB/da`` of one segment at ``a`` (``W`` and ``B`` centred)."""
    h = s.h
    p1, _, d1, _ = (float(f[0]) for f in phi_functions(np.array([a * h])))
    e = math.exp(-a * h)
    p, dp = h * p1, h * h * d1
    m, w_da = s.work, s.w_da
    np.multiply(s.tau, -a, out=m)
    np.expm1(m, out=m)                               # M = exp(-a tau) - 1
    np.multiply(s.tau, m, out=w_da)
    w_da += s.tau                                    # tau exp(-a tau)
    w_da /= a
    w_da += m / (a * a)                              # dW/da = tau E / a + M / a^2
    np.divide(m, -a, out=s.w_col)                    # W = -M / a
    speed = s.speed
    speed[0] = 0.0
    speed[1:], _ = lfilter([p], [1.0, -e], s.u, zi=[0.0])
    np.subtract(s.h_sum, speed, out=s.b_col)
    s.b_col /= a                                     # B = (h S - w) / a
    # dw/da: w'_{k+1} = e w'_k - h e w_k + dp u_k
    np.multiply(speed[:-1], -h * e, out=m[:-1])
    m[:-1] += dp * s.u
    s.b_da[0] = 0.0
    s.b_da[1:], _ = lfilter([1.0], [1.0, -e], m[:-1], zi=[0.0])
    s.b_da += s.b_col
    s.b_da /= -a                                     # dB/da = -(B + dw/da) / a
    s.b_col -= s.b_col.mean()
    s.w_col -= s.w_col.mean()


def _evaluate(segs: list[_Segment], a: float) -> tuple[float, np.ndarray, float, float]:
    """Linear parameters at ``a``: ``(b, omega0s, g.r, |P g|^2)``; leaves ``r`` in each segment's ``work``.

    Per segment the offset is removed by centring and ``W`` by one Gram--Schmidt step;
    ``b`` is shared, so its column ``B~ = B - (B.W/W.W) W`` is projected out across segments.
    """
    by = bb = 0.0
    parts = []
    for s in segs:
        _columns(s, a)
        ww = _dot(s.w_col, s.w_col)
        bw = _dot(s.b_col, s.w_col) / ww
        yw = _dot(s.y, s.w_col) / ww
        by += _dot(s.b_col, s.y) - bw * yw * ww
        bb += _dot(s.b_col, s.b_col) - bw * bw * ww
        parts.append((ww, bw, yw))
    b = by / bb
    omega0 = np.empty(len(segs))
    gr = gg = gb = 0.0
    for i, (s, (ww, bw, yw)) in enumerate(zip(segs, parts)):
        w0 = yw - b * bw
        omega0[i] = w0
        r = s.work
        np.multiply(s.b_col, -b, out=r)
        r += s.y
        r -= w0 * s.w_col                            # r = y - b B - omega0 W (all centred)
        g = _direction(s, b, w0)
        gw = _dot(g, s.w_col)
        gr += _dot(g, r)
        gg += _dot(g, g) - gw * gw / ww
        gb += _dot(g, s.b_col) - gw * bw
    gg -= gb * gb / bb
    return b, omega0, gr, gg


def _direction(s: _Segment, b: float, omega0: float) -> np.ndarray:
    """``g = b dB/da + omega0 dW/da``, centred, in the segment's ``speed`` array (no longer needed)."""
    g = s.speed
    np.multiply(s.b_da, b, out=g)
    g += omega0 * s.w_da
    g -= g.mean()
    return g


def solve_separable(segments: list[Segment], a0: float) -> SeparableSolution | None:
    """Gauss--Newton on ``a`` with ``b``, the initial speeds and offsets projected out.

    Parameters
    ----------
    segments : list of Segment
        Angle segments on uniform clocks (:func:`is_separable`).
    a0 : float
        Starting pole in 1/s, > 0.

    Returns
    -------
    SeparableSolution or None
        None when the iteration leaves ``a > 0`` or does not converge (the caller
        then uses the general Levenberg--Marquardt fit and its diagnostics).
    """
    segs = [_Segment(s) for s in segments]
    a = float(a0)
    evaluations = 0
    while True:
        if not (a > 0 and math.isfinite(a)) or evaluations == MAX_ITERATIONS:
            return None
        b, omega0, gr, gg = _evaluate(segs, a)
        evaluations += 1
        if not (gg > 0 and math.isfinite(gr)):
            return None
        step = gr / gg
        a += step
        if abs(step) <= STEP_RTOL * abs(a):
            break
    if not a > 0:
        return None
    b, omega0, _, _ = _evaluate(segs, a)
    return SeparableSolution(a=a, b=b, initial_speeds=omega0,
                             residuals=np.concatenate([s.work for s in segs]),
                             normal_matrix=_normal_matrix(segs, b, omega0), iterations=evaluations + 1,
                             segment_lengths=tuple(s.n for s in segs))


def _normal_matrix(segs: list[_Segment], b: float, omega0: np.ndarray) -> np.ndarray:
    """``J^T J`` over ``(a, b)`` with ``omega0`` and the offsets projected out, per segment, summed."""
    out = np.zeros((2, 2))
    for s, w0 in zip(segs, omega0):
        g = _direction(s, b, w0)
        ww = _dot(s.w_col, s.w_col)
        cols = (g, s.b_col)
        proj = [_dot(c, s.w_col) / ww for c in cols]
        for i in range(2):
            for j in range(i, 2):
                out[i, j] += _dot(cols[i], cols[j]) - proj[i] * proj[j] * ww
        out[1, 0] = out[0, 1]
    return out
