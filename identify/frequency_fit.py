"""``a`` and ``b`` fitted to a frequency response: a cross-check of the time-domain fits.

The model is the exact ZOH response of ``b/(s + a)`` for the response's output
(:func:`identify.frequency_estimate.zoh_speed_response`), the residual at each line is
weighted by the line's standard error, and ``(a, b)`` minimise::

    sum_k |G_k - G(e^{j omega_k dt}; a, b)|^2 / var_k

(a weighted nonlinear least squares in the frequency domain, Pintelon & Schoukens, *System
Identification: A Frequency Domain Approach*, 2nd ed. 2012, sec. 7.2.2 and 9.4).  The
covariance is the Gauss-Newton one, ``(J^T W J)^-1``, scaled up by the reduced chi-square when
the model misses the data by more than its bounds allow (a model error then counts as noise).
The start is the linear least squares of ``G (j omega + a) = b`` (Levy 1959).
"""
from __future__ import annotations

import math

import numpy as np

from motorsim.checks import ParameterTypeError, check_int

from .errors import NotIdentifiableError
from .estimate import Estimate
from .frequency_estimate import FrequencyResponse, zoh_speed_response

__all__ = ["fit_frequency_response"]


def _levy_start(frf: FrequencyResponse, weight: np.ndarray) -> tuple[float, float]:
    """``a, b`` from ``a G - b = -j omega G`` by weighted linear least squares (continuous time)."""
    g, w = frf.response, frf.omega
    rows = np.column_stack([g, -np.ones_like(g)]) * weight[:, None]
    rhs = -1j * w * g * weight
    x, *_ = np.linalg.lstsq(np.vstack([rows.real, rows.imag]), np.concatenate([rhs.real, rhs.imag]), rcond=None)
    a, b = float(x[0]), float(x[1])
    if not a > 0 or b == 0:
        a = max(float(np.median(w)), 1e-3)
        b = float(np.abs(g[0])) * a
    return a, b


def fit_frequency_response(frf: FrequencyResponse, *, input_delay: int = 0) -> Estimate:
    """``a`` and ``b`` of ``b/(s + a)`` fitted to a frequency response, weighted by its bounds.

    Parameters
    ----------
    frf : FrequencyResponse
        The data (:func:`identify.frequency_estimate.frequency_response`), at least 2 lines.
    input_delay : int
        Whole samples of input delay in the model, default 0.

    Returns
    -------
    Estimate
        Method ``"frequency"``; ``n_samples`` counts lines, ``residual_rms`` is the RMS of the
        standardised residuals (about 1 when the model fits within the bounds) and
        ``fit_percent`` the NRMSE fit of the model's response to the data's.

    Raises
    ------
    NotIdentifiableError
        Fewer than 2 lines, or a fit that does not converge to a stable motor.

    Examples
    --------
    >>> from motorsim import Encoder, Experiment, Motor, OddMultisine, SimRig
    >>> from identify.frequency_estimate import frequency_response
    >>> rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(0))
    >>> rec = rig.run(Experiment(OddMultisine(1024, 63, 20), sample_period=0.005, duration=1024 * 0.005 * 4))
    >>> est = fit_frequency_response(frequency_response(rec))
    >>> round(est.a, 1), round(est.b, 2)
    (25.0, 3.0)
    """
    from scipy.optimize import least_squares
    if not isinstance(frf, FrequencyResponse):
        raise ParameterTypeError(f"frf must be a FrequencyResponse, got {type(frf).__name__}")
    input_delay = check_int("input_delay", input_delay, 0)
    if len(frf) < 2:
        raise NotIdentifiableError(f"a fit of a and b needs at least 2 frequencies, got {len(frf)}")
    variance = np.maximum(frf.variance, np.finfo(float).tiny)
    weight = np.sqrt(2.0 / variance)   # real and imaginary parts each carry half the variance

    def residuals(p: np.ndarray) -> np.ndarray:
        d = (zoh_speed_response(p[0], p[1], frf.sample_period, frf.omega, output=frf.output,
                                input_delay=input_delay) - frf.response) * weight
        return np.concatenate([d.real, d.imag])

    a0, b0 = _levy_start(frf, 1.0 / np.sqrt(variance))
    scale = np.array([a0, abs(b0)])
    sol = least_squares(residuals, [a0, b0], x_scale=scale, bounds=([1e-9, -np.inf], [np.inf, np.inf]))
    if not sol.success:
        raise NotIdentifiableError(f"the frequency-domain fit did not converge: {sol.message}")
    a, b = float(sol.x[0]), float(sol.x[1])
    J = sol.jac
    dof = max(len(sol.fun) - 2, 1)
    chi2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * max(chi2, 1.0)
    except np.linalg.LinAlgError:
        raise NotIdentifiableError("the frequency response cannot separate a and b (singular Jacobian); "
                                   "use lines on both sides of the corner frequency a") from None
    model = zoh_speed_response(a, b, frf.sample_period, frf.omega, output=frf.output, input_delay=input_delay)
    spread = np.linalg.norm(frf.response - frf.response.mean())
    fit = 100.0 * (1.0 - np.linalg.norm(frf.response - model) / spread) if spread > 0 else float("nan")
    return Estimate("frequency", a, b, len(frf), frf.sample_period, math.sqrt(chi2), float(fit), cov, ("a", "b"),
                    {"input_delay": input_delay}, residual_unit="standard errors", input_unit=frf.input_unit,
                    covariance_method="gauss-newton")
