"""The numbers a controller is designed from: :class:`PlantModel`, and its exact model of the measured speed."""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..checks import ParameterError, ParameterTypeError, check_int, check_real
from ..plant import Motor, delay_at

if TYPE_CHECKING:
    import control

__all__ = ["PlantModel"]


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
    electrical_time_constant : float, optional
        Time constant ``tau_e`` in s of a lag between the duty and the torque, >= 0 (default 0:
        none): the plant is then ``b / ((s + a)(tau_e s + 1))`` (the ``second-order`` structure,
        :attr:`motorsim.plant.Motor.electrical_time_constant`).  The designs use the first-order
        part (:meth:`speed_coefficients`, :meth:`first_order`); the margins, the stability
        verdict and the predicted closed loop use the full plant (:meth:`speed_transfer_function`).
    dead_zone : float, optional
        Duty magnitude the driver does not deliver, >= 0 (default 0), as
        :attr:`motorsim.plant.Motor.dead_zone`.  Kept with the model (its :meth:`motor`, its metadata,
        what ``motorid control design`` prints); the designs, like the prediction, are made on the
        linear part and do not compensate it.
    static_friction : float, optional
        Static friction ``c_s`` in rad/s^2, 0 (none) or >= ``friction``, as
        :attr:`motorsim.plant.Motor.static_friction`: kept with the model like the dead zone; the
        feedforward terms compensate the sliding level, ``friction``.

    Notes
    -----
    The measured speed's exact model (first-order part, full plant) is the plant's own,
    :meth:`motorsim.plant.Motor.speed_polynomials`, in counts per sample (:attr:`speed_scale`).

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
    electrical_time_constant: float = 0.0
    dead_zone: float = 0.0
    static_friction: float = 0.0

    def __post_init__(self):
        motor = Motor(self.a, self.b, **{name: getattr(self, name) for name in _PLANT_PARTS})
        for name in ("a", "b", *_PLANT_PARTS):
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
            Anything with ``a`` and ``b``; an estimate's model structure gives ``friction``,
            ``bias``, ``input_delay``, ``electrical_time_constant``, ``dead_zone`` and
            ``static_friction`` (its plant, ``Estimate.motor()``), a Motor's fields give them
            directly.  Every part of that plant is kept: ``model.motor()`` is the source's plant
            (its delay counted at ``sample_period``), never a simpler one.
        sample_period : float, optional
            Controller sample period in s (default: the source's, if it has one).  A source
            with a sample period of its own has its input delay counted again at this one (the
            delay is a time, :func:`~motorsim.plant.delay_at`): refused when it is not a whole
            number of samples here.
        counts_per_rev : int, optional
            Encoder resolution (default: the source's, if it has one).
        """
        if isinstance(source, PlantModel):
            period = sample_period or source.sample_period
            return dataclasses.replace(source, sample_period=period,
                                       counts_per_rev=counts_per_rev or source.counts_per_rev,
                                       input_delay=delay_at(source.input_delay, source.sample_period, period))
        if not (hasattr(source, "a") and hasattr(source, "b")):
            raise ParameterTypeError("source must be an Estimate, a Motor or a PlantModel, "
                                     f"got {type(source).__name__}")
        extra = dict(getattr(source, "extra", {}) or {})
        plant = source.motor() if callable(getattr(source, "motor", None)) else source   # the structure's plant
        for name in _PLANT_PARTS:          # the plant's value first (a stiction fit's level below friction is none)
            for holder in (plant, source):
                if hasattr(holder, name) and not isinstance(holder, type):
                    extra[name] = getattr(holder, name)
                    break
        own_period = getattr(source, "sample_period", None)
        sample_period = sample_period if sample_period is not None else own_period
        if sample_period is None:
            raise ParameterError("sample_period must be given when the source has none, got None")
        if counts_per_rev is None:
            raise ParameterError("counts_per_rev must be given for a controller, got None")
        delay = int(extra.get("input_delay", 0))
        if own_period is not None:        # the source's delay is a time: counted again at this sample period
            delay = delay_at(delay, own_period, check_real("sample_period", sample_period, positive=True))
        parts = {name: float(extra.get(name, 0.0)) for name in _PLANT_PARTS if name != "input_delay"}
        return cls(float(source.a), float(source.b), sample_period, counts_per_rev, input_delay=delay, **parts)

    @property
    def speed_scale(self) -> float:
        """Counts per sample per rad/s: ``counts_per_rev sample_period / (2 pi)``."""
        return self.counts_per_rev * self.sample_period / (2.0 * math.pi)

    @property
    def angle_scale(self) -> float:
        """Counts per rad: ``counts_per_rev / (2 pi)``."""
        return self.counts_per_rev / (2.0 * math.pi)

    def first_order(self) -> "PlantModel":
        """This model without its electrical time constant: the first-order part the designs are made on."""
        return dataclasses.replace(self, electrical_time_constant=0.0) if self.electrical_time_constant else self

    def motor(self) -> Motor:
        """The plant as the simulator's :class:`~motorsim.plant.Motor`, every part included."""
        return Motor(self.a, self.b, **{name: getattr(self, name) for name in _PLANT_PARTS})

    def speed_coefficients(self) -> tuple[float, float, float, float]:
        """``(e, g, beta1, beta2)`` of the exact first-order model (:mod:`motorsim.control`), in counts per
        sample per duty: the first-order part's when the model has an electrical time constant."""
        return self.motor().speed_coefficients(self.sample_period, self.speed_scale)

    def drive_offset(self, sign: int) -> float:
        """``(bias - friction sign) / b`` in duty: what the drive adds when the speed has ``sign``."""
        return (self.bias - self.friction * sign) / self.b

    def speed_transfer_function(self) -> control.TransferFunction:
        """Duty to measured speed (counts per sample), ``(beta1 z + beta2) / (z^(D+1) (z - e))``; with an
        electrical time constant the full plant's (class Notes), both poles exact."""
        import control
        delay = np.r_[1.0, np.zeros(self.input_delay + 1)]
        num, den = self.motor().speed_polynomials(self.sample_period, self.speed_scale)
        return control.tf(num, np.polymul(delay, den), self.sample_period)

    def metadata(self) -> dict[str, str]:
        """The model as recording metadata ``model_NAME`` (the electrical time constant, dead zone and static
        friction only when nonzero)."""
        return {f"model_{f.name}": repr(getattr(self, f.name)) for f in dataclasses.fields(self)
                if f.name not in _SAID_WHEN_SET or getattr(self, f.name)}


#: The plant's parts besides ``a`` and ``b``: every field of :class:`~motorsim.plant.Motor` a model carries
#: (a test checks it is all of them, so a part the simulator gains cannot be dropped here).
_PLANT_PARTS = ("friction", "bias", "input_delay", "electrical_time_constant", "dead_zone", "static_friction")
#: Parts written to metadata only when set (older recordings' metadata stays as it was).
_SAID_WHEN_SET = frozenset({"electrical_time_constant", "dead_zone", "static_friction"})
