"""What the pole-placement designs (``pi``, ``position``) share: a time constant, and the phase margin
the loop on the exact model keeps (:class:`PolePlacement`, :data:`MIN_PHASE_MARGIN`, :class:`DesignLimitWarning`);
and the check every feedback design made on the first-order part of a model with an electrical time
constant passes on the full model (:func:`check_full_model`, :data:`ELECTRICAL_PHASE_COST`)."""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from ..checks import ParameterError, check_real
from ..margins import Margins
from .base import Controller

__all__ = ["PolePlacement", "MIN_PHASE_MARGIN", "DesignLimitWarning", "UnstableDesignError", "ELECTRICAL_PHASE_COST",
           "check_full_model"]

#: The least phase margin, in degrees, a pole-placement design (``pi``, ``position``) keeps by default.
MIN_PHASE_MARGIN = 60.0
#: Degrees of phase margin the electrical pole may cost a design made on the first-order part before
#: :func:`check_full_model` warns (when less than :data:`MIN_PHASE_MARGIN` is left): a usual allowance
#: for dynamics a design leaves out, a sixth of :data:`MIN_PHASE_MARGIN`.
ELECTRICAL_PHASE_COST = 10.0


class DesignLimitWarning(UserWarning):
    """A controller was designed slower than asked, so that its loop keeps the phase margin required; or
    a design made on a model's first-order part loses more than :data:`ELECTRICAL_PHASE_COST` on the full model."""


class UnstableDesignError(ParameterError):
    """A design made on a model's first-order part gives a loop unstable on the full model
    (:func:`check_full_model`)."""


def check_full_model(controller: Controller) -> None:
    """Check a design made on the first-order part against the full model (with its electrical pole).

    Nothing to check for a model without an electrical time constant, or a controller without
    feedback.  The same gains are closed around the full plant (:meth:`Controller.margins`) and around
    the first-order part (:meth:`Controller.first_order_margins`): a loop unstable on the full model is
    refused (:class:`~motorsim.checks.ParameterError`, both verdicts named), and one whose phase margin
    drops by more than :data:`ELECTRICAL_PHASE_COST` degrees at crossover, to less than
    :data:`MIN_PHASE_MARGIN`, is warned of (:class:`DesignLimitWarning`, the full model's margins named).

    Raises
    ------
    UnstableDesignError
        The loop is unstable on the full model (a :class:`~motorsim.checks.ParameterError`).
    """
    model = controller.model
    if not model.electrical_time_constant or not np.any(np.ravel(controller.laws()[1].num[0][0])):
        return
    full, part = controller.margins(), controller.first_order_margins()
    what = (f"{controller.kind} design {_settings_text(controller)} on the first-order part (phase margin "
            f"{part.phase_margin:.3g} deg, {'stable' if part.stable else 'UNSTABLE'})")
    tau = f"electrical time constant {model.electrical_time_constant:.4g} s"
    if not full.stable:
        raise UnstableDesignError(f"the {what} gives an unstable loop on the full model with its {tau}: "
                                  f"{_SLOWER.get(controller.kind, 'design more slowly')}")
    cost = part.phase_margin - full.phase_margin
    if math.isfinite(cost) and cost > ELECTRICAL_PHASE_COST and full.phase_margin < MIN_PHASE_MARGIN:
        warnings.warn(f"the {tau} costs the {what} {cost:.3g} deg of phase margin (crossover now at "
                      f"{full.crossover:.4g} rad/s), more than {ELECTRICAL_PHASE_COST:g}, leaving less than "
                      f"{MIN_PHASE_MARGIN:g}: on the full model "
                      f"{full.describe()}", DesignLimitWarning, stacklevel=4)


_SLOWER = {"mpc": "raise duty_weight", "lqr": "raise duty_weight", "lqr-integral": "raise duty_weight or lower "
           "integral_weight", "lqr-position": "raise duty_weight", "pi": "lengthen time_constant or keep "
           "min_phase_margin above 0", "position": "lengthen time_constant or keep min_phase_margin above 0"}


def _settings_text(controller: Controller) -> str:
    return "(" + ", ".join(f"{k} {v!r}" for k, v in controller.settings().items()) + ")"


@dataclasses.dataclass(frozen=True)
class PolePlacement(Controller):
    """A controller whose closed-loop poles sit at ``-1/time_constant`` (s, > 0, default 0.05).

    The poles are placed on a model without the input delay (and on the first-order part of one with
    an electrical time constant); the loop on the exact model, delay and electrical pole included,
    must keep ``min_phase_margin`` degrees (keyword only, default :data:`MIN_PHASE_MARGIN`,
    0 turns the check off).  A time constant too short for it is lengthened to the shortest one
    that keeps it (rounded up to 3 significant digits), with a :class:`DesignLimitWarning` that
    names both; ``time_constant`` is then the one designed with.  With ``min_phase_margin`` 0 a model
    with an electrical time constant is still checked (:func:`check_full_model`).
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
            check_full_model(self)
            return
        achieved = self.margins()
        if self._keeps_margin(achieved):
            return
        asked = self.time_constant
        fastest = self._fastest_time_constant()
        what = (f"leaves a phase margin of {achieved.phase_margin:.3g} deg" if achieved.stable
                else "gives an unstable loop")
        delay, tau = self.model.input_delay, self.model.electrical_time_constant
        lag = f", electrical time constant {tau:.4g} s" if tau else ""
        warnings.warn(f"{self.kind} time_constant {asked!r} s {what} on the model (input delay {delay} "
                      f"sample{'' if delay == 1 else 's'} at {self.model.sample_period!r} s{lag}); designed with "
                      f"time_constant {fastest!r} s, the shortest that keeps min_phase_margin {margin:g} deg "
                      "(min_phase_margin 0 keeps the time constant asked for)", DesignLimitWarning, stacklevel=3)
        object.__setattr__(self, "time_constant", fastest)

    def _keeps_margin(self, margins: Margins) -> bool:
        return margins.stable and margins.phase_margin >= self.min_phase_margin

    def _keeps_margin_at(self, time_constant: float) -> bool | None:
        """Whether the design at ``time_constant`` keeps the margin (None: the fixed point cannot hold it)."""
        try:
            with warnings.catch_warnings():     # a candidate's own verdict is what is asked, not said
                warnings.simplefilter("ignore", DesignLimitWarning)
                candidate = dataclasses.replace(self, time_constant=time_constant, min_phase_margin=0.0)
            return self._keeps_margin(candidate.margins())
        except UnstableDesignError:     # unstable on the full model: it does not keep the margin
            return False
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
