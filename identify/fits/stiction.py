"""Static friction (stiction): the break-away level of ``oe-friction``, fitted by a profile.

A shaft with stiction needs a force ``|b u + d|`` above the static level ``c_s`` (``>= c``, the
Coulomb friction) to break away from rest, and a speed that reaches zero sticks while the force
is at most ``c_s``.  The level moves only those discrete decisions: with the input held over each
interval the response is piecewise constant in ``c_s``, changing only where ``c_s`` crosses one of
the forces ``|b u_k + d|`` the data apply.  So ``c_s`` has no derivative to follow; it is fitted by
a profile over those candidate levels (:func:`candidate_levels`), each level's continuous
parameters (``a``, ``b``, ``c``, ``d``, the initial speeds) refitted by the friction fit's own
Levenberg–Marquardt.

The search (:func:`profile_static_level`) ranks the candidate levels by the cost one Gauss–Newton step
from the current fit would reach (the continuous parameters refitted, linearised), refits the best
:data:`REFITS_PER_ROUND` of them, and repeats from the best refit, near its level, until no refit
improves.  Its interval is the profile's: the levels whose refitted cost is within :data:`PROFILE_QUANTILE`
residual variances of the least (the likelihood-ratio interval of one parameter, Venzon & Moolgavkar
1988), the residual variance taken from the batch means of the residuals (an encoder's rounding stays
put while the shaft sticks, so the residuals are correlated), widened to the forces between which those
levels lie.  The ``a`` and ``b`` of every level in that bracket are kept too: they widen ``a``'s and
``b``'s intervals to cover every level the data allow.  :func:`stiction_evident` is the default's cheap
test of whether the search is worth making.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Protocol

import numpy as np

from ..comparison import BLOCKS, CLOSE, LEVEL, statistic
from ..sums import sum_squares

__all__ = ["StaticProfile", "candidate_levels", "profile_static_level", "search_static_level", "stiction_evident",
           "MAX_LEVELS", "WIDE_LEVELS", "WIDE_REFITS",
           "PROFILE_QUANTILE", "MAX_ROUNDS", "GATE_LEVELS", "GATE_ROWS", "GATE_FACTOR", "GATE_REFITS", "LOCAL_LEVELS",
           "REFITS_PER_ROUND", "MAX_BRACKET_REFITS"]

#: Rows (the first of every segment) on which the default tests whether a static level is worth fitting.
GATE_ROWS = 1000

#: Most candidate levels one scan evaluates (quantiles of the distinct forces above the friction level).
MAX_LEVELS = 64
#: Residual variances of cost within which a level is in the profile's bracket: the 95 % quantile of
#: chi-square with one degree of freedom.
PROFILE_QUANTILE = 3.841
#: Scan-and-refit rounds of the search at most.
MAX_ROUNDS = 6
#: The second, wider scan of :func:`profile_static_level`: its levels and its refits per round.
WIDE_LEVELS = 128
WIDE_REFITS = 24
#: Refits at most on either side of the best level while the bracket is widened.
MAX_BRACKET_REFITS = 4
#: Levels next above the friction (and as many spread up to three times it) that :func:`stiction_evident` tries.
GATE_LEVELS = 3
#: Share of the selection's threshold the gate's statistic must reach: on a thousand rows the 32 batch means
#: are 31 samples each and the statistic has a fraction of its power on all rows.  Measured at the first
#: 1000 rows: 6.3-2600 with static friction 1.6-2 times the friction (a sine, a multisine, 1000 and 360
#: counts), 1.0 on the position loop of ``motorid bench selection`` (a random load torque, no stiction).
GATE_FACTOR = 0.25
#: Levels the gate refits (those of least predicted cost).
GATE_REFITS = 2
#: Levels on either side of the current one that the search's later rounds and the bracket try.
LOCAL_LEVELS = 12
#: Levels refitted per round of the search: those of least predicted cost.
REFITS_PER_ROUND = 8


class _Problem(Protocol):
    """What the profile needs of the friction fit's problem (:class:`identify.fits.friction.FrictionProblem`)."""

    segments: list
    static: float
    n_global: int
    dof: int

    def unpack(self, x: np.ndarray) -> tuple[float, float, float, float, float]: ...

    def at_level(self, static: float) -> None: ...

    def residuals(self, x: np.ndarray) -> np.ndarray: ...

    def evaluate(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]: ...

    def reachable_cost(self, r: np.ndarray, J: np.ndarray | None) -> float: ...


@dataclasses.dataclass(frozen=True)
class StaticProfile:
    """The fitted static level and what the profile says about it.

    Attributes
    ----------
    level : float
        The static friction ``c_s`` (rad/s^2), at least the fitted friction ``c``.
    low, high : float
        The profile's bracket of ``c_s`` (rad/s^2): from the largest force that sticks at its lowest level
        (the friction level at least) to the least force that breaks away at its highest (``inf`` when
        none does).
    ranges : dict of str to (float, float)
        ``a`` and ``b`` over the levels in the bracket (their refits).
    refits : int
        Levels the profile refitted.
    """

    level: float
    low: float
    high: float
    ranges: dict[str, tuple[float, float]]
    refits: int


def _forces(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """The distinct forces ``|b v_k + d|`` the data apply at the parameters ``x``, sorted."""
    a, b, c, d, zone = problem.unpack(x)
    forces = []
    for seg in problem.segments:
        u = np.asarray(seg.drive, dtype=float)[:-1]
        v = np.where(np.abs(u) > zone, u - np.sign(u) * zone, 0.0)
        forces.append(np.abs(b * v + d))
    return np.unique(np.concatenate(forces)) if forces else np.zeros(0)


def candidate_levels(problem: _Problem, x: np.ndarray, max_levels: int = MAX_LEVELS) -> np.ndarray:
    """The levels that give the distinct responses, at the parameters ``x``: the friction ``c``, and midway
    between consecutive distinct forces ``|b v_k + d|`` above it (at most :data:`MAX_LEVELS`, evenly among
    them by rank).  Midway, a refit that moves ``b`` and ``d`` a little keeps the same decisions."""
    c = problem.unpack(x)[2]
    found = _forces(problem, x)
    found = found[found >= c]
    middles = 0.5 * (found[:-1] + found[1:])
    if len(middles) > max_levels:
        middles = middles[np.unique(np.round(np.linspace(0, len(middles) - 1, max_levels)).astype(int))]
    return np.concatenate([[c], middles])


def _predicted_costs(problem: _Problem, x: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """At each level, the residual sum one Gauss–Newton step from ``x`` would reach (the continuous parameters
    refitted, linearised): the profile's cost, roughly, for one evaluation with sensitivities per level."""
    costs = np.empty(len(levels))
    with np.errstate(over="ignore", invalid="ignore"):
        for j, level in enumerate(levels):
            problem.at_level(float(level))
            r, J = problem.evaluate(x, True)
            costs[j] = problem.reachable_cost(r, J)
    return np.where(np.isfinite(costs), costs, np.inf)


def _noise_variance(r: np.ndarray, dof: int, blocks: int = 32) -> float:
    """The residual variance a cost difference is measured in: ``r.r / dof``, times the ratio of the
    batch means' variance to the white one when the residuals are correlated (never less than 1)."""
    white = float(r @ r) / max(dof, 1)
    n = len(r) // blocks
    if n < 2:
        return white
    sums = r[:n * blocks].reshape(blocks, n).sum(axis=1)
    ratio = float(np.var(sums, ddof=1)) / max(n * float(np.var(r[:n * blocks])), 1e-300)
    return white * max(ratio, 1.0)


def stiction_evident(problem: _Problem, x: np.ndarray, refit: Callable[[Any, np.ndarray], Any],
                     level: float = LEVEL) -> bool:
    """Whether a static level above the friction fits the data better than the fit at ``x`` without one
    (``problem.static`` 0) beyond the noise, as the default's selection would judge it.

    The first :data:`GATE_LEVELS` candidate levels above the friction and as many spread up to three times
    it are ranked by the cost one Gauss–Newton step would reach; the best :data:`GATE_REFITS` of them are
    refitted (``refit(problem, x0)``, as in :func:`profile_static_level`), and the best refit is compared with
    the fit without a static level refitted on the same rows, by the selection's batch-means statistic
    (:func:`identify.comparison.statistic`), which must reach :data:`GATE_FACTOR` times the threshold of one
    more parameter at ``level``, and by the residual sum, which must drop by
    :data:`~identify.comparison.CLOSE` of it at least.  A cheap test (a few evaluations on the rows the caller
    gives, e.g. the first thousand) that lets the default leave the profile out where the data do not call for
    it.  Leaves ``problem.static`` at 0.
    """
    from scipy.special import fdtri  # the F quantile, lighter than scipy.stats
    problem.at_level(0.0)
    r0 = np.array(problem.residuals(x), dtype=float)
    cost = float(r0 @ r0)
    levels = candidate_levels(problem, x)[1:]
    friction = float(problem.unpack(x)[2])
    spread = levels[levels <= 3.0 * friction + 1e-300]
    if len(spread) > GATE_LEVELS:
        spread = spread[np.unique(np.round(np.linspace(GATE_LEVELS, len(spread) - 1, GATE_LEVELS)).astype(int))]
    chosen = np.unique(np.concatenate([levels[:GATE_LEVELS], spread]))
    if not len(chosen) or not math.isfinite(cost):
        return False
    predicted = _predicted_costs(problem, x, chosen)
    order = [j for j in np.argsort(predicted)[:GATE_REFITS] if predicted[j] < (1.0 - 0.5 * CLOSE) * cost]
    if not order:                                   # not even the linearised step comes near
        problem.at_level(0.0)
        return False
    # on these rows, the fit without a static level is refitted too: what a level adds, not what the rows do
    problem.at_level(0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        base = refit(problem, x)
    if _cost_of(base) < cost:
        x, r0, cost = base.x, np.asarray(base.fun, dtype=float), _cost_of(base)
    best = np.asarray(r0)
    for j in order:
        problem.at_level(float(chosen[j]))
        with np.errstate(over="ignore", invalid="ignore"):
            fitted = refit(problem, x)
        if _cost_of(fitted) < float(best @ best):
            best = np.asarray(fitted.fun, dtype=float)
    problem.at_level(0.0)
    drop = cost - float(best @ best)
    if not drop >= CLOSE * cost:
        return False
    return bool(statistic(r0 - best, drop, best) >= GATE_FACTOR * float(fdtri(1, BLOCKS - 1, 1.0 - level)))


def _cost_of(result: Any) -> float:
    value = sum_squares(result.fun)
    return value if math.isfinite(value) and np.all(np.isfinite(result.x)) and result.x[0] > 1e-8 else math.inf


def profile_static_level(problem: _Problem, res: Any,
                         refit: Callable[[Any, np.ndarray], Any]) -> tuple[Any, StaticProfile]:
    """:func:`search_static_level` from two scans, :data:`MAX_LEVELS` levels with :data:`REFITS_PER_ROUND`
    refits and :data:`WIDE_LEVELS` with :data:`WIDE_REFITS`, the fit of least cost kept: the cost over the
    levels has local minima, and each scan alone stopped in one on some of the tests' runs (a sine through
    static friction twice the sliding level, at 1000 or at 360 counts), at ``a`` 1 % low.  Parameters and
    returns as :func:`search_static_level`."""
    start = problem.static
    found = []
    for levels, refits in ((MAX_LEVELS, REFITS_PER_ROUND), (WIDE_LEVELS, WIDE_REFITS)):
        problem.at_level(start)
        found.append(search_static_level(problem, res, refit, levels, refits))
    best, profile = min(found, key=lambda f: _cost_of(f[0]))
    problem.at_level(profile.level)
    return best, profile


def search_static_level(problem: _Problem, res: Any, refit: Callable[[Any, np.ndarray], Any],
                        max_levels: int = MAX_LEVELS, refits: int = REFITS_PER_ROUND) -> tuple[Any, StaticProfile]:
    """The static level that least-squares the data, its continuous parameters refitted (module docstring).

    Parameters
    ----------
    problem : FrictionProblem
        The friction fit's problem (its ``static`` is changed; left at the fitted level).
    res : OptimizeResult
        The fit without stiction (``problem.static`` 0): where the search starts.
    refit : callable
        ``refit(problem, x0) -> OptimizeResult``: the continuous parameters fitted at ``problem.static``.

    Returns
    -------
    res : OptimizeResult
        The fit at the chosen level.
    profile : StaticProfile
    """
    best, best_cost, level = res, _cost_of(res), 0.0
    fits: dict[float, tuple[float, float, float]] = {}       # level -> (cost, a, b) of its refit
    for round_ in range(MAX_ROUNDS):
        # the first round looks everywhere (evenly among the levels); the next ones at every level near its own
        levels = _near(candidate_levels(problem, best.x, len(_forces(problem, best.x))), level) if round_ else \
            candidate_levels(problem, best.x, max_levels)
        predicted = _predicted_costs(problem, best.x, levels)
        improved = False
        start_cost = best_cost
        for j in np.argsort(predicted)[:refits]:
            candidate = float(levels[j])
            if candidate in fits or not predicted[j] < start_cost:
                continue
            problem.at_level(candidate)
            with np.errstate(over="ignore", invalid="ignore"):
                fitted = refit(problem, best.x)
            cost = _cost_of(fitted)
            fits[candidate] = (cost, float(fitted.x[0]), float(fitted.x[1]))
            if cost < best_cost:
                best, best_cost, level, improved = fitted, cost, candidate, True
        if not improved:
            break
    level = max(level, float(problem.unpack(best.x)[2]))
    fits[level] = (best_cost, float(best.x[0]), float(best.x[1]))
    ceiling = best_cost + PROFILE_QUANTILE * _noise_variance(np.asarray(best.fun, float), problem.dof)
    inside = _bracket(problem, best, ceiling, fits, refit) + [level]
    problem.at_level(level)
    ab = [fits[lv][1:] for lv in inside]
    ranges = {"a": (min(p[0] for p in ab), max(p[0] for p in ab)), "b": (min(p[1] for p in ab), max(p[1] for p in ab))}
    # every level between the same two forces gives the same response: the bracket reaches from the largest
    # force the lowest level in it holds (the friction level at least) to the least force the highest lets go
    forces = _forces(problem, best.x)
    friction = float(problem.unpack(best.x)[2])
    below = forces[forces <= min(inside)]
    above = forces[forces > max(inside)]
    low = max(float(below[-1]), friction) if len(below) else friction
    high = float(above[0]) if len(above) else math.inf
    return best, StaticProfile(level, low, high, ranges, len(fits))


def _near(levels: np.ndarray, level: float) -> np.ndarray:
    """The :data:`LOCAL_LEVELS` levels on either side of ``level`` (and the friction level, the first)."""
    i = int(np.searchsorted(levels, level))
    return np.unique(np.concatenate([levels[:1], levels[max(i - LOCAL_LEVELS, 0):i + LOCAL_LEVELS + 1]]))


def _bracket(problem: _Problem, best: Any, ceiling: float, fits: dict[float, tuple[float, float, float]],
             refit: Callable[[Any, np.ndarray], Any]) -> list[float]:
    """The levels whose refitted cost is below ``ceiling``: those refitted already, and of the levels whose
    predicted cost is below it, the lowest and the highest, each refitted and, when it lands above the
    ceiling, replaced by the next one inwards (at most :data:`MAX_BRACKET_REFITS` per side)."""
    inside = [lv for lv, (cost, _, _) in fits.items() if cost <= ceiling]
    levels = _near(candidate_levels(problem, best.x), problem.static)
    predicted = _predicted_costs(problem, best.x, levels)
    near = [float(lv) for lv, p in zip(levels, predicted) if p <= ceiling]
    for order in (near, near[::-1]):
        for lv in order[:MAX_BRACKET_REFITS]:
            if lv not in fits:
                problem.at_level(lv)
                with np.errstate(over="ignore", invalid="ignore"):
                    fitted = refit(problem, best.x)
                fits[lv] = (_cost_of(fitted), float(fitted.x[0]), float(fitted.x[1]))
            if fits[lv][0] <= ceiling:
                inside.append(lv)
                break
    return inside
