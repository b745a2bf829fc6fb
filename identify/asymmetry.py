"""``oe-asymmetric``: output error of the motor whose gain differs by direction, and the default's use of it.

The structure (:class:`identify.model_structures.asymmetric.AsymmetricGain`) is
``d omega/dt = -a omega + b_forward u+ + b_reverse u- + d``: linear in the two halves of the drive, so its exact
zero-order-hold response is the linear motor's (:func:`identify.sensitivity.zoh_response`) driven by
``b_forward u+ + b_reverse u-``, and its output-error fit is Gauss--Newton on ``(a, b_forward, b_reverse, d)`` with
each segment's initial speed (and angle offset) projected out, the Jacobian exact (the response's analytic
sensitivity to ``a``, including the initial speed's, and the responses to ``u+``, ``u-`` and 1).  The covariance is
the linearised encoder bootstrap's where the residuals are mostly an encoder's rounding (as ``oe-friction``'s:
:func:`identify.encoder_bootstrap.linearised_encoder_bootstrap_covariance`), else Gauss--Newton's, or Newey--West's
where the residuals are not white (:func:`identify.uncertainty.robust_covariance`).

The default (:func:`identify.fit`) fits it only where its answer's forward / reverse part check
(:mod:`identify.consistency`) finds the parts' gains materially different: :func:`direction_dependent`.  It is
chosen only where

* the choice was clear but for the part checks (no other doubt to hide),
* the gains differ materially (by more than :data:`~identify.comparison.MATERIAL` of their mean),
* it fits better than the chosen model beyond the noise (the selection's own batch-means test,
  :func:`identify.comparison.statistic`, at :data:`~identify.comparison.LEVEL`), and
* its own part checks find no material difference and its intervals are finite and narrower than the values;

it is then called a clear choice, its ``b`` (the mean gain) with an interval over both directions' own, and the
intervals of ``a`` and ``b`` wide enough to hold ``a``, ``b_forward`` and ``b_reverse`` together (:data:`JOINT_Z`).
Otherwise the answer stays the one the part checks left (not clear), and a note says what the gain per direction gave.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Sequence

import numpy as np

from motorsim.checks import check_choice
from motorsim.recording import Recording

from .comparison import LEVEL, MATERIAL, Candidate, parameters_threshold, statistic
from .data import (
    DEFAULT_INPUT_DELAY,
    Segment,
    as_recordings,
    check_excitation,
    check_input_delay,
    prepare_segments,
    residual_unit,
)
from .errors import NotIdentifiableError
from .estimate import Estimate
from .sensitivity import zoh_response
from .sums import sum_squares

__all__ = ["fit_output_error_asymmetric", "direction_dependent", "STRUCTURE", "FITTED"]

#: The structure's name.
STRUCTURE = "asymmetric-gain"
#: The parameters the fit estimates (``b``, their mean, is derived).
FITTED = ("a", "b_forward", "b_reverse", "bias")
#: Normal quantile of the chosen answer's ``a`` and ``b`` intervals: ``1 - 0.05/3`` each, so that they hold ``a``,
#: ``b_forward`` and ``b_reverse`` together in 95 % of runs (Bonferroni; ``b``'s interval is judged on both gains).
#: At 95 % each, 2 of 6 clear answers on the forward-gain-11 %-above-reverse plant of ``motorid bench coverage``
#: missed one of the three by a hair (z = 2.0).
JOINT_Z = 2.3939797998185104
#: Gauss--Newton iterations at most, and the relative step below which it has converged.
MAX_ITERATIONS = 60
STEP_TOL = 1e-12


@dataclasses.dataclass
class _Evaluation:
    residual: np.ndarray          # measured less model, every segment's rows
    jacobian: np.ndarray | None   # d model / d theta, initial state projected out
    rss: float


#: A drive map: ``(duty, gain parameters) -> (acceleration it gives, its derivative by each gain parameter)``.
DriveMap = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, list[np.ndarray]]]


def directional(u: np.ndarray, gains: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The gain per direction's drive map: ``b_forward u+ + b_reverse u-`` and its derivatives ``u+``, ``u-``."""
    up, un = np.maximum(u, 0.0), np.minimum(u, 0.0)
    return gains[0] * up + gains[1] * un, [up, un]


def evaluate(segments: Sequence[Segment], theta: np.ndarray, drive_map: DriveMap = directional,
             jacobian: bool = True) -> _Evaluation:
    """The residual (and the model's Jacobian) of ``d omega/dt = -a omega + g(u) + d`` at ``theta = (a, gain
    parameters..., d)``, ``g`` the ``drive_map``'s, each segment's initial speed and, on an angle, its offset at
    their least-squares values (exact: the linear motor of gain 1 driven by ``g(u)``, its analytic sensitivity to
    ``a``, the responses to ``g``'s derivatives)."""
    a, d = float(theta[0]), float(theta[-1])
    gains = np.asarray(theta[1:-1], dtype=float)
    residuals, columns = [], []
    for seg in segments:
        u = np.asarray(seg.drive, dtype=float)
        drive, derivatives = drive_map(u, gains)
        angle = seg.kind == "angle"
        full = zoh_response(a, 1.0, drive, seg.time, 0.0, bias=d, uniform=seg.uniform, sensitivities=jacobian)
        out = full.angle if angle else full.speed
        s0 = full.angle_initial_speed if angle else full.speed_initial_speed
        err = seg.output - out
        if angle:
            s0 = s0 - s0.mean()
            err = err - err.mean()
        ss = float(s0 @ s0)
        w = float(s0 @ err) / ss if ss > 0 else 0.0
        residuals.append(err - w * s0)
        if not jacobian:
            continue
        sens = full.angle_sensitivity if angle else full.speed_sensitivity
        parts = [getattr(zoh_response(a, 1.0, x, seg.time, 0.0, uniform=seg.uniform, sensitivities=False),
                         "angle" if angle else "speed") for x in derivatives]
        g = np.column_stack([sens[:, 0] + w * (full.angle_initial_speed_a if angle else full.speed_initial_speed_a),
                             *parts, sens[:, 3]])
        if angle:
            g = g - g.mean(axis=0)
        if ss > 0:
            g = g - np.outer(s0, s0 @ g) / ss
        columns.append(g)
    r = np.concatenate(residuals)
    return _Evaluation(r, np.vstack(columns) if jacobian else None, sum_squares(r))


def solve(segments: Sequence[Segment], theta0: np.ndarray, drive_map: DriveMap = directional,
          valid: Callable[[np.ndarray], bool] = lambda theta: bool(theta[0] > 0)) -> tuple[np.ndarray, _Evaluation]:
    """Gauss--Newton on :func:`evaluate` from ``theta0`` with step halving, within ``valid``; the converged
    parameters and their evaluation."""
    theta = np.array(theta0, dtype=float)
    here = evaluate(segments, theta, drive_map)
    for _ in range(MAX_ITERATIONS):
        assert here.jacobian is not None
        scale = np.linalg.norm(here.jacobian, axis=0)
        scale[scale == 0] = 1.0
        step = np.linalg.lstsq(here.jacobian / scale, here.residual, rcond=None)[0] / scale
        for _ in range(30):
            trial = theta + step
            if valid(trial):
                with np.errstate(over="ignore", invalid="ignore"):
                    there = evaluate(segments, trial, drive_map)
                if math.isfinite(there.rss) and there.rss <= here.rss * (1 + 1e-12):
                    break
            step = step / 2
        else:
            break
        theta, here = trial, there
        if np.all(np.abs(step) <= STEP_TOL * np.maximum(np.abs(theta), 1e-300)):
            break
    return theta, here


def _start(recs: list[Recording], delay: int) -> np.ndarray:
    """``(a, b, b, bias)`` of the linear motor with a bias fitted by ``oe`` at ``delay``."""
    from .output_error import fit_output_error
    est = fit_output_error(recs, input_delay=delay, fit_bias=True, covariance="gauss-newton")
    return np.array([est.a, est.b, est.b, est.extra.get("bias", 0.0)])


@dataclasses.dataclass
class MappedFit:
    """A fit of :func:`evaluate`'s model: its parameters, covariance (and how it was made) and what an
    :class:`Estimate` needs."""

    theta: np.ndarray
    covariance: np.ndarray
    covariance_method: str
    n_samples: int
    rss: float
    fit_percent: float
    residual_unit: str


def fit_mapped(recs: list[Recording], delay: int, start: np.ndarray, drive_map: DriveMap, what: str,
               valid: Callable[[np.ndarray], bool] = lambda theta: bool(theta[0] > 0),
               covariance: str = "auto") -> MappedFit:
    """:func:`solve` on the recordings' segments at ``delay`` from ``start``, with its covariance: the linearised
    encoder bootstrap where the residuals are mostly an encoder's rounding, else Gauss--Newton or Newey--West
    (module docstring); ``what`` names the structure in messages."""
    from .encoder_bootstrap import linearised_encoder_bootstrap_covariance
    from .friction import ROUNDING_DOMINATED
    from .uncertainty import covariance_from_jacobian, robust_covariance
    from .validation import segment_fit_percent
    p = len(start)
    segments = prepare_segments(recs, delay)
    n = sum(len(s.time) for s in segments)
    nuisance = sum(2 if s.kind == "angle" else 1 for s in segments)
    if not segments or n - nuisance <= p + 1:
        raise NotIdentifiableError(f"recording is too short for {what}: {p} parameters and the initial state of "
                                   f"{len(segments)} segments; record longer")
    theta, found = solve(segments, start, drive_map, valid)
    if not (np.all(np.isfinite(theta)) and valid(theta)):
        raise NotIdentifiableError(f"the fit of {what} landed on a = {theta[0]:.6g} 1/s: no stable model of this "
                                   "structure fits; check that the motor moved")
    dof = max(n - nuisance - p, 1)
    s2 = found.rss / dof
    J = found.jacobian
    assert J is not None
    models, lo = [], 0
    for seg in segments:
        hi = lo + len(seg.time)
        models.append(seg.output - found.residual[lo:hi])
        lo = hi
    steps = [2 * math.pi / c if c else None for c in (recs[s.recording].counts_per_rev for s in segments)]
    variance = found.rss / n
    encoders = all(s.kind == "angle" and st for s, st in zip(segments, steps))
    if covariance == "gauss-newton":
        cov, how = covariance_from_jacobian(J, s2, p), "gauss-newton"
    elif encoders and variance <= ROUNDING_DOMINATED * max(st or 0.0 for st in steps) ** 2 / 12.0:
        # mostly the encoder's rounding, which stays put while the shaft is slow: its spread over the phases
        cov = linearised_encoder_bootstrap_covariance(segments, models, steps, variance, -J, p)
        how = "linearised-encoder-bootstrap"
    else:
        cov, how = robust_covariance(J, found.residual, s2, p)
    return MappedFit(theta, cov, how, n, found.rss, segment_fit_percent(segments, models), residual_unit(segments))


def _fit(recs: list[Recording], delay: int, start: np.ndarray, covariance: str = "auto") -> Estimate:
    """The fit at ``delay`` from ``start`` (``(a, b_forward, b_reverse, bias)``) as an :class:`Estimate`."""
    drive = np.concatenate([s.drive for s in prepare_segments(recs, delay)] or [np.zeros(0)])
    if not (np.any(drive > 0) and np.any(drive < 0)):
        raise NotIdentifiableError("a gain per direction needs a drive of both signs, got one sign only: run the "
                                   "motor both ways (a sine or a multisine about zero)")
    found = fit_mapped(recs, delay, start, directional, "a gain per direction", covariance=covariance)
    # (a, b, b_forward, b_reverse, bias) from (a, b_forward, b_reverse, bias): b is their mean
    T = np.array([[1, 0, 0, 0], [0, 0.5, 0.5, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    a, bf, br, d = (float(x) for x in found.theta)
    return Estimate(method="oe-asymmetric", a=a, b=0.5 * (bf + br), n_samples=found.n_samples,
                    sample_period=recs[0].sample_period, residual_rms=math.sqrt(found.rss / found.n_samples),
                    fit_percent=found.fit_percent, covariance=T @ found.covariance @ T.T,
                    param_names=("a", "b", "b_forward", "b_reverse", "bias"),
                    extra={"b_forward": bf, "b_reverse": br, "bias": d, "input_delay": delay},
                    residual_unit=found.residual_unit, input_unit=recs[0].input_unit,
                    input_limit=recs[0].input_limit, structure=STRUCTURE, covariance_method=found.covariance_method)


def fit_output_error_asymmetric(recordings: Recording | Sequence[Recording], *,
                                input_delay: int | str = DEFAULT_INPUT_DELAY, covariance: str = "auto") -> Estimate:
    """Output-error fit of the motor with a gain per direction of the drive (``oe-asymmetric``).

    ``d omega/dt = -a omega + b_forward u+ + b_reverse u- + d`` (module docstring), exact under the zero-order hold,
    on the encoder angle (or the speed column).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled: one set of parameters, an initial speed (and angle offset) per gap-free segment; the drive must
        take both signs.
    input_delay : int or "auto"
        Whole samples, or ``"auto"`` (default): the delay ``oe`` with a bias chooses.
    covariance : {"auto", "gauss-newton"}
        ``"auto"``: the linearised encoder bootstrap where the residuals are mostly an encoder's rounding,
        Newey--West where they are not white, else Gauss--Newton; ``"gauss-newton"``: the fit's own (white noise
        assumed).

    Returns
    -------
    Estimate
        Structure ``asymmetric-gain``: ``a``; ``b``, the mean of ``b_forward`` and ``b_reverse`` (the gain of the
        best linear approximation under a symmetric input); ``extra`` ``b_forward``, ``b_reverse`` and ``bias``;
        the covariance over ``("a", "b", "b_forward", "b_reverse", "bias")`` (singular: ``b`` is their mean).

    Raises
    ------
    NotIdentifiableError
        Too short, a drive of one sign, or no stable fit.

    Examples
    --------
    A motor 10 % stronger forward than in reverse, noise-free:

    >>> import numpy as np
    >>> from identify import fit
    >>> from identify.model_structures import structure
    >>> t = np.arange(4000) * 0.002
    >>> duty = np.round(120 * np.sin(7 * t) + 60 * np.sin(41 * t + 1)).astype(int)
    >>> truth = {"a": 25.0, "b_forward": 3.15, "b_reverse": 2.85, "bias": 0.0}
    >>> angle = structure("asymmetric-gain").response(truth, duty, t).angle
    >>> from motorsim import Recording
    >>> est = fit(Recording(time=t, duty=duty, sample_period=0.002, angle=angle), "oe-asymmetric", input_delay=0)
    >>> print(f"a = {est.a:.6f}, b forward {est.extra['b_forward']:.6f}, reverse {est.extra['b_reverse']:.6f}")
    a = 25.000000, b forward 3.150000, reverse 2.850000
    """
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    check_choice("covariance", covariance, ("auto", "gauss-newton"))
    check_excitation(recs, 3)
    if input_delay == "auto":
        from .output_error import select_delay
        input_delay = select_delay(recs, with_bias=True)
    delay = int(input_delay)
    return _fit(recs, delay, _start(recs, delay), covariance)


#: How the doubt of a choice among candidates the data cannot tell apart begins (:func:`identify.selection._widen`).
CANDIDATES_DOUBT = "the data cannot tell "


def _refit(recs: list[Recording], candidate: Candidate) -> Estimate:
    """``candidate`` fitted on all rows by its own method."""
    import warnings

    from .methods import method_function
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return method_function(candidate.method)(recs, **candidate.options())


def _residuals(est: Estimate, segments: Sequence[Segment]) -> np.ndarray:
    """``est``'s residual (measured less model) on ``segments``, its structure's own output."""
    shape = est.model_structure()
    values = est.values()
    return np.concatenate([seg.output - shape.segment_output(values, seg) for seg in segments])


Answer = tuple[Estimate, Any, tuple]


def direction_dependent(recs: list[Recording], before: tuple[Estimate, Any], after: Answer,
                        check_parts: Callable[..., Answer]) -> Answer:
    """The default's answer with a gain per direction where the evidence asks for it (module docstring).

    Parameters
    ----------
    recs : list of Recording
        The recordings, as the default has them.
    before : (Estimate, Selection)
        The chosen answer before its part checks.
    after : (Estimate, Selection, tuple of PartCheck)
        The answer after them (returned unchanged unless the forward / reverse check found the parts' gains
        materially different).
    check_parts : callable
        The default's part checks, ``check_parts(recs, estimate, selection, open_loop=True)``.
    """
    est0, selection0 = before
    est, selection, parts = after
    split = next((c for c in parts if c.split == "forward / reverse" and c.material), None)
    rivals = [c for c in selection0.candidates if c.within_noise and c is not selection0.chosen]
    # only the part checks' doubt, or that and candidates the misfit left within its noise, which the gain per
    # direction must then beat too: any other doubt (a delay at the top of the range, a loop, ...) stands
    settled = selection0.clear or selection0.doubt.startswith(CANDIDATES_DOUBT)
    if split is None or not settled or est0.structure == STRUCTURE:
        return after
    delays = sorted({est0.input_delay} | {c.input_delay for c in rivals})
    start = np.array([est0.a, est0.b, est0.b, float(est0.extra.get("bias", 0.0))])
    fits: list[Estimate] = []
    try:
        for d in delays:
            fits.append(_fit(recs, d, start))
        # the rivals' best, on all rows, where the choice was in doubt
        best = selection0.best
        others = [est0] + ([_refit(recs, best)] if not selection0.clear and best is not selection0.chosen else [])
    except (NotIdentifiableError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return _noted(after, f"a gain per direction ({STRUCTURE}) could not be fitted: {exc}")
    skip = max(delays)
    rows = {d: prepare_segments(recs, d, skip=skip) for d in {*delays, *(e.input_delay for e in others)}}
    residuals = [_residuals(e, rows[e.input_delay]) for e in fits]
    i = int(np.argmin([sum_squares(r) for r in residuals]))
    alt, r1 = fits[i], residuals[i]
    s1 = sum_squares(r1)
    bf, br = alt.extra["b_forward"], alt.extra["b_reverse"]
    said = (f"a gain per direction ({STRUCTURE}, delay {alt.input_delay}) gives b forward {bf:.4g}, reverse "
            f"{br:.4g}, a = {alt.a:.4g}")
    if not abs(bf - br) > MATERIAL * abs(alt.b):
        return _noted(after, f"{said}: the gains differ by less than {100 * MATERIAL:g} %, so it is not chosen")
    for other, r in zip(fits, residuals):       # its fits at the other delays: within the noise and different?
        if other is not alt and statistic(r - r1, sum_squares(r) - s1, r1) <= parameters_threshold(1, LEVEL) and (
                abs(other.a - alt.a) > MATERIAL * abs(alt.a) or abs(other.b - alt.b) > MATERIAL * abs(alt.b)):
            return _noted(after, f"{said}, but cannot tell delay {other.input_delay} from it (a = {other.a:.4g}), so "
                                 "it is not chosen")
    t, limit = math.inf, 0.0
    for other in others:        # it must fit better than the chosen (and the rivals' best) beyond the noise
        r0 = _residuals(other, rows[other.input_delay])
        k = max(len(FITTED) - len(other.param_names), 1)
        here, bound = statistic(r0 - r1, sum_squares(r0) - s1, r1), parameters_threshold(k, LEVEL)
        if not here > bound:
            return _noted(after, f"{said}, but fits no better than {other.structure} (delay {other.input_delay}) "
                                 f"beyond the noise (T = {here:.3g}, threshold {bound:.3g}), so it is not chosen")
        if here / bound < t / max(limit, 1e-300):
            t, limit = here, bound
    se = alt.stderr()
    unsure = [n for n in ("a", "b_forward", "b_reverse") if not (math.isfinite(se[n]) and
                                                                  1.959963984540054 * se[n] < abs(alt.value(n)))]
    if unsure:
        return _noted(after, f"{said}, but the run does not determine {', '.join(unsure)}, so it is not chosen")
    old = selection0.chosen
    chosen = Candidate(STRUCTURE, alt.input_delay, alt.a, alt.b, s1, 0.0, True)
    runner = dataclasses.replace(old, statistic=t, within_noise=False)
    candidates = tuple(runner if c is old else c for c in selection0.candidates) + (chosen,)
    note = (f"{said}: the {old.label} model's forward and reverse parts differ ({split.hint}, p = "
            f"{split.p_value:.2g}), and the gain per direction fits better beyond the noise (T = {t:.3g}, "
            f"threshold {limit:.3g})" + (f", than {', '.join(c.label for c in rivals[:4])} too" if rivals and
                                         not selection0.clear else ""))
    trial = dataclasses.replace(selection0, candidates=candidates, chosen=chosen, best=chosen, runner_up=runner,
                                notes=(*selection0.notes, note), clear=True, doubt="")
    new_est, new_sel, new_parts = check_parts(recs, alt, trial, open_loop=True)
    if not new_sel.clear:
        return _noted(after, f"{said}, but its own parts differ too ({new_sel.doubt}), so it is not chosen")
    # the answer's a and b intervals hold a, b_forward and b_reverse together: each at 1 - 0.05/3 (Bonferroni)
    ci, se = new_est.confidence_interval(0.95), new_est.stderr()
    z = JOINT_Z
    gains = [(new_est.value(n), se[n]) for n in ("b_forward", "b_reverse")]
    ranges = {"a": (min(ci["a"][0], new_est.a - z * se["a"]), max(ci["a"][1], new_est.a + z * se["a"])),
              "b": (min([ci["b"][0]] + [x - z * e for x, e in gains]),
                    max([ci["b"][1]] + [x + z * e for x, e in gains]))}
    return (dataclasses.replace(new_est, model_range=ranges),
            dataclasses.replace(new_sel, notes=(*new_sel.notes, _B_NOTE)), new_parts)


#: The note of an answer with a gain per direction: what its ``b`` is, and its interval.
_B_NOTE = ("the gain differs by direction: b is the mean of b_forward and b_reverse (the gain a symmetric input "
           "sees), its interval holds both; a controller must be given one direction's gain on purpose")


def _noted(after: Answer, line: str) -> Answer:
    """``after`` with ``line`` among its selection's notes."""
    est, selection, parts = after
    return est, dataclasses.replace(selection, notes=(*selection.notes, line)), parts
