"""One-step model predictive control of the speed: :class:`OneStepMPC` (``mpc``)."""
from __future__ import annotations

import dataclasses
from typing import ClassVar

from ..checks import ParameterError, check_real
from ..fixed_point import SPEED_REFERENCE_LSB, quantise_gain
from .base import Controller, delay_line_laws
from .model import PlantModel  # noqa: F401  (the examples')
from .pole_placement import check_full_model

__all__ = ["OneStepMPC"]


@dataclasses.dataclass(frozen=True)
class OneStepMPC(Controller):
    """One-step model predictive control of the speed (the plan of the article's section 6).

    At each sample, the integer duty ``u_k`` in ``-duty_limit ... duty_limit`` that minimises
    ``J(u) = (r_{k+D+1} - y_hat_{k+D+1})^2 + duty_weight u^2``, where ``y_hat`` is the exact
    model's prediction of the measured speed (:mod:`motorsim.control`) ``D + 1`` samples ahead
    (the first sample the duty can affect), friction taken with the reference's sign.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        lambda in (rad/s)^2 per duty^2, >= 0 (default 1e-4).

    Notes
    -----
    ``y_hat = f + beta1 u`` with ``f`` known at sample ``k``, so ``J`` is a convex quadratic
    in one variable, symmetric about ``u* = beta1 (r - f) / (beta1^2 + lambda)``.  Over the
    integers of an interval its minimum is therefore the integer nearest ``u*`` clipped to
    the interval: ``J`` grows with the distance to ``u*`` on both sides, so rounding picks
    the nearest integer, and when ``u*`` lies outside the interval ``J`` is monotone on it
    and the limit nearest ``u*`` wins.  No search is needed: the step is one linear form
    in ``r``, ``y_k`` and the past duties, rounded and clipped.

    The cost weighs the whole duty, so the model's bias and friction are compensated by
    the fraction ``beta1^2 / (beta1^2 + lambda)`` of their duty equivalent, and a constant
    reference keeps a steady error when ``lambda > 0`` (there is no integral action);
    ``lambda`` near 0 approaches dead-beat control of the measured speed, whose duty rings
    at the zero ``-beta2 / beta1`` (about -0.96 at 5 ms) of the differenced-counts model.

    A model with an electrical time constant is predicted on its first-order part (the step
    feeds back the speed and the past duties only); the loop is then checked on the full model
    (:func:`~motorsim.control.pole_placement.check_full_model`): refused when unstable there, warned
    of when the electrical pole costs more than
    :data:`~motorsim.control.pole_placement.ELECTRICAL_PHASE_COST` degrees of phase margin.

    Examples
    --------
    >>> mpc = OneStepMPC(PlantModel(25.0, 3.0, 0.005, 16667))
    >>> sorted(mpc.gains())
    ['k0', 'kf', 'kr', 'ku1', 'ky']
    >>> mpc.is_stable()
    True
    """

    duty_weight: float = 1e-4
    kind: ClassVar[str] = "mpc"

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "duty_weight", check_real("duty_weight", self.duty_weight, nonnegative=True))
        check_full_model(self)

    def _coefficients(self) -> tuple[float, list[float], float, float]:
        """``(K, [c_1 ... c_{D+1}], e^(D+1), g S_D)`` of ``y_hat = e^(D+1) y + beta1 u + sum c_m u_{k-m} + g S_D o``."""
        m = self.model
        e, g, b1, b2 = m.speed_coefficients()
        d = m.input_delay
        c = [(e ** j * b1 if j <= d else 0.0) + e ** (j - 1) * b2 for j in range(1, d + 2)]
        weight = self.duty_weight * m.speed_scale ** 2
        if b1 * b1 + weight == 0:  # pragma: no cover - b != 0 makes beta1 != 0
            raise ParameterError("the model's beta1 is zero: the duty does not reach the next sample")
        return b1 / (b1 * b1 + weight), c, e ** (d + 1), g * sum(e ** j for j in range(d + 1))

    def gains(self) -> dict[str, int]:
        k, c, e_ahead, gs = self._coefficients()
        m = self.model
        out = {"kr": quantise_gain(k * SPEED_REFERENCE_LSB), "ky": quantise_gain(-k * e_ahead),
               "k0": quantise_gain(-k * gs * m.bias / m.b), "kf": quantise_gain(k * gs * m.friction / m.b)}
        out.update({f"ku{j}": quantise_gain(-k * cj) for j, cj in enumerate(c, 1)})
        return out

    def laws(self):
        return delay_line_laws(self.gains(), self.model)
