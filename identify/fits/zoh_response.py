"""The exact zero-order-hold frequency response of ``b/(s + a)``, input to speed: :func:`zoh_speed_response`.

Apart from :mod:`identify.frequency.frequency_estimate` (which re-exports both names and explains the two
outputs) so that the model structures (:meth:`identify.model_structures.ModelStructure.frequency_response`)
can give it without importing the estimator.
"""
from __future__ import annotations

import math

import numpy as np

from motorsim.checks import ParameterError, check_real

from .sensitivity import phi_functions

__all__ = ["zoh_speed_response", "OUTPUTS"]

#: What the response's output is: the interval-mean speed from the angle, or the sampled speed column.
OUTPUTS = ("angle", "speed")


def zoh_speed_response(a: float, b: float, sample_period: float, omega: np.ndarray, *, output: str = "angle",
                       input_delay: int = 0) -> np.ndarray:
    """The exact ZOH response of ``b/(s + a)`` duty -> speed at ``omega`` rad/s (complex).

    Parameters
    ----------
    a, b : float
        Pole in 1/s and gain in (rad/s^2)/duty.
    sample_period : float
        Sample period ``dt`` in s.
    omega : array_like
        Angular frequencies in rad/s.
    output : {"angle", "speed"}
        ``"speed"``: the sampled speed, ``(b/a)(1 - e)/(z - e)``; ``"angle"``: the mean speed
        over the interval the duty is held, ``phi1(a dt) G(z) + b dt phi2(a dt)``
        (:mod:`identify.frequency.frequency_estimate`'s docstring).
    input_delay : int
        Whole samples of input delay, a factor ``z^-input_delay``.

    Examples
    --------
    >>> g = zoh_speed_response(25.0, 3.0, 0.005, [1e-6])
    >>> round(float(abs(g[0])), 6)   # the static gain b/a
    0.12
    """
    if output not in OUTPUTS:
        raise ParameterError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")
    dt = check_real("sample_period", sample_period, positive=True)
    w = np.asarray(omega, dtype=float)
    x = a * dt
    e = math.exp(-x)
    z = np.exp(1j * w * dt)
    p1, p2, _, _ = phi_functions(np.array([x]))
    g = b * dt * p1[0] / (z - e)   # (b/a)(1 - e) = b dt phi1(x)
    if output == "angle":
        g = p1[0] * g + b * dt * p2[0]
    return g * z ** (-int(input_delay))
