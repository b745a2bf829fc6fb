"""The encoder: counts from angle, and speed by backward difference (as the article does).

``counts = floor((angle + noise) * counts_per_rev / (2 pi)) + count_offset``.  Differencing
counts gives the *average* speed over the last sample interval, quantised to
``2 pi / (counts_per_rev dt)`` rad/s.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .checks import ParameterError, ParameterTypeError, check_int, check_real
from .knobs import knob

#: The largest count magnitude an encoder gives: integers past it are not exact in a float.
MAX_EXACT_COUNT = 2**53

__all__ = ["Encoder", "counts_to_angle", "backward_difference", "DEFAULT_COUNTS_PER_REV"]

#: The article's encoder, 16667 counts per revolution.
DEFAULT_COUNTS_PER_REV = 16667


@dataclasses.dataclass(frozen=True)
class Encoder:
    """A quadrature encoder read at the sample instants.

    Parameters
    ----------
    counts_per_rev : int
        Counts per revolution (after quadrature decoding), default 16667.
    count_offset : int
        Count reported at angle 0 (encoders start anywhere), default 0.
    angle_noise : float
        Standard deviation in rad of Gaussian noise added to the angle before
        flooring, default 0 (noise-free, but still quantised).
    """

    counts_per_rev: int = knob(DEFAULT_COUNTS_PER_REV, unit="counts/rev",
                               help="encoder counts per revolution after quadrature decoding")
    count_offset: int = knob(0, unit="counts", help="count reported at angle 0", recorded=True)
    angle_noise: float = knob(0.0, unit="rad", help="std of Gaussian angle noise before the encoder floors it",
                              recorded=True)

    def __post_init__(self):
        object.__setattr__(self, "counts_per_rev", check_int("counts_per_rev", self.counts_per_rev, 1, 2**31 - 1))
        object.__setattr__(self, "count_offset", check_int("count_offset", self.count_offset, -(2**62), 2**62))
        object.__setattr__(self, "angle_noise", check_real("angle_noise", self.angle_noise, nonnegative=True))

    def counts(self, angle, rng: np.random.Generator | None = None) -> np.ndarray:
        """Integer counts (int64) for ``angle`` in rad; ``rng`` is required when noise > 0."""
        angle = np.asarray(angle, dtype=float)
        if self.angle_noise > 0:
            if not isinstance(rng, np.random.Generator):
                raise ParameterTypeError(f"rng must be a numpy.random.Generator when angle_noise > 0, got {rng!r}")
            angle = angle + rng.normal(0.0, self.angle_noise, angle.shape)
        scaled = np.floor(angle * (self.counts_per_rev / (2.0 * math.pi)))
        if scaled.size and not float(np.max(np.abs(scaled))) + abs(self.count_offset) <= MAX_EXACT_COUNT:
            k = int(np.argmax(~np.isfinite(scaled) | (np.abs(scaled) + abs(self.count_offset) > MAX_EXACT_COUNT)))
            raise ParameterError(f"the encoder's counts must stay within +-2**53 (beyond, a count is not exact, and "
                                 f"past 2**63 it wraps), got an angle of {float(angle.flat[k]):.6g} rad with "
                                 f"count_offset {self.count_offset}: the motion asked for (initial speed, bias, "
                                 "angle noise) is beyond any encoder")
        return scaled.astype(np.int64) + self.count_offset


def counts_to_angle(counts, counts_per_rev: int) -> np.ndarray:
    """Angle in rad of integer ``counts`` (the offset is kept), ``counts 2 pi / counts_per_rev``."""
    return np.asarray(counts, dtype=float) * (2.0 * math.pi / counts_per_rev)


def backward_difference(angle, time) -> np.ndarray:
    """Speed ``(angle[k] - angle[k-1]) / (time[k] - time[k-1])`` in rad/s; ``nan`` at k = 0.

    ``angle`` in rad, ``time`` in s.
    """
    angle = np.asarray(angle, dtype=float)
    time = np.asarray(time, dtype=float)
    speed = np.empty(angle.shape)
    speed[:1] = np.nan
    np.subtract(angle[1:], angle[:-1], out=speed[1:])   # in place: one temporary (the intervals), not three
    speed[1:] /= np.diff(time)
    return speed
