"""``oe-asymmetric``: output error of the motor whose gain differs by direction, and the default's use of it.

The structure (:class:`identify.model_structures.drive_map.AsymmetricGain`) is
``d omega/dt = -a omega + b_forward u+ + b_reverse u- + d``: linear in the two halves of the drive, so its exact
zero-order-hold response is the linear motor's (:func:`identify.fits.sensitivity.zoh_response`) driven by
``b_forward u+ + b_reverse u-``, and its output-error fit is Gauss--Newton on ``(a, b_forward, b_reverse, d)`` with
each segment's initial speed (and angle offset) projected out, the Jacobian exact (the response's analytic
sensitivity to ``a``, including the initial speed's, and the responses to ``u+``, ``u-`` and 1).  The covariance is
the linearised encoder bootstrap's where the residuals are mostly an encoder's rounding (as ``oe-friction``'s:
:func:`identify.checks.encoder_bootstrap.linearised_encoder_bootstrap_covariance`), else Gauss--Newton's, or
Newey--West's
where the residuals are not white (:func:`identify.checks.uncertainty.robust_covariance`).

The Gauss--Newton and its covariance (:func:`evaluate`, :func:`solve`, :func:`fit_mapped`) take any map of the
drive, ``d omega/dt = -a omega + g(u) + d`` with ``g`` and its derivatives given: a gain per direction is one
(:func:`directional`), a driver's limit another (:mod:`identify.fits.drive_limit`).  The default fits these structures
only where its part checks ask for them (:mod:`identify.default.evidence`).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable, Sequence

import numpy as np

from motorsim.recording import Recording

from ..data import (
    DEFAULT_INPUT_DELAY,
    Segment,
    prepare_segments,
    residual_unit,
)
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..sums import sum_squares
from .oe_common import check_rows, fit_covariance, linear_start, segment_models
from .sensitivity import zoh_response

__all__ = ["fit_output_error_asymmetric", "evaluate", "solve", "fit_mapped", "directional", "MappedFit", "STRUCTURE",
           "FITTED"]

#: The structure's name.
STRUCTURE = "asymmetric-gain"
#: The parameters the fit estimates (``b``, their mean, is derived).
FITTED = ("a", "b_forward", "b_reverse", "bias")
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


def _start(linear: Estimate) -> np.ndarray:
    """``(a, b, b, bias)`` of the linear motor with a bias (``oe``'s, :func:`identify.fits.oe_common.linear_start`)."""
    return np.array([linear.a, linear.b, linear.b, linear.extra.get("bias", 0.0)])


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
    from ..checks.validation import segment_fit_percent
    p = len(start)
    segments = prepare_segments(recs, delay)
    n, nuisance = check_rows(segments, p, what)
    theta, found = solve(segments, start, drive_map, valid)
    if not (np.all(np.isfinite(theta)) and valid(theta)):
        raise NotIdentifiableError(f"the fit of {what} landed on a = {theta[0]:.6g} 1/s: no stable model of this "
                                   "structure fits; check that the motor moved")
    assert found.jacobian is not None
    models = segment_models(segments, found.residual)
    cov, how = fit_covariance(recs, segments, models, found.residual, -found.jacobian, max(n - nuisance - p, 1), p,
                              covariance)
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
    recs, delay, linear = linear_start(recordings, input_delay, covariance, 3)
    return _fit(recs, delay, _start(linear), covariance)
