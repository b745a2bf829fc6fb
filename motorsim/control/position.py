"""Position P or PD control by pole placement: :class:`PositionPD` (``position``)."""
from __future__ import annotations

import dataclasses
from typing import ClassVar

from ..fixed_point import gain_value, quantise_gain
from .base import fir
from .model import PlantModel  # noqa: F401  (the examples')
from .pole_placement import PolePlacement

__all__ = ["PositionPD"]


@dataclasses.dataclass(frozen=True)
class PositionPD(PolePlacement):
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
        return fir([kp], dt), fir([-kp - kd, kd], dt)
