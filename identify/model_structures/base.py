"""``ModelStructure``: what one model structure is, independent of any data or fit.

A structure is the *form* of the plant (``b/(s + a)``, with a bias, with Coulomb friction, ...):
the names of its parameters, their units and bounds, which of them the input delay joins, the
estimator that fits it, and how a set of values becomes something to simulate or analyse (the
simulator's :class:`motorsim.plant.Motor`, a python-control system, a model output on a
recording's segment).  An :class:`identify.Estimate` is a structure plus values, covariance and
fit diagnostics; the estimators, the default's selection, validation, the frequency view and
control design ask the structure instead of restating the model.

The pattern is statsmodels' state-space models (a model class declares ``param_names``,
``start_params`` and how its parameters enter; ``fit()`` returns a separate results object) and
python-control's ``NonlinearIOSystem(updfcn, outfcn, params)``: one small class per structure,
every consumer unchanged.  :mod:`identify.structures` registers them by name.
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from motorsim.checks import ParameterError, check_real
from motorsim.linear_plant import LinearPlant
from motorsim.plant import Motor, Plant, Stepper, Trajectory, first_order_coefficients, simulate

from ..estimators import OE, Estimator

if TYPE_CHECKING:
    import control

    from ..data import Segment

__all__ = ["Parameter", "ModelStructure"]


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One parameter of a structure.

    Attributes
    ----------
    name : str
        The name every package, flag and JSON field uses (``a``, ``b``, ``friction``, ...).
    unit : str
        Its unit; ``{input}`` stands for the recording's input unit (``duty`` on the bench).
    low, high : float
        Bounds of a valid value (``-inf``/``inf`` when open).
    description : str
        One line, for listings and help.
    strict : bool
        Whether ``low`` itself is excluded (``a > 0``).
    starts : tuple of float
        Start values of an iterative fit (:meth:`ModelStructure.starts`; none: 0).
    """

    name: str
    unit: str
    low: float = -math.inf
    high: float = math.inf
    description: str = ""
    strict: bool = False
    starts: tuple[float, ...] = ()

    def check(self, value: Any) -> float:
        """``value`` as a float within the bounds, else a :class:`ParameterError` naming it."""
        x = check_real(self.name, value)
        if x < self.low or (self.strict and x == self.low) or x > self.high:
            rule = f"{'>' if self.strict else '>='} {self.low:g}" if math.isfinite(self.low) else ""
            if math.isfinite(self.high):
                rule = (rule + " and " if rule else "") + f"<= {self.high:g}"
            raise ParameterError(f"{self.name} must be {rule} {self.unit}, got {value!r}")
        return x


class ModelStructure:
    """A model structure: parameters, units, bounds, its estimator, and conversions of its values.

    Subclasses set the class attributes and override what differs (:meth:`plant` for a structure
    the simulator carries, :meth:`segment_output` for the model output an estimator or validation
    compares with the data).  Instances are immutable and compared by name.

    Attributes
    ----------
    name : str
        Registry key (``motorid identify`` prints it as the model).
    description : str
        One line: what the structure adds.
    parameters : tuple of Parameter
        The parameters it fits, ``a`` and ``b`` first.
    fixed : mapping of str to float
        Parameters of the wider family this structure holds at a value (``friction = 0`` for a
        linear one); :meth:`values` fills them in.
    estimator : identify.estimators.Estimator
        The estimator that fits it, as an object (:attr:`method` is its name:
        ``identify.fit(rec, method, **options)``).
    options : mapping
        The options that make its estimator fit exactly this structure.
    linear : bool
        Whether the model is linear in the input (a bias counts as linear: an affine input);
        the default screens the nonlinear ones.
    in_default : bool
        Whether the default estimator (``identify.fit`` with no method) considers it.
    simulated : bool
        Whether the simulator's :class:`~motorsim.plant.Motor` carries it: :meth:`plant`, :meth:`stepper`, the
        controllers' model and :meth:`identify.Estimate.io_system` (a structure it does not carry, a gain per
        direction, refuses them by name; its :meth:`response` and :meth:`segment_output` are its own).
    rank : int
        0 for the first-order motor's family; a structure of a higher rank (a second pole) is
        chosen by the default only where no candidate of a lower rank is within the noise of the
        best: the data must show what it adds.
    """

    name: str = ""
    description: str = ""
    parameters: tuple[Parameter, ...] = ()
    fixed: Mapping[str, float] = {}
    estimator: Estimator = OE
    options: Mapping[str, Any] = {}
    linear: bool = True
    in_default: bool = True
    simulated: bool = True
    rank: int = 0

    @property
    def method(self) -> str:
        """The name of the estimator that fits it (``identify.fit(rec, method, **options)``)."""
        return self.estimator.name

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of the fitted parameters, in the order of a covariance matrix."""
        return tuple(p.name for p in self.parameters)

    @property
    def n_params(self) -> int:
        """How many parameters it fits (the selection's measure of simplicity)."""
        return len(self.parameters)

    def units(self, input_unit: str = "duty") -> dict[str, str]:
        """Unit of each parameter (fitted and fixed), ``{input}`` replaced by ``input_unit``."""
        out = {p.name: p.unit.replace("{input}", input_unit) for p in self.parameters}
        for name in self.fixed:
            out.setdefault(name, _FAMILY_UNITS.get(name, "").replace("{input}", input_unit))
        return out

    def values(self, given: Mapping[str, float]) -> dict[str, float]:
        """Every parameter's value: ``given`` checked against the bounds, fixed ones filled in.

        A further parameter (after ``a`` and ``b``) that is not given takes its neutral value, 0, where 0 is
        within its bounds; one whose bounds exclude 0 (a shaft's frequency) is asked for.

        Raises
        ------
        ParameterError
            ``a`` or ``b`` missing, or a value not finite or outside its bounds.
        """
        out: dict[str, float] = {}
        for p in self.parameters:
            if p.name not in given and p.name not in ("a", "b") and p.low <= 0.0 <= p.high and not (
                    p.strict and p.low == 0.0):
                out[p.name] = 0.0          # a further parameter not given: its neutral value (absent)
                continue
            if p.name not in given:
                raise ParameterError(f"the {self.name} structure needs a value for {p.name!r}, got "
                                     f"{sorted(given)}")
            out[p.name] = p.check(given[p.name])
        for name, value in self.fixed.items():
            out[name] = float(given.get(name, value))
        return out

    def plant(self, values: Mapping[str, float], input_delay: int = 0) -> Plant:
        """The simulator's plant with these values (:class:`motorsim.plant.Motor` for the first-order family; a
        structure with other dynamics returns its own :class:`motorsim.plant.Plant`, e.g. a
        :class:`motorsim.linear_plant.LinearPlant`, whose dynamics every method here then asks)."""
        v = self.values(values)
        return Motor(v["a"], v["b"], friction=v.get("friction", 0.0), bias=v.get("bias", 0.0),
                     dead_zone=v.get("dead_zone", 0.0), input_delay=input_delay)

    def state_space(self, values: Mapping[str, float]) -> control.StateSpace:
        """Its continuous system, the linear part with these values: states ``angle``, ``speed`` (and the
        structure's own, e.g. the lag's ``current``), input ``duty``, outputs ``angle`` and ``speed``
        (:meth:`motorsim.plant.Motor.state_space`; delay and nonlinear parts omitted)."""
        return self.plant(values).state_space()

    def discretise(self, values: Mapping[str, float], sample_period: float) -> control.StateSpace:
        """Its exact discretisation over a held sample (zero-order hold) at ``sample_period`` s, the linear
        part (:meth:`motorsim.plant.Motor.discretise`)."""
        return self.plant(values).discretise(sample_period)

    def stepper(self, values: Mapping[str, float], intervals) -> Stepper:
        """One exact step of its state per sample interval, every part included (:class:`motorsim.plant.Stepper`:
        what a per-sample loop runs; the input delay is the caller's delay line)."""
        return self.plant(values).stepper(intervals)

    def response(self, values: Mapping[str, float], duty, time, *, input_delay: int = 0,
                 initial_speed: float = 0.0, initial_angle: float = 0.0) -> Trajectory:
        """The model's angle and speed at ``time`` under ``duty`` (zero-order hold, exact)."""
        return simulate(self.plant(values, input_delay), duty, time, initial_speed=initial_speed,
                        initial_angle=initial_angle)

    def segment_output(self, values: Mapping[str, float], segment: Segment) -> np.ndarray:
        """The model's native output (angle or speed) on ``segment``, its initial state from the data.

        What validation and the residual checks compare with the measurement (the segment's drive
        is already delayed).  For a linear plant (:class:`motorsim.linear_plant.LinearPlant`): its forced
        response plus its free responses, their initial states (and the angle's offset) by exact least
        squares (the output is linear in them); a structure with other dynamics writes its own.
        """
        plant = self.plant(values)
        if not isinstance(plant, LinearPlant):
            raise NotImplementedError(f"the {self.name} structure must write its segment_output")
        forced, free = plant.columns(segment.time, segment.drive, segment.kind)
        coef, *_ = np.linalg.lstsq(free, segment.output - forced, rcond=None)
        return forced + free @ coef

    def starts(self, recordings, guess: tuple[float, float]) -> list[dict[str, float]]:
        """Start values of an iterative fit (:mod:`identify.fits.structure_fit`): the first-order motor's ``a`` and
        ``b`` (``guess``, :func:`identify.fits.start.initial_guess`'s) with each further parameter's
        :attr:`Parameter.starts` values, every combination."""
        import itertools
        a, b = guess
        further = [p for p in self.parameters if p.name not in ("a", "b")]
        return [{"a": float(a), "b": float(b), **{p.name: x for p, x in zip(further, combo)}}
                for combo in itertools.product(*(p.starts or (0.0,) for p in further))]

    def linear_part(self, values: Mapping[str, float]) -> tuple[list[float], list[float]]:
        """Numerator and denominator of the linear part in ``s``, from the input to the speed (a linear plant's
        from its continuous system)."""
        plant = self.plant(values) if self.simulated else None
        if isinstance(plant, LinearPlant):
            import control
            tf = control.ss2tf(plant.state_space()[1, 0])
            return [float(x) for x in tf.num[0][0]], [float(x) for x in tf.den[0][0]]
        v = self.values(values)
        return [v["b"]], [1.0, v["a"]]

    def transfer_function(self, values: Mapping[str, float], sample_period: float, input_delay: int = 0,
                          form: str = "continuous", *, delay: str | None = None,
                          pade_order: int = 3) -> control.TransferFunction:
        """The linear part as a python-control transfer function (:meth:`identify.Estimate.transfer_function`)."""
        import control
        if form not in ("continuous", "discrete"):
            raise ParameterError(f"form must be 'continuous' or 'discrete', got {form!r}")
        if delay not in (None, "pade"):
            raise ParameterError(f"delay must be None or 'pade', got {delay!r}")
        names = {"inputs": "duty", "outputs": "speed"}
        d = int(input_delay)
        num, den = self.linear_part(values)
        if form == "discrete":
            tf = self.discrete_linear_part(values, sample_period)
            return control.tf(tf[0], [*tf[1], *([0.0] * d)], sample_period, **names)
        tf = control.tf(num, den, **names)
        if d == 0:
            return tf
        if delay is None:
            raise ParameterError(f"this estimate has an input delay of {d} samples ({d * sample_period:.6g} s), "
                                 f"which {self.formula} cannot carry: use transfer_function('discrete') for the "
                                 "exact model with z^-d, or delay='pade' for a continuous approximation")
        if not (isinstance(pade_order, int) and pade_order >= 1):
            raise ParameterError(f"pade_order must be an integer >= 1, got {pade_order!r}")
        pnum, pden = control.pade(d * sample_period, pade_order)
        return control.tf(np.polymul(pnum, num), np.polymul(pden, den), **names)

    #: The linear part written out, for messages.
    formula: str = "b/(s + a)"
    #: The parameters the linear part's frequency response depends on, in the order a frequency-domain
    #: fit estimates them (:func:`identify.fit_frequency_response`); a bias, friction or a dead zone has none.
    response_parameters: tuple[str, ...] = ("a", "b")

    def frequency_response(self, values: Mapping[str, float], sample_period: float, omega, *,
                           output: str = "angle", input_delay: int = 0) -> np.ndarray:
        """The exact zero-order-hold response of the linear part, input to speed, at ``omega`` rad/s (complex).

        ``output`` as :class:`identify.FrequencyResponse`'s: ``"speed"``, the sampled speed;
        ``"angle"``, the mean speed over the interval the input is held; ``input_delay`` whole samples
        (a factor ``z^-input_delay``).  Here ``b/(s + a)``:
        :func:`identify.frequency.frequency_estimate.zoh_speed_response`.
        """
        from ..fits.zoh_response import zoh_speed_response
        plant = self.plant(values) if self.simulated else None
        if isinstance(plant, LinearPlant):
            return plant.frequency_response(sample_period, omega, output=output, input_delay=input_delay)
        # the values as given, not checked against the bounds: a poor fit's model is still drawn
        return zoh_speed_response(float(values["a"]), float(values["b"]), sample_period, omega, output=output,
                                  input_delay=input_delay)

    def discrete_linear_part(self, values: Mapping[str, float], sample_period: float) -> tuple[list[float],
                                                                                                list[float]]:
        """Numerator and denominator in ``z`` of the exact zero-order-hold model (no delay)."""
        plant = self.plant(values) if self.simulated else None
        if isinstance(plant, LinearPlant):
            from scipy.signal import ss2tf
            s = plant.sampled(sample_period)
            num, den = ss2tf(s.Ad, s.Bd[:, None], np.eye(len(s.Ad))[:1], [[0.0]])
            return [float(x) for x in np.trim_zeros(num[0], "f")], [float(x) for x in den]
        v = self.values(values)
        e, p, _ = first_order_coefficients(v["a"], sample_period)
        return [v["b"] * p], [1.0, -e]

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}: {', '.join(self.param_names)}>"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ModelStructure) and other.name == self.name

    def __hash__(self) -> int:
        return hash(self.name)

    def to_dict(self) -> dict:
        """JSON-ready description: name, parameters with units and bounds, estimator."""
        return {"name": self.name, "description": self.description, "method": self.method,
                "parameters": [{"name": p.name, "unit": p.unit, "low": p.low, "high": p.high,
                                "description": p.description} for p in self.parameters],
                "fixed": dict(self.fixed)}


#: Units of the parameters of the motor family, for fixed ones a structure fills in.
_FAMILY_UNITS = {"a": "1/s", "b": "(rad/s^2)/{input}", "friction": "rad/s^2", "bias": "rad/s^2",
                 "dead_zone": "{input}"}
