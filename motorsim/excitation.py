"""Excitation signals, computed exactly as the bench firmware computes them.

Every excitation turns a sample count and a sample period into an integer duty
sequence (``-duty_limit ... duty_limit``).  The arithmetic is integer-exact and is
specified byte for byte in ``hardware/PROTOCOL.md`` ("Waveforms"): a 32-bit phase
accumulator, a 1024-entry Q15 sine table with linear interpolation, a Galois LFSR
for PRBS.  The simulator and the Arduino firmware therefore produce the *same*
duty sequence, which is what lets ``SimRig`` and ``SerialRig`` share
``rig.run(experiment)``.

The sine of the article (eqs. 29-32), ``eta = A sin(omega t + alpha)``, is
:class:`Sine`.  Its duty differs from ``round(A sin(omega k dt + alpha))`` only
where that value lies within 0.016 duty units of a rounding tie (the
interpolated Q15 table, divided by 32768, is within 7.7e-5 of full scale;
0.5 % of the samples of ``200 sin(10 t + 0.3)`` at 5 ms differ by one unit),
and its frequency
is realised to within 2**-32 of a cycle per sample.
"""
from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, Sequence

import numpy as np

from .checks import ParameterError, check_int, check_real

__all__ = [
    "Excitation", "Constant", "Step", "Sine", "Multisine", "Chirp", "PRBS", "OddMultisine",
    "sine_table", "sine_q15", "phase_increment", "multisine_duty", "chirp_duty", "prbs_bits",
    "parse_excitation", "split_spec", "spec_numbers",
    "DUTY_LIMIT", "MAX_AMPLITUDE", "MAX_COMPONENTS", "MAX_ODD_LINES", "PRBS_MASKS",
]

#: Largest duty magnitude an 8-bit PWM (Arduino ``analogWrite``) accepts.
DUTY_LIMIT = 255
#: Largest amplitude or offset of one component; keeps the firmware's int32 sums exact.
MAX_AMPLITUDE = 1023
#: Most sine components in one multisine (firmware limit).
MAX_COMPONENTS = 4
#: Most odd harmonics (excited or left out) of an odd multisine: 64 lines of amplitude 1023
#: keep the int32 sum of ``amplitude * sine_q15`` exact.
MAX_ODD_LINES = 64
_TABLE_BITS = 10
_TABLE_SIZE = 1 << _TABLE_BITS
_TWO32 = 1 << 32

#: Galois LFSR feedback masks (right shift) giving maximal-length sequences,
#: period ``2**order - 1``; indexed by order.
PRBS_MASKS = {
    2: 0x3, 3: 0x6, 4: 0xC, 5: 0x14, 6: 0x30, 7: 0x60, 8: 0xB8, 9: 0x110,
    10: 0x240, 11: 0x500, 12: 0xE08, 13: 0x1C80, 14: 0x3802, 15: 0x6000,
    16: 0xB400,
}


def sine_table() -> np.ndarray:
    """The 1024-entry Q15 sine table: ``round(32767 sin(2 pi i / 1024))``, int16."""
    i = np.arange(_TABLE_SIZE)
    return np.rint(32767.0 * np.sin(2.0 * np.pi * i / _TABLE_SIZE)).astype(np.int16)


_TABLE = sine_table().astype(np.int64)


def sine_q15(phase: np.ndarray) -> np.ndarray:
    """Interpolated sine of a 32-bit phase (``2**32`` is one cycle), in Q15.

    ``i = phase >> 22``, ``f = (phase >> 6) & 0xFFFF``,
    ``s = T[i] + (((T[i+1 mod 1024] - T[i]) * f) >> 16)`` with an arithmetic shift.
    """
    phase = np.asarray(phase, dtype=np.int64) & 0xFFFFFFFF
    i = phase >> (32 - _TABLE_BITS)
    f = (phase >> 6) & 0xFFFF
    y0 = _TABLE[i]
    y1 = _TABLE[(i + 1) & (_TABLE_SIZE - 1)]
    return y0 + (((y1 - y0) * f) >> 16)


def phase_increment(frequency: float, sample_period: float) -> int:
    """Phase step per sample of a sine of ``frequency`` rad/s, as a u32 (``2**32`` = 1 cycle)."""
    return int(round(frequency * sample_period / (2.0 * math.pi) * _TWO32)) % _TWO32


def multisine_duty(components, offset: int, n_samples: int) -> np.ndarray:
    """Unclamped MULTISINE duty from its wire words (``hardware/PROTOCOL.md``).

    ``duty_k = offset + ((sum_j amplitude_j sine_q15(phase0_j + k phase_inc_j)) + 16384) >> 15``.

    Parameters
    ----------
    components : sequence of (int, int, int)
        ``(amplitude, phase0, phase_inc)`` per sine; phases are u32 words (``2**32`` = 1 cycle).
    offset : int
        Constant duty added.
    n_samples : int
        Number of samples.
    """
    k = np.arange(n_samples, dtype=np.uint64)
    acc = np.zeros(n_samples, dtype=np.int64)
    for amplitude, phase0, inc in components:
        phase = (np.uint64(phase0) + k * np.uint64(inc)) & np.uint64(0xFFFFFFFF)
        acc += int(amplitude) * sine_q15(phase.astype(np.int64))
    return int(offset) + ((acc + 16384) >> 15)


def chirp_duty(offset: int, amplitude: int, phase0: int, inc0: int, inc_step: int, n_samples: int) -> np.ndarray:
    """Unclamped CHIRP duty from its wire words (``hardware/PROTOCOL.md``).

    The device keeps ``phase += inc; inc += inc_step`` after each sample, so
    ``phase_k = phase0 + k inc0 + inc_step k (k - 1) / 2`` (mod ``2**32``; uint64
    arithmetic wraps modulo ``2**64``, which is exact modulo ``2**32``).

    Parameters
    ----------
    offset, amplitude : int
        Duty offset and amplitude.
    phase0, inc0 : int
        u32 start phase and start phase step.
    inc_step : int
        i32 change of the phase step per sample.
    n_samples : int
        Number of samples.
    """
    k = np.arange(n_samples, dtype=np.uint64)
    tri = k * (k - np.uint64(1)) // np.uint64(2) if n_samples else k
    phase = (np.uint64(phase0) + k * np.uint64(inc0) + tri * np.uint64(int(inc_step) % 2**64)) \
        & np.uint64(0xFFFFFFFF)
    return int(offset) + ((int(amplitude) * sine_q15(phase.astype(np.int64)) + 16384) >> 15)


def prbs_bits(order: int, seed: int, n_bits: int) -> np.ndarray:
    """The first ``n_bits`` output bits (uint8) of the Galois LFSR of ``hardware/PROTOCOL.md``.

    Per bit: ``out = state & 1; state >>= 1; if out: state ^= PRBS_MASKS[order]``.

    Parameters
    ----------
    order : int
        LFSR length, a key of :data:`PRBS_MASKS`.
    seed : int
        Initial state, 1 ... ``2**order - 1``.
    n_bits : int
        Number of bits; the sequence repeats every ``2**order - 1``.
    """
    mask = PRBS_MASKS[order]
    period = (1 << order) - 1
    out = np.empty(min(n_bits, period), dtype=np.uint8)
    state = seed
    for i in range(len(out)):
        bit = state & 1
        out[i] = bit
        state >>= 1
        if bit:
            state ^= mask
    return np.resize(out, n_bits) if n_bits > period else out


def _phase_word(phase: float) -> int:
    # fmod (exact, and the phase itself within one turn) first: a phase of 1e308 rad overflowed the product
    return int(round(math.fmod(phase, 2.0 * math.pi) / (2.0 * math.pi) * _TWO32)) % _TWO32


def _clamp(duty: np.ndarray, duty_limit: int) -> np.ndarray:
    return np.clip(duty, -duty_limit, duty_limit).astype(np.int64)


def _check_common(n_samples: int, sample_period: float, duty_limit: int) -> tuple[int, float, int]:
    n_samples = check_int("n_samples", n_samples, 0, 2**32 - 1)
    sample_period = check_real("sample_period", sample_period, positive=True)
    duty_limit = check_int("duty_limit", duty_limit, 0, 32767)
    return n_samples, sample_period, duty_limit


class Excitation:
    """Base class: an integer duty sequence generated sample by sample.

    Subclasses are frozen dataclasses; :meth:`duty` is the whole contract.
    """

    kind: ClassVar[str] = ""

    def duty(self, n_samples: int, sample_period: float, duty_limit: int = DUTY_LIMIT) -> np.ndarray:
        """Duty for samples ``0 ... n_samples-1`` (int64), clamped to ``+-duty_limit``.

        Parameters
        ----------
        n_samples : int
            Number of samples.
        sample_period : float
            Nominal sample period in s (sets the phase step of sines and chirps).
        duty_limit : int, optional
            Clamp, default 255.
        """
        n, dt, lim = _check_common(n_samples, sample_period, duty_limit)
        return _clamp(self._raw(n, dt), lim)

    def _raw(self, n: int, dt: float) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> str:
        """A one-line spec that :func:`parse_excitation` reads back."""
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Constant(Excitation):
    """A constant duty ``level``."""

    level: int = 0
    kind: ClassVar[str] = "constant"

    def __post_init__(self):
        object.__setattr__(self, "level", check_int("level", self.level, -MAX_AMPLITUDE, MAX_AMPLITUDE))

    def _raw(self, n, dt):
        return np.full(n, self.level, dtype=np.int64)

    def describe(self):
        return f"constant:{self.level}"


@dataclasses.dataclass(frozen=True)
class Step(Excitation):
    """Duty ``before`` until ``at_time`` s, then ``after``.

    The switch happens at sample ``round(at_time / sample_period)``.
    """

    after: int = 100
    at_time: float = 0.0
    before: int = 0
    kind: ClassVar[str] = "step"

    def __post_init__(self):
        object.__setattr__(self, "after", check_int("after", self.after, -MAX_AMPLITUDE, MAX_AMPLITUDE))
        object.__setattr__(self, "before", check_int("before", self.before, -MAX_AMPLITUDE, MAX_AMPLITUDE))
        object.__setattr__(self, "at_time", check_real("at_time", self.at_time, nonnegative=True))

    def step_index(self, sample_period: float) -> int:
        """Index of the first sample with duty ``after``."""
        return int(round(self.at_time / sample_period))

    def _raw(self, n, dt):
        k = np.arange(n)
        return np.where(k < self.step_index(dt), self.before, self.after).astype(np.int64)

    def describe(self):
        return f"step:{self.after},{self.at_time!r},{self.before}"


@dataclasses.dataclass(frozen=True)
class Multisine(Excitation):
    """Sum of sines ``offset + sum_j A_j sin(omega_j t + alpha_j)``.

    Parameters
    ----------
    frequencies : sequence of float
        Angular frequencies omega_j in rad/s (each below the Nyquist frequency).
    amplitudes : sequence of int
        Amplitudes A_j in duty units, ``|A_j| <= 1023``.
    phases : sequence of float, optional
        Phases alpha_j in rad, default 0.
    offset : int, optional
        Constant added to the sum, default 0.
    """

    frequencies: tuple = (10.0,)
    amplitudes: tuple = (200,)
    phases: tuple = ()
    offset: int = 0
    kind: ClassVar[str] = "multisine"

    def __post_init__(self):
        f = tuple(check_real("frequencies", x, positive=True) for x in np.atleast_1d(self.frequencies))
        if not 1 <= len(f) <= MAX_COMPONENTS:
            raise ParameterError(f"frequencies must have 1...{MAX_COMPONENTS} components, got {len(f)}")
        a = tuple(check_int("amplitudes", x, -MAX_AMPLITUDE, MAX_AMPLITUDE) for x in np.atleast_1d(self.amplitudes))
        if len(a) == 1 and len(f) > 1:
            a = a * len(f)
        p = tuple(check_real("phases", x) for x in np.atleast_1d(self.phases)) or (0.0,) * len(f)
        if not len(a) == len(p) == len(f):
            raise ParameterError(f"frequencies, amplitudes and phases must have equal lengths, "
                             f"got {len(f)}, {len(a)} and {len(p)}")
        object.__setattr__(self, "frequencies", f)
        object.__setattr__(self, "amplitudes", a)
        object.__setattr__(self, "phases", p)
        object.__setattr__(self, "offset", check_int("offset", self.offset, -MAX_AMPLITUDE, MAX_AMPLITUDE))

    def components(self, sample_period: float) -> list[tuple[int, int, int]]:
        """``(amplitude, phase0, phase_inc)`` per component, as the firmware receives them."""
        out = []
        for f, a, p in zip(self.frequencies, self.amplitudes, self.phases):
            if f * sample_period >= math.pi:
                raise ParameterError(f"frequencies must be below the Nyquist frequency "
                                 f"pi/sample_period = {math.pi / sample_period:.6g} rad/s, got {f!r}")
            out.append((a, _phase_word(p), phase_increment(f, sample_period)))
        return out

    def _raw(self, n, dt):
        return multisine_duty(self.components(dt), self.offset, n)

    def describe(self):
        if len(self.frequencies) == 1:
            return (f"sine:{self.frequencies[0]!r},{self.amplitudes[0]},{self.phases[0]!r}"
                    + (f"@{self.offset}" if self.offset else ""))
        parts = ";".join(f"{f!r},{a},{p!r}" for f, a, p in zip(self.frequencies, self.amplitudes, self.phases))
        return f"multisine:{parts}" + (f"@{self.offset}" if self.offset else "")


class Sine(Multisine):
    """The article's sine ``eta = A sin(omega t + alpha)`` (eqs. 29-32): a one-component :class:`Multisine`.

    Parameters
    ----------
    frequency : float
        omega in rad/s.
    amplitude : int
        A in duty units, default 200 (the article's).
    phase : float
        alpha in rad.
    offset : int
        Constant duty added.

    Examples
    --------
    >>> s = Sine(10, 200)
    >>> s.describe()
    'sine:10.0,200,0.0'
    >>> s.duty(4, 0.005).tolist()
    [0, 10, 20, 30]
    """

    def __init__(self, frequency: float = 10.0, amplitude: int = 200, phase: float = 0.0, offset: int = 0):
        super().__init__((frequency,), (amplitude,), (phase,), offset)

    @property
    def frequency(self) -> float:
        """omega in rad/s."""
        return self.frequencies[0]

    @property
    def amplitude(self) -> int:
        """A in duty units."""
        return self.amplitudes[0]

    @property
    def phase(self) -> float:
        """alpha in rad."""
        return self.phases[0]

    def __repr__(self) -> str:
        return (f"Sine(frequency={self.frequency!r}, amplitude={self.amplitude!r}, phase={self.phase!r}, "
                f"offset={self.offset!r})")

    def __reduce__(self):
        return (Sine, (self.frequency, self.amplitude, self.phase, self.offset))


@dataclasses.dataclass(frozen=True)
class Chirp(Excitation):
    """Linear chirp from ``f0`` to ``f1`` rad/s over the whole run, amplitude ``amplitude``.

    The phase step grows by a constant integer per sample, so the firmware's
    second-order accumulator reproduces it exactly.

    Parameters
    ----------
    f0, f1 : float
        Start and end frequency in rad/s.
    amplitude : int
        Amplitude in duty units.
    offset : int
        Constant duty added.
    """

    f0: float = 1.0
    f1: float = 50.0
    amplitude: int = 200
    offset: int = 0
    kind: ClassVar[str] = "chirp"

    def __post_init__(self):
        object.__setattr__(self, "f0", check_real("f0", self.f0, positive=True))
        object.__setattr__(self, "f1", check_real("f1", self.f1, positive=True))
        object.__setattr__(self, "amplitude", check_int("amplitude", self.amplitude, -MAX_AMPLITUDE, MAX_AMPLITUDE))
        object.__setattr__(self, "offset", check_int("offset", self.offset, -MAX_AMPLITUDE, MAX_AMPLITUDE))

    def words(self, n_samples: int, sample_period: float) -> tuple[int, int]:
        """``(inc0, inc_step)``: the u32 start step and the i32 step change per sample."""
        for name, f in (("f0", self.f0), ("f1", self.f1)):
            if f * sample_period >= math.pi:
                raise ParameterError(f"{name} must be below the Nyquist frequency "
                                 f"pi/sample_period = {math.pi / sample_period:.6g} rad/s, got {f!r}")
        inc0 = phase_increment(self.f0, sample_period)
        inc1 = phase_increment(self.f1, sample_period)
        step = int(round((inc1 - inc0) / max(n_samples - 1, 1)))
        return inc0, step

    def _raw(self, n, dt):
        inc0, step = self.words(n, dt)
        return chirp_duty(self.offset, self.amplitude, 0, inc0, step, n)

    def describe(self):
        return f"chirp:{self.f0!r},{self.f1!r},{self.amplitude}" + (f"@{self.offset}" if self.offset else "")


@dataclasses.dataclass(frozen=True)
class PRBS(Excitation):
    """Two-level pseudo-random binary sequence from a maximal-length Galois LFSR.

    Each bit is held for ``hold`` samples; bit 1 gives ``high``, bit 0 ``low``.
    Per bit: ``out = state & 1; state >>= 1; if out: state ^= PRBS_MASKS[order]``.

    Parameters
    ----------
    high, low : int
        Duty of a 1 bit and of a 0 bit.
    order : int
        LFSR length, 2...16; the sequence repeats every ``2**order - 1`` bits.
    hold : int
        Samples per bit, >= 1.
    seed : int
        Initial LFSR state, 1 ... ``2**order - 1``.
    """

    high: int = 200
    low: int = -200
    order: int = 10
    hold: int = 1
    seed: int = 1
    kind: ClassVar[str] = "prbs"

    def __post_init__(self):
        for name in ("high", "low"):
            object.__setattr__(self, name, check_int(name, getattr(self, name), -MAX_AMPLITUDE, MAX_AMPLITUDE))
        object.__setattr__(self, "order", check_int("order", self.order, 2, 16))
        object.__setattr__(self, "hold", check_int("hold", self.hold, 1, 65535))
        object.__setattr__(self, "seed", check_int("seed", self.seed, 1, (1 << self.order) - 1))

    def bits(self, n_bits: int) -> np.ndarray:
        """The first ``n_bits`` output bits of the LFSR (uint8); see :func:`prbs_bits`."""
        return prbs_bits(self.order, self.seed, n_bits)

    def _raw(self, n, dt):
        n_bits = -(-n // self.hold)
        b = np.repeat(self.bits(n_bits), self.hold)[:n]
        return np.where(b == 1, self.high, self.low).astype(np.int64)

    def describe(self):
        return f"prbs:{self.high},{self.low},{self.order},{self.hold},{self.seed}"


def _lfsr_words(seed: int, n_words: int) -> list[int]:
    """``n_words`` 16-bit words from the order-16 LFSR of :func:`prbs_bits`, least significant bit first."""
    bits = prbs_bits(16, seed, 16 * n_words).reshape(n_words, 16).astype(np.int64)
    return (bits << np.arange(16)).sum(axis=1).tolist()


@dataclasses.dataclass(frozen=True)
class OddMultisine(Excitation):
    """Odd random-phase multisine: odd harmonics of a period, some left out to detect distortion.

    The period is ``period`` samples (a power of two, so each line's phase step
    ``h * 2**32 / period`` is an exact integer and the duty repeats exactly every period).
    The odd harmonics ``h = 3, 5, ..., max_harmonic`` are taken in groups of ``group``
    consecutive ones (the fundamental is always excited); one line of each group is left out
    (a *detection line*: a linear motor puts nothing there, a nonlinear one does).  Even
    harmonics are never excited, so output at them is even-order distortion.  The duty is the
    :class:`Multisine` arithmetic (``hardware/PROTOCOL.md``) over the excited lines, each of
    amplitude ``amplitude``.

    Random numbers are 16-bit words of the order-16 Galois LFSR of :class:`PRBS`, least
    significant bit first.  The left-out lines are the same for every seed (so realisations
    share one amplitude spectrum): word ``g`` of the LFSR started at 1 leaves out line
    ``word mod group`` of group ``g`` (an incomplete last group keeps all its lines).  The
    phases are the realisation: word ``i`` of the LFSR started at ``seed`` is the phase of the
    ``i``-th odd harmonic, ``word * 2**16`` (a u32 phase word).  ``seed = 0`` gives Schroeder
    phases instead, ``-pi j (j - 1) / F`` for the ``j``-th of ``F`` excited lines (phase word
    ``floor(-j (j - 1) 2**31 / F) mod 2**32``).

    Parameters
    ----------
    period : int
        Samples per period, a power of two, 16 ... 65536.
    max_harmonic : int
        Highest odd harmonic, odd, below ``period / 2``; at most :data:`MAX_ODD_LINES` odd lines.
    amplitude : int
        Amplitude of each excited line in duty units, ``1 ... 1023``.
    seed : int, optional
        LFSR seed 1 ... 65535 of the random phases (one realisation), or 0 (Schroeder phases).
    group : int, optional
        One odd line of every ``group`` consecutive ones is left out, 2 ... 16; 0 leaves none out.
    offset : int, optional
        Constant duty added.

    Examples
    --------
    >>> ex = OddMultisine(period=256, max_harmonic=15, amplitude=20, seed=7)
    >>> ex.excited_harmonics(), ex.detection_harmonics()
    ((1, 5, 7, 9, 13, 15), (3, 11))
    >>> ex.describe()
    'odd-multisine:256,15,20,7,3'
    >>> d = ex.duty(512, 0.005)
    >>> bool((d[:256] == d[256:]).all())
    True
    """

    period: int = 1024
    max_harmonic: int = 31
    amplitude: int = 20
    seed: int = 1
    group: int = 3
    offset: int = 0
    kind: ClassVar[str] = "odd-multisine"

    def __post_init__(self):
        period = check_int("period", self.period, 16, 65536)
        if period & (period - 1):
            raise ParameterError(f"period must be a power of two (samples), got {period!r}")
        h = check_int("max_harmonic", self.max_harmonic, 1, period // 2 - 1)
        if h % 2 == 0:
            raise ParameterError(f"max_harmonic must be odd, got {h!r}")
        if (h + 1) // 2 > MAX_ODD_LINES:
            raise ParameterError(f"max_harmonic must be at most {2 * MAX_ODD_LINES - 1} "
                             f"({MAX_ODD_LINES} odd lines), got {h!r}")
        object.__setattr__(self, "period", period)
        object.__setattr__(self, "max_harmonic", h)
        object.__setattr__(self, "amplitude", check_int("amplitude", self.amplitude, 1, MAX_AMPLITUDE))
        object.__setattr__(self, "seed", check_int("seed", self.seed, 0, 65535))
        group = check_int("group", self.group, 0, 16)
        if group == 1:
            raise ParameterError(f"group must be 0 (no line left out) or 2...16, got {group!r}")
        object.__setattr__(self, "group", group)
        object.__setattr__(self, "offset", check_int("offset", self.offset, -MAX_AMPLITUDE, MAX_AMPLITUDE))

    def _odd(self) -> list[int]:
        return list(range(1, self.max_harmonic + 1, 2))

    def _left_out(self) -> set[int]:
        odd = self._odd()[1:]  # the fundamental is always excited
        if self.group == 0:
            return set()
        n_groups = -(-len(odd) // self.group)
        picks = [w % self.group for w in _lfsr_words(1, n_groups)]
        out = set()
        for g, pick in enumerate(picks):
            members = odd[g * self.group:(g + 1) * self.group]
            if len(members) == self.group:  # an incomplete last group keeps all its lines
                out.add(members[pick])
        return out

    def excited_harmonics(self) -> tuple[int, ...]:
        """The excited harmonics (odd, increasing)."""
        left_out = self._left_out()
        return tuple(h for h in self._odd() if h not in left_out)

    def detection_harmonics(self) -> tuple[int, ...]:
        """The odd harmonics left out (nothing there but noise and odd-order distortion)."""
        return tuple(sorted(self._left_out()))

    def line_frequencies(self, sample_period: float, harmonics: Sequence[int] | None = None) -> np.ndarray:
        """Angular frequencies in rad/s of ``harmonics`` (default the excited ones), ``2 pi h / (period dt)``."""
        sample_period = check_real("sample_period", sample_period, positive=True)
        h = np.asarray(self.excited_harmonics() if harmonics is None else harmonics, dtype=float)
        return 2.0 * math.pi * h / (self.period * sample_period)

    def phase_words(self) -> tuple[int, ...]:
        """u32 start phase of each excited line (``2**32`` = one cycle)."""
        excited = self.excited_harmonics()
        if self.seed == 0:
            f = len(excited)
            return tuple((-(j * (j - 1)) * 2**31 // f) % _TWO32 for j in range(1, f + 1))
        odd = self._odd()
        words = _lfsr_words(self.seed, len(odd))
        by_harmonic = dict(zip(odd, words))
        return tuple(by_harmonic[h] << 16 for h in excited)

    def components(self, sample_period: float = 1.0) -> list[tuple[int, int, int]]:
        """``(amplitude, phase0, phase_inc)`` per excited line, as :func:`multisine_duty` takes them.

        The words do not depend on the sample period (the period is counted in samples).
        """
        shift = 32 - (self.period.bit_length() - 1)
        return [(self.amplitude, p, h << shift) for h, p in zip(self.excited_harmonics(), self.phase_words())]

    def _raw(self, n, dt):
        return multisine_duty(self.components(), self.offset, n)

    def describe(self):
        return (f"odd-multisine:{self.period},{self.max_harmonic},{self.amplitude},{self.seed},{self.group}"
                + (f"@{self.offset}" if self.offset else ""))


_PARSE_HELP = ("sine:FREQ[,AMP[,PHASE]]  multisine:F,A,P;F,A,P...  chirp:F0,F1[,AMP]  "
               "prbs:HIGH,LOW[,ORDER[,HOLD[,SEED]]]  step:AFTER[,AT_TIME[,BEFORE]]  constant:LEVEL  "
               "odd-multisine:PERIOD,MAX_HARMONIC,AMP[,SEED[,GROUP]]")


def split_spec(spec: str, what: str, forms: str) -> tuple[str, str, float]:
    """Split a one-line spec ``KIND:ARGS[@OFFSET]`` (an excitation, a controller's reference).

    Returns the lower-cased kind, the argument text and the offset (0 when there is none).
    ``what`` names the spec and ``forms`` lists its accepted forms in the error messages.
    """
    if not isinstance(spec, str) or ":" not in spec:
        raise ParameterError(f"{what} must look like KIND:ARGS ({forms}), got {spec!r}")
    kind, _, args = spec.partition(":")
    offset = 0.0
    if "@" in args:
        args, _, off = args.partition("@")
        numbers = spec_numbers(off, spec, what, forms)      # an empty offset (``sine:10,10@``) is refused too
        if len(numbers) != 1:
            raise ParameterError(f"{what} {spec!r}: @ takes one OFFSET, got {len(numbers) or 'none'}; forms: {forms}")
        offset = numbers[0]
    return kind.strip().lower(), args, offset


def spec_numbers(text: str, spec: str, what: str, forms: str) -> list[float]:
    """The comma-separated numbers of ``text`` (part of ``spec``), or an error naming ``what`` and ``forms``.

    Every item must be a finite number in ASCII digits: an empty item (``10,,200``) is refused,
    not skipped, since skipping it would move the numbers after it to other parameters.
    """
    items = text.split(",")
    if not text.strip():
        items = []
    try:
        values = [float(x) for x in items if x.strip() and x.isascii() and "_" not in x]
    except ValueError:
        values = []
    if len(values) != len(items) or not all(math.isfinite(v) for v in values):
        raise ParameterError(f"{what} {spec!r}: expected comma-separated numbers (finite, digits 0-9, none "
                             f"left empty); forms: {forms}")
    return values


def _numbers(text: str, spec: str) -> list[float]:
    return spec_numbers(text, spec, "excitation", _PARSE_HELP)


def _ints(values: Sequence[float]) -> list:
    """Integral floats as ints (the checks of the excitation then refuse the rest)."""
    return [int(x) if float(x).is_integer() else x for x in values]


def _parse_sine(args: str, spec: str, offset: float) -> Excitation:
    v = _numbers(args, spec)
    if not 1 <= len(v) <= 3:
        raise ParameterError(f"excitation {spec!r}: sine takes FREQ[,AMP[,PHASE]]")
    amplitude = _ints(v[1:2])[0] if len(v) > 1 else 200
    phase = v[2] if len(v) > 2 else 0.0
    return Sine(v[0], amplitude, phase, offset=_ints([offset])[0])


def _parse_multisine(args: str, spec: str, offset: float) -> Excitation:
    parts = args.split(";")
    if parts and not parts[-1].strip():
        parts = parts[:-1]                    # one trailing ';' is harmless
    comps = [_numbers(c, spec) for c in parts]
    if not comps or any(not 1 <= len(c) <= 3 for c in comps):
        raise ParameterError(f"excitation {spec!r}: multisine takes F,A,P;F,A,P...")
    return Multisine(tuple(c[0] for c in comps),
                     tuple(_ints([c[1] if len(c) > 1 else 200])[0] for c in comps),
                     tuple(c[2] if len(c) > 2 else 0.0 for c in comps), _ints([offset])[0])


def _parse_chirp(args: str, spec: str, offset: float) -> Excitation:
    v = _numbers(args, spec)
    if not 2 <= len(v) <= 3:
        raise ParameterError(f"excitation {spec!r}: chirp takes F0,F1[,AMP]")
    amplitude = _ints(v[2:3])[0] if len(v) > 2 else 200
    return Chirp(v[0], v[1], amplitude, offset=_ints([offset])[0])


def _parse_prbs(args: str, spec: str, offset: float) -> Excitation:
    v = _ints(_numbers(args, spec))
    if not 2 <= len(v) <= 5:
        raise ParameterError(f"excitation {spec!r}: prbs takes HIGH,LOW[,ORDER[,HOLD[,SEED]]]")
    return PRBS(*v)


def _parse_step(args: str, spec: str, offset: float) -> Excitation:
    v = _numbers(args, spec)
    if not 1 <= len(v) <= 3:
        raise ParameterError(f"excitation {spec!r}: step takes AFTER[,AT_TIME[,BEFORE]]")
    at_time = v[1] if len(v) > 1 else 0.0
    before = _ints(v[2:3])[0] if len(v) > 2 else 0
    return Step(_ints(v[:1])[0], at_time, before)


def _parse_constant(args: str, spec: str, offset: float) -> Excitation:
    v = _ints(_numbers(args, spec))
    if len(v) != 1:
        raise ParameterError(f"excitation {spec!r}: constant takes LEVEL")
    return Constant(v[0])


def _parse_odd_multisine(args: str, spec: str, offset: float) -> Excitation:
    v = _ints(_numbers(args, spec))
    if not 3 <= len(v) <= 5:
        raise ParameterError(f"excitation {spec!r}: odd-multisine takes PERIOD,MAX_HARMONIC,AMP[,SEED[,GROUP]]")
    period, max_harmonic, amplitude, *rest = v
    seed = rest[0] if rest else 1
    group = rest[1] if len(rest) > 1 else 3
    return OddMultisine(period, max_harmonic, amplitude, seed, group, offset=_ints([offset])[0])


#: kind -> reader of ``ARGS`` (with the ``@OFFSET`` already split off).
_PARSERS = {"sine": _parse_sine, "multisine": _parse_multisine, "chirp": _parse_chirp, "prbs": _parse_prbs,
            "step": _parse_step, "constant": _parse_constant, "odd-multisine": _parse_odd_multisine}


def parse_excitation(spec: str) -> Excitation:
    """Read an excitation from its one-line form (``sine:10,200,0.5``; see :meth:`Excitation.describe`).

    Optional ``@OFFSET`` at the end of sine, multisine, chirp and odd-multisine adds a constant duty.

    Parameters
    ----------
    spec : str
        ``KIND:ARGS``, e.g. ``sine:FREQ[,AMP[,PHASE]]``, ``prbs:HIGH,LOW[,ORDER[,HOLD[,SEED]]]``.

    Examples
    --------
    >>> parse_excitation("sine:10,200")
    Sine(frequency=10.0, amplitude=200, phase=0.0, offset=0)
    >>> parse_excitation("prbs:200,-200,9,3").describe()
    'prbs:200,-200,9,3,1'
    """
    kind, args, offset = split_spec(spec, "excitation", _PARSE_HELP)
    if kind not in _PARSERS:
        raise ParameterError(f"excitation kind must be one of {', '.join(_PARSERS)}, got {kind!r}")
    try:
        return _PARSERS[kind](args, spec, offset)
    except ParameterError:
        raise
    except (ValueError, TypeError) as exc:     # a rule of the excitation itself, said for this spec
        raise ParameterError(f"excitation {spec!r}: {exc}") from None
