"""LQR designs on the exact model with the input delay in the state: :class:`LQRSpeed` (``lqr``),
:class:`LQRSpeedIntegral` (``lqr-integral``) and :class:`LQRPosition` (``lqr-position``).

The state the firmware feeds back is the speed and the duties in the delay line: a model with an
electrical time constant is designed on its first-order part, and the loop checked on the full model
(:func:`~motorsim.control.pole_placement.check_full_model`)."""
from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from ..checks import ParameterError, check_real
from ..fixed_point import SPEED_REFERENCE_BITS, SPEED_REFERENCE_LSB, gain_value, quantise_gain
from .base import Controller, delay_line_laws
from .model import PlantModel
from .pole_placement import check_full_model

__all__ = ["LQRSpeed", "LQRSpeedIntegral", "LQRPosition", "INTEGRAL_WEIGHT"]


def _delay_line_matrices(model: PlantModel) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the exact speed model with the input delay in the state.

    The state is ``x_k = [y_k, u_{k-1}, ..., u_{k-D-1}]`` (speed in counts per sample and the
    ``D + 1`` duties the motor has still to feel), the input ``u_k``; ``A`` shifts the duties
    along and ``y_{k+1} = e y_k + beta1 u_{k-D} + beta2 u_{k-D-1}`` (:mod:`motorsim.control`).
    """
    e, _, b1, b2 = model.speed_coefficients()
    d = model.input_delay
    n = d + 2
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    a[0, 0] = e
    if d == 0:
        b[0, 0] = b1
    else:
        a[0, d] = b1
    a[0, d + 1] = b2
    b[1, 0] = 1.0
    for m in range(2, n):
        a[m, m - 1] = 1.0
    return a, b


def _lqr(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: float) -> np.ndarray:
    """The state-feedback gain ``K`` (``u = -K x``) minimising ``sum x'Qx + r u^2`` (discrete Riccati)."""
    from scipy.linalg import solve_discrete_are
    try:
        p = solve_discrete_are(a, b, q, np.array([[r]]))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ParameterError(f"the LQR design has no solution for this model and weight: {exc}") from None
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a).ravel()


@dataclasses.dataclass(frozen=True)
class _LQR(Controller):
    """An LQR: the weight of ``u^2`` against the controlled quantity's square (> 0)."""

    duty_weight: float = 1e-3

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "duty_weight", check_real("duty_weight", self.duty_weight, positive=True))
        check_full_model(self)     # a design on the first-order part, checked with the electrical pole


@dataclasses.dataclass(frozen=True)
class LQRSpeed(_LQR):
    """Speed LQR on the exact ZOH model with the input delay augmented into the state.

    The state is the measured speed and the ``D + 1`` duties still in the delay line (the
    device's own sample of delay included, through the model's ``input_delay``); the gain
    ``K`` minimises ``sum omega_k^2 + duty_weight u_k^2`` (discrete Riccati equation, SciPy).
    The step is ``u_k = kr r_{k+D+1} + ky y_k + sum_m ku_m u_{k-m} + k0 + kf sign(r_{k+D+1})``,
    ``ky`` and ``ku_m`` the quantised ``-K``; ``kr`` makes the steady speed equal the reference
    and ``k0``, ``kf`` cancel the model's bias and friction there, both computed from the
    quantised feedback gains.  The step is the one of :class:`OneStepMPC` (one linear form
    in the reference, the speed and the past duties): only the design differs.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        Weight of ``u^2`` in (rad/s)^2 per duty^2, > 0 (default 1e-3).

    Examples
    --------
    >>> lqr = LQRSpeed(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1))
    >>> sorted(lqr.gains())
    ['k0', 'kf', 'kr', 'ku1', 'ku2', 'ky']
    >>> lqr.is_stable()
    True
    """

    duty_weight: float = 1e-3
    kind: ClassVar[str] = "lqr"

    def state_gain(self) -> np.ndarray:
        """``K`` of ``u = -K x`` in the model's integer units (counts per sample, duty)."""
        a, b = _delay_line_matrices(self.model)
        q = np.zeros_like(a)
        q[0, 0] = 1.0
        return _lqr(a, b, q, self.duty_weight * self.model.speed_scale ** 2)

    def gains(self) -> dict[str, int]:
        k = self.state_gain()
        return _speed_lqr_gains(self.model, quantise_gain(-k[0]), [quantise_gain(-x) for x in k[1:]])

    def laws(self):
        return delay_line_laws(self.gains(), self.model)


def _speed_lqr_gains(model: PlantModel, ky: int, ku: list[int], ki: int | None = None) -> dict[str, int]:
    """The speed LQR's gains in wire order: ``kr`` and ``k0``, ``kf`` from the quantised feedback gains.

    At a steady speed ``r`` (counts per sample) the duty is ``u = (1 - e) r / g - o`` (``o`` the
    model's drive offset) and every past duty equals it, so ``kr r + ky r + k0 + kf = u (1 - sum ku)``
    makes the steady output the reference, and an integral (``ki``) stays at 0 on the model.
    """
    e, g, _, _ = model.speed_coefficients()
    hold = 1.0 - sum(gain_value(x) for x in ku)     # what is left of u at steady state
    out = {"kr": quantise_gain(((1.0 - e) / g * hold - gain_value(ky)) * SPEED_REFERENCE_LSB), "ky": ky}
    if ki is not None:
        out["ki"] = ki
    out["k0"] = quantise_gain(-model.bias / model.b * hold)
    out["kf"] = quantise_gain(model.friction / model.b * hold)
    out.update({f"ku{j}": x for j, x in enumerate(ku, 1)})
    return out


#: Default weight of the squared angle error (the integral of the speed error) of :class:`LQRSpeedIntegral`, 1/s^2.
INTEGRAL_WEIGHT = 100.0


@dataclasses.dataclass(frozen=True)
class LQRSpeedIntegral(_LQR):
    """Speed LQR with integral action: the integral of the speed error in the state.

    The state of :class:`LQRSpeed` (the measured speed and the ``D + 1`` duties in the delay
    line) gains ``s_k``, the sum of the errors ``r_j - y_j`` before sample ``k``
    (``s_{k+1} = s_k + r_k - y_k``); the gain minimises
    ``sum omega_k^2 + integral_weight theta_k^2 + duty_weight u_k^2``, where ``theta_k``,
    ``sample_period`` times the sum in rad/s, is the error's integral, an angle in rad.  The step is
    :class:`LQRSpeed`'s with ``ki s_k`` added and the sum updated after it,
    ``u_k = kr r_{k+D+1} + ky y_k + ki s_k + sum_m ku_m u_{k-m} + k0 + kf sign(r_{k+D+1})``;
    the sum stops growing while the duty is at the limit and the error pushes further into it
    (the PI's conditional integration).  ``kr``, ``k0`` and ``kf`` are :class:`LQRSpeed`'s for
    the new feedback gains, so on the model the sum stays at 0; a bias, friction or gain the
    model lacks is what it integrates, and a constant reference is tracked with no steady error.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        Weight of ``u^2`` in (rad/s)^2 per duty^2, > 0 (default 1e-3).
    integral_weight : float
        Weight of ``theta^2`` in (rad/s)^2 per rad^2 (1/s^2), > 0 (default
        :data:`INTEGRAL_WEIGHT`, 100: an angle error of 0.1 rad costs as much as a speed error
        of 1 rad/s).

    Examples
    --------
    >>> lqr = LQRSpeedIntegral(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1))
    >>> list(lqr.gains())
    ['kr', 'ky', 'ki', 'k0', 'kf', 'ku1', 'ku2']
    >>> lqr.is_stable()
    True
    """

    integral_weight: float = INTEGRAL_WEIGHT
    kind: ClassVar[str] = "lqr-integral"

    def __post_init__(self):
        object.__setattr__(self, "integral_weight", check_real("integral_weight", self.integral_weight, positive=True))
        super().__post_init__()

    def state_gain(self) -> np.ndarray:
        """``K`` of ``u = -K x``, ``x = [y, u_{k-1}, ..., u_{k-D-1}, s]`` in counts per sample, duty, counts."""
        a, b = _integral_matrices(self.model)
        q = np.zeros_like(a)
        q[0, 0] = 1.0
        q[-1, -1] = self.integral_weight * self.model.sample_period ** 2
        return _lqr(a, b, q, self.duty_weight * self.model.speed_scale ** 2)

    def gains(self) -> dict[str, int]:
        k = self.state_gain()
        return _speed_lqr_gains(self.model, quantise_gain(-k[0]), [quantise_gain(-x) for x in k[1:-1]],
                                ki=quantise_gain(-k[-1] * SPEED_REFERENCE_LSB))

    def laws(self):
        import control
        g, m = self.gains(), self.model
        kr, ky, ki = (gain_value(g[name]) for name in ("kr", "ky", "ki"))
        n = m.input_delay + 1                       # the past duties weighed, and the preview
        ku = [gain_value(g[f"ku{j}"]) for j in range(1, n + 1)]
        # u (1 - sum_m ku_m z^-m) = kr r + ky y + ki s with s = (z^-n r - 16 y) / (z - 1); one
        # denominator, (z - 1)(z^n - sum_m ku_m z^(n-m)), as the step has one state per term
        den = np.polymul([1.0, -1.0], [1.0, *(-x for x in ku)])
        cr = np.polyadd(np.polymul([kr, -kr], np.r_[1.0, np.zeros(n)]), [ki])
        cy = np.polymul([ky, -ky - (1 << SPEED_REFERENCE_BITS) * ki], np.r_[1.0, np.zeros(n)])
        return control.tf(cr, den, m.sample_period), control.tf(cy, den, m.sample_period)


def _integral_matrices(model: PlantModel) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of :func:`_delay_line_matrices` with the error's sum last: ``s_{k+1} = s_k - y_k`` (r = 0)."""
    a_speed, b_speed = _delay_line_matrices(model)
    n = a_speed.shape[0] + 1
    a = np.zeros((n, n))
    a[:-1, :-1] = a_speed
    a[-1, 0] = -1.0
    a[-1, -1] = 1.0
    return a, np.vstack([b_speed, [[0.0]]])


@dataclasses.dataclass(frozen=True)
class LQRPosition(_LQR):
    """Position LQR on the counts, with the input delay augmented into the state.

    The state is the angle (counts since the first sample), the measured speed and the
    ``D + 1`` duties still in the delay line; ``K`` minimises
    ``sum theta_k^2 + duty_weight u_k^2`` (theta in rad).  The step is
    ``u_k = kp (r_{k+D+1} - theta_k) + ky y_k + sum_m ku_m u_{k-m} + k0``: ``kp`` the
    quantised angle gain, ``ky`` and ``ku_m`` the quantised ``-K``, ``k0`` the model's bias
    cancelled at standstill.

    Parameters
    ----------
    model : PlantModel
        The motor model.
    duty_weight : float
        Weight of ``u^2`` in rad^2 per duty^2, > 0 (default 1e-6).

    Examples
    --------
    >>> LQRPosition(PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1)).is_stable()
    True
    """

    duty_weight: float = 1e-6
    kind: ClassVar[str] = "lqr-position"
    quantity: ClassVar[str] = "angle"

    def state_gain(self) -> np.ndarray:
        """``K`` of ``u = -K x``, ``x = [theta, y, u_{k-1}, ..., u_{k-D-1}]`` in counts and duty."""
        a_speed, b_speed = _delay_line_matrices(self.model)
        n = a_speed.shape[0] + 1
        a = np.zeros((n, n))
        a[1:, 1:] = a_speed
        a[0, 0] = 1.0
        a[0, 1:] = a_speed[0]               # theta_{k+1} = theta_k + y_{k+1}
        b = np.vstack([b_speed[:1], b_speed])
        q = np.zeros_like(a)
        q[0, 0] = 1.0
        return _lqr(a, b, q, self.duty_weight * self.model.angle_scale ** 2)

    def gains(self) -> dict[str, int]:
        k = self.state_gain()
        ku = [quantise_gain(-x) for x in k[2:]]
        hold = 1.0 - sum(gain_value(x) for x in ku)
        out = {"kp": quantise_gain(k[0]), "ky": quantise_gain(-k[1]),
               "k0": quantise_gain(-self.model.bias / self.model.b * hold)}
        out.update({f"ku{j}": x for j, x in enumerate(ku, 1)})
        return out

    def laws(self):
        return delay_line_laws(self.gains(), self.model, position=True)
