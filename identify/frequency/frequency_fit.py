"""A model structure fitted to a frequency response: a cross-check of the time-domain fits.

The model is the exact ZOH response of the structure's linear part for the response's output
(:meth:`identify.model_structures.ModelStructure.frequency_response`: ``b/(s + a)`` by default,
``b/((s + a)(tau_e s + 1))`` for ``second-order``), the residual at each line is weighted by the
line's standard error, and the response parameters ``theta`` (``a, b`` and, for ``second-order``,
``tau_e``) minimise::

    sum_k |G_k - G(e^{j omega_k dt}; theta)|^2 / var_k

(a weighted nonlinear least squares in the frequency domain, Pintelon & Schoukens, *System
Identification: A Frequency Domain Approach*, 2nd ed. 2012, sec. 7.2.2 and 9.4).  The
covariance is the Gauss-Newton one, ``(J^T W J)^-1``, scaled up by the reduced chi-square when
the model misses the data by more than its bounds allow (a model error then counts as noise).
The start is the linear least squares of ``G (j omega + a) = b`` (Levy 1959); ``tau_e`` starts on
``oe-electrical``'s grid from the first-order fit.
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int

from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..model_structures import ModelStructure
from .frequency_estimate import FrequencyResponse

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


def fit_frequency_response(frf: FrequencyResponse, *, input_delay: int = 0,
                           structure: str | ModelStructure = "linear") -> Estimate:
    """The parameters of a model structure fitted to a frequency response, weighted by its bounds.

    Parameters
    ----------
    frf : FrequencyResponse
        The data (:func:`identify.frequency.frequency_estimate.frequency_response`), at least as many lines as
        the structure has response parameters.
    input_delay : int
        Whole samples of input delay in the model, default 0.
    structure : str or ModelStructure
        The model (:func:`identify.structures`): ``"linear"`` (the default), ``b/(s + a)``; or
        ``"second-order"``, ``b/((s + a)(tau_e s + 1))``.  Its :attr:`~ModelStructure.response_parameters`
        are fitted through its :meth:`~ModelStructure.frequency_response`; a bias has no frequency
        response and is left at 0.

    Returns
    -------
    Estimate
        Method ``"frequency"``, the structure asked for; ``n_samples`` counts lines, ``residual_rms`` is
        the RMS of the standardised residuals (about 1 when the model fits within the bounds) and
        ``fit_percent`` the NRMSE fit of the model's response to the data's.  For ``second-order``,
        ``extra`` holds ``electrical_time_constant`` (s), the covariance is over
        ``("a", "b", "electrical_time_constant")``, and the electrical pole is the faster one
        (``a tau_e <= 1``: the model is the same with the two swapped and ``b`` rescaled, as ``oe-electrical``'s).

    Raises
    ------
    NotIdentifiableError
        Too few lines, or a fit that does not converge to a stable motor.
    ParameterError
        A structure with no frequency response of its own (friction, a dead zone) or one that adds
        nothing to ``linear`` here (``bias``).

    Examples
    --------
    >>> from motorsim import Encoder, Experiment, Motor, OddMultisine, SimRig
    >>> from identify.frequency.frequency_estimate import frequency_response
    >>> rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(0))
    >>> rec = rig.run(Experiment(OddMultisine(1024, 63, 20), sample_period=0.005, duration=1024 * 0.005 * 4))
    >>> est = fit_frequency_response(frequency_response(rec))
    >>> round(est.a, 1), round(est.b, 2)
    (25.0, 3.0)
    """
    from ..model_structures import structure as find_structure
    if not isinstance(frf, FrequencyResponse):
        raise ParameterTypeError(f"frf must be a FrequencyResponse, got {type(frf).__name__}")
    input_delay = check_int("input_delay", input_delay, 0)
    model = _response_structure(find_structure(structure))
    names = model.response_parameters
    if len(frf) < len(names):
        raise NotIdentifiableError(f"a fit of {', '.join(names)} needs at least {len(names)} frequencies, "
                                   f"got {len(frf)}")
    variance = np.maximum(frf.variance, np.finfo(float).tiny)
    weight = np.sqrt(2.0 / variance)   # real and imaginary parts each carry half the variance

    def response(p: np.ndarray) -> np.ndarray:
        return model.frequency_response(dict(zip(names, p)), frf.sample_period, frf.omega, output=frf.output,
                                        input_delay=input_delay)

    def residuals(p: np.ndarray) -> np.ndarray:
        d = (response(p) - frf.response) * weight
        return np.concatenate([d.real, d.imag])

    sol = _fit_first_order(frf, residuals) if len(names) == 2 else _fit_with_lag(frf, residuals)
    if not sol.success:
        raise NotIdentifiableError(f"the frequency-domain fit did not converge: {sol.message}")
    x = [float(v) for v in sol.x]
    chi2, cov = _covariance(sol, names)
    fitted = response(np.array(x))
    spread = np.linalg.norm(frf.response - frf.response.mean())
    fit = 100.0 * (1.0 - np.linalg.norm(frf.response - fitted) / spread) if spread > 0 else float("nan")
    extra = {**dict(zip(names[2:], x[2:])), "input_delay": input_delay}
    return Estimate("frequency", x[0], x[1], len(frf), frf.sample_period, math.sqrt(chi2), float(fit), cov, names,
                    extra, residual_unit="standard errors", input_unit=frf.input_unit,
                    covariance_method="gauss-newton", structure=model.name)


def _response_structure(model: ModelStructure) -> ModelStructure:
    """``model`` if a frequency-domain fit can estimate it, else a ParameterError naming it."""
    if not model.linear:
        raise ParameterError(f"structure must be linear for a frequency-domain fit (friction and a dead zone have "
                             f"no frequency response), got {model.name!r}")
    if model.response_parameters == ("a", "b") and model.name != "linear":
        raise ParameterError(f"structure {model.name!r} has the frequency response of 'linear' (a bias has none): "
                             "use structure 'linear'")
    return model


def _fit_first_order(frf: FrequencyResponse, residuals: Callable[[np.ndarray], np.ndarray]) -> Any:
    """``(a, b)`` by least squares from Levy's start."""
    from scipy.optimize import least_squares
    a0, b0 = _levy_start(frf, 1.0 / np.sqrt(np.maximum(frf.variance, np.finfo(float).tiny)))
    scale = np.array([a0, abs(b0)])
    return least_squares(residuals, [a0, b0], x_scale=scale, bounds=([1e-9, -np.inf], [np.inf, np.inf]))


def _fit_with_lag(frf: FrequencyResponse, residuals: Callable[[np.ndarray], np.ndarray]) -> Any:
    """``(a, b, tau_e)``: from the first-order fit's ``(a, b)`` with ``tau_e`` on ``oe-electrical``'s grid
    (:data:`~identify.fits.electrical.TAU_GRID_SAMPLES` sample periods), the best start refined within its bounds
    (:data:`~identify.fits.electrical.TAU_BOUNDS_SAMPLES`); a fit whose electrical pole came out the slower one is
    refitted from its twin (the same response, the poles swapped)."""
    from scipy.optimize import least_squares

    from ..fits.electrical import TAU_BOUNDS_SAMPLES, TAU_GRID_SAMPLES
    h = frf.sample_period
    first = _fit_first_order(frf, lambda p: residuals(np.r_[p, TAU_BOUNDS_SAMPLES[0] * h]))
    a1, b1 = (float(v) for v in first.x)
    low, high = [1e-9, -np.inf, TAU_BOUNDS_SAMPLES[0] * h], [np.inf, np.inf, TAU_BOUNDS_SAMPLES[1] * h]
    fits = [least_squares(residuals, start, x_scale=np.abs(start), bounds=(low, high))
            for start in (np.array([a1, b1, k * h]) for k in TAU_GRID_SAMPLES)]
    best = min(fits, key=lambda sol: (not sol.success, sol.cost))
    a, b, tau = (float(v) for v in best.x)
    if a * tau > 1.0 and low[2] <= 1.0 / a <= high[2]:       # the twin: poles swapped, the same response
        twin = np.array([1.0 / tau, b / (a * tau), 1.0 / a])
        best = least_squares(residuals, twin, x_scale=np.abs(twin), bounds=(low, high))
    return best


def _covariance(sol, names: tuple[str, ...]) -> tuple[float, np.ndarray]:
    """The weighted residuals' chi-square per degree of freedom and the parameters' covariance (Gauss-Newton,
    scaled by the chi-square where it exceeds 1)."""
    dof = max(len(sol.fun) - len(names), 1)
    chi2 = float(sol.fun @ sol.fun) / dof
    try:
        return chi2, np.linalg.inv(sol.jac.T @ sol.jac) * max(chi2, 1.0)
    except np.linalg.LinAlgError:
        raise NotIdentifiableError(f"the frequency response cannot separate {', '.join(names)} (singular "
                                   "Jacobian); use lines on both sides of each corner frequency") from None
