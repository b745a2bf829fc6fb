"""Levenberg–Marquardt on the normal equations with parameters held at their lower bounds: the solver of
``oe-friction`` (:mod:`identify.fits.friction`) and of each static level's refit (:mod:`identify.fits.stiction`).

With a handful of parameters the normal equations are a tiny solve, so each iteration costs one
evaluation of the model and its sensitivities; the problem gives residuals and Jacobian
(``evaluate``), lower bounds and its degrees of freedom.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..sums import sum_squares

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

__all__ = ["levenberg_marquardt", "reachable_cost", "BoundedProblem", "FINAL_STEP"]


class BoundedProblem(Protocol):
    """What :func:`levenberg_marquardt` needs of a problem (:class:`identify.fits.friction.FrictionProblem`)."""

    dof: int

    def evaluate(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]: ...

    def lower_bounds(self) -> np.ndarray: ...


def _bounded_step(H: np.ndarray, g: np.ndarray, damping: float, at_bound: np.ndarray) -> np.ndarray:
    """Damped Gauss-Newton step (scaled); parameters at their lower bound that the step would push
    below it are held there and the step is solved again for the others (an active set)."""
    free = np.ones(len(g), bool)
    step = np.zeros(len(g))
    for _ in range(len(g) + 1):
        sub = np.ix_(free, free)
        step[:] = 0.0
        step[free] = -np.linalg.solve(H[sub] + damping * np.eye(int(free.sum())), g[free])
        blocked = free & at_bound & (step < 0)
        if not blocked.any():
            return step
        free &= ~blocked
    return step


def _scaled_normal_equations(J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Column norms of ``J``, and ``H = Js^T Js``, ``g = Js^T r`` with ``Js`` its columns scaled to unit norm."""
    norms = np.sqrt(np.einsum("ij,ij->j", J, J))
    # a column the data barely see (the initial speed of a segment that starts stuck by friction)
    # is held, not scaled up to a step of 1e14
    unseen = norms <= 1e-9 * float(norms.max(initial=0.0))
    norms[unseen] = 1.0
    Js = J / norms
    Js[:, unseen] = 0.0
    return norms, Js.T @ Js, Js.T @ r


def _reachable(H: np.ndarray, g: np.ndarray) -> float:
    """``g^T H^+ g``: the decrease of the residual sum a full Gauss–Newton step promises (by least squares)."""
    try:
        value = float(g @ np.linalg.lstsq(H, g, rcond=1e-12)[0])
    except np.linalg.LinAlgError:
        return 0.0
    return value if math.isfinite(value) else math.inf


#: Standard errors (Mahalanobis length of the step, residual variance ``cost / dof``) below which the
#: Levenberg–Marquardt step is the last one (:func:`levenberg_marquardt`).  On the 10 000-sample
#: friction runs of ``motorid bench accuracy`` the step after one of 0.14 standard errors was
#: 0.0023 of them, after one of 0.025 it was 2e-5: what stopping leaves is far below the spread.
FINAL_STEP = 0.2


def _cut_at_bound(step: np.ndarray, x: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """``step`` cut at the first lower bound it meets: that parameter lands on it (exactly), held from then on."""
    crossing = np.flatnonzero((x + step < lower) & (step < 0))
    if len(crossing):
        first = crossing[np.argmin((lower[crossing] - x[crossing]) / step[crossing])]
        step = step * ((lower[first] - x[first]) / step[first])
        step[first] = lower[first] - x[first]            # exactly on it, not a rounding away
    return step


def _converged(x: np.ndarray, x_new: np.ndarray, norms: np.ndarray, cost: float, cost_new: float) -> bool:
    """An accepted step lowered the cost by under 1e-10 of it, or moved every scaled parameter by under 1e-10."""
    small = bool(np.all(np.abs((x_new - x) * norms) <= 1e-10 * (1.0 + np.abs(x * norms))))
    return cost - cost_new <= 1e-10 * cost or small


def levenberg_marquardt(problem: BoundedProblem, x0: np.ndarray, max_iterations: int = 200,
                         final_step: float | None = None, bound: float = math.inf) -> OptimizeResult:
    """Levenberg–Marquardt on the normal equations, parameters at a bound held there (:func:`_bounded_step`).

    With a handful of parameters the normal equations (columns scaled to unit norm) are a tiny
    solve, so each iteration costs one evaluation of the response and its sensitivities.  A step that
    would take a parameter below its bound is cut where the first one meets it (that one lands on its
    bound and is held there while the steps push it outward): a step clipped at the bound instead, the
    other parameters moved as if it were free, can climb the cost (a dead zone fitted towards 0 had
    its steps rejected one after another).  Stops
    when an accepted step lowers the cost by less than 1e-10 of it or moves every scaled
    parameter by less than 1e-10, when the Gauss-Newton step promises less than 1e-12 of the
    cost (converged to rounding), or when the damping exceeds 1e12 (no descent left).  It also
    stops when the step would move the parameters by less than ``final_step`` (default
    :data:`FINAL_STEP`) standard errors: the step promises ``delta^T J^T J delta``, which is
    ``final_step^2`` times the residuals' variance ``cost / dof`` at that length.  That last step is taken without a new
    evaluation (the residuals moved by ``J delta``): near the minimum Gauss–Newton converges
    about quadratically, so what is left after it is far below ``final_step`` standard errors
    (noise-free data never stop this way: their residuals shrink with the step).

    With a ``bound`` (a residual sum), the fit also stops, with status 3, as soon as the least residual
    sum of the model linearised at the current point (``cost - g^T H^-1 g``, what a full Gauss–Newton
    step would reach) exceeds it: a candidate model that cannot come near the best one is left there.
    """
    final_step = FINAL_STEP if final_step is None else final_step
    lower = problem.lower_bounds()
    x = np.maximum(x0, lower)
    r, J = problem.evaluate(x, True)
    cost = sum_squares(r)
    damping = 1e-4
    status = 0
    normal = None
    rejected = False
    for _ in range(max_iterations):
        assert J is not None
        if normal is None:           # once per accepted step: a rejected one only raises the damping
            normal = _scaled_normal_equations(J, r)
            if bound < math.inf and cost - _reachable(normal[1], normal[2]) > bound:
                status = 3
                break
        norms, H, g = normal
        try:
            step = _bounded_step(H, g, damping, x <= lower) / norms
        except np.linalg.LinAlgError:
            damping *= 10.0
            continue
        step = _cut_at_bound(step, x, lower)
        scaled = step * norms
        predicted = -(2.0 * float(g @ scaled) + float(scaled @ H @ scaled))   # Gauss-Newton cost decrease
        if predicted <= max(1e-12 * cost, final_step ** 2 * cost / problem.dof):
            if predicted > 1e-12 * cost:
                x_new = np.maximum(x + step, lower)
                r = r + J @ (x_new - x)
                x, cost = x_new, sum_squares(r)
            status = 1
            break
        x_new = np.maximum(x + step, lower)
        with np.errstate(over="ignore", invalid="ignore"):
            r_new = problem.evaluate(x_new, False)[0]      # the sensitivities only once the step is taken
        cost_new = sum_squares(r_new)
        if np.isfinite(cost_new) and cost_new < cost:
            with np.errstate(over="ignore", invalid="ignore"):
                r_new, J_new = problem.evaluate(x_new, True)
            done = _converged(x, x_new, norms, cost, cost_new)
            x, r, J, cost = x_new, r_new, J_new, cost_new
            normal = None
            if not rejected:         # a step taken right after a rejected one keeps its damping (no zigzag)
                damping = max(damping / 5.0, 1e-12)
            rejected = False
            if done:
                status = 1
                break
        else:
            rejected = True
            damping *= 10.0
            if damping > 1e12:
                status = 2
                break
    from scipy.optimize import OptimizeResult  # imported when used: slow to import
    return OptimizeResult(x=x, fun=r, jac=J, cost=0.5 * cost, status=status)


def reachable_cost(r: np.ndarray, J: np.ndarray) -> float:
    """The residual sum a full Gauss–Newton step from residuals ``r`` with Jacobian ``J`` would reach."""
    _, H, g = _scaled_normal_equations(J, r)
    return sum_squares(r) - _reachable(H, g)

