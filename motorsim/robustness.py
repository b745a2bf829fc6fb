"""How a controller designed at a point estimate behaves across the model's uncertainty.

:func:`loop_margins` gives the gain, phase and delay margins of a controller's feedback loop
``L = -Cy P`` (the loop broken at the duty; :meth:`~motorsim.control.Controller.laws` gives
``Cy``, :meth:`~motorsim.control.Controller.plant` gives ``P``), computed by
:func:`motorsim.margins.discrete_margins` independently of python-control (a test checks them
against ``control.stability_margins`` on the same loop).

:func:`analyse_robustness` keeps the controller's gains fixed and draws plants ``(a, b)`` from a
normal distribution with the estimate's covariance (a seeded Monte Carlo: ``rng`` is a
``numpy.random.Generator``; it is a sample, not a guaranteed bound), and reports the worst case
and a percentile of the predicted tracking RMS and of the margins, the share of draws whose loop
is unstable or badly damped, and warnings.  The draws are made once, never again: a draw with
``a <= 0`` (no motor of this model) is left out and counted, and a draw whose ``b`` has the other
sign than the model's (the uncertainty does not know the motor's direction) is analysed as the
plant it is, counted, and warned of.  A model with an electrical time constant keeps it in every
drawn plant, or draws it too when the covariance has its row (``(a, b, electrical_time_constant)``, a
draw with ``tau_e < 0`` left out and counted like ``a <= 0``), and every loop is closed on the full plant
(:meth:`~motorsim.control.PlantModel.speed_transfer_function`).  :func:`robust_design` tunes a controller's knob
(``duty_weight`` of ``mpc``, ``time_constant`` of ``pi`` and ``position``) to the best worst-case
tracking RMS over the same draws instead of the point estimate.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Sequence

import numpy as np

from .checks import ParameterError, ParameterTypeError, check_int, check_real
from .control import Controller, DesignLimitWarning, PlantModel, Reference, design_controller
from .margins import Margins, discrete_margins
from .plant import Motor

__all__ = ["Margins", "Robustness", "ModelDraws", "loop_margins", "analyse_robustness", "robust_design",
           "draw_models", "BADLY_DAMPED", "ROBUST_KNOB"]

#: A closed-loop pole whose damping ratio (of its continuous equivalent ``log(z) / h``) is below
#: this makes a loop badly damped.
BADLY_DAMPED = 0.2
#: The knob :func:`robust_design` tunes, per controller.
ROBUST_KNOB = {"mpc": "duty_weight", "pi": "time_constant", "position": "time_constant", "lqr": "duty_weight",
               "lqr-integral": "duty_weight", "lqr-position": "duty_weight"}
_KNOB_FACTORS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)


def _loop(controller: Controller, model: PlantModel | None = None, laws: Any = None) -> Any:
    """``L = -Cy P`` with the controller's gains and the plant of ``model`` (default: its own).

    ``laws``, the controller's ``(Cr, Cy)`` when already computed (they are the same for every plant).
    """
    _, cy = controller.laws() if laws is None else laws
    p = controller.plant() if model is None else _plant(controller, model)
    return -(p * cy)


def _margins(loop: Any) -> Margins:
    return discrete_margins(np.ravel(loop.num[0][0]), np.ravel(loop.den[0][0]), float(loop.dt))


def _plant(controller: Controller, model: PlantModel) -> Any:
    import control
    p = model.speed_transfer_function()
    if controller.quantity == "angle":
        p = p * control.tf([1.0, 0.0], [1.0, -1.0], model.sample_period)
    return p


def _closed_loop_poles(loop: Any) -> np.ndarray:
    import control
    return np.asarray(control.feedback(loop, 1).poles())


def loop_margins(controller: Controller, model: PlantModel | None = None) -> Margins:
    """Gain, phase and delay margins of the controller's loop, on its own model or on ``model``.

    Parameters
    ----------
    controller : Controller
        Its gains are kept as designed.
    model : PlantModel, optional
        The plant the loop is closed on (default: the one the controller was designed from).

    Returns
    -------
    Margins

    Examples
    --------
    >>> from motorsim.control import PISpeed
    >>> m = loop_margins(PISpeed(PlantModel(25.0, 3.0, 0.005, 16667)))
    >>> m.stable, round(m.phase_margin)
    (True, 84)
    """
    return _margins(_loop(controller, model))


@dataclasses.dataclass(frozen=True)
class Robustness:
    """A controller's predicted behaviour at the point estimate and across the drawn plants.

    Attributes
    ----------
    point : Margins
        Margins at the point estimate.
    tracking_rms : float
        Predicted tracking RMS at the point estimate (rad/s, or rad for position).
    worst_rms, percentile_rms : float
        Largest and ``percentile``-th percentile (the draw at or above it) predicted tracking RMS
        over the draws (``inf`` for an unstable one).
    worst_gain_margin, worst_phase_margin, worst_delay_margin : float
        Smallest margins over the draws (gain margin: closest to 1, in its ratio).
    percentile : float
        The percentile reported, %.
    unstable, badly_damped : float
        Shares of the draws whose closed loop is unstable, or has a pole with damping ratio
        below :data:`BADLY_DAMPED`.
    n_draws : int
        Plants analysed (drawn and kept).
    method : str
        How the interval was explored (a seeded Monte Carlo over the covariance).
    n_rejected : int
        Plants drawn with ``a <= 0`` and left out (no motor of this model has them).
    other_sign : float
        Share of the plants analysed whose ``b`` has the other sign than the model's.
    """

    point: Margins
    tracking_rms: float
    worst_rms: float
    percentile_rms: float
    worst_gain_margin: float
    worst_phase_margin: float
    worst_delay_margin: float
    percentile: float
    unstable: float
    badly_damped: float
    n_draws: int
    method: str
    n_rejected: int = 0
    other_sign: float = 0.0

    @property
    def rejected(self) -> float:
        """Share of the plants drawn that were left out (``a <= 0``)."""
        return self.n_rejected / (self.n_draws + self.n_rejected)

    def warnings(self) -> list[str]:
        """What a user should know before trusting the design."""
        out = []
        if not self.point.stable:
            out.append("the loop is unstable at the point estimate")
        if self.unstable > 0:
            out.append(f"{100 * self.unstable:.3g} % of the plants within the model's uncertainty give an "
                       "unstable loop: design more cautiously (--robust, a slower time constant or a larger "
                       "duty weight) or identify the motor more precisely")
        if self.badly_damped > 0:
            out.append(f"{100 * self.badly_damped:.3g} % of the plants within the model's uncertainty give a "
                       f"badly damped loop (a closed-loop pole with damping ratio below {BADLY_DAMPED:g})")
        if self.other_sign > 0:
            out.append(f"{100 * self.other_sign:.3g} % of the plants within the model's uncertainty have b of the "
                       "other sign: the model does not know which way the motor turns, so no design from it is "
                       "robust; identify the motor more precisely (a longer or stronger excitation)")
        if self.n_rejected:
            out.append(f"{100 * self.rejected:.3g} % of the plants drawn ({self.n_rejected} of "
                       f"{self.n_draws + self.n_rejected}) have a <= 0, which no motor of this model has: they are "
                       "left out, and the shares above are of the others; the model's a is barely known")
        return out


@dataclasses.dataclass(frozen=True)
class ModelDraws(Sequence[PlantModel]):
    """Plants drawn from a model's covariance, and what the draw left out (a sequence of the plants kept).

    Attributes
    ----------
    models : tuple of PlantModel
        The plants kept (``a > 0``, ``b`` nonzero).
    n_rejected : int
        Draws left out: ``a <= 0``, or a ``b`` of exactly 0 (no motor of this model).
    n_other_sign : int
        Plants kept whose ``b`` has the other sign than the model's.
    """

    models: tuple[PlantModel, ...]
    n_rejected: int = 0
    n_other_sign: int = 0

    def __len__(self) -> int:
        return len(self.models)

    def __getitem__(self, index):
        return self.models[index]


def draw_models(model: PlantModel, covariance: np.ndarray, n_draws: int, rng: np.random.Generator, *,
                names: Sequence[str] | None = None) -> ModelDraws:
    """Plants with ``(a, b)`` (and the electrical time constant) drawn from a normal distribution around
    ``model``'s, drawn once.

    Parameters
    ----------
    model : PlantModel
        The point estimate (its other fields are kept).
    covariance : array_like, shape (2, 2) or (3, 3)
        Covariance of ``(a, b)``, in (1/s)^2, (1/s)((rad/s^2)/duty), ((rad/s^2)/duty)^2; or of
        ``(a, b, electrical_time_constant)`` (s) for a model with an electrical time constant, which is
        then drawn too (else every plant keeps the model's).
    n_draws : int
        Plants to draw, once: a draw with ``a <= 0`` (or a negative electrical time constant) is left out
        and counted (``n_rejected``), one whose ``b`` has the other sign than the model's is kept and
        counted (``n_other_sign``).
    rng : numpy.random.Generator
        The source of randomness.
    names : sequence of str, optional
        The plant's values ``covariance`` is over, in its order (``Estimate.param_names``: any structure's,
        ``a`` and ``b`` first); each draw is the plant with them replaced, a draw the plant refuses (a value
        outside its bounds) left out and counted.  Default: ``(a, b)`` or ``(a, b, electrical_time_constant)``
        by the covariance's shape, as above, for a :class:`~motorsim.plant.Motor`; for a plant of another
        structure its values in the order :meth:`~motorsim.plant.Plant.values` lists them (the estimate's
        parameters), as many as the covariance has rows.

    Examples
    --------
    >>> draws = draw_models(PlantModel(25.0, -3.0, 0.005, 16667), [[1.0, 0.0], [0.0, 4.0]], 1000,
    ...                     np.random.default_rng(0))        # a motor wired backwards, b barely known
    >>> len(draws) + draws.n_rejected, 0.05 < draws.n_other_sign / len(draws) < 0.1   # P(b > 0) = 6.7 %
    (1000, True)
    """
    if names is None and not isinstance(model.plant, Motor):    # another structure: over its values, in order
        names = tuple(model.plant.values())[:len(np.atleast_2d(np.asarray(covariance, dtype=float)))]
    if names is not None:
        return _draw_named(model, covariance, n_draws, rng, tuple(names))
    cov = _checked_covariance(model, covariance)
    n_draws = check_int("n_draws", n_draws, 1, 10**6)
    if not isinstance(rng, np.random.Generator):
        raise ParameterTypeError(f"rng must be a numpy.random.Generator, got {rng!r}")
    mean = [model.a, model.b, model.electrical_time_constant][:len(cov)]
    drawn = rng.multivariate_normal(mean, cov, size=n_draws)
    keep = (drawn[:, 0] > 0) & (drawn[:, 1] != 0) & (drawn[:, 2] >= 0 if len(cov) == 3 else True)
    tau = model.electrical_time_constant
    out = tuple(model.with_values(a=float(row[0]), b=float(row[1]),
                                  electrical_time_constant=float(row[2]) if len(row) == 3 else tau)
                for row in drawn[keep])
    other = int(np.sum(np.sign(drawn[keep, 1]) != np.sign(model.b)))
    return ModelDraws(out, n_rejected=int(n_draws - keep.sum()), n_other_sign=other)


def _draw_named(model: PlantModel, covariance: np.ndarray, n_draws: int, rng: np.random.Generator,
                names: tuple[str, ...]) -> ModelDraws:
    """:func:`draw_models` over the plant's values ``names``."""
    values = model.plant.values()
    unknown = [n for n in names if n not in values]
    if unknown or names[:2] != ("a", "b"):
        raise ParameterError(f"names must start with 'a', 'b' and name the plant's values {list(values)}, "
                             f"got {list(names)}")
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (len(names), len(names)) or not np.all(np.isfinite(cov)):
        raise ParameterError(f"covariance must be a finite {len(names)} x {len(names)} array over {list(names)}, "
                             f"got shape {cov.shape}")
    n_draws = check_int("n_draws", n_draws, 1, 10**6)
    if not isinstance(rng, np.random.Generator):
        raise ParameterTypeError(f"rng must be a numpy.random.Generator, got {rng!r}")
    drawn = rng.multivariate_normal([values[n] for n in names], cov, size=n_draws)
    out = []
    for row in drawn:
        if not row[0] > 0:
            continue
        try:
            out.append(model.with_values(**{n: float(x) for n, x in zip(names, row)}))
        except ParameterError:
            continue
    other = sum(1 for m in out if np.sign(m.b) != np.sign(model.b))
    return ModelDraws(tuple(out), n_rejected=n_draws - len(out), n_other_sign=other)


def _checked_covariance(model: PlantModel, covariance: np.ndarray) -> np.ndarray:
    """``covariance`` as a finite 2 x 2 array over ``(a, b)`` or 3 x 3 over ``(a, b, electrical_time_constant)``
    (the latter only for a model with an electrical time constant)."""
    try:
        cov = np.asarray(covariance, dtype=float)
    except (TypeError, ValueError):
        cov = np.full(0, math.nan)
    if cov.shape not in ((2, 2), (3, 3)) or not np.all(np.isfinite(cov)):
        found = f"shape {cov.shape}" if cov.shape not in ((2, 2), (3, 3)) else "non-finite entries"
        raise ParameterError(f"covariance must be a finite 2 x 2 array of (a, b), or 3 x 3 of (a, b, "
                             f"electrical_time_constant), got {found if cov.size else repr(covariance)}")
    if len(cov) == 3 and not model.electrical_time_constant > 0:
        raise ParameterError("covariance is 3 x 3 (a, b, electrical_time_constant) but the model has no electrical "
                             "time constant to draw around (electrical_time_constant="
                             f"{model.electrical_time_constant!r}); pass the 2 x 2 block of (a, b)")
    return cov


def _draw_rms(controller: Controller, model: PlantModel, r_ahead: np.ndarray, ref: np.ndarray,
              t: np.ndarray, laws: Any = None) -> float:
    import control
    cr, cy = controller.laws() if laws is None else laws
    p = _plant(controller, model)
    sensitivity = control.feedback(control.tf([1.0], [1.0], model.sample_period), p * cy, sign=1)
    y = np.asarray(control.forced_response(p * sensitivity * cr, timepts=t, inputs=r_ahead).outputs, dtype=float)
    scale = model.angle_scale if controller.quantity == "angle" else model.speed_scale
    return float(np.sqrt(np.mean((ref[1:] - y[1:] / scale) ** 2)))


def _damping_ok(loop: Any, h: float) -> bool:
    poles = _closed_loop_poles(loop)
    poles = poles[np.abs(poles) > 1e-9]
    s = np.log(poles.astype(complex)) / h
    zeta = -s.real / np.maximum(np.abs(s), 1e-300)
    return bool(np.all(zeta >= BADLY_DAMPED))


def analyse_robustness(controller: Controller, covariance: np.ndarray, reference: Reference, duration: float, *,
                       n_draws: int = 200, percentile: float = 95.0, rng: np.random.Generator,
                       models: Sequence[PlantModel] | None = None) -> Robustness:
    """The controller's margins and predicted tracking across plants drawn from the covariance.

    Parameters
    ----------
    controller : Controller
        Designed at the point estimate; its gains are kept for every drawn plant.
    covariance : array_like, shape (2, 2) or (3, 3)
        Covariance of ``(a, b)`` (e.g. ``Estimate.covariance`` restricted to them), or of ``(a, b,
        electrical_time_constant)`` to draw that too (:func:`draw_models`).
    reference : Reference
        What the loop tracks (rad/s, or rad for position).
    duration : float
        Length of the predicted response in s.
    n_draws : int
        Plants drawn (default 200).
    percentile : float
        Percentile of the tracking RMS reported besides the worst case, % (default 95).
    rng : numpy.random.Generator
        The source of the draws (seed it for a reproducible analysis).
    models : sequence of PlantModel, optional
        Plants to use instead of drawing (e.g. the same draws for several designs); the
        :class:`ModelDraws` of :func:`draw_models` bring what their draw left out.

    Returns
    -------
    Robustness

    Examples
    --------
    >>> from motorsim.control import PISpeed, parse_reference
    >>> pi = PISpeed(PlantModel(25.0, 3.0, 0.005, 16667))
    >>> r = analyse_robustness(pi, [[0.25, 0.02], [0.02, 0.0025]], parse_reference("sine:10,10"), 1.0,
    ...                        n_draws=20, rng=np.random.default_rng(0))
    >>> r.unstable, r.worst_rms >= r.percentile_rms
    (0.0, True)
    """
    duration = check_real("duration", duration, positive=True)
    percentile = check_real("percentile", percentile)
    if not 0.0 <= percentile <= 100.0:
        raise ParameterError(f"percentile must be in 0...100 %, got {percentile!r}")
    model = controller.model
    drawn = models if models is not None else draw_models(model, covariance, n_draws, rng)
    draws = list(drawn)
    n_rejected = drawn.n_rejected if isinstance(drawn, ModelDraws) else 0
    if not draws:
        raise ParameterError(f"no plant to analyse: all {n_rejected} plants drawn from the covariance have a <= 0; "
                             "the model's a is not known well enough for a robustness analysis")
    other = sum(np.sign(m.b) != np.sign(model.b) for m in draws)
    tau_drawn = any(m.electrical_time_constant != model.electrical_time_constant for m in draws)
    if isinstance(model.plant, Motor):
        drawn_names, refused = ("a, b, tau_e", "a <= 0 or tau_e < 0") if tau_drawn else ("a, b", "a <= 0")
    else:                       # another structure: the values that differ among the draws
        point = model.plant.values()
        drawn_names = ", ".join(n for n in point if any(m.plant.values()[n] != point[n] for m in draws)) or "none"
        refused = "a <= 0 or a value outside its bounds"
    h = model.sample_period
    n = int(round(duration / h))
    r = reference.samples(n + controller.preview, h, controller.reference_scale).astype(float)
    t = np.arange(n) * h
    r_ahead, ref = r[controller.preview:controller.preview + n], r[:n] / controller.reference_scale
    laws = controller.laws()       # the gains are kept: one design (an LQR's is a Riccati solve) for every draw
    rms, margins, unstable, damped = [], [], 0, 0
    for m in draws:
        loop = _loop(controller, m, laws)
        mg = _margins(loop)
        margins.append(mg)
        if not mg.stable:
            unstable += 1
            rms.append(math.inf)
            continue
        damped += not _damping_ok(loop, h)
        rms.append(_draw_rms(controller, m, r_ahead, ref, t, laws))
    rms_a = np.array(rms)
    gms = [g.gain_margin for g in margins]
    return Robustness(
        point=_margins(_loop(controller, None, laws)), tracking_rms=_draw_rms(controller, model, r_ahead, ref, t, laws),
        worst_rms=float(rms_a.max()), percentile_rms=float(np.percentile(rms_a, percentile, method="higher")),
        worst_gain_margin=float(min(gms, key=lambda g: abs(math.log(g)) if g > 0 else math.inf)),
        worst_phase_margin=float(min(g.phase_margin for g in margins)),
        worst_delay_margin=float(min(g.delay_margin for g in margins)),
        percentile=percentile, unstable=unstable / len(draws), badly_damped=damped / len(draws),
        n_draws=len(draws), n_rejected=n_rejected, other_sign=other / len(draws),
        method=f"Monte Carlo: {len(draws)} plants ({drawn_names}) drawn from a normal "
               "distribution with the model's covariance (seeded)"
               + (f", {n_rejected} more with {refused} left out"
                  if n_rejected else "")
               + (f", electrical time constant {model.electrical_time_constant:g} s kept in every plant"
                  if model.electrical_time_constant and not tau_drawn else "")
               + ", not a guaranteed bound")


def robust_design(kind: str, model: PlantModel, covariance: np.ndarray, reference: Reference, duration: float, *,
                  n_draws: int = 200, rng: np.random.Generator, **settings: Any) -> tuple[Controller, Robustness]:
    """The controller whose knob gives the best worst-case tracking RMS over plants drawn from the covariance.

    The knob (:data:`ROBUST_KNOB`: ``duty_weight`` of ``mpc`` and the LQRs,
    ``time_constant`` of ``pi`` and ``position``) is tried at factors 0.25 ... 4 of its given or
    default value; every candidate is judged on the same draws: the fewest unstable draws, then
    the fewest badly damped ones, then the smallest worst-case tracking RMS wins.  A time constant
    shorter than the design's ``min_phase_margin`` allows is tried once, at that limit, without a
    warning.

    Parameters
    ----------
    kind : str
        ``mpc``, ``pi``, ``position``, ``lqr``, ``lqr-integral`` or ``lqr-position``.
    model : PlantModel
        The point estimate.
    covariance : array_like, shape (2, 2) or (3, 3)
        Covariance of ``(a, b)``, or of ``(a, b, electrical_time_constant)`` (:func:`draw_models`).
    reference : Reference
        What the loop tracks.
    duration : float
        Length of the predicted response in s.
    n_draws : int
        Plants drawn (default 200).
    rng : numpy.random.Generator
        The source of the draws.
    **settings
        The controller's other settings (and the knob's starting value).

    Returns
    -------
    (Controller, Robustness)
        The chosen design and its analysis.
    """
    if kind not in ROBUST_KNOB:
        raise ParameterError(f"kind must be one of {sorted(ROBUST_KNOB)} for a robust design, got {kind!r}")
    knob = ROBUST_KNOB[kind]
    start = settings.pop(knob, None)
    if start is None:
        start = getattr(design_controller(kind, model, **settings), knob)
    draws = draw_models(model, covariance, n_draws, rng)
    best: tuple[tuple[float, float, float], Controller, Robustness] | None = None
    tried = set()
    for factor in _KNOB_FACTORS:
        try:
            with warnings.catch_warnings():
                # a time constant below what the phase margin allows is designed at that limit: one candidate
                warnings.simplefilter("ignore", DesignLimitWarning)
                candidate = design_controller(kind, model, **settings, **{knob: start * factor})
        except ParameterError:
            continue
        if getattr(candidate, knob) in tried:
            continue
        tried.add(getattr(candidate, knob))
        result = analyse_robustness(candidate, covariance, reference, duration, rng=rng, models=draws)
        score = (result.unstable, result.badly_damped, result.worst_rms)
        if best is None or score < best[0]:
            best = (score, candidate, result)
    if best is None:  # pragma: no cover - the starting value itself is a valid design
        raise ParameterError(f"no {kind} design could be made around {knob} = {start!r}")
    return best[1], best[2]
