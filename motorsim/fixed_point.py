"""The fixed-point controller step every rig runs, the simulator and the firmware alike.

A controller designed in floating point (:mod:`motorsim.control`) ends in a handful of
integer gains (Q16: a gain ``G`` stands for ``G / 2**16``, :func:`quantise_gain`); the
per-sample step, :class:`ControlLoop`, uses integers only, so that the simulator and a
microcontroller compute the *same* duty from the same counts.  The step here is the
reference implementation the firmware's C step is tested against; so is
:func:`reference_values`, the integer reference a device generates from the words of
:class:`ReferenceWords`.  :data:`GAIN_ORDER` and :func:`gains_from_wire` are the gains in
the order the protocol sends them.

Integer units of the step
-------------------------
* measured speed ``y_k = counts_k - counts_{k-1}`` in counts per sample (the backward
  difference of the encoder, the average speed over the last interval);
* speed references in :data:`SPEED_REFERENCE_LSB` = 1/16 count per sample;
* position references in counts, relative to the count at the first sample;
* duty: an integer, ``u_k = clip((acc + 2**15) >> 16, -duty_limit, duty_limit)`` where
  ``acc`` is an integer sum of gain-times-signal products (64-bit on the device).
"""
from __future__ import annotations

import math
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from .checks import ParameterError, check_int
from .excitation import DUTY_LIMIT, multisine_duty

__all__ = ["GAIN_BITS", "SPEED_REFERENCE_BITS", "SPEED_REFERENCE_LSB", "MAX_REFERENCE", "quantise_gain", "gain_value",
           "ReferenceWords", "reference_values", "ControlLoop", "GAIN_ORDER", "DELAY_LINE_KINDS",
           "gains_from_wire"]

#: Fraction bits of every gain: an integer gain ``G`` stands for ``G / 2**GAIN_BITS``.
GAIN_BITS = 16
#: Fraction bits of a speed reference: its unit is ``2**-SPEED_REFERENCE_BITS`` count per sample.
SPEED_REFERENCE_BITS = 4
#: Speed reference unit in counts per sample.
SPEED_REFERENCE_LSB = 1.0 / (1 << SPEED_REFERENCE_BITS)
#: Largest magnitude of a reference in its integer unit (the device's 32-bit sine sum stays exact).
MAX_REFERENCE = 65535
_HALF = 1 << (GAIN_BITS - 1)


def quantise_gain(x: float) -> int:
    """``x`` as a Q16 integer gain."""
    if not math.isfinite(x) or abs(x) * (1 << GAIN_BITS) >= 2**47:
        raise ParameterError(f"gain {x!r} does not fit the fixed-point step (|gain| < 2**31)")
    return int(round(x * (1 << GAIN_BITS)))


def _sign(x: int) -> int:
    return (x > 0) - (x < 0)


class ReferenceWords(NamedTuple):
    """A reference as the integers a device generates it from (the REFERENCE message of protocol v2).

    ``kind`` is ``constant``, ``step``, ``multisine`` (a sine is one component) or ``trapezoid``;
    ``level`` is the constant, the step value after ``start``, the sines' offset or the
    trapezoid's plateau; ``before`` the step value before ``start``; ``start`` the step's switch
    or the trapezoid's first sample; ``ramp`` and ``hold`` the trapezoid's ramp and plateau in
    samples; ``components`` the sines' ``(amplitude, phase0, phase_inc)`` words.
    """

    kind: str
    level: int = 0
    before: int = 0
    start: int = 0
    ramp: int = 1
    hold: int = 0
    components: tuple = ()


def reference_values(words: ReferenceWords, n_samples: int) -> np.ndarray:
    """The integer reference of samples ``0 ... n_samples-1`` (int64), as a device computes it.

    constant: ``level``; step: ``before`` for ``k < start``, else ``level``; multisine:
    :func:`~motorsim.excitation.multisine_duty` of the components, plus ``level``; trapezoid,
    with ``i = k - start``: ``floor(level min(max(i, 0), ramp) / ramp)`` while ``i < ramp + hold``,
    then ``floor(level min(max(2 ramp + hold - i, 0), ramp) / ramp)`` (floor division, 64-bit).

    Parameters
    ----------
    words : ReferenceWords
        The reference's integers.
    n_samples : int
        Number of samples.
    """
    n = check_int("n_samples", n_samples, 0, 2**32 - 1)
    k = np.arange(n, dtype=np.int64)
    if words.kind == "constant":
        return np.full(n, words.level, dtype=np.int64)
    if words.kind == "step":
        return np.where(k < words.start, words.before, words.level).astype(np.int64)
    if words.kind == "multisine":
        return multisine_duty(words.components, words.level, n)
    if words.kind == "trapezoid":
        nr = check_int("ramp", words.ramp, 1, 2**32 - 1)
        i = k - words.start
        up = (words.level * np.clip(i, 0, nr)) // nr
        down = (words.level * np.clip(2 * nr + words.hold - i, 0, nr)) // nr
        return np.where(i < nr + words.hold, up, down).astype(np.int64)
    raise ParameterError(f"reference kind must be constant, step, multisine or trapezoid, got {words.kind!r}")


class ControlLoop:
    """One run of a controller: the integer step, sample by sample (the device's arithmetic).

    Parameters
    ----------
    kind : str
        ``mpc``, ``pi``, ``position``, ``feedforward``, ``lqr``, ``lqr-integral`` or ``lqr-position``.
    gains : mapping of str to int
        The Q16 gains by name (:meth:`Controller.gains`, or :func:`gains_from_wire`).
    preview : int
        Samples of reference the step looks ahead.
    reference : sequence of int or ndarray
        The integer reference, at least ``n_samples + preview`` long.
    duty_limit : int
        Duty clamp, 0...255.
    """

    def __init__(self, kind: str, gains: Mapping[str, int], preview: int, reference: Sequence[int] | np.ndarray,
                 duty_limit: int = DUTY_LIMIT):
        if kind not in GAIN_ORDER:
            raise ParameterError(f"kind must be one of {', '.join(GAIN_ORDER)}, got {kind!r}")
        self.gains = {k: int(v) for k, v in gains.items()}
        self.reference = [int(x) for x in reference]
        self.preview = check_int("preview", preview, 0, 255)
        self.limit = check_int("duty_limit", duty_limit, 0, DUTY_LIMIT)
        self.ku = [self.gains[f"ku{m}"] for m in range(1, len(self.gains) + 1) if f"ku{m}" in self.gains]
        self.history = [0] * max(1, len(self.ku))
        self.integral = 0
        self.previous: int | None = None
        self.origin = 0
        self.law = getattr(self, "_" + kind.replace("-", "_"))
        self.with_feedforward = "kn" in self.gains

    def step(self, k: int, counts: int) -> int:
        """The duty to apply from sample ``k`` on, given the encoder's ``counts`` read at ``k``."""
        if self.previous is None:
            self.previous = self.origin = counts
        y = counts - self.previous
        self.previous = counts
        u = self.law(k, counts, y)
        self.history = [u] + self.history[:-1]
        return u

    def _clip(self, acc: int) -> int:
        u = (acc + _HALF) >> GAIN_BITS
        return -self.limit if u < -self.limit else (self.limit if u > self.limit else u)

    def _mpc(self, k: int, counts: int, y: int) -> int:
        g, r = self.gains, self.reference[k + self.preview]
        acc = g["kr"] * r + g["ky"] * y + g["k0"] + g["kf"] * _sign(r)
        for gain, u in zip(self.ku, self.history):
            acc += gain * u
        return self._clip(acc)

    #: The speed LQR's step is the MPC's linear form (gains ``kr, ky, k0, kf, ku1 ...``).
    _lqr = _mpc

    def _lqr_integral(self, k: int, counts: int, y: int) -> int:
        g, r = self.gains, self.reference[k + self.preview]
        acc = g["kr"] * r + g["ky"] * y + g["ki"] * self.integral + g["k0"] + g["kf"] * _sign(r)
        for gain, u in zip(self.ku, self.history):
            acc += gain * u
        err = self.reference[k] - (y << SPEED_REFERENCE_BITS)
        raw = (acc + _HALF) >> GAIN_BITS
        if not ((raw > self.limit and err > 0) or (raw < -self.limit and err < 0)):
            self.integral += err  # anti-windup as the PI's; the sum enters the next sample's duty
        return self._clip(acc)

    def _lqr_position(self, k: int, counts: int, y: int) -> int:
        g = self.gains
        acc = g["kp"] * (self.reference[k + self.preview] - (counts - self.origin)) + g["ky"] * y + g["k0"]
        for gain, u in zip(self.ku, self.history):
            acc += gain * u
        return self._clip(acc)

    def _feedforward_sum(self, k: int) -> int:
        g, r1 = self.gains, self.reference[k + self.preview]
        return g["kn"] * r1 + g["kc"] * self.reference[k + self.preview - 1] + g["k0"] + g["kf"] * _sign(r1)

    def _feedforward(self, k: int, counts: int, y: int) -> int:
        return self._clip(self._feedforward_sum(k))

    def _pi(self, k: int, counts: int, y: int) -> int:
        g = self.gains
        err = self.reference[k] - (y << SPEED_REFERENCE_BITS)
        integral = self.integral + err
        acc = g["kp"] * err + g["ki"] * integral
        if self.with_feedforward:
            acc += self._feedforward_sum(k)
        raw = (acc + _HALF) >> GAIN_BITS
        if not ((raw > self.limit and err > 0) or (raw < -self.limit and err < 0)):
            self.integral = integral  # anti-windup: no integration further into the limit
        return self._clip(acc)

    def _position(self, k: int, counts: int, y: int) -> int:
        g = self.gains
        return self._clip(g["kp"] * (self.reference[k] - (counts - self.origin)) - g["kd"] * y)


def gain_value(x: int) -> float:
    """The number a Q16 integer gain ``x`` stands for."""
    return x / (1 << GAIN_BITS)


#: Names of each controller's gains in the order a device receives them (protocol v2 CONTROL);
#: ``mpc``, ``lqr``, ``lqr-integral`` and ``lqr-position`` then have ``ku1 ... ku(D+1)``
#: (:data:`DELAY_LINE_KINDS`), and ``pi`` may add the feedforward's ``kn, kc, k0, kf``.
GAIN_ORDER: dict[str, tuple[str, ...]] = {"mpc": ("kr", "ky", "k0", "kf"), "pi": ("kp", "ki"),
                                          "position": ("kp", "kd"), "feedforward": ("kn", "kc", "k0", "kf"),
                                          "lqr": ("kr", "ky", "k0", "kf"),
                                          "lqr-integral": ("kr", "ky", "ki", "k0", "kf"),
                                          "lqr-position": ("kp", "ky", "k0")}
#: Controllers whose gains end in one ``ku`` per past duty they weigh (at least one).
DELAY_LINE_KINDS = ("mpc", "lqr", "lqr-integral", "lqr-position")


def gains_from_wire(kind: str, values: Sequence[int]) -> dict[str, int]:
    """The named gains of controller ``kind`` from the integers in their wire order (:data:`GAIN_ORDER`).

    Parameters
    ----------
    kind : str
        ``mpc``, ``pi``, ``position``, ``feedforward``, ``lqr``, ``lqr-integral`` or ``lqr-position``.
    values : sequence of int
        The gains as sent.

    Examples
    --------
    >>> gains_from_wire("mpc", [1, 2, 3, 4, 5, 6])
    {'kr': 1, 'ky': 2, 'k0': 3, 'kf': 4, 'ku1': 5, 'ku2': 6}
    """
    if kind not in GAIN_ORDER:
        raise ParameterError(f"kind must be one of {', '.join(GAIN_ORDER)}, got {kind!r}")
    names = list(GAIN_ORDER[kind])
    values = [int(v) for v in values]
    if kind in DELAY_LINE_KINDS and len(values) < len(names) + 1:
        raise ParameterError(f"controller {kind!r} takes at least {len(names) + 1} gains in the order "
                             f"{names + ['ku1', '...']}, got {len(values)}")
    if kind in DELAY_LINE_KINDS:
        names += [f"ku{m}" for m in range(1, len(values) - len(names) + 1)]
    elif kind == "pi" and len(values) == 6:
        names += list(GAIN_ORDER["feedforward"])
    if len(values) != len(names):
        raise ParameterError(f"controller {kind!r} takes {len(names)} gains in the order {names}, got {len(values)}")
    return dict(zip(names, values))
