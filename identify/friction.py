"""``oe-friction``: output error of ``d omega/dt = -a omega + b u - c sign(omega) + d``.

In the code (and in :class:`~identify.estimate.Estimate`) the friction ``c`` is
named ``friction`` and the constant acceleration ``d`` is named ``bias``.

Real motors have Coulomb friction ``c`` and a duty dead zone; fitted with the
linear model their ``a`` and ``b`` drift with the input's frequency and
amplitude.  This fit simulates the friction model exactly, event by event
(zero crossings, and sticking at rest while ``|b u + d| <= c``), with the
vectorised response of :mod:`identify.friction_response` (no loop per sample),
against the encoder angle, with the same segments, offsets and initial speeds as
:mod:`identify.output_error`.  Its Jacobian is analytic, differentiated through
the event times: the exact model's exact derivative wherever the stick/slip
pattern does not change, so no smoothed friction law and no final polish are
needed.  Each segment's angle offset is projected out (variable projection);
the rest are found by trust-region reflective (``a > 0``, ``c >= 0`` and dead zone
``>= 0`` as bounds): a few iterations from the linear output-error fit with each of
a few friction guesses, then the best one to convergence.

When the speed never reverses or comes to rest, ``-c sign(omega)`` is a
constant and cannot be told from ``d``: the fit then reports the net constant
acceleration as ``d`` (linear model with bias, analytic Jacobian), sets
``c = 0`` and says so in a warning.
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
from scipy.optimize import OptimizeResult, least_squares

from motorsim.checks import check_bool
from motorsim.recording import Recording

from .data import Segment, as_recordings, check_excitation, check_input_delay, prepare_segments, residual_unit
from .errors import NotIdentifiableError
from .estimate import Estimate
from .friction_response import FRICTION_PARAMETERS, FrictionResponse, friction_response
from .output_error import fit_output_error, select_delay, solve_output_error
from .uncertainty import covariance_from_jacobian
from .validation import segment_fit_percent

__all__ = ["fit_output_error_friction", "speed_reverses"]

#: Starting (c / (|b| max|u|), dead zone / max|u|) pairs; the first two have no dead zone.
_STARTS = ((0.05, 0.0), (0.2, 0.0), (0.05, 0.05), (0.2, 0.1))
#: Evaluations spent on each start before the best one is continued to convergence.
_SCOUT_EVALUATIONS = 8


def speed_reverses(recordings: Recording | list[Recording], *, rest_fraction: float = 0.02) -> bool:
    """Whether the speed changes sign or comes near rest (``|omega| < rest_fraction max|omega|``) anywhere.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        The runs.
    rest_fraction : float
        Share of the largest speed below which the motor counts as at rest.
    """
    speeds = []
    for r in as_recordings(recordings):
        w = r.measured_speed()
        speeds.append(w[np.isfinite(w)])
    w = np.concatenate(speeds)
    if len(w) == 0:
        return False
    top = float(np.max(np.abs(w)))
    return bool(np.any(w > 0) and np.any(w < 0)) or bool(np.any(np.abs(w) < rest_fraction * top))


class _FrictionProblem:
    """Residuals and analytic Jacobian of the friction model on pooled segments.

    The parameter vector holds the shared parameters ``names`` (``a``, ``b``,
    ``friction``, then ``bias`` and ``dead_zone`` when fitted) followed by each
    segment's initial speed; each angle segment's offset enters linearly and is
    projected out (residual and Jacobian columns centred: variable projection,
    Golub & Pereyra 1973).  Each segment keeps the modes of its last evaluation as
    the start of the next (:func:`identify.friction_response.friction_response`).
    """

    def __init__(self, segments: list[Segment], names: tuple[str, ...]):
        self.segments = segments
        self.names = names
        self.n_global = len(names)
        self.n_rows = sum(len(s.time) for s in segments)
        self.columns = [FRICTION_PARAMETERS.index(n) for n in names]
        self.modes: list[np.ndarray | None] = [None] * len(segments)
        self._key: bytes | None = None
        self._value: tuple[np.ndarray, np.ndarray | None] | None = None

    def unpack(self, x: np.ndarray) -> tuple[float, float, float, float, float]:
        """``(a, b, friction, bias, dead_zone)`` from ``x`` (0 for what is not fitted)."""
        named = dict(zip(self.names, x[:self.n_global]))
        return named["a"], named["b"], named["friction"], named.get("bias", 0.0), named.get("dead_zone", 0.0)

    def _response(self, x: np.ndarray, i: int, sensitivities: bool) -> FrictionResponse:
        seg = self.segments[i]
        resp = friction_response(*self.unpack(x), seg.drive, seg.time, float(x[self.n_global + i]),
                                 uniform=seg.uniform, sensitivities=sensitivities, modes=self.modes[i])
        self.modes[i] = resp.modes
        return resp

    def outputs(self, x: np.ndarray) -> list[np.ndarray]:
        """The model's angle or speed (as each segment) at ``x``."""
        out = []
        for i, seg in enumerate(self.segments):
            resp = self._response(x, i, False)
            out.append(resp.angle if seg.kind == "angle" else resp.speed)
        return out

    def evaluate(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals (measured minus model, angle segments centred) and, if asked, their Jacobian."""
        key = x.tobytes()
        if key == self._key and self._value is not None and (self._value[1] is not None or not jacobian):
            return self._value
        r = np.empty(self.n_rows)
        J = np.zeros((self.n_rows, len(x))) if jacobian else None
        row = 0
        for i, seg in enumerate(self.segments):
            n = len(seg.time)
            resp = self._response(x, i, jacobian)
            model, sens = ((resp.angle, resp.angle_sensitivity) if seg.kind == "angle"
                           else (resp.speed, resp.speed_sensitivity))
            err = seg.output - model
            if seg.kind == "angle":
                err = err - err.mean()
            r[row:row + n] = err
            if J is not None and sens is not None:
                cols = np.column_stack([sens[:, self.columns], sens[:, -1]])
                if seg.kind == "angle":
                    cols = cols - cols.mean(axis=0)
                J[row:row + n, :self.n_global] = -cols[:, :-1]
                J[row:row + n, self.n_global + i] = -cols[:, -1]
            row += n
        self._key, self._value = key, (r, J)
        return r, J

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


def fit_output_error_friction(recordings: Recording | list[Recording], *, input_delay: int | str = 0,
                              fix_bias: bool = False, dead_zone: bool = True) -> Estimate:
    """Fit ``a``, ``b``, Coulomb friction ``c``, bias ``d`` and a duty dead zone by output error.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for ``oe``.
    input_delay : int or "auto"
        Input delay in samples (``"auto"``: chosen with the linear model).
    fix_bias : bool
        Hold the bias ``d = 0``.
    dead_zone : bool
        Also fit a dead zone ``z >= 0`` in input units: the motor receives
        ``u - sign(u) z`` when ``|u| > z``, else nothing (default True).

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
    check_excitation(recs, 3 + (not fix_bias) + dead_zone)
    delay = select_delay(recs) if input_delay == "auto" else int(input_delay)
    if not speed_reverses(recs):
        return _no_reversal(recs, delay, fix_bias)
    segments = prepare_segments(recs, delay)
    names = ("a", "b", "friction") + (() if fix_bias else ("bias",)) + (("dead_zone",) if dead_zone else ())
    problem = _FrictionProblem(segments, names)
    res = _best_of_starts(problem, _starts(recs, problem, delay))
    a, b, friction, bias, zone = (float(v) for v in problem.unpack(res.x))
    if not (np.all(np.isfinite(res.x)) and a > 1e-8 and b != 0):
        raise NotIdentifiableError(f"oe-friction landed on a = {a:.6g} 1/s (theta1 = exp(-a dt) not in (0, 1)); "
                                   "check the sign of the input and that the motor moved")
    n_angle_offsets = sum(1 for s in segments if s.kind == "angle")
    dof = problem.n_rows - len(res.x) - n_angle_offsets
    s2 = float(res.fun @ res.fun) / max(dof, 1)
    jac = problem.jacobian(res.x)
    return Estimate(method="oe-friction", a=a, b=b, n_samples=problem.n_rows, sample_period=recs[0].sample_period,
                    residual_rms=math.sqrt(float(res.fun @ res.fun) / problem.n_rows),
                    fit_percent=segment_fit_percent(segments, problem.outputs(res.x)),
                    covariance=covariance_from_jacobian(jac, s2, problem.n_global), param_names=names,
                    extra={"friction": friction, "bias": bias, "dead_zone": zone, "input_delay": delay},
                    residual_unit=residual_unit(segments), input_unit=recs[0].input_unit)


def _starts(recs: list[Recording], problem: _FrictionProblem, input_delay: int) -> list[np.ndarray]:
    """Starting vectors: the linear output-error fit with a few (friction, dead zone) guesses.

    Friction and dead zone make the cost kinked and multi-modal, so the guesses are
    fractions of ``b max|u|`` and of ``max|u|`` (:data:`_STARTS`).
    """
    lin = solve_output_error(recs, problem.segments, input_delay)
    a0, b0 = float(lin.result.x[0]), float(lin.result.x[1])
    if b0 == 0:
        raise NotIdentifiableError("oe-friction: the linear start has b = 0; the input does not move the motor")
    u_scale = float(np.max(np.abs(np.concatenate([s.drive for s in problem.segments])))) or 1.0
    w0 = list(lin.initial_speeds())
    fit_bias = "bias" in problem.names
    dead_zone = "dead_zone" in problem.names
    return [np.concatenate([[a0, b0, fc * abs(b0) * u_scale] + ([0.0] if fit_bias else [])
                            + ([fz * u_scale] if dead_zone else []), w0])
            for fc, fz in _STARTS[: (len(_STARTS) if dead_zone else 2)]]


def _best_of_starts(problem: _FrictionProblem, starts: list[np.ndarray]) -> OptimizeResult:
    """Trust-region reflective with the analytic Jacobian: a few iterations from every start, then
    the one of least cost (the first on a tie) to convergence."""
    if not starts:
        raise ValueError("starts must hold at least one vector, got none")
    lower = problem.lower_bounds()
    best: OptimizeResult | None = None
    best_modes: list[np.ndarray | None] = []
    for x0 in starts:
        problem.modes = [None] * len(problem.segments)
        trial = _solve(problem, np.maximum(x0, lower), lower, _SCOUT_EVALUATIONS)
        if best is None or trial.cost < best.cost:
            best, best_modes = trial, list(problem.modes)
    assert best is not None
    if best.status != 0:
        return best
    problem.modes = best_modes
    return _solve(problem, best.x, lower, 200)


def _solve(problem: _FrictionProblem, x0: np.ndarray, lower: np.ndarray, max_nfev: int) -> OptimizeResult:
    with np.errstate(over="ignore", invalid="ignore"):
        return least_squares(problem.residuals, x0, jac=problem.jacobian, method="trf", bounds=(lower, np.inf),
                             x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)


def _no_reversal(recs: list[Recording], input_delay: int, fix_bias: bool) -> Estimate:
    if fix_bias:
        warnings.warn("oe-friction: the speed never reverses or rests, so Coulomb friction c acts as a constant; "
                      "with the bias d fixed at 0 it cannot be separated from b u: fitting the linear model (c = 0)",
                      UserWarning, stacklevel=3)
        est = fit_output_error(recs, input_delay=input_delay)
        return dataclasses.replace(est, method="oe-friction", extra={**est.extra, "friction": 0.0, "bias": 0.0})
    warnings.warn("oe-friction: the speed never reverses or comes to rest, so Coulomb friction c is a constant "
                  "indistinguishable from the bias d: reporting c = 0 and d as the net constant acceleration "
                  "(d - c sign(omega))", UserWarning, stacklevel=3)
    est = fit_output_error(recs, input_delay=input_delay, fit_bias=True)
    return dataclasses.replace(est, method="oe-friction", extra={**est.extra, "friction": 0.0})
