"""Output error of any linear structure: its parameters fitted by the model output its plant gives.

The generic estimator a new linear structure names (:func:`identify.estimators.linear_estimator`) instead of writing
its own: the structure declares its parameters (names, bounds), its start values
(:meth:`identify.model_structures.ModelStructure.starts`) and its plant
(:class:`motorsim.linear_plant.LinearPlant`, whose continuous system gives every response); the
fit is the same for all (the pattern of statsmodels' ``MLEModel``: a model declares its
parameters, starts and how they enter; one ``fit``).

On each segment the model output is the plant's forced response plus its free responses, whose
initial states (and the angle's offset) are projected out by least squares
(:meth:`~identify.model_structures.ModelStructure.segment_output`); ``scipy.optimize.least_squares``
moves the parameters within their bounds from each start, the best kept.  The covariance is
:func:`identify.checks.uncertainty.robust_covariance`'s on the Jacobian at the optimum (central
differences), the initial states counted as nuisance parameters; a fit that ends on a parameter's bound
(closer to it than the differences' step) is refused by a :class:`~identify.errors.NotIdentifiableError` naming
it.  The input delay is searched as every estimator's (:data:`identify.data.DEFAULT_INPUT_DELAY`,
:func:`identify.comparison.choose_delay`).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import numpy as np

from motorsim.recording import Recording

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
from .oe_common import segment_models, segments_at

if TYPE_CHECKING:
    from ..model_structures import ModelStructure

__all__ = ["fit_linear_structure"]


def _residuals(theta: np.ndarray, structure: ModelStructure, segs: Sequence[Segment]) -> np.ndarray:
    values = dict(zip(structure.param_names, (float(x) for x in theta)))
    with np.errstate(all="ignore"):
        out = np.concatenate([seg.output - structure.segment_output(values, seg) for seg in segs])
    return np.where(np.isfinite(out), out, 1e150)


#: The fit's budget, in scipy's count of model evaluations (a Jacobian's differences apart): each start's coarse
#: steps, and the full fit from the best of them.  A structure that does not describe the recording drifts to a
#: bound without converging (on the lab recordings of tests/data the two-mass fit's parameters ran to 1e-9 and
#: 300, its cost still falling after 400 steps per start); the budget bounds what that costs, the best kept.
COARSE_EVALUATIONS = 10
FULL_EVALUATIONS = 200


def _solve(structure: ModelStructure, segs: Sequence[Segment], x0: np.ndarray, tol: float, budget: int):
    """One bounded least-squares run from ``x0`` (None where it fails)."""
    from scipy.optimize import least_squares
    low, high = _bounds(structure)
    try:
        return least_squares(_residuals, np.clip(x0, low, high), args=(structure, segs), bounds=(low, high),
                             x_scale="jac", xtol=tol, ftol=tol, gtol=tol, max_nfev=budget)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _bounds(structure: ModelStructure) -> tuple[list[float], list[float]]:
    low = [p.low * (1 + 1e-12) + 1e-300 if p.strict else p.low for p in structure.parameters]
    return low, [p.high for p in structure.parameters]


def _coarse(structure: ModelStructure, recs: list[Recording], segs: list[Segment]) -> np.ndarray:
    """The best parameters after a few steps from each of the structure's starts."""
    from .start import initial_guess
    best = None
    for start in structure.starts(recs, initial_guess(recs, segs)):
        x0 = np.asarray([start[n] for n in structure.param_names], dtype=float)
        sol = _solve(structure, segs, x0, 1e-6, COARSE_EVALUATIONS)
        if sol is not None and np.all(np.isfinite(sol.x)) and (best is None or sol.cost < best.cost):
            best = sol
    if best is None:
        raise NotIdentifiableError(f"the {structure.name} structure could not be fitted from any start")
    return best.x


def _full(structure: ModelStructure, segs: list[Segment], x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The full fit from ``x0`` (a coarse fit's, whose residuals it can only lower), and its residuals."""
    sol = _solve(structure, segs, x0, 1e-10, FULL_EVALUATIONS)
    x = sol.x if sol is not None and np.all(np.isfinite(sol.x)) else x0
    r, r0 = _residuals(x, structure, segs), _residuals(x0, structure, segs)
    return (x, r) if r @ r <= r0 @ r0 else (x0, r0)


def _steps(x: np.ndarray) -> np.ndarray:
    """The covariance's central-difference steps: relative, ``1e-6`` of each value (``1e-12`` near 0)."""
    return 1e-6 * np.maximum(np.abs(x), 1e-6)


def _check_inside(structure: ModelStructure, x: np.ndarray, steps: np.ndarray) -> None:
    """A :class:`~identify.errors.NotIdentifiableError` naming each parameter the fit left on a bound (closer to
    it than its difference step): the best fit the structure allows lies at the edge of its range, the data asking
    for a value outside it (a shaft's damping below 0, a load's inertia at 0), so the structure does not describe
    the recording and no interval can be given for it.  The estimators' own error for data that do not determine a
    structure, which the default and the comparison of methods report as such."""
    low, high = _bounds(structure)
    pinned = [f"{p.name} = {v:.6g} (its bound {lo if v - st < lo else hi:.6g})"
              for p, v, st, lo, hi in zip(structure.parameters, x, steps, low, high) if v - st < lo or v + st > hi]
    if pinned:
        raise NotIdentifiableError(
            f"the {structure.name} fit ended on the edge of the structure's range: {', '.join(pinned)}; the data ask "
            f"for a value outside it, so the {structure.name} structure does not describe this recording (fit a "
            "simpler structure, or record where the parts it adds show)")


def fit_linear_structure(recordings: Recording | list[Recording], *, structure: str,
                         input_delay: int | str = DEFAULT_INPUT_DELAY) -> Estimate:
    """Output error of the registered linear ``structure`` (module docstring).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for every estimator.
    structure : str
        A registered structure whose plant is a :class:`motorsim.linear_plant.LinearPlant`.
    input_delay : int or "auto"
        Whole samples of input delay, or ``"auto"`` (default): the shortest within the noise of the best
        over ``0 ... 10``.

    Returns
    -------
    Estimate
        ``method`` the structure's estimator's name; covariance over the structure's parameters.
    """
    from ..checks.uncertainty import robust_covariance
    from ..checks.validation import segment_fit_percent
    from ..comparison import LEVEL, MAX_AUTO_DELAY, Candidate, CandidateFit, choose_delay
    from ..model_structures import structure as registered
    s = registered(structure)
    recs = as_recordings(recordings)
    check_excitation(recs, s.n_params)
    delay_option = check_input_delay(input_delay)
    full: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    if delay_option == "auto":
        coarse: dict[int, np.ndarray] = {}

        def fit_at(segs: list[Segment], d: int, refine: bool) -> CandidateFit:
            try:
                if d not in coarse:
                    coarse[d] = _coarse(s, recs, segs)
                if refine and d not in full:
                    full[d] = _full(s, segs, coarse[d])
                x, r = full[d] if refine else (coarse[d], _residuals(coarse[d], s, segs))
            except NotIdentifiableError as exc:
                return CandidateFit(Candidate(s.name, d, math.nan, math.nan, math.nan, note=str(exc)), None)
            return CandidateFit(Candidate(s.name, d, float(x[0]), float(x[1]), float(r @ r)), r, refined=refine)
        delay = choose_delay(recs, fit_at, MAX_AUTO_DELAY, LEVEL, s.method)
    else:
        delay = int(delay_option)
    segs = segments_at(recs, delay)
    # the full fit on every row from the common rows' full fit at this delay, where the search made one
    x, r = _full(s, segs, full[delay][0] if delay in full else _coarse(s, recs, segs))
    nuisance = sum(len(s.plant(dict(zip(s.param_names, x))).state_names()) - (seg.kind != "angle")
                   for seg in segs)
    n, k = len(r), s.n_params + nuisance
    if n <= k + 1:
        raise NotIdentifiableError(f"recording is too short: {n} samples for {k} parameters")
    steps = _steps(x)
    _check_inside(s, x, steps)
    J = np.empty((n, s.n_params))
    for i in range(s.n_params):                     # central differences, relative steps
        up, down = x.copy(), x.copy()
        up[i] += steps[i]
        down[i] -= steps[i]
        J[:, i] = (_residuals(down, s, segs) - _residuals(up, s, segs)) / (2 * steps[i])
    s2 = float(r @ r) / (n - k)
    cov, how = robust_covariance(J, r, s2, s.n_params)
    values = dict(zip(s.param_names, (float(v) for v in x)))
    models = segment_models(segs, r)
    return Estimate(method=s.method, structure=s.name, a=values["a"], b=values["b"], n_samples=n,
                    sample_period=recs[0].sample_period, residual_rms=float(np.sqrt(np.mean(r * r))),
                    fit_percent=segment_fit_percent(segs, models), covariance=cov, param_names=s.param_names,
                    extra={k_: v for k_, v in values.items() if k_ not in ("a", "b")}, input_delay=delay,
                    residual_unit=residual_unit(segs), input_unit=recs[0].input_unit,
                    input_limit=recs[0].input_limit, covariance_method=how)
