"""Gain, phase and delay margins of a sampled feedback loop given by its polynomials.

:func:`discrete_margins` takes the loop ``L(z) = num(z) / den(z)`` (negative feedback, the loop
broken at one point) and finds its crossings on a dense grid of the frequency response up to the
Nyquist frequency, refined by root finding (``brentq``); the closed loop's stability comes from the
roots of ``den + num``.  It depends on nothing but numpy and scipy, so that a controller's design
(:mod:`motorsim.control`) can check its own margins and :mod:`motorsim.robustness` can report them
with the same numbers; a test checks them against ``control.stability_margins`` on the same loop.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from .checks import ParameterError, check_real

__all__ = ["Margins", "discrete_margins"]

#: Points of each of the two frequency grids (geometric and linear) the crossings are bracketed on.
_GRID_POINTS = 20000


@dataclasses.dataclass(frozen=True)
class Margins:
    """Stability margins of a feedback loop.

    Attributes
    ----------
    gain_margin : float
        Factor by which the loop gain can grow (or shrink, when below 1) before instability;
        ``inf`` when the phase never crosses -180 degrees.
    phase_margin : float
        Degrees; ``inf`` when the loop gain never crosses 1.
    delay_margin : float
        Extra input delay in s the loop tolerates (phase margin / crossover frequency).
    crossover : float
        Gain crossover frequency in rad/s (nan without one).
    stable : bool
        Whether the closed loop's poles lie inside the unit circle.
    """

    gain_margin: float
    phase_margin: float
    delay_margin: float
    crossover: float
    stable: bool

    def describe(self) -> str:
        """One line: the margins in engineering units."""
        gm = "inf" if math.isinf(self.gain_margin) else f"{20 * math.log10(self.gain_margin):.3g} dB"
        pm = "inf" if math.isinf(self.phase_margin) else f"{self.phase_margin:.3g} deg"
        dm = "inf" if math.isinf(self.delay_margin) else f"{self.delay_margin * 1e3:.3g} ms"
        return f"gain margin {gm}, phase margin {pm}, delay margin {dm}" + ("" if self.stable else " (UNSTABLE)")


def discrete_margins(num: np.ndarray, den: np.ndarray, sample_period: float) -> Margins:
    """The margins of the sampled loop ``L(z) = num(z) / den(z)`` under negative feedback.

    Parameters
    ----------
    num, den : array_like
        Coefficients of the loop's numerator and denominator in descending powers of ``z``.
    sample_period : float
        Sample period in s, > 0.

    Returns
    -------
    Margins

    Notes
    -----
    Where the loop gain crosses 1 several times, the phase margin is the one closest to 0 (the
    smallest distance of the phase from -180 degrees, signed), and the gain margin the one
    closest to 1 in ratio; the delay margin is the phase margin over its crossover frequency (0
    when the phase margin is negative).

    Examples
    --------
    An integrator ``1 / (z - 1)`` sampled at 1 s: its gain crosses 1 at a third of the Nyquist
    frequency, where its phase is -120 degrees; the phase reaches -180 degrees only at Nyquist.

    >>> m = discrete_margins([1.0], [1.0, -1.0], 1.0)
    >>> round(m.phase_margin, 6), round(m.crossover / math.pi, 6), round(m.delay_margin, 6), m.gain_margin, m.stable
    (60.0, 0.333333, 1.0, inf, True)
    """
    h = check_real("sample_period", sample_period, positive=True)
    num = np.atleast_1d(np.asarray(num, dtype=float))
    den = np.atleast_1d(np.asarray(den, dtype=float))
    if num.ndim != 1 or den.ndim != 1 or not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))) \
            or not np.any(den):
        raise ParameterError(f"num and den must be finite 1-D coefficient arrays, den not all 0, got {num!r}, {den!r}")
    roots = np.roots(np.polyadd(den, num))
    stable = bool(np.all(np.abs(roots) < 1.0 - 1e-12))
    if not np.any(num):
        return Margins(math.inf, math.inf, math.inf, math.nan, stable)

    def response(w: np.ndarray | float) -> np.ndarray:
        z = np.exp(1j * np.asarray(w) * h)
        return np.polyval(num, z) / np.polyval(den, z)

    nyquist = math.pi / h
    w = np.unique(np.r_[np.geomspace(nyquist * 1e-6, nyquist, _GRID_POINTS),
                        np.linspace(0, nyquist, _GRID_POINTS)[1:]])
    l_w = response(w)
    crossings = _crossings(lambda x: np.abs(response(x)) - 1.0, w, np.abs(l_w) - 1.0)
    phase = [math.degrees(math.atan2(response(x).imag, response(x).real)) for x in crossings]
    pms = [180.0 + p if p <= 0 else p - 180.0 for p in phase]   # distance from -180 degrees, signed
    phase_crossings = [x for x in _crossings(lambda x: response(x).imag, w, l_w.imag) if response(x).real < 0]
    gms = [1.0 / abs(response(x)) for x in phase_crossings]
    if pms:
        i = int(np.argmin(np.abs(pms)))
        pm, wc = pms[i], crossings[i]
        dm = math.radians(pm) / wc if pm > 0 else 0.0
    else:
        pm, wc, dm = math.inf, math.nan, math.inf
    gm = min(gms, key=lambda g: abs(math.log(g))) if gms else math.inf
    return Margins(float(gm), float(pm), float(dm), float(wc), stable)


def _crossings(f: Callable[[float], Any], w: np.ndarray, values: np.ndarray) -> list[float]:
    """Zeros of ``f`` between grid points where ``values`` changes sign, refined by ``brentq``."""
    from scipy.optimize import brentq
    idx = np.flatnonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0)
    return [float(brentq(f, w[i], w[i + 1], xtol=1e-12)) for i in idx]
