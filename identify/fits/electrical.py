"""``oe-electrical``: output error of the motor behind an electrical lag, ``b / ((s + a)(tau_e s + 1))``.

The structure is :class:`identify.model_structures.second_order.SecondOrder`.  For fixed poles
``a`` and ``c = 1/tau_e`` the output (angle or speed) is linear in ``b``, the bias ``d`` and each
segment's initial speed, initial ``b i`` and angle offset, so those are solved exactly by least
squares and only the two poles are searched (variable projection: Golub and Pereyra, *Inverse
Problems* 19 (2003) R1-R26), in logarithms so both stay positive, from the first-order ``oe`` fit's
pole and a short grid of ``tau_e`` from a fifth of a sample to twenty samples.
The covariance is :func:`identify.checks.uncertainty.robust_covariance`'s on the full Jacobian
(``a, b, tau_e, d`` and the nuisances), by central differences in the poles.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

from ..checks.uncertainty import robust_covariance
from ..checks.validation import segment_fit_percent
from ..comparison import LEVEL, MAX_AUTO_DELAY, Candidate, CandidateFit, choose_delay
from ..data import (
    DEFAULT_INPUT_DELAY,
    Segment,
    as_recordings,
    check_excitation,
    check_input_delay,
    residual_unit,
)
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..model_structures import ModelStructure
from ..model_structures.second_order import segment_columns
from .oe_common import segment_models, segments_at

__all__ = ["fit_output_error_electrical", "fit_electrical_from", "structure_candidate", "TAU_GRID_SAMPLES", "RESTARTS"]

#: Start values of ``tau_e``, in sample periods.
TAU_GRID_SAMPLES = (0.3, 1.0, 3.0, 10.0, 30.0)


class _Projection:
    """The projected problem at poles ``(a, c)``: every linear parameter solved, the residual left."""

    def __init__(self, segments: Sequence[Segment]):
        self.segments = list(segments)
        self.outputs = np.concatenate([s.output for s in self.segments])
        self._last: tuple[tuple[float, float], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None

    def solve(self, a: float, c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual, the linear solution ``[b, d, nuisances...]`` and the design matrix at ``(a, c)`` (the last
        poles' kept: the search ends where it last evaluated, and the candidate asks for that point again)."""
        if self._last is not None and self._last[0] == (a, c):
            return self._last[1]
        self._last = ((a, c), self._solve(a, c))
        return self._last[1]

    def _solve(self, a: float, c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        blocks, shared = [], []
        for seg in self.segments:
            forced, free = segment_columns(a, c, seg)
            shared.append(forced)
            blocks.append(free)
        n = sum(len(s.time) for s in self.segments)
        m = sum(b.shape[1] for b in blocks)
        X = np.zeros((n, 2 + m))
        X[:, :2] = np.vstack(shared)
        row = col = 0
        for block in blocks:
            X[row:row + len(block), 2 + col:2 + col + block.shape[1]] = block
            row += len(block)
            col += block.shape[1]
        if not np.all(np.isfinite(X)):
            return np.full(n, np.inf), np.full(X.shape[1], np.nan), X
        scale = np.linalg.norm(X, axis=0)
        scale[scale == 0] = 1.0
        coef, *_ = np.linalg.lstsq(X / scale, self.outputs, rcond=None)
        coef = coef / scale
        return self.outputs - X @ coef, coef, X


#: Bounds of ``tau_e`` searched, in sample periods: below the lower one the pole is a fraction of a
#: sample's delay (the selection's ``MIN_TAU_SAMPLES`` is well above it), above the upper one a second
#: slow pole, not a driver's lag.
TAU_BOUNDS_SAMPLES = (0.02, 500.0)
#: Evaluations of the projected residual one fit may take.
MAX_EVALUATIONS = 80
#: Further starts a search tries when it ends with ``tau_e`` at its lower bound.
RESTARTS = 2


def _fit_poles(problem: _Projection, starts: Sequence[tuple[float, float]], h: float,
               tolerance: float = 1e-10, quick: bool = False) -> tuple[float, float]:
    """The poles ``(a, c)`` of least projected residual: a trust-region search in ``log a`` and
    ``log(c / a) >= 0`` (the electrical pole the faster one: the model is the same with the two swapped
    and ``b`` rescaled, so this names them), ``c`` at most the bound of :data:`TAU_BOUNDS_SAMPLES`, from the
    best of ``starts``, to ``tolerance`` (relative, in the poles).

    ``quick``: when the first start's pole with ``tau_e`` at its lower bound fits better than every start,
    that is the answer (no search): the data favour a lag shorter than any start."""
    from scipy.optimize import least_squares  # imported when used: slow to import
    c_max = 1.0 / (TAU_BOUNDS_SAMPLES[0] * h)

    def poles(z: np.ndarray) -> tuple[float, float]:
        a = math.exp(z[0])
        return a, min(a * math.exp(z[1]), c_max)

    def residual(z: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            r = problem.solve(*poles(z))[0]
        return r if np.all(np.isfinite(r)) else np.full_like(r, 1e50)
    low, high = np.array([-30.0, 0.0]), np.array([30.0, 60.0])
    points = [np.clip([math.log(a), math.log(c / a)], low, high) for a, c in starts
              if min(a, c) > 0 and math.isfinite(a) and math.isfinite(c)]
    if not points:
        raise NotIdentifiableError("oe-electrical: no finite start value for the poles")
    costs = [float(np.dot(r, r)) for r in map(residual, points)]
    at_bound = np.array([points[0][0], math.log(c_max) - points[0][0]])   # the first start's pole, c at its bound
    if quick and at_bound[1] >= 0 and float(np.dot(*(2 * [residual(at_bound)]))) <= min(costs):
        return poles(at_bound)
    # from the best start; a search that ends with tau_e at its lower bound (the lag gone) may have slid off a
    # poor first-order pole (a PRBS behind a delay: a = 4.6 for 25), so the next starts are tried too
    found: list[tuple[float, np.ndarray]] = []
    for j in np.argsort(costs)[:1 + RESTARTS]:
        with np.errstate(all="ignore"):
            res = least_squares(residual, points[j], bounds=(low, high), method="trf",
                                xtol=tolerance, ftol=tolerance * 1e-2, max_nfev=MAX_EVALUATIONS)
        found.append((float(res.cost), res.x))
        best = min(found, key=lambda f: f[0])[1]
        if poles(best)[1] < c_max * (1.0 - 1e-6):
            break
    return poles(best)


def _starts(a0: float, h: float) -> list[tuple[float, float]]:
    """The first-order pole with ``tau_e`` on :data:`TAU_GRID_SAMPLES`."""
    return [(a0, 1.0 / (k * h)) for k in TAU_GRID_SAMPLES]


def structure_candidate(recs: list[Recording], segs: list[Segment], delay: int, structure: ModelStructure, *,
                        refine: bool = True, fix_bias: bool = False,
                        starts: Sequence[tuple[float, float]] = ()) -> CandidateFit:
    """The second-order structure fitted at ``delay`` on ``segs``, as the default's selection scores it.

    ``starts``: start values ``(a, 1/tau_e)`` (a neighbouring delay's fit) tried besides the first-order
    pole with the grid of :data:`TAU_GRID_SAMPLES`; ``refine`` False: to a relative 1e-6 only (a first
    look).  The candidate's ``start`` is its ``(a, 1/tau_e)``."""
    name = structure.name
    try:
        problem = _Projection(segs)
        h = recs[0].sample_period
        near = [p for a_, c_ in starts for p in ((a_, c_), (a_, 1.0 / (1.0 / c_ + h)))]   # one sample less delay
        a, c = _fit_poles(problem, _starts(_start_pole(segs, recs), h) + near, h, 1e-10 if refine else 1e-6,
                          quick=not refine)
        r, coef, _ = problem.solve(a, c)
    except (NotIdentifiableError, np.linalg.LinAlgError, ValueError) as exc:
        return CandidateFit(Candidate(name, delay, math.nan, math.nan, math.nan, note=str(exc)), None)
    return CandidateFit(Candidate(name, delay, a, float(coef[0]), float(r @ r)), r, float(coef[1]), start=(a, c))



def _start_pole(segs: list[Segment], recs: list[Recording]) -> float:
    """The first-order model's pole as a start (``zoh-ls``'s regression, else the general start value)."""
    from .start import initial_guess
    from .variable_projection import regression_start
    start = regression_start(segs) if all(s.kind == "angle" for s in segs) else None
    if start is None or not (start > 0 and math.isfinite(start)):
        start = float(initial_guess(recs, segs)[0])
    return start if start > 0 and math.isfinite(start) else 10.0


def fit_output_error_electrical(recordings: Recording | list[Recording], *,
                                input_delay: int | str = DEFAULT_INPUT_DELAY) -> Estimate:
    """Output error of ``b / ((s + a)(tau_e s + 1))`` with a bias (module docstring).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for every estimator.
    input_delay : int or "auto"
        Whole samples of input delay, or ``"auto"`` (default, :data:`identify.data.DEFAULT_INPUT_DELAY`):
        the shortest within the noise of the best over ``0 ... 10``.
    Returns
    -------
    Estimate
        ``method = "oe-electrical"``, structure ``second-order``; ``extra`` holds
        ``electrical_time_constant`` (s) and ``bias`` (rad/s^2); covariance over
        ``("a", "b", "electrical_time_constant", "bias")``.

    Examples
    --------
    >>> from motorsim import Experiment, Motor, Multisine, SimRig
    >>> rec = SimRig(Motor(25.0, 3.0, electrical_time_constant=0.004)).run(
    ...     Experiment(Multisine((5.0, 40.0, 150.0), (80, 60, 50), (0, 1, 2)), 0.001, 4.0))
    >>> est = fit_output_error_electrical(rec)
    >>> print(f"a = {est.a:.3f}, b = {est.b:.4f}, tau_e = {est.extra['electrical_time_constant']:.5f} s")
    a = 25.000, b = 3.0000, tau_e = 0.00400 s
    """
    return fit_electrical_from(recordings, input_delay=input_delay)


def fit_electrical_from(recordings: Recording | list[Recording], *, input_delay: int | str = DEFAULT_INPUT_DELAY,
                        starts: Sequence[tuple[float, float]] = ()) -> Estimate:
    """:func:`fit_output_error_electrical` with ``starts``, start values ``(a, 1/tau_e)`` of the poles tried
    besides the first-order pole with the grid of lags: for a caller that knows a good first-order ``a``
    (from a poor regression start the search can end on the two poles equal, far from a short lag)."""
    from ..model_structures import structure
    recs = as_recordings(recordings)
    check_excitation(recs, 3)
    delay_option = check_input_delay(input_delay)
    if delay_option == "auto":
        def fit_at(segs: list[Segment], d: int, refine: bool) -> CandidateFit:
            return structure_candidate(recs, segs, d, structure("second-order"))
        delay = choose_delay(recs, fit_at, MAX_AUTO_DELAY, LEVEL, "oe-electrical")
    else:
        delay = int(delay_option)
    segs = segments_at(recs, delay)
    problem = _Projection(segs)
    h = recs[0].sample_period
    a, c = _fit_poles(problem, _starts(_start_pole(segs, recs), h) + [(float(x), float(y)) for x, y in starts], h)
    r, coef, X = problem.solve(a, c)
    b, d = float(coef[0]), float(coef[1])
    n, k = len(r), X.shape[1] + 2
    if n <= k + 1:
        raise NotIdentifiableError(f"recording is too short: {n} samples for {k} parameters")
    J = _jacobian(problem, a, c, coef, X)
    s2 = float(r @ r) / (n - k)
    cov, how = robust_covariance(J, r, s2, 4)
    models = segment_models(segs, r)
    return Estimate(method="oe-electrical", structure="second-order", a=a, b=b, n_samples=n,
                    sample_period=recs[0].sample_period, residual_rms=float(np.sqrt(np.mean(r * r))),
                    fit_percent=segment_fit_percent(segs, models), covariance=cov,
                    param_names=("a", "b", "electrical_time_constant", "bias"),
                    extra={"electrical_time_constant": 1.0 / c, "bias": d}, input_delay=delay,
                    residual_unit=residual_unit(segs), input_unit=recs[0].input_unit,
                    input_limit=recs[0].input_limit, covariance_method=how)


def _jacobian(problem: _Projection, a: float, c: float, coef: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Columns ``(a, b, tau_e, d, nuisances...)`` of the model output's Jacobian at the optimum."""
    cols = []
    for which in (0, 1):
        step = 1e-6
        up = [a, c]
        down = [a, c]
        up[which] *= 1 + step
        down[which] *= 1 - step
        X_up = problem.solve(*up)[2]
        X_down = problem.solve(*down)[2]
        cols.append((X_up - X_down) @ coef / (2 * step * [a, c][which]))
    d_a, d_c = cols
    d_tau = d_c * (-c * c)                     # d/d tau_e = d/dc * dc/dtau_e, c = 1/tau_e
    return np.column_stack([d_a, X[:, 0], d_tau, X[:, 1], X[:, 2:]])
