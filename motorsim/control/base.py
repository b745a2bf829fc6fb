"""What every controller shares: the :class:`Controller` base class, its :class:`Prediction`, and the
transfer-function pieces (:func:`fir`, :func:`delay_line_laws`) the designs write their laws with."""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, ClassVar, Mapping, Sequence

import numpy as np

from ..checks import ParameterError, ParameterTypeError, check_real
from ..excitation import DUTY_LIMIT
from ..fixed_point import SPEED_REFERENCE_LSB, ControlLoop, gain_value
from ..margins import Margins, discrete_margins
from .model import PlantModel
from .references import Reference

if TYPE_CHECKING:
    import control

__all__ = ["Controller", "Prediction", "fir", "delay_line_laws", "MAX_PREDICTION_SAMPLES"]

#: The most samples :meth:`Controller.predict` simulates (10 s at 1 MHz; a few seconds of work).
MAX_PREDICTION_SAMPLES = 10_000_000


@dataclasses.dataclass(frozen=True)
class Prediction:
    """A closed-loop response predicted from the model (linear: no duty limit, no quantisation).

    Attributes
    ----------
    time : ndarray
        Sample instants in s.
    reference : ndarray
        The reference in physical units (rad/s or rad), as the device quantises it.
    output : ndarray
        Predicted measured speed (rad/s, differenced counts) or angle from the start (rad).
    duty : ndarray
        Predicted duty (unrounded, unclipped).
    tracking_rms : float
        RMS of ``reference - output`` over samples 1 ... n-1, in the reference's unit.
    """

    time: np.ndarray
    reference: np.ndarray
    output: np.ndarray
    duty: np.ndarray
    tracking_rms: float


@dataclasses.dataclass(frozen=True)
class Controller:
    """Base class: a controller designed from a :class:`PlantModel`.

    Subclasses set ``kind`` and ``quantity`` and define :meth:`gains` (the fixed-point
    parameters a device receives) and :meth:`laws` (the same law as transfer functions).
    """

    model: PlantModel
    kind: ClassVar[str] = ""
    quantity: ClassVar[str] = "speed"

    def __post_init__(self):
        if not isinstance(self.model, PlantModel):
            raise ParameterTypeError(f"model must be a PlantModel, got {type(self.model).__name__}")

    @property
    def preview(self) -> int:
        """Samples of reference the step looks ahead (``input_delay + 1`` for model-based laws, else 0)."""
        return self.model.input_delay + 1

    @property
    def reference_scale(self) -> float:
        """Integer reference units per physical unit (per rad/s, or per rad for position)."""
        if self.quantity == "angle":
            return self.model.angle_scale
        return self.model.speed_scale / SPEED_REFERENCE_LSB

    @property
    def reference_unit(self) -> str:
        """``rad/s`` (speed controllers) or ``rad`` (position)."""
        return "rad" if self.quantity == "angle" else "rad/s"

    def gains(self) -> dict[str, int]:  # pragma: no cover - abstract
        """The fixed-point parameters of the step, by name (Q16 integers)."""
        raise NotImplementedError

    def settings(self) -> dict[str, float | bool]:
        """The design knobs (every field but the model)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "model"}

    def laws(self) -> tuple[control.TransferFunction, control.TransferFunction]:  # pragma: no cover
        """``(Cr, Cy)``: duty from the previewed reference and from the measurement, ``u = Cr r + Cy y``."""
        raise NotImplementedError

    def start(self, reference: Sequence[int] | np.ndarray, duty_limit: int = DUTY_LIMIT) -> ControlLoop:
        """A fresh :class:`ControlLoop` on the integer ``reference``."""
        return ControlLoop(self.kind, self.gains(), self.preview, reference, duty_limit)

    def plant(self) -> control.TransferFunction:
        """Duty to what the controller measures: speed in counts/sample, or counts for position (the full
        model: input delay and electrical time constant included)."""
        return self._plant_of(self.model)

    def _plant_of(self, model: PlantModel) -> control.TransferFunction:
        import control
        p = model.speed_transfer_function()
        if self.quantity == "angle":
            p = p * control.tf([1.0, 0.0], [1.0, -1.0], model.sample_period)
        return p

    def closed_loop(self) -> tuple[control.LTI, control.LTI]:
        """``(T_y, T_u)``: previewed reference to measured output and to duty, via ``control.feedback``.

        Transfer functions; state-space systems for a model with an electrical time constant, whose
        two poles near 1 (and an integrating law's) make the closed loop's polynomials lose digits
        (about 1e-6 of the response, where state space keeps 1e-12).
        """
        import control
        cr, cy = self.laws()
        p = self.plant()
        one: control.LTI = control.tf([1.0], [1.0], self.model.sample_period)
        if self.model.electrical_time_constant:
            cr, cy, p, one = control.ss(cr), control.ss(cy), control.ss(p), control.ss([], [], [], 1.0,
                                                                                         self.model.sample_period)
        sensitivity = control.feedback(one, p * cy, sign=1)
        t_u = sensitivity * cr
        return p * t_u, t_u

    def margins(self) -> Margins:
        """Gain, phase and delay margins of the loop broken at the duty, ``L = -Cy P``, on the model (delay
        and electrical time constant included).

        :func:`motorsim.robustness.loop_margins` gives the same on another plant.
        """
        _, cy = self.laws()
        loop = -(self.plant() * cy)
        return discrete_margins(np.ravel(loop.num[0][0]), np.ravel(loop.den[0][0]), self.model.sample_period)

    def first_order_margins(self) -> Margins:
        """:meth:`margins` of the same gains on the model's first-order part (:meth:`PlantModel.first_order`):
        what a design that drops the electrical time constant would report; :meth:`margins` itself when
        the model has none."""
        _, cy = self.laws()
        loop = -(self._plant_of(self.model.first_order()) * cy)
        return discrete_margins(np.ravel(loop.num[0][0]), np.ravel(loop.den[0][0]), self.model.sample_period)

    def is_stable(self) -> bool:
        """Whether every closed-loop pole lies inside the unit circle."""
        import control
        cr, cy = self.laws()
        loop = control.feedback(-(self.plant() * cy), 1)
        return bool(np.all(np.abs(loop.poles()) < 1.0 - 1e-12))

    def predict(self, reference: Reference, duration: float) -> Prediction:
        """The closed-loop response to ``reference`` over ``duration`` s (``control.forced_response``).

        Parameters
        ----------
        reference : Reference
            The wave, in rad/s (speed controllers) or rad (position).
        duration : float
            Run length in s (``round(duration / sample_period)`` samples).
        """
        import control
        h = self.model.sample_period
        n_float = check_real("duration", duration, positive=True) / h
        if n_float > MAX_PREDICTION_SAMPLES:
            raise ParameterError(f"duration / sample_period must give at most {MAX_PREDICTION_SAMPLES:,} samples "
                                 f"for a prediction, got {duration!r} s / {h!r} s = {n_float:.3g}; shorten the "
                                 "duration or lengthen the sample period")
        n = int(round(n_float))
        r = reference.samples(n + self.preview, h, self.reference_scale).astype(float)
        t = np.arange(n) * h
        t_y, t_u = self.closed_loop()
        r_ahead = r[self.preview:self.preview + n]
        y = control.forced_response(t_y, timepts=t, inputs=r_ahead).outputs
        u = control.forced_response(t_u, timepts=t, inputs=r_ahead).outputs
        scale = self.model.angle_scale if self.quantity == "angle" else self.model.speed_scale
        ref = r[:n] / self.reference_scale
        out = np.asarray(y, dtype=float) / scale
        rms = float(np.sqrt(np.mean((ref[1:] - out[1:]) ** 2))) if n > 1 else math.nan
        return Prediction(t, ref, out, np.asarray(u, dtype=float), rms)

    def metadata(self) -> dict[str, str]:
        """Recording metadata: ``controller``, its knobs, gains and the model it was designed from."""
        meta = {"controller": self.kind, "controlled": self.quantity, "reference_unit": self.reference_unit}
        meta.update({f"controller_{k}": repr(v) for k, v in self.settings().items()})
        meta["controller_gains"] = " ".join(f"{k}={v}" for k, v in self.gains().items())
        meta.update(self.model.metadata())
        return meta


def fir(coefficients: Sequence[float], dt: float) -> control.TransferFunction:
    """``c0 + c1 z^-1 + ... + cm z^-m`` as a transfer function in z."""
    import control
    den = np.r_[1.0, np.zeros(len(coefficients) - 1)]
    return control.tf(list(coefficients), den, dt)



def delay_line_laws(gains: Mapping[str, int], model: PlantModel, *, position: bool = False):
    """``(Cr, Cy)`` of ``u (1 - sum_m ku_m z^-m) = kr r + ky y`` (speed) or
    ``= kp (r - theta) + ky (1 - z^-1) theta`` (position, where the measurement is theta)."""
    dt = model.sample_period
    ku = [gain_value(gains[f"ku{j}"]) for j in range(1, model.input_delay + 2)]
    den = fir([1.0, *(-x for x in ku)], dt)
    ky = gain_value(gains["ky"])
    if position:
        kp = gain_value(gains["kp"])
        return fir([kp], dt) / den, fir([ky - kp, -ky], dt) / den
    return fir([gain_value(gains["kr"])], dt) / den, fir([ky], dt) / den
