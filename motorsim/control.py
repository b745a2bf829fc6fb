"""Controllers designed from a model: their gains, their predicted closed loop, the references they track.

A controller is designed once, in floating point, from the numbers of a motor model
(:class:`PlantModel`: ``a``, ``b``, ``friction``, ``bias``, ``input_delay``,
``sample_period``, ``counts_per_rev``; built from an identified estimate, a
:class:`~motorsim.plant.Motor` or plain numbers).  The design ends in a handful of
integer gains (Q16: a gain ``G`` stands for ``G / 2**16``), and the per-sample step
uses integers only: that step, shared with the firmware, and its integer units are
:mod:`motorsim.fixed_point` (:class:`~motorsim.fixed_point.ControlLoop`, which
:meth:`Controller.start` returns).

Exact model of the measured speed
---------------------------------
With ``e = exp(-a h)`` and the ZOH coefficients ``g, p, q`` of :func:`~motorsim.plant.zoh_matrices`,
the averaged speed ``y_k = (angle_k - angle_{k-1}) / h`` obeys exactly::

    y_{k+1} = e y_k + beta1 v_{k-D} + beta2 v_{k-D-1},   beta1 = q / h,  beta2 = (p g - e q) / h,

``beta1 + beta2 = g``, where ``v = u + (bias - friction sign(omega)) / b`` is the drive and
``D`` the input delay.  :meth:`PlantModel.speed_transfer_function` is this model in counts
per sample; every controller's :meth:`~Controller.predict` closes the loop on it with
python-control (``feedback``, ``forced_response``), delay included, using the quantised gains.

Controllers
-----------
:class:`OneStepMPC` (``mpc``), :class:`PISpeed` (``pi``, optionally with feedforward),
:class:`PositionPD` (``position``), :class:`Feedforward` (``feedforward``), :class:`LQRSpeed` (``lqr``),
:class:`LQRSpeedIntegral` (``lqr-integral``, with the speed error's integral in the state) and
:class:`LQRPosition` (``lqr-position``): LQR on the model with the input delay in the state.
The pole-placement designs (``pi``, ``position``) keep ``min_phase_margin`` on the exact model,
input delay included (:meth:`Controller.margins`), lengthening a time constant that cannot.
:class:`ClosedLoopExperiment` asks a rig to run one of them against a :class:`Reference`.

One concept, controller design, in one module although it is long: the model, the
references and the closed-loop experiment are what every controller's design and
prediction take and give, and the controllers share one base class.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import TYPE_CHECKING, Any, ClassVar, Mapping, Sequence

import numpy as np

from .checks import ParameterError, ParameterTypeError, check_int, check_real
from .excitation import DUTY_LIMIT, MAX_COMPONENTS, phase_increment, spec_numbers, split_spec
from .fixed_point import (
    MAX_REFERENCE,
    SPEED_REFERENCE_BITS,
    SPEED_REFERENCE_LSB,
    ControlLoop,
    ReferenceWords,
    gain_value,
    quantise_gain,
    reference_values,
)
from .margins import Margins, discrete_margins
from .plant import Motor, zoh_matrices

if TYPE_CHECKING:
    import control

__all__ = ["PlantModel", "Reference", "parse_reference", "Controller", "OneStepMPC", "PISpeed", "PositionPD",
           "Feedforward", "LQRSpeed", "LQRSpeedIntegral", "LQRPosition", "Prediction", "ClosedLoopExperiment",
           "CONTROLLERS", "design_controller", "tracking_error", "feedforward_gains", "settings_from",
           "DesignLimitWarning", "MIN_PHASE_MARGIN", "INTEGRAL_WEIGHT"]


# ----------------------------------------------------------------------------------------------------------
# The model
# ----------------------------------------------------------------------------------------------------------

#: The most samples :meth:`Controller.predict` simulates (10 s at 1 MHz; a few seconds of work).
MAX_PREDICTION_SAMPLES = 10_000_000


@dataclasses.dataclass(frozen=True)
class PlantModel:
    """The numbers a controller is designed from.

    Parameters
    ----------
    a : float
        Pole in 1/s, > 0.
    b : float
        Gain in (rad/s^2)/duty, nonzero.
    sample_period : float
        Controller sample period in s, > 0.
    counts_per_rev : int
        Encoder counts per revolution.
    friction : float, optional
        Coulomb friction ``c`` in rad/s^2, >= 0.
    bias : float, optional
        Constant acceleration ``d`` in rad/s^2.
    input_delay : int, optional
        Whole samples between a duty and the motor, >= 0.

    Examples
    --------
    >>> m = PlantModel(25.0, 3.0, 0.005, 16667)
    >>> round(m.speed_scale, 4)   # counts per sample per rad/s
    13.2632
    """

    a: float
    b: float
    sample_period: float
    counts_per_rev: int
    friction: float = 0.0
    bias: float = 0.0
    input_delay: int = 0

    def __post_init__(self):
        motor = Motor(self.a, self.b, friction=self.friction, bias=self.bias, input_delay=self.input_delay)
        for name in ("a", "b", "friction", "bias", "input_delay"):
            object.__setattr__(self, name, getattr(motor, name))
        if self.input_delay > 50:
            raise ParameterError(f"input_delay must be <= 50 samples for a controller, got {self.input_delay!r}")
        object.__setattr__(self, "sample_period", check_real("sample_period", self.sample_period, positive=True))
        object.__setattr__(self, "counts_per_rev", check_int("counts_per_rev", self.counts_per_rev, 1, 2**31 - 1))

    @classmethod
    def from_source(cls, source: Any, sample_period: float | None = None,
                    counts_per_rev: int | None = None) -> "PlantModel":
        """A model from an identified estimate, a :class:`Motor` or a :class:`PlantModel`.

        Parameters
        ----------
        source : Estimate, Motor or PlantModel
            Anything with ``a`` and ``b``; an estimate's ``extra`` gives ``friction``,
            ``bias`` and ``input_delay``, a Motor's fields give them directly.
        sample_period : float, optional
            Controller sample period in s (default: the source's, if it has one).
        counts_per_rev : int, optional
            Encoder resolution (default: the source's, if it has one).
        """
        if isinstance(source, PlantModel):
            return dataclasses.replace(source, sample_period=sample_period or source.sample_period,
                                       counts_per_rev=counts_per_rev or source.counts_per_rev)
        if not (hasattr(source, "a") and hasattr(source, "b")):
            raise ParameterTypeError("source must be an Estimate, a Motor or a PlantModel, "
                                     f"got {type(source).__name__}")
        extra = dict(getattr(source, "extra", {}) or {})
        for name in ("friction", "bias", "input_delay"):
            if hasattr(source, name) and not isinstance(source, type):
                extra.setdefault(name, getattr(source, name))
        sample_period = sample_period if sample_period is not None else getattr(source, "sample_period", None)
        if sample_period is None:
            raise ParameterError("sample_period must be given when the source has none, got None")
        if counts_per_rev is None:
            raise ParameterError("counts_per_rev must be given for a controller, got None")
        return cls(float(source.a), float(source.b), sample_period, counts_per_rev,
                   friction=float(extra.get("friction", 0.0)), bias=float(extra.get("bias", 0.0)),
                   input_delay=int(extra.get("input_delay", 0)))

    @property
    def speed_scale(self) -> float:
        """Counts per sample per rad/s: ``counts_per_rev sample_period / (2 pi)``."""
        return self.counts_per_rev * self.sample_period / (2.0 * math.pi)

    @property
    def angle_scale(self) -> float:
        """Counts per rad: ``counts_per_rev / (2 pi)``."""
        return self.counts_per_rev / (2.0 * math.pi)

    def speed_coefficients(self) -> tuple[float, float, float, float]:
        """``(e, g, beta1, beta2)`` of the exact model (module docstring), in counts per sample per duty."""
        e, g, p, q = (float(x) for x in zoh_matrices(self.a, self.b, self.sample_period))
        h, s = self.sample_period, self.speed_scale
        return e, g * s, q / h * s, (p * g - e * q) / h * s

    def drive_offset(self, sign: int) -> float:
        """``(bias - friction sign) / b`` in duty: what the drive adds when the speed has ``sign``."""
        return (self.bias - self.friction * sign) / self.b

    def speed_transfer_function(self) -> control.TransferFunction:
        """Duty to measured speed (counts per sample), ``(beta1 z + beta2) / (z^(D+1) (z - e))``."""
        import control
        e, _, b1, b2 = self.speed_coefficients()
        den = np.polymul(np.r_[1.0, np.zeros(self.input_delay + 1)], [1.0, -e])
        return control.tf([b1, b2], den, self.sample_period)

    def metadata(self) -> dict[str, str]:
        """The model as recording metadata ``model_NAME``."""
        return {f"model_{f.name}": repr(getattr(self, f.name)) for f in dataclasses.fields(self)}


# ----------------------------------------------------------------------------------------------------------
# References
# ----------------------------------------------------------------------------------------------------------

_REFERENCE_HELP = ("constant:LEVEL  step:AFTER[,AT_TIME[,BEFORE]]  sine:FREQ,AMP[,PHASE][@OFFSET]  "
                   "multisine:F,A,P;F,A,P...[@OFFSET]  trapezoid:LEVEL,RAMP_TIME,HOLD_TIME[,AT_TIME]")


@dataclasses.dataclass(frozen=True)
class Reference:
    """A reference wave in physical units (rad/s for speed, rad for position), integer-exact on a device.

    Parameters
    ----------
    kind : str
        ``constant``, ``step``, ``sine``, ``multisine`` or ``trapezoid``.
    level : float
        Constant level; step value after the switch; trapezoid plateau; sine offset.
    frequencies, amplitudes, phases : tuple of float
        Sine components (rad/s, physical unit, rad); ``sine`` has one, ``multisine`` up to 4.
    at_time : float
        Step switch or trapezoid start in s (rounded to a sample).
    before : float
        Step value before the switch.
    ramp_time, hold_time : float
        Trapezoid ramp and plateau durations in s (rounded to samples).

    Notes
    -----
    :meth:`samples` turns the wave into integers of the controller's reference unit:
    levels ``L = round(level scale)``; sines as the excitations compute them
    (``multisine_duty`` of :mod:`motorsim.excitation`, amplitudes ``round(A scale)``);
    trapezoid ramps ``floor(L i / n_ramp)``.

    Examples
    --------
    >>> r = parse_reference("trapezoid:10,0.02,0.01")
    >>> r.samples(11, 0.005, 1.0).tolist()   # the level is held from 0.02 s to 0.03 s
    [0, 2, 5, 7, 10, 10, 10, 7, 5, 2, 0]
    """

    kind: str
    level: float = 0.0
    frequencies: tuple = ()
    amplitudes: tuple = ()
    phases: tuple = ()
    at_time: float = 0.0
    before: float = 0.0
    ramp_time: float = 0.0
    hold_time: float = 0.0
    kinds: ClassVar[tuple[str, ...]] = ("constant", "step", "sine", "multisine", "trapezoid")

    def __post_init__(self):
        if self.kind not in self.kinds:
            raise ParameterError(f"reference kind must be one of {', '.join(self.kinds)}, got {self.kind!r}")
        for name in ("level", "at_time", "before", "ramp_time", "hold_time"):
            object.__setattr__(self, name, check_real(name, getattr(self, name)))
        f = tuple(check_real("frequencies", x, positive=True) for x in self.frequencies)
        a = tuple(check_real("amplitudes", x) for x in self.amplitudes)
        p = tuple(check_real("phases", x) for x in self.phases) or (0.0,) * len(f)
        if self.kind in ("sine", "multisine") and not (1 <= len(f) <= MAX_COMPONENTS and len(a) == len(f) == len(p)):
            raise ParameterError(f"a {self.kind} reference needs 1...{MAX_COMPONENTS} components of equal length, "
                             f"got {len(f)} frequencies, {len(a)} amplitudes, {len(p)} phases")
        if self.kind == "trapezoid" and self.ramp_time <= 0:
            raise ParameterError(f"ramp_time must be > 0 s for a trapezoid, got {self.ramp_time!r}")
        if min(self.at_time, self.hold_time) < 0:
            raise ParameterError(f"at_time and hold_time must be >= 0 s, got {self.at_time!r}, {self.hold_time!r}")
        object.__setattr__(self, "frequencies", f)
        object.__setattr__(self, "amplitudes", a)
        object.__setattr__(self, "phases", p)

    def samples(self, n_samples: int, sample_period: float, scale: float) -> np.ndarray:
        """The integer reference for samples ``0 ... n_samples-1`` (int64).

        Parameters
        ----------
        n_samples : int
            Number of samples.
        sample_period : float
            Sample period in s.
        scale : float
            Integer units per physical unit (e.g. 1/16 count per sample per rad/s).
        """
        return reference_values(self.words(sample_period, scale), n_samples)

    def words(self, sample_period: float, scale: float) -> ReferenceWords:
        """The integers a device generates this reference from (see :func:`reference_values`).

        Parameters
        ----------
        sample_period : float
            Sample period in s.
        scale : float
            Integer units per physical unit.
        """
        dt = check_real("sample_period", sample_period, positive=True)

        def lsb(x: float, name: str) -> int:
            units = x * scale
            if not abs(units) <= MAX_REFERENCE:     # also an overflow to inf
                raise ParameterError(f"reference {name} {x!r} is {units:.4g} units of the controller's reference, "
                                     f"beyond the device's limit +-{MAX_REFERENCE}")
            return int(round(units))

        if self.kind == "constant":
            return ReferenceWords("constant", lsb(self.level, "level"))
        if self.kind == "step":
            return ReferenceWords("step", lsb(self.level, "after"), lsb(self.before, "before"),
                                  int(round(self.at_time / dt)))
        if self.kind == "trapezoid":
            return ReferenceWords("trapezoid", lsb(self.level, "level"), 0, int(round(self.at_time / dt)),
                                  max(1, int(round(self.ramp_time / dt))), int(round(self.hold_time / dt)))
        amps = [lsb(x, "amplitude") for x in self.amplitudes]
        if sum(abs(x) for x in amps) > MAX_REFERENCE:
            raise ParameterError(f"reference amplitudes sum to {sum(abs(x) for x in amps)} units, "
                             f"beyond the device's limit {MAX_REFERENCE}")
        comps = []
        for f, amp, ph in zip(self.frequencies, amps, self.phases):
            if f * dt >= math.pi:
                raise ParameterError(f"reference frequencies must be below pi/sample_period = {math.pi / dt:.6g} "
                                 f"rad/s, got {f!r}")
            comps.append((amp, int(round(ph / (2 * math.pi) * 2**32)) % 2**32, phase_increment(f, dt)))
        return ReferenceWords("multisine", lsb(self.level, "offset"), components=tuple(comps))

    def describe(self) -> str:
        """A one-line spec that :func:`parse_reference` reads back."""
        if self.kind == "constant":
            return f"constant:{self.level!r}"
        if self.kind == "step":
            return f"step:{self.level!r},{self.at_time!r},{self.before!r}"
        if self.kind == "trapezoid":
            return f"trapezoid:{self.level!r},{self.ramp_time!r},{self.hold_time!r},{self.at_time!r}"
        parts = ";".join(f"{f!r},{a!r},{p!r}" for f, a, p in zip(self.frequencies, self.amplitudes, self.phases))
        return f"{self.kind}:{parts}" + (f"@{self.level!r}" if self.level else "")


def parse_reference(spec: str) -> Reference:
    """Read a reference from its one-line form (see :meth:`Reference.describe`).

    Parameters
    ----------
    spec : str
        ``constant:LEVEL``, ``step:AFTER[,AT_TIME[,BEFORE]]``, ``sine:FREQ,AMP[,PHASE][@OFFSET]``,
        ``multisine:F,A,P;...[@OFFSET]`` or ``trapezoid:LEVEL,RAMP_TIME,HOLD_TIME[,AT_TIME]``;
        levels and amplitudes in rad/s (speed controllers) or rad (position).

    Examples
    --------
    >>> parse_reference("sine:10,20@5").describe()
    'sine:10.0,20.0,0.0@5.0'
    """
    kind, args, offset = split_spec(spec, "reference", _REFERENCE_HELP)
    if kind in ("sine", "multisine"):
        comps = [_numbers(c, spec) for c in args.split(";") if c.strip()]
        if not comps or any(not 2 <= len(c) <= 3 for c in comps) or (kind == "sine" and len(comps) != 1):
            raise ParameterError(f"reference {spec!r}: {kind} takes FREQ,AMP[,PHASE] per component")
        return Reference(kind, offset, tuple(c[0] for c in comps), tuple(c[1] for c in comps),
                         tuple(c[2] if len(c) > 2 else 0.0 for c in comps))
    v = _numbers(args, spec)
    forms = {"constant": (1, 1), "step": (1, 3), "trapezoid": (3, 4)}
    if kind not in forms:
        raise ParameterError(f"reference kind must be one of {', '.join(Reference.kinds)}, got {kind!r}")
    lo, hi = forms[kind]
    if not lo <= len(v) <= hi:
        raise ParameterError(f"reference {spec!r}: expected {_REFERENCE_HELP}")
    if kind == "constant":
        return Reference("constant", v[0])
    if kind == "step":
        return Reference("step", v[0], at_time=v[1] if len(v) > 1 else 0.0, before=v[2] if len(v) > 2 else 0.0)
    return Reference("trapezoid", v[0], ramp_time=v[1], hold_time=v[2], at_time=v[3] if len(v) > 3 else 0.0)


def _numbers(text: str, spec: str) -> list[float]:
    return spec_numbers(text, spec, "reference", _REFERENCE_HELP)


# ----------------------------------------------------------------------------------------------------------
# Controllers
# ----------------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Prediction:
    """A closed-loop response predicted from the model (linear: no duty limit, no quantisation).

    Attributes
    ----------
    time : ndarray
        Sample instants in s.
    reference : ndarray
        The reference in physical units (rad/s or rad), as the device quantises it.
    output : ndarray
        Predicted measured speed (rad/s, differenced counts) or angle from the start (rad).
    duty : ndarray
        Predicted duty (unrounded, unclipped).
    tracking_rms : float
        RMS of ``reference - output`` over samples 1 ... n-1, in the reference's unit.
    """

    time: np.ndarray
    reference: np.ndarray
    output: np.ndarray
    duty: np.ndarray
    tracking_rms: float


@dataclasses.dataclass(frozen=True)
class Controller:
    """Base class: a controller designed from a :class:`PlantModel`.

    Subclasses set ``kind`` and ``quantity`` and define :meth:`gains` (the fixed-point
    parameters a device receives) and :meth:`laws` (the same law as transfer functions).
    """

    model: PlantModel
    kind: ClassVar[str] = ""
    quantity: ClassVar[str] = "speed"

    def __post_init__(self):
        if not isinstance(self.model, PlantModel):
            raise ParameterTypeError(f"model must be a PlantModel, got {type(self.model).__name__}")

    @property
    def preview(self) -> int:
        """Samples of reference the step looks ahead (``input_delay + 1`` for model-based laws, else 0)."""
        return self.model.input_delay + 1

    @property
    def reference_scale(self) -> float:
        """Integer reference units per physical unit (per rad/s, or per rad for position)."""
        if self.quantity == "angle":
            return self.model.angle_scale
        return self.model.speed_scale / SPEED_REFERENCE_LSB

    @property
    def reference_unit(self) -> str:
        """``rad/s`` (speed controllers) or ``rad`` (position)."""
        return "rad" if self.quantity == "angle" else "rad/s"

    def gains(self) -> dict[str, int]:  # pragma: no cover - abstract
        """The fixed-point parameters of the step, by name (Q16 integers)."""
        raise NotImplementedError

    def settings(self) -> dict[str, float | bool]:
        """The design knobs (every field but the model)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "model"}

    def laws(self) -> tuple[control.TransferFunction, control.TransferFunction]:  # pragma: no cover
        """``(Cr, Cy)``: duty from the previewed reference and from the measurement, ``u = Cr r + Cy y``."""
        raise NotImplementedError

    def start(self, reference: Sequence[int] | np.ndarray, duty_limit: int = DUTY_LIMIT) -> ControlLoop:
        """A fresh :class:`ControlLoop` on the integer ``reference``."""
        return ControlLoop(self.kind, self.gains(), self.preview, reference, duty_limit)

    def plant(self) -> control.TransferFunction:
        """Duty to what the controller measures: speed in counts/sample, or counts for position."""
        import control
        p = self.model.speed_transfer_function()
        if self.quantity == "angle":
            p = p * control.tf([1.0, 0.0], [1.0, -1.0], self.model.sample_period)
        return p

    def closed_loop(self) -> tuple[control.TransferFunction, control.TransferFunction]:
        """``(T_y, T_u)``: previewed reference to measured output and to duty, via ``control.feedback``."""
        import control
        cr, cy = self.laws()
        p = self.plant()
        sensitivity = control.feedback(control.tf([1.0], [1.0], self.model.sample_period), p * cy, sign=1)
        t_u = sensitivity * cr
        return p * t_u, t_u

    def margins(self) -> Margins:
        """Gain, phase and delay margins of the loop broken at the duty, ``L = -Cy P``, on the model (delay included).

        :func:`motorsim.robustness.loop_margins` gives the same on another plant.
        """
        _, cy = self.laws()
        loop = -(self.plant() * cy)
        return discrete_margins(np.ravel(loop.num[0][0]), np.ravel(loop.den[0][0]), self.model.sample_period)

    def is_stable(self) -> bool:
        """Whether every closed-loop pole lies inside the unit circle."""
        import control
        cr, cy = self.laws()
        loop = control.feedback(-(self.plant() * cy), 1)
        return bool(np.all(np.abs(loop.poles()) < 1.0 - 1e-12))

    def predict(self, reference: Reference, duration: float) -> Prediction:
        """The closed-loop response to ``reference`` over ``duration`` s (``control.forced_response``).

        Parameters
        ----------
        reference : Reference
            The wave, in rad/s (speed controllers) or rad (position).
        duration : float
            Run length in s (``round(duration / sample_period)`` samples).
        """
        import control
        h = self.model.sample_period
        n_float = check_real("duration", duration, positive=True) / h
        if n_float > MAX_PREDICTION_SAMPLES:
            raise ParameterError(f"duration / sample_period must give at most {MAX_PREDICTION_SAMPLES:,} samples "
                                 f"for a prediction, got {duration!r} s / {h!r} s = {n_float:.3g}; shorten the "
                                 "duration or lengthen the sample period")
        n = int(round(n_float))
        r = reference.samples(n + self.preview, h, self.reference_scale).astype(float)
        t = np.arange(n) * h
        t_y, t_u = self.closed_loop()
        r_ahead = r[self.preview:self.preview + n]
        y = control.forced_response(t_y, timepts=t, inputs=r_ahead).outputs
        u = control.forced_response(t_u, timepts=t, inputs=r_ahead).outputs
        scale = self.model.angle_scale if self.quantity == "angle" else self.model.speed_scale
        ref = r[:n] / self.reference_scale
        out = np.asarray(y, dtype=float) / scale
        rms = float(np.sqrt(np.mean((ref[1:] - out[1:]) ** 2))) if n > 1 else math.nan
        return Prediction(t, ref, out, np.asarray(u, dtype=float), rms)

    def metadata(self) -> dict[str, str]:
        """Recording metadata: ``controller``, its knobs, gains and the model it was designed from."""
        meta = {"controller": self.kind, "controlled": self.quantity, "reference_unit": self.reference_unit}
        meta.update({f"controller_{k}": repr(v) for k, v in self.settings().items()})
        meta["controller_gains"] = " ".join(f"{k}={v}" for k, v in self.gains().items())
        meta.update(self.model.metadata())
        return meta


def _fir(coefficients: Sequence[float], dt: float) -> control.TransferFunction:
    """``c0 + c1 z^-1 + ... + cm z^-m`` as a transfer function in z."""
    import control
    den = np.r_[1.0, np.zeros(len(coefficients) - 1)]
    return control.tf(list(coefficients), den, dt)


@dataclasses.dataclass(frozen=True)
class OneStepMPC(Controller):
    """One-step model predictive control of the speed (the plan of the article's section 6).

    At each sample, the integer duty ``u_k`` in ``-duty_limit ... duty_limit`` that minimises
    ``J(u) = (r_{k+D+1} - y_hat_{k+D+1})^2 + duty_weight u^2``, where ``y_hat`` is the exact
    model's prediction of the measured speed (module docstring) ``D + 1`` samples ahead
    (the first sample the duty can affect), friction taken with the reference's sign.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        lambda in (rad/s)^2 per duty^2, >= 0 (default 1e-4).

    Notes
    -----
    ``y_hat = f + beta1 u`` with ``f`` known at sample ``k``, so ``J`` is a convex quadratic
    in one variable, symmetric about ``u* = beta1 (r - f) / (beta1^2 + lambda)``.  Over the
    integers of an interval its minimum is therefore the integer nearest ``u*`` clipped to
    the interval: ``J`` grows with the distance to ``u*`` on both sides, so rounding picks
    the nearest integer, and when ``u*`` lies outside the interval ``J`` is monotone on it
    and the limit nearest ``u*`` wins.  No search is needed: the step is one linear form
    in ``r``, ``y_k`` and the past duties, rounded and clipped.

    The cost weighs the whole duty, so the model's bias and friction are compensated by
    the fraction ``beta1^2 / (beta1^2 + lambda)`` of their duty equivalent, and a constant
    reference keeps a steady error when ``lambda > 0`` (there is no integral action);
    ``lambda`` near 0 approaches dead-beat control of the measured speed, whose duty rings
    at the zero ``-beta2 / beta1`` (about -0.96 at 5 ms) of the differenced-counts model.

    Examples
    --------
    >>> mpc = OneStepMPC(PlantModel(25.0, 3.0, 0.005, 16667))
    >>> sorted(mpc.gains())
    ['k0', 'kf', 'kr', 'ku1', 'ky']
    >>> mpc.is_stable()
    True
    """

    duty_weight: float = 1e-4
    kind: ClassVar[str] = "mpc"

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "duty_weight", check_real("duty_weight", self.duty_weight, nonnegative=True))

    def _coefficients(self) -> tuple[float, list[float], float, float]:
        """``(K, [c_1 ... c_{D+1}], e^(D+1), g S_D)`` of ``y_hat = e^(D+1) y + beta1 u + sum c_m u_{k-m} + g S_D o``."""
        m = self.model
        e, g, b1, b2 = m.speed_coefficients()
        d = m.input_delay
        c = [(e ** j * b1 if j <= d else 0.0) + e ** (j - 1) * b2 for j in range(1, d + 2)]
        weight = self.duty_weight * m.speed_scale ** 2
        if b1 * b1 + weight == 0:  # pragma: no cover - b != 0 makes beta1 != 0
            raise ParameterError("the model's beta1 is zero: the duty does not reach the next sample")
        return b1 / (b1 * b1 + weight), c, e ** (d + 1), g * sum(e ** j for j in range(d + 1))

    def gains(self) -> dict[str, int]:
        k, c, e_ahead, gs = self._coefficients()
        m = self.model
        out = {"kr": quantise_gain(k * SPEED_REFERENCE_LSB), "ky": quantise_gain(-k * e_ahead),
               "k0": quantise_gain(-k * gs * m.bias / m.b), "kf": quantise_gain(k * gs * m.friction / m.b)}
        out.update({f"ku{j}": quantise_gain(-k * cj) for j, cj in enumerate(c, 1)})
        return out

    def laws(self):
        return _delay_line_laws(self.gains(), self.model)


@dataclasses.dataclass(frozen=True)
class Feedforward(Controller):
    """Speed feedforward from the model alone: the duty that makes the model follow the reference.

    ``u_k = (r_{k+D+1} - e r_{k+D}) / g + (friction sign(r_{k+D+1}) - bias) / b``: the exact
    ZOH form of ``u = (d omega_ref/dt + a omega_ref - bias + friction sign omega_ref) / b``.

    Parameters
    ----------
    model : PlantModel
        The motor model.

    Examples
    --------
    >>> Feedforward(PlantModel(25.0, 3.0, 0.005, 16667)).gains()["kn"] >= 0
    True
    """

    kind: ClassVar[str] = "feedforward"

    def gains(self) -> dict[str, int]:
        return feedforward_gains(self.model)

    def laws(self):
        g, dt = self.gains(), self.model.sample_period
        return _fir([gain_value(g["kn"]), gain_value(g["kc"])], dt), _fir([0.0], dt)


def feedforward_gains(model: PlantModel) -> dict[str, int]:
    """Q16 gains ``kn, kc, k0, kf`` of the speed feedforward (see :class:`Feedforward`)."""
    e, g, _, _ = model.speed_coefficients()
    return {"kn": quantise_gain(SPEED_REFERENCE_LSB / g), "kc": quantise_gain(-e * SPEED_REFERENCE_LSB / g),
            "k0": quantise_gain(-model.bias / model.b), "kf": quantise_gain(model.friction / model.b)}


#: The least phase margin, in degrees, a pole-placement design (``pi``, ``position``) keeps by default.
MIN_PHASE_MARGIN = 60.0


class DesignLimitWarning(UserWarning):
    """A controller was designed slower than asked, so that its loop keeps the phase margin required."""


@dataclasses.dataclass(frozen=True)
class _PolePlacement(Controller):
    """A controller whose closed-loop poles sit at ``-1/time_constant`` (s, > 0, default 0.05).

    The poles are placed on a model without the input delay; the loop on the exact model, delay
    included, must keep ``min_phase_margin`` degrees (keyword only, default :data:`MIN_PHASE_MARGIN`,
    0 turns the check off).  A time constant too short for it is lengthened to the shortest one
    that keeps it (rounded up to 3 significant digits), with a :class:`DesignLimitWarning` that
    names both; ``time_constant`` is then the one designed with.
    """

    time_constant: float = 0.05
    min_phase_margin: float = dataclasses.field(default=MIN_PHASE_MARGIN, kw_only=True)

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "time_constant", check_real("time_constant", self.time_constant, positive=True))
        margin = check_real("min_phase_margin", self.min_phase_margin)
        if not 0.0 <= margin < 180.0:
            raise ParameterError(f"min_phase_margin must be in 0...180 deg, got {margin!r}")
        object.__setattr__(self, "min_phase_margin", margin)
        if margin == 0.0:
            return
        achieved = self.margins()
        if self._keeps_margin(achieved):
            return
        asked = self.time_constant
        fastest = self._fastest_time_constant()
        what = (f"leaves a phase margin of {achieved.phase_margin:.3g} deg" if achieved.stable
                else "gives an unstable loop")
        delay = self.model.input_delay
        warnings.warn(f"{self.kind} time_constant {asked!r} s {what} on the model (input delay {delay} "
                      f"sample{'' if delay == 1 else 's'} at {self.model.sample_period!r} s); designed with "
                      f"time_constant {fastest!r} s, the shortest that keeps min_phase_margin {margin:g} deg "
                      "(min_phase_margin 0 keeps the time constant asked for)", DesignLimitWarning, stacklevel=3)
        object.__setattr__(self, "time_constant", fastest)

    def _keeps_margin(self, margins: Margins) -> bool:
        return margins.stable and margins.phase_margin >= self.min_phase_margin

    def _keeps_margin_at(self, time_constant: float) -> bool | None:
        """Whether the design at ``time_constant`` keeps the margin (None: the fixed point cannot hold it)."""
        try:
            candidate = dataclasses.replace(self, time_constant=time_constant, min_phase_margin=0.0)
            return self._keeps_margin(candidate.margins())
        except ParameterError:
            return None

    def _fastest_time_constant(self) -> float:
        """The shortest time constant above ``time_constant`` that keeps ``min_phase_margin``, 3 digits, rounded up."""
        failing = passing = self.time_constant
        while True:
            passing *= 1.25
            ok = self._keeps_margin_at(passing)
            if ok:
                break
            if ok is None or passing > 1e4 * self.time_constant:
                raise ParameterError(f"min_phase_margin {self.min_phase_margin:g} deg cannot be kept by a {self.kind} "
                                     f"design with time_constant >= {self.time_constant!r} s on this model; "
                                     "lower min_phase_margin")
            failing = passing
        while passing / failing > 1.0 + 1e-4:
            middle = math.sqrt(failing * passing)
            if self._keeps_margin_at(middle):
                passing = middle
            else:
                failing = middle
        digits = 2 - math.floor(math.log10(passing))
        step = 10.0 ** -digits
        fastest = round(math.ceil(round(passing / step, 6)) * step, digits)
        while not self._keeps_margin_at(fastest):    # the search's tolerance, not the rounding, decided
            fastest = round(fastest + step, digits)
        return fastest


@dataclasses.dataclass(frozen=True)
class PISpeed(_PolePlacement):
    """PI speed control by pole placement on the exact ZOH model, with anti-windup.

    ``u_k = kp e_k + ki sum_{j<=k} e_j`` with ``e = r - y``; both closed-loop poles of the
    model ``y_{k+1} = e_a y_k + g u_k`` sit at ``p = exp(-sample_period / time_constant)``:
    ``kp = (e_a - p^2) / g``, ``ki = (1 - p)^2 / g``.  The sum stops growing while the duty
    is at the limit and the error pushes further into it (conditional integration).
    :meth:`predict` closes the loop on the full model (differenced counts, delay).

    The model the poles are placed on has no input delay; the loop on the full one must keep
    ``min_phase_margin`` degrees, or the time constant is lengthened until it does (a
    :class:`DesignLimitWarning` names both time constants).  On the article's motor at 5 ms the
    shortest time constants that keep 60 degrees are 16.7, 26 and 32.5 ms for an input delay of
    0, 1 and 2 samples (45 degrees: 10.7, 19.4 and 25.4 ms); a step then overshoots by about 6 %
    (about 27 % at 45 degrees), where 10 ms with one sample of delay leaves 6 degrees and 107 %.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    time_constant : float
        Closed-loop time constant in s, > 0 (default 0.05); the one designed with, when the
        phase margin asked for needs a longer one.
    feedforward : bool
        Add the model's feedforward (:class:`Feedforward`) to the PI output (default False).
    min_phase_margin : float
        Keyword only: the least phase margin in degrees of the loop on the model, input delay
        included, 0...180 (default :data:`MIN_PHASE_MARGIN`, 60; 0 keeps ``time_constant`` as given).

    Examples
    --------
    >>> pi = PISpeed(PlantModel(25.0, 3.0, 0.005, 16667), time_constant=0.05)
    >>> pi.gains()
    {'kp': 1397, 'ki': 198}
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     fast = PISpeed(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1), time_constant=0.01)
    >>> fast.time_constant, round(fast.margins().phase_margin, 1)
    (0.026, 60.1)
    >>> print(caught[0].message)    # doctest: +ELLIPSIS
    pi time_constant 0.01 s leaves a phase margin of 6.05 deg on the model (input delay 1 sample at 0.005 s); ...
    """

    feedforward: bool = False
    kind: ClassVar[str] = "pi"

    @property
    def preview(self) -> int:
        return self.model.input_delay + 1 if self.feedforward else 0

    def gains(self) -> dict[str, int]:
        e, g, _, _ = self.model.speed_coefficients()
        p = math.exp(-self.model.sample_period / self.time_constant)
        out = {"kp": quantise_gain((e - p * p) / g * SPEED_REFERENCE_LSB),
               "ki": quantise_gain((1 - p) ** 2 / g * SPEED_REFERENCE_LSB)}
        if out["ki"] == 0:
            raise ParameterError(f"time_constant {self.time_constant!r} s is too slow for the fixed-point integral "
                                 "gain (it rounds to 0); choose a shorter one")
        if self.feedforward:
            out.update(feedforward_gains(self.model))
        return out

    def laws(self):
        import control
        g, dt = self.gains(), self.model.sample_period
        c = control.tf([gain_value(g["kp"]) + gain_value(g["ki"]), -gain_value(g["kp"])], [1.0, -1.0], dt)
        delay = _fir([0.0] * self.preview + [1.0], dt)
        cr = c * delay
        if self.feedforward:
            cr = cr + _fir([gain_value(g["kn"]), gain_value(g["kc"])], dt)
        return cr, -(1 << SPEED_REFERENCE_BITS) * c


@dataclasses.dataclass(frozen=True)
class PositionPD(_PolePlacement):
    """Position P or PD control on the counts: ``u = kp (r - counts) - kd y``.

    The gains place both poles of the continuous model ``theta'' + a theta' = b u`` at
    ``-1/time_constant``: ``kp = 1 / (b time_constant^2)`` per rad, ``kd = (2/time_constant - a) / b``
    per rad/s (0 when negative, or with ``derivative=False``); :meth:`predict` closes the
    loop on the exact sampled model.  As for :class:`PISpeed`, the loop on the exact model,
    input delay included, keeps ``min_phase_margin`` degrees, the time constant lengthened
    until it does.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    time_constant : float
        Closed-loop time constant in s, > 0 (default 0.05); the one designed with, when the
        phase margin asked for needs a longer one.
    derivative : bool
        Use the speed term (PD, default) or not (P).
    min_phase_margin : float
        Keyword only: the least phase margin in degrees, 0...180 (default :data:`MIN_PHASE_MARGIN`,
        60; 0 keeps ``time_constant`` as given).

    Examples
    --------
    >>> PositionPD(PlantModel(25.0, 3.0, 0.005, 16667)).is_stable()
    True
    """

    derivative: bool = True
    kind: ClassVar[str] = "position"
    quantity: ClassVar[str] = "angle"

    @property
    def preview(self) -> int:
        return 0

    def gains(self) -> dict[str, int]:
        m, tau = self.model, self.time_constant
        kd = max(0.0, (2.0 / tau - m.a) / m.b) if self.derivative else 0.0
        return {"kp": quantise_gain(1.0 / (m.b * tau * tau) / m.angle_scale), "kd": quantise_gain(kd / m.speed_scale)}

    def laws(self):
        g, dt = self.gains(), self.model.sample_period
        kp, kd = gain_value(g["kp"]), gain_value(g["kd"])
        return _fir([kp], dt), _fir([-kp - kd, kd], dt)


def _delay_line_matrices(model: PlantModel) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the exact speed model with the input delay in the state.

    The state is ``x_k = [y_k, u_{k-1}, ..., u_{k-D-1}]`` (speed in counts per sample and the
    ``D + 1`` duties the motor has still to feel), the input ``u_k``; ``A`` shifts the duties
    along and ``y_{k+1} = e y_k + beta1 u_{k-D} + beta2 u_{k-D-1}`` (module docstring).
    """
    e, _, b1, b2 = model.speed_coefficients()
    d = model.input_delay
    n = d + 2
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    a[0, 0] = e
    if d == 0:
        b[0, 0] = b1
    else:
        a[0, d] = b1
    a[0, d + 1] = b2
    b[1, 0] = 1.0
    for m in range(2, n):
        a[m, m - 1] = 1.0
    return a, b


def _lqr(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: float) -> np.ndarray:
    """The state-feedback gain ``K`` (``u = -K x``) minimising ``sum x'Qx + r u^2`` (discrete Riccati)."""
    from scipy.linalg import solve_discrete_are
    try:
        p = solve_discrete_are(a, b, q, np.array([[r]]))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ParameterError(f"the LQR design has no solution for this model and weight: {exc}") from None
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a).ravel()


@dataclasses.dataclass(frozen=True)
class _LQR(Controller):
    """An LQR: the weight of ``u^2`` against the controlled quantity's square (> 0)."""

    duty_weight: float = 1e-3

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "duty_weight", check_real("duty_weight", self.duty_weight, positive=True))


@dataclasses.dataclass(frozen=True)
class LQRSpeed(_LQR):
    """Speed LQR on the exact ZOH model with the input delay augmented into the state.

    The state is the measured speed and the ``D + 1`` duties still in the delay line (the
    device's own sample of delay included, through the model's ``input_delay``); the gain
    ``K`` minimises ``sum omega_k^2 + duty_weight u_k^2`` (discrete Riccati equation, SciPy).
    The step is ``u_k = kr r_{k+D+1} + ky y_k + sum_m ku_m u_{k-m} + k0 + kf sign(r_{k+D+1})``,
    ``ky`` and ``ku_m`` the quantised ``-K``; ``kr`` makes the steady speed equal the reference
    and ``k0``, ``kf`` cancel the model's bias and friction there, both computed from the
    quantised feedback gains.  The step is the one of :class:`OneStepMPC` (one linear form
    in the reference, the speed and the past duties): only the design differs.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        Weight of ``u^2`` in (rad/s)^2 per duty^2, > 0 (default 1e-3).

    Examples
    --------
    >>> lqr = LQRSpeed(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1))
    >>> sorted(lqr.gains())
    ['k0', 'kf', 'kr', 'ku1', 'ku2', 'ky']
    >>> lqr.is_stable()
    True
    """

    duty_weight: float = 1e-3
    kind: ClassVar[str] = "lqr"

    def state_gain(self) -> np.ndarray:
        """``K`` of ``u = -K x`` in the model's integer units (counts per sample, duty)."""
        a, b = _delay_line_matrices(self.model)
        q = np.zeros_like(a)
        q[0, 0] = 1.0
        return _lqr(a, b, q, self.duty_weight * self.model.speed_scale ** 2)

    def gains(self) -> dict[str, int]:
        k = self.state_gain()
        return _speed_lqr_gains(self.model, quantise_gain(-k[0]), [quantise_gain(-x) for x in k[1:]])

    def laws(self):
        return _delay_line_laws(self.gains(), self.model)


def _speed_lqr_gains(model: PlantModel, ky: int, ku: list[int], ki: int | None = None) -> dict[str, int]:
    """The speed LQR's gains in wire order: ``kr`` and ``k0``, ``kf`` from the quantised feedback gains.

    At a steady speed ``r`` (counts per sample) the duty is ``u = (1 - e) r / g - o`` (``o`` the
    model's drive offset) and every past duty equals it, so ``kr r + ky r + k0 + kf = u (1 - sum ku)``
    makes the steady output the reference, and an integral (``ki``) stays at 0 on the model.
    """
    e, g, _, _ = model.speed_coefficients()
    hold = 1.0 - sum(gain_value(x) for x in ku)     # what is left of u at steady state
    out = {"kr": quantise_gain(((1.0 - e) / g * hold - gain_value(ky)) * SPEED_REFERENCE_LSB), "ky": ky}
    if ki is not None:
        out["ki"] = ki
    out["k0"] = quantise_gain(-model.bias / model.b * hold)
    out["kf"] = quantise_gain(model.friction / model.b * hold)
    out.update({f"ku{j}": x for j, x in enumerate(ku, 1)})
    return out


#: Default weight of the squared angle error (the integral of the speed error) of :class:`LQRSpeedIntegral`, 1/s^2.
INTEGRAL_WEIGHT = 100.0


@dataclasses.dataclass(frozen=True)
class LQRSpeedIntegral(_LQR):
    """Speed LQR with integral action: the integral of the speed error in the state.

    The state of :class:`LQRSpeed` (the measured speed and the ``D + 1`` duties in the delay
    line) gains ``s_k``, the sum of the errors ``r_j - y_j`` before sample ``k``
    (``s_{k+1} = s_k + r_k - y_k``); the gain minimises
    ``sum omega_k^2 + integral_weight theta_k^2 + duty_weight u_k^2``, where ``theta_k``,
    ``sample_period`` times the sum in rad/s, is the error's integral, an angle in rad.  The step is
    :class:`LQRSpeed`'s with ``ki s_k`` added and the sum updated after it,
    ``u_k = kr r_{k+D+1} + ky y_k + ki s_k + sum_m ku_m u_{k-m} + k0 + kf sign(r_{k+D+1})``;
    the sum stops growing while the duty is at the limit and the error pushes further into it
    (the PI's conditional integration).  ``kr``, ``k0`` and ``kf`` are :class:`LQRSpeed`'s for
    the new feedback gains, so on the model the sum stays at 0; a bias, friction or gain the
    model lacks is what it integrates, and a constant reference is tracked with no steady error.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        Weight of ``u^2`` in (rad/s)^2 per duty^2, > 0 (default 1e-3).
    integral_weight : float
        Weight of ``theta^2`` in (rad/s)^2 per rad^2 (1/s^2), > 0 (default
        :data:`INTEGRAL_WEIGHT`, 100: an angle error of 0.1 rad costs as much as a speed error
        of 1 rad/s).

    Examples
    --------
    >>> lqr = LQRSpeedIntegral(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1))
    >>> list(lqr.gains())
    ['kr', 'ky', 'ki', 'k0', 'kf', 'ku1', 'ku2']
    >>> lqr.is_stable()
    True
    """

    integral_weight: float = INTEGRAL_WEIGHT
    kind: ClassVar[str] = "lqr-integral"

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "integral_weight", check_real("integral_weight", self.integral_weight, positive=True))

    def state_gain(self) -> np.ndarray:
        """``K`` of ``u = -K x``, ``x = [y, u_{k-1}, ..., u_{k-D-1}, s]`` in counts per sample, duty, counts."""
        a, b = _integral_matrices(self.model)
        q = np.zeros_like(a)
        q[0, 0] = 1.0
        q[-1, -1] = self.integral_weight * self.model.sample_period ** 2
        return _lqr(a, b, q, self.duty_weight * self.model.speed_scale ** 2)

    def gains(self) -> dict[str, int]:
        k = self.state_gain()
        return _speed_lqr_gains(self.model, quantise_gain(-k[0]), [quantise_gain(-x) for x in k[1:-1]],
                                ki=quantise_gain(-k[-1] * SPEED_REFERENCE_LSB))

    def laws(self):
        import control
        g, m = self.gains(), self.model
        kr, ky, ki = (gain_value(g[name]) for name in ("kr", "ky", "ki"))
        n = m.input_delay + 1                       # the past duties weighed, and the preview
        ku = [gain_value(g[f"ku{j}"]) for j in range(1, n + 1)]
        # u (1 - sum_m ku_m z^-m) = kr r + ky y + ki s with s = (z^-n r - 16 y) / (z - 1); one
        # denominator, (z - 1)(z^n - sum_m ku_m z^(n-m)), as the step has one state per term
        den = np.polymul([1.0, -1.0], [1.0, *(-x for x in ku)])
        cr = np.polyadd(np.polymul([kr, -kr], np.r_[1.0, np.zeros(n)]), [ki])
        cy = np.polymul([ky, -ky - (1 << SPEED_REFERENCE_BITS) * ki], np.r_[1.0, np.zeros(n)])
        return control.tf(cr, den, m.sample_period), control.tf(cy, den, m.sample_period)


def _integral_matrices(model: PlantModel) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of :func:`_delay_line_matrices` with the error's sum last: ``s_{k+1} = s_k - y_k`` (r = 0)."""
    a_speed, b_speed = _delay_line_matrices(model)
    n = a_speed.shape[0] + 1
    a = np.zeros((n, n))
    a[:-1, :-1] = a_speed
    a[-1, 0] = -1.0
    a[-1, -1] = 1.0
    return a, np.vstack([b_speed, [[0.0]]])


@dataclasses.dataclass(frozen=True)
class LQRPosition(_LQR):
    """Position LQR on the counts, with the input delay augmented into the state.

    The state is the angle (counts since the first sample), the measured speed and the
    ``D + 1`` duties still in the delay line; ``K`` minimises
    ``sum theta_k^2 + duty_weight u_k^2`` (theta in rad).  The step is
    ``u_k = kp (r_{k+D+1} - theta_k) + ky y_k + sum_m ku_m u_{k-m} + k0``: ``kp`` the
    quantised angle gain, ``ky`` and ``ku_m`` the quantised ``-K``, ``k0`` the model's bias
    cancelled at standstill.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        Weight of ``u^2`` in rad^2 per duty^2, > 0 (default 1e-6).

    Examples
    --------
    >>> LQRPosition(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1)).is_stable()
    True
    """

    duty_weight: float = 1e-6
    kind: ClassVar[str] = "lqr-position"
    quantity: ClassVar[str] = "angle"

    def state_gain(self) -> np.ndarray:
        """``K`` of ``u = -K x``, ``x = [theta, y, u_{k-1}, ..., u_{k-D-1}]`` in counts and duty."""
        a_speed, b_speed = _delay_line_matrices(self.model)
        n = a_speed.shape[0] + 1
        a = np.zeros((n, n))
        a[1:, 1:] = a_speed
        a[0, 0] = 1.0
        a[0, 1:] = a_speed[0]               # theta_{k+1} = theta_k + y_{k+1}
        b = np.vstack([b_speed[:1], b_speed])
        q = np.zeros_like(a)
        q[0, 0] = 1.0
        return _lqr(a, b, q, self.duty_weight * self.model.angle_scale ** 2)

    def gains(self) -> dict[str, int]:
        k = self.state_gain()
        ku = [quantise_gain(-x) for x in k[2:]]
        hold = 1.0 - sum(gain_value(x) for x in ku)
        out = {"kp": quantise_gain(k[0]), "ky": quantise_gain(-k[1]),
               "k0": quantise_gain(-self.model.bias / self.model.b * hold)}
        out.update({f"ku{j}": x for j, x in enumerate(ku, 1)})
        return out

    def laws(self):
        return _delay_line_laws(self.gains(), self.model, position=True)


def _delay_line_laws(gains: Mapping[str, int], model: PlantModel, *, position: bool = False):
    """``(Cr, Cy)`` of ``u (1 - sum_m ku_m z^-m) = kr r + ky y`` (speed) or
    ``= kp (r - theta) + ky (1 - z^-1) theta`` (position, where the measurement is theta)."""
    dt = model.sample_period
    ku = [gain_value(gains[f"ku{j}"]) for j in range(1, model.input_delay + 2)]
    den = _fir([1.0, *(-x for x in ku)], dt)
    ky = gain_value(gains["ky"])
    if position:
        kp = gain_value(gains["kp"])
        return _fir([kp], dt) / den, _fir([ky - kp, -ky], dt) / den
    return _fir([gain_value(gains["kr"])], dt) / den, _fir([ky], dt) / den

#: Controllers by ``kind`` (``motorid control design --controller``).
CONTROLLERS: dict[str, type[Controller]] = {c.kind: c for c in (OneStepMPC, PISpeed, PositionPD, Feedforward,
                                                                 LQRSpeed, LQRSpeedIntegral, LQRPosition)}


def design_controller(kind: str, model: PlantModel, **settings: Any) -> Controller:
    """The controller ``kind`` (a key of :data:`CONTROLLERS`) designed from ``model``.

    Parameters
    ----------
    kind : str
        ``mpc``, ``pi``, ``position``, ``feedforward``, ``lqr`` or ``lqr-position``.
    model : PlantModel
        The motor model.
    **settings
        The controller's knobs (``duty_weight``, ``time_constant``, ``feedforward``, ``derivative``).
    """
    if kind not in CONTROLLERS:
        raise ParameterError(f"controller must be one of {', '.join(CONTROLLERS)}, got {kind!r}")
    cls = CONTROLLERS[kind]
    known = {f.name for f in dataclasses.fields(cls)} - {"model"}
    unknown = set(settings) - known
    if unknown:
        raise ParameterError(f"controller {kind!r} takes {sorted(known) or 'no settings'}, got {sorted(unknown)}")
    return cls(model, **settings)


# ----------------------------------------------------------------------------------------------------------
# The closed-loop experiment
# ----------------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class ClosedLoopExperiment:
    """What a rig should run in closed loop: a controller tracking a reference.

    Parameters
    ----------
    controller : Controller
        The controller (its model's ``sample_period`` is the run's).
    reference : Reference
        The wave to track, in rad/s (speed controllers) or rad (position).
    duration : float
        Length of the run in s.
    duty_limit : int
        Duty clamp, 0...255 (default 255).
    """

    controller: Controller
    reference: Reference
    duration: float = 10.0
    duty_limit: int = DUTY_LIMIT

    def __post_init__(self):
        if not isinstance(self.controller, Controller):
            raise ParameterTypeError(f"controller must be a Controller, got {type(self.controller).__name__}")
        if not isinstance(self.reference, Reference):
            raise ParameterTypeError(f"reference must be a Reference, got {type(self.reference).__name__}")
        object.__setattr__(self, "duration", check_real("duration", self.duration, positive=True))
        object.__setattr__(self, "duty_limit", check_int("duty_limit", self.duty_limit, 0, DUTY_LIMIT))
        if self.n_samples < 2:
            raise ParameterError(f"duration must cover at least 2 samples of {self.sample_period!r} s, "
                             f"got {self.duration!r} s")
        self.reference_samples()  # validate the reference against the controller's units

    @property
    def sample_period(self) -> float:
        """The controller's sample period in s."""
        return self.controller.model.sample_period

    @property
    def n_samples(self) -> int:
        """Number of samples, ``round(duration / sample_period)``."""
        return int(round(self.duration / self.sample_period))

    def reference_samples(self) -> np.ndarray:
        """The integer reference, ``n_samples + controller.preview`` long (the step looks ahead)."""
        c = self.controller
        return self.reference.samples(self.n_samples + c.preview, self.sample_period, c.reference_scale)

    def reference_values(self) -> np.ndarray:
        """The reference at each sample in physical units (what the device tracks), length ``n_samples``."""
        return self.reference_samples()[:self.n_samples] / self.controller.reference_scale

    def metadata(self) -> dict[str, str]:
        """Metadata lines for the recording: the reference, duty limit, duration and the controller's."""
        return {"reference": self.reference.describe(), "duty_limit": str(self.duty_limit),
                "duration": repr(self.duration), **self.controller.metadata()}


def tracking_error(recording: Any) -> np.ndarray:
    """``reference - measured`` of a closed-loop recording, samples 1 ... n-1 (rad/s or rad).

    The measured quantity is the differenced-counts speed, or the angle since the first
    sample when the metadata say ``controlled: angle``.

    Parameters
    ----------
    recording : Recording
        A recording with a ``reference`` column.
    """
    ref = getattr(recording, "reference", None)
    if ref is None:
        raise ParameterError("recording has no reference column: it is not a closed-loop recording")
    if recording.metadata.get("controlled") == "angle":
        angle = recording.measured_angle()
        out = angle - angle[0]
    else:
        out = recording.measured_speed()
    err = (ref - out)[1:]
    return err[np.isfinite(err)]


def settings_from(values: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """The knobs of controller ``kind`` found in ``values`` (e.g. parsed CLI arguments), others ignored."""
    known = {f.name for f in dataclasses.fields(CONTROLLERS[kind])} - {"model"}
    return {k: v for k, v in values.items() if k in known and v is not None}


#: Names of the fixed-point step this module no longer holds (old imports warn for one release).
_MOVED = ("GAIN_BITS", "GAIN_ORDER", "gains_from_wire")


def __getattr__(name: str):
    # the step's other names are imported above and still resolve here; these warn and point to the new place
    if name in _MOVED:
        import warnings

        from . import fixed_point
        warnings.warn(f"motorsim.control.{name} moved to motorsim.fixed_point.{name}; the old name goes in the "
                      "next release", DeprecationWarning, stacklevel=2)
        return getattr(fixed_point, name)
    raise AttributeError(f"module 'motorsim.control' has no attribute {name!r}")
