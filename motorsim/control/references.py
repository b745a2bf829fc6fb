"""References a controller tracks: :class:`Reference` and its one-line form, :func:`parse_reference`."""
from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from ..checks import ParameterError, check_real
from ..excitation import MAX_COMPONENTS, phase_increment, spec_numbers, split_spec
from ..fixed_point import MAX_REFERENCE, ReferenceWords, reference_values

__all__ = ["Reference", "parse_reference"]

_REFERENCE_HELP = ("constant:LEVEL  step:AFTER[,AT_TIME[,BEFORE]]  sine:FREQ,AMP[,PHASE][@OFFSET]  "
                   "multisine:F,A,P;F,A,P...[@OFFSET]  trapezoid:LEVEL,RAMP_TIME,HOLD_TIME[,AT_TIME]")


@dataclasses.dataclass(frozen=True)
class Reference:
    """A reference wave in physical units (rad/s for speed, rad for position), integer-exact on a device.

    Parameters
    ----------
    kind : str
        ``constant``, ``step``, ``sine``, ``multisine`` or ``trapezoid``.
    level : float
        Constant level; step value after the switch; trapezoid plateau; sine offset.
    frequencies, amplitudes, phases : tuple of float
        Sine components (rad/s, physical unit, rad); ``sine`` has one, ``multisine`` up to 4.
    at_time : float
        Step switch or trapezoid start in s (rounded to a sample).
    before : float
        Step value before the switch.
    ramp_time, hold_time : float
        Trapezoid ramp and plateau durations in s (rounded to samples).

    Notes
    -----
    :meth:`samples` turns the wave into integers of the controller's reference unit:
    levels ``L = round(level scale)``; sines as the excitations compute them
    (``multisine_duty`` of :mod:`motorsim.excitation`, amplitudes ``round(A scale)``);
    trapezoid ramps ``floor(L i / n_ramp)``.

    Examples
    --------
    >>> r = parse_reference("trapezoid:10,0.02,0.01")
    >>> r.samples(11, 0.005, 1.0).tolist()   # the level is held from 0.02 s to 0.03 s
    [0, 2, 5, 7, 10, 10, 10, 7, 5, 2, 0]
    """

    kind: str
    level: float = 0.0
    frequencies: tuple = ()
    amplitudes: tuple = ()
    phases: tuple = ()
    at_time: float = 0.0
    before: float = 0.0
    ramp_time: float = 0.0
    hold_time: float = 0.0
    kinds: ClassVar[tuple[str, ...]] = ("constant", "step", "sine", "multisine", "trapezoid")

    def __post_init__(self):
        if self.kind not in self.kinds:
            raise ParameterError(f"reference kind must be one of {', '.join(self.kinds)}, got {self.kind!r}")
        for name in ("level", "at_time", "before", "ramp_time", "hold_time"):
            object.__setattr__(self, name, check_real(name, getattr(self, name)))
        f = tuple(check_real("frequencies", x, positive=True) for x in self.frequencies)
        a = tuple(check_real("amplitudes", x) for x in self.amplitudes)
        p = tuple(check_real("phases", x) for x in self.phases) or (0.0,) * len(f)
        if self.kind in ("sine", "multisine") and not (1 <= len(f) <= MAX_COMPONENTS and len(a) == len(f) == len(p)):
            raise ParameterError(f"a {self.kind} reference needs 1...{MAX_COMPONENTS} components of equal length, "
                             f"got {len(f)} frequencies, {len(a)} amplitudes, {len(p)} phases")
        if self.kind == "trapezoid" and self.ramp_time <= 0:
            raise ParameterError(f"ramp_time must be > 0 s for a trapezoid, got {self.ramp_time!r}")
        if min(self.at_time, self.hold_time) < 0:
            raise ParameterError(f"at_time and hold_time must be >= 0 s, got {self.at_time!r}, {self.hold_time!r}")
        object.__setattr__(self, "frequencies", f)
        object.__setattr__(self, "amplitudes", a)
        object.__setattr__(self, "phases", p)

    def samples(self, n_samples: int, sample_period: float, scale: float) -> np.ndarray:
        """The integer reference for samples ``0 ... n_samples-1`` (int64).

        Parameters
        ----------
        n_samples : int
            Number of samples.
        sample_period : float
            Sample period in s.
        scale : float
            Integer units per physical unit (e.g. 1/16 count per sample per rad/s).
        """
        return reference_values(self.words(sample_period, scale), n_samples)

    def words(self, sample_period: float, scale: float) -> ReferenceWords:
        """The integers a device generates this reference from (see :func:`reference_values`).

        Parameters
        ----------
        sample_period : float
            Sample period in s.
        scale : float
            Integer units per physical unit.
        """
        dt = check_real("sample_period", sample_period, positive=True)

        def lsb(x: float, name: str) -> int:
            units = x * scale
            if not abs(units) <= MAX_REFERENCE:     # also an overflow to inf
                raise ParameterError(f"reference {name} {x!r} is {units:.4g} units of the controller's reference, "
                                     f"beyond the device's limit +-{MAX_REFERENCE}")
            return int(round(units))

        if self.kind == "constant":
            return ReferenceWords("constant", lsb(self.level, "level"))
        if self.kind == "step":
            return ReferenceWords("step", lsb(self.level, "after"), lsb(self.before, "before"),
                                  int(round(self.at_time / dt)))
        if self.kind == "trapezoid":
            return ReferenceWords("trapezoid", lsb(self.level, "level"), 0, int(round(self.at_time / dt)),
                                  max(1, int(round(self.ramp_time / dt))), int(round(self.hold_time / dt)))
        amps = [lsb(x, "amplitude") for x in self.amplitudes]
        if sum(abs(x) for x in amps) > MAX_REFERENCE:
            raise ParameterError(f"reference amplitudes sum to {sum(abs(x) for x in amps)} units, "
                             f"beyond the device's limit {MAX_REFERENCE}")
        comps = []
        for f, amp, ph in zip(self.frequencies, amps, self.phases):
            if f * dt >= math.pi:
                raise ParameterError(f"reference frequencies must be below pi/sample_period = {math.pi / dt:.6g} "
                                 f"rad/s, got {f!r}")
            comps.append((amp, int(round(ph / (2 * math.pi) * 2**32)) % 2**32, phase_increment(f, dt)))
        return ReferenceWords("multisine", lsb(self.level, "offset"), components=tuple(comps))

    def describe(self) -> str:
        """A one-line spec that :func:`parse_reference` reads back."""
        if self.kind == "constant":
            return f"constant:{self.level!r}"
        if self.kind == "step":
            return f"step:{self.level!r},{self.at_time!r},{self.before!r}"
        if self.kind == "trapezoid":
            return f"trapezoid:{self.level!r},{self.ramp_time!r},{self.hold_time!r},{self.at_time!r}"
        parts = ";".join(f"{f!r},{a!r},{p!r}" for f, a, p in zip(self.frequencies, self.amplitudes, self.phases))
        return f"{self.kind}:{parts}" + (f"@{self.level!r}" if self.level else "")


def parse_reference(spec: str) -> Reference:
    """Read a reference from its one-line form (see :meth:`Reference.describe`).

    Parameters
    ----------
    spec : str
        ``constant:LEVEL``, ``step:AFTER[,AT_TIME[,BEFORE]]``, ``sine:FREQ,AMP[,PHASE][@OFFSET]``,
        ``multisine:F,A,P;...[@OFFSET]`` or ``trapezoid:LEVEL,RAMP_TIME,HOLD_TIME[,AT_TIME]``;
        levels and amplitudes in rad/s (speed controllers) or rad (position).

    Examples
    --------
    >>> parse_reference("sine:10,20@5").describe()
    'sine:10.0,20.0,0.0@5.0'
    """
    kind, args, offset = split_spec(spec, "reference", _REFERENCE_HELP)
    if kind in ("sine", "multisine"):
        comps = [_numbers(c, spec) for c in args.split(";") if c.strip()]
        if not comps or any(not 2 <= len(c) <= 3 for c in comps) or (kind == "sine" and len(comps) != 1):
            raise ParameterError(f"reference {spec!r}: {kind} takes FREQ,AMP[,PHASE] per component")
        return Reference(kind, offset, tuple(c[0] for c in comps), tuple(c[1] for c in comps),
                         tuple(c[2] if len(c) > 2 else 0.0 for c in comps))
    v = _numbers(args, spec)
    forms = {"constant": (1, 1), "step": (1, 3), "trapezoid": (3, 4)}
    if kind not in forms:
        raise ParameterError(f"reference kind must be one of {', '.join(Reference.kinds)}, got {kind!r}")
    lo, hi = forms[kind]
    if not lo <= len(v) <= hi:
        raise ParameterError(f"reference {spec!r}: expected {_REFERENCE_HELP}")
    if kind == "constant":
        return Reference("constant", v[0])
    if kind == "step":
        return Reference("step", v[0], at_time=v[1] if len(v) > 1 else 0.0, before=v[2] if len(v) > 2 else 0.0)
    return Reference("trapezoid", v[0], ramp_time=v[1], hold_time=v[2], at_time=v[3] if len(v) > 3 else 0.0)


def _numbers(text: str, spec: str) -> list[float]:
    return spec_numbers(text, spec, "reference", _REFERENCE_HELP)
