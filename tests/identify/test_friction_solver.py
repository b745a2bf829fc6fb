"""The friction fit's Levenberg–Marquardt (:mod:`identify.fits.friction_solver`) on problems with known answers."""
import numpy as np
import pytest

from identify.fits.friction_solver import levenberg_marquardt


class _Linear:
    """``min |A x - y|^2`` with lower bounds: a problem whose constrained minimum scipy computes exactly."""

    def __init__(self, A, y, lower):
        self.A, self.y, self.lower = A, y, np.asarray(lower, float)
        self.dof = len(y) - A.shape[1]
        self.evaluations = 0

    def evaluate(self, x, jacobian):
        self.evaluations += 1
        return self.A @ x - self.y, (self.A if jacobian else None)

    def lower_bounds(self):
        return self.lower


@pytest.mark.parametrize("seed", range(5))
def test_a_step_across_a_bound_stops_on_it_and_reaches_the_bounded_minimum(seed):
    # correlated columns and a minimum beyond the bound of the second: a step clipped there (the other parameters
    # moved as if it were free) climbs the cost, a step cut where it meets the bound descends
    from scipy.optimize import lsq_linear
    rng = np.random.default_rng(seed)
    n = 200
    base = rng.normal(size=n)
    A = np.column_stack([base, base + 0.05 * rng.normal(size=n), rng.normal(size=n)])
    y = A @ np.array([1.0, -1.0, 0.5]) + 1e-3 * rng.normal(size=n)
    lower = [-np.inf, 0.0, -np.inf]
    problem = _Linear(A, y, lower)
    res = levenberg_marquardt(problem, np.array([0.0, 0.5, 0.0]), final_step=0.0)
    reference = lsq_linear(A, y, bounds=(lower, np.inf), tol=1e-14).x
    assert res.x[1] == 0.0                           # on the bound exactly
    # a quadratic cost: the bounded minimum to rounding (scaled by the conditioning of the correlated columns)
    np.testing.assert_allclose(res.x, reference, rtol=1e-9, atol=1e-9)
    # the first point, then two evaluations per step taken (its residuals, then its sensitivities): the cut
    # step, the one with the parameter held, the one that finds nothing left; clipping instead of cutting
    # climbs the cost and has its steps rejected until the damping shrinks them (10 evaluations)
    assert problem.evaluations <= 7
