"""The numbers a controller is designed from: :class:`PlantModel`, and its exact model of the measured speed."""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..checks import ParameterError, ParameterTypeError, check_int, check_real
from ..plant import Motor, Plant, delay_at

if TYPE_CHECKING:
    import control

__all__ = ["PlantModel"]


@dataclasses.dataclass(frozen=True, init=False)
class PlantModel:
    """A plant sampled for a controller: the plant (:class:`motorsim.plant.Plant`, the one plant type:
    the simulator's, the estimate's), the controller's sample period and the encoder's resolution.

    It is not a second plant type: every value and every model of the plant is the plant's own
    (``model.a``, ``model.friction``, ... read it; :meth:`speed_transfer_function` is the plant's
    :meth:`~motorsim.plant.Plant.speed_polynomials` in counts per sample).  Built from plain numbers
    (a :class:`~motorsim.plant.Motor` then), from a plant (``PlantModel(plant=p, sample_period=h,
    counts_per_rev=n)``) or from an estimate (:meth:`from_source`).  ``dataclasses.replace(model,
    input_delay=2)`` (or any value of the plant) changes the plant.

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
        Whole samples between a duty and the motor, >= 0 (at most 50 for a controller).
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
    plant : Plant, keyword only
        The plant itself instead of its values (any structure's); the values above are then not given,
        or are changes to it.

    Notes
    -----
    The measured speed's exact model (first-order part, full plant) is the plant's own,
    :meth:`motorsim.plant.Plant.speed_polynomials`, in counts per sample (:attr:`speed_scale`).

    Examples
    --------
    >>> m = PlantModel(25.0, 3.0, 0.005, 16667)
    >>> round(m.speed_scale, 4)   # counts per sample per rad/s
    13.2632
    """

    plant: Plant
    sample_period: float
    counts_per_rev: int

    def __init__(self, a: float | None = None, b: float | None = None, sample_period: float | None = None,
                 counts_per_rev: int | None = None, friction: float | None = None, bias: float | None = None,
                 input_delay: int | None = None, electrical_time_constant: float | None = None,
                 dead_zone: float | None = None, static_friction: float | None = None, *,
                 plant: Plant | None = None) -> None:
        given = {name: value for name, value in (("a", a), ("b", b), ("friction", friction), ("bias", bias),
                                                 ("input_delay", input_delay),
                                                 ("electrical_time_constant", electrical_time_constant),
                                                 ("dead_zone", dead_zone), ("static_friction", static_friction))
                 if value is not None}
        if plant is None:
            if a is None or b is None:
                raise ParameterError(f"a and b must be given (or plant=), got a={a!r}, b={b!r}")
            plant = Motor(**given)  # type: ignore[arg-type]
        elif not isinstance(plant, Plant):
            raise ParameterTypeError(f"plant must be a plant (motorsim.plant.Plant), got {type(plant).__name__}")
        elif given:
            plant = plant.replace(**given)
        if plant.input_delay > 50:
            raise ParameterError(f"input_delay must be <= 50 samples for a controller, got {plant.input_delay!r}")
        object.__setattr__(self, "plant", plant)
        object.__setattr__(self, "sample_period", check_real("sample_period", sample_period, positive=True))
        object.__setattr__(self, "counts_per_rev", check_int("counts_per_rev", counts_per_rev, 1, 2**31 - 1))

    def __repr__(self) -> str:
        if isinstance(self.plant, Motor):      # the numbers, as a model of the first-order family was always shown
            return (f"PlantModel(a={self.a!r}, b={self.b!r}, sample_period={self.sample_period!r}, "
                    f"counts_per_rev={self.counts_per_rev!r}, "
                    + ", ".join(f"{name}={getattr(self, name)!r}" for name in _PLANT_PARTS) + ")")
        return f"PlantModel(plant={self.plant!r}, sample_period={self.sample_period!r}, " \
               f"counts_per_rev={self.counts_per_rev!r})"

    @property
    def a(self) -> float:
        """The plant's pole (its first-order part's), 1/s."""
        return float(self.plant.values()["a"])

    @property
    def b(self) -> float:
        """The plant's gain (its first-order part's), (rad/s^2)/duty."""
        return float(self.plant.values()["b"])

    @property
    def input_delay(self) -> int:
        """The plant's input delay, samples at :attr:`sample_period`."""
        return self.plant.input_delay

    def _value(self, name: str) -> float:
        return float(self.plant.values().get(name, 0.0))

    @property
    def friction(self) -> float:
        """The plant's Coulomb friction, rad/s^2 (0 when its structure has none)."""
        return self._value("friction")

    @property
    def bias(self) -> float:
        """The plant's constant acceleration, rad/s^2 (0 when its structure has none)."""
        return self._value("bias")

    @property
    def electrical_time_constant(self) -> float:
        """The plant's electrical time constant, s (0 when its structure has none)."""
        return self._value("electrical_time_constant")

    @property
    def dead_zone(self) -> float:
        """The plant's dead zone, duty (0 when its structure has none)."""
        return self._value("dead_zone")

    @property
    def static_friction(self) -> float:
        """The plant's static friction, rad/s^2 (0 when its structure has none)."""
        return self._value("static_friction")

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
            return cls(plant=source.plant.replace(input_delay=delay_at(source.input_delay, source.sample_period,
                                                                       period)),
                       sample_period=period, counts_per_rev=counts_per_rev or source.counts_per_rev)
        if isinstance(source, Plant) and not isinstance(source, Motor) or (
                callable(getattr(source, "motor", None)) and not isinstance(source.motor(), Motor)):
            return cls._of_plant(source, sample_period, counts_per_rev)
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
        return cls(float(source.a), float(source.b), sample_period, counts_per_rev, input_delay=delay,
                   **parts)  # type: ignore[arg-type]

    @classmethod
    def _of_plant(cls, source: Any, sample_period: float | None, counts_per_rev: int | None) -> "PlantModel":
        """A model of a plant of another structure than the first-order family's (or of an estimate of one)."""
        plant = source if isinstance(source, Plant) else source.motor()
        own_period = getattr(source, "sample_period", None)
        sample_period = sample_period if sample_period is not None else own_period
        if sample_period is None:
            raise ParameterError("sample_period must be given when the source has none, got None")
        if counts_per_rev is None:
            raise ParameterError("counts_per_rev must be given for a controller, got None")
        if own_period is not None:        # the source's delay is a time: counted again at this sample period
            plant = plant.replace(input_delay=delay_at(plant.input_delay, own_period,
                                                       check_real("sample_period", sample_period, positive=True)))
        return cls(plant=plant, sample_period=sample_period, counts_per_rev=counts_per_rev)

    @property
    def speed_scale(self) -> float:
        """Counts per sample per rad/s: ``counts_per_rev sample_period / (2 pi)``."""
        return self.counts_per_rev * self.sample_period / (2.0 * math.pi)

    @property
    def angle_scale(self) -> float:
        """Counts per rad: ``counts_per_rev / (2 pi)``."""
        return self.counts_per_rev / (2.0 * math.pi)

    def first_order(self) -> "PlantModel":
        """This model on its plant's first-order part (:meth:`motorsim.plant.Plant.first_order`: an electrical
        time constant left out): what the designs are made on."""
        part = self.plant.first_order()
        return self if part == self.plant else dataclasses.replace(self, plant=part)

    def motor(self) -> Plant:
        """The plant, every part included (the simulator's: a :class:`~motorsim.plant.Motor` for the first-order
        family)."""
        return self.plant

    def with_values(self, **values: float) -> "PlantModel":
        """This model with some of its plant's values changed (a robustness draw)."""
        return dataclasses.replace(self, plant=self.plant.replace(**values))

    def speed_coefficients(self) -> tuple[float, float, float, float]:
        """``(e, g, beta1, beta2)`` of the exact first-order model (:mod:`motorsim.control`), in counts per
        sample per duty: the first-order part's when the model has an electrical time constant."""
        return self.plant.first_order().speed_coefficients(self.sample_period, self.speed_scale)

    def drive_offset(self, sign: int) -> float:
        """``(bias - friction sign) / b`` in duty: what the drive adds when the speed has ``sign``."""
        return (self.bias - self.friction * sign) / self.b

    def speed_transfer_function(self) -> control.TransferFunction:
        """Duty to measured speed (counts per sample), ``(beta1 z + beta2) / (z^(D+1) (z - e))``; with an
        electrical time constant the full plant's (class Notes), both poles exact."""
        import control
        delay = np.r_[1.0, np.zeros(self.input_delay + 1)]
        num, den = self.plant.speed_polynomials(self.sample_period, self.speed_scale)
        return control.tf(num, np.polymul(delay, den), self.sample_period)

    def metadata(self) -> dict[str, str]:
        """The model as recording metadata ``model_NAME`` (the electrical time constant, dead zone and static
        friction only when nonzero)."""
        names: tuple[str, ...] = ("a", "b", "sample_period", "counts_per_rev", *_PLANT_PARTS)
        if not isinstance(self.plant, Motor):           # another structure: its own values too
            names += tuple(n for n in self.plant.values() if n not in names)
            return {f"model_{n}": repr(self.plant.values()[n] if n in self.plant.values() else getattr(self, n))
                    for n in names if n in ("a", "b", "sample_period", "counts_per_rev", "input_delay")
                    or (self.plant.values().get(n, 0.0) if n != "input_delay" else True)}
        return {f"model_{n}": repr(getattr(self, n)) for n in names if n not in _SAID_WHEN_SET or getattr(self, n)}


#: The plant's parts besides ``a`` and ``b``: every field of :class:`~motorsim.plant.Motor` a model carries
#: (a test checks it is all of them, so a part the simulator gains cannot be dropped here).
_PLANT_PARTS = ("friction", "bias", "input_delay", "electrical_time_constant", "dead_zone", "static_friction")
#: Parts written to metadata only when set (older recordings' metadata stays as it was).
_SAID_WHEN_SET = frozenset({"electrical_time_constant", "dead_zone", "static_friction"})
