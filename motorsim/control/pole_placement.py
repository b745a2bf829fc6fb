"""What the pole-placement designs (``pi``, ``position``) share: a time constant, and the phase margin
the loop on the exact model keeps (:class:`PolePlacement`, :data:`MIN_PHASE_MARGIN`, :class:`DesignLimitWarning`)."""
from __future__ import annotations

import dataclasses
import math
import warnings

from ..checks import ParameterError, check_real
from ..margins import Margins
from .base import Controller

__all__ = ["PolePlacement", "MIN_PHASE_MARGIN", "DesignLimitWarning"]

#: The least phase margin, in degrees, a pole-placement design (``pi``, ``position``) keeps by default.
MIN_PHASE_MARGIN = 60.0


class DesignLimitWarning(UserWarning):
    """A controller was designed slower than asked, so that its loop keeps the phase margin required."""


@dataclasses.dataclass(frozen=True)
class PolePlacement(Controller):
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
