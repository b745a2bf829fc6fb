"""PI speed control by pole placement: :class:`PISpeed` (``pi``)."""
from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

from ..checks import ParameterError
from ..fixed_point import SPEED_REFERENCE_BITS, SPEED_REFERENCE_LSB, gain_value, quantise_gain
from .base import fir
from .feedforward import feedforward_gains
from .model import PlantModel  # noqa: F401  (the examples')
from .pole_placement import PolePlacement

__all__ = ["PISpeed"]


@dataclasses.dataclass(frozen=True)
class PISpeed(PolePlacement):
    """PI speed control by pole placement on the exact ZOH model, with anti-windup.

    ``u_k = kp e_k + ki sum_{j<=k} e_j`` with ``e = r - y``; both closed-loop poles of the
    model ``y_{k+1} = e_a y_k + g u_k`` sit at ``p = exp(-sample_period / time_constant)``:
    ``kp = (e_a - p^2) / g``, ``ki = (1 - p)^2 / g``.  The sum stops growing while the duty
    is at the limit and the error pushes further into it (conditional integration).
    :meth:`predict` closes the loop on the full model (differenced counts, delay).

    The model the poles are placed on has no input delay (nor an electrical time constant: its
    first-order part); the loop on the full one must keep ``min_phase_margin`` degrees, or the time
    constant is lengthened until it does (a :class:`DesignLimitWarning` names both time constants).
    On the article's motor at 5 ms the shortest time constants that keep 60 degrees are 16.7, 26
    and 32.5 ms for an input delay of 0, 1 and 2 samples (45 degrees: 10.7, 19.4 and 25.4 ms); a
    step then overshoots by about 6 % (about 27 % at 45 degrees), where 10 ms with one sample of
    delay leaves 6 degrees and 107 %.

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
        delay = fir([0.0] * self.preview + [1.0], dt)
        cr = c * delay
        if self.feedforward:
            cr = cr + fir([gain_value(g["kn"]), gain_value(g["kc"])], dt)
        return cr, -(1 << SPEED_REFERENCE_BITS) * c
