"""Speed feedforward from the model alone: :class:`Feedforward` (``feedforward``) and its gains."""
from __future__ import annotations

import dataclasses
from typing import ClassVar

from ..fixed_point import SPEED_REFERENCE_LSB, gain_value, quantise_gain
from .base import Controller, fir
from .model import PlantModel

__all__ = ["Feedforward", "feedforward_gains"]


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
        return fir([gain_value(g["kn"]), gain_value(g["kc"])], dt), fir([0.0], dt)


def feedforward_gains(model: PlantModel) -> dict[str, int]:
    """Q16 gains ``kn, kc, k0, kf`` of the speed feedforward (see :class:`Feedforward`)."""
    e, g, _, _ = model.speed_coefficients()
    return {"kn": quantise_gain(SPEED_REFERENCE_LSB / g), "kc": quantise_gain(-e * SPEED_REFERENCE_LSB / g),
            "k0": quantise_gain(-model.bias / model.b), "kf": quantise_gain(model.friction / model.b)}
