"""The numbers a controller is designed from: :class:`PlantModel`, and its exact model of the measured speed."""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..checks import ParameterError, ParameterTypeError, check_int, check_real
from ..plant import Motor, delay_at, zoh_matrices

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
        for name in ("friction", "bias", "input_delay"):
            if hasattr(source, name) and not isinstance(source, type):
                extra.setdefault(name, getattr(source, name))
        own_period = getattr(source, "sample_period", None)
        sample_period = sample_period if sample_period is not None else own_period
        if sample_period is None:
            raise ParameterError("sample_period must be given when the source has none, got None")
        if counts_per_rev is None:
            raise ParameterError("counts_per_rev must be given for a controller, got None")
        delay = int(extra.get("input_delay", 0))
        if own_period is not None:        # the source's delay is a time: counted again at this sample period
            delay = delay_at(delay, own_period, check_real("sample_period", sample_period, positive=True))
        return cls(float(source.a), float(source.b), sample_period, counts_per_rev,
                   friction=float(extra.get("friction", 0.0)), bias=float(extra.get("bias", 0.0)),
                   input_delay=delay)

    @property
    def speed_scale(self) -> float:
        """Counts per sample per rad/s: ``counts_per_rev sample_period / (2 pi)``."""
        return self.counts_per_rev * self.sample_period / (2.0 * math.pi)

    @property
    def angle_scale(self) -> float:
        """Counts per rad: ``counts_per_rev / (2 pi)``."""
        return self.counts_per_rev / (2.0 * math.pi)

    def speed_coefficients(self) -> tuple[float, float, float, float]:
        """``(e, g, beta1, beta2)`` of the exact model (:mod:`motorsim.control`), in counts per sample per duty."""
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
