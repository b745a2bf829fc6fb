"""The closed-loop experiment: what a rig runs (:class:`ClosedLoopExperiment`), and how far a
closed-loop recording was from its reference (:func:`tracking_error`)."""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..checks import ParameterError, ParameterTypeError, check_int, check_real
from ..excitation import DUTY_LIMIT
from .base import Controller
from .references import Reference

__all__ = ["ClosedLoopExperiment", "tracking_error"]


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
