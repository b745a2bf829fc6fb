"""The range every design number passes where a command takes it: a model, a reference, a run length, the bench.

A number can be finite and still break the arithmetic that follows it: ``b = 1e-308`` gives
gains of 0 and a feedforward of ``inf``, a step at ``1e308`` s has no sample index, a run of
0.001 s at 5 ms has no sample, a pole of ``4.3e9`` 1/s at 5 ms settles a motor that moves no count.
Each check here refuses such a value in one line naming the parameter, the rule and the value,
before any design or run starts.
"""
from __future__ import annotations

import math
from typing import Any

from motorid.arguments import CommandError
from motorsim.ranges import (
    BENCH_RULES,
    LAG_STEP_RANGE,
    MAX_ANGLE_NOISE,
    MAX_SAMPLE_PERIOD,
    MAX_SPEED,
    MIN_SAMPLE_PERIOD,
    POLE_STEP_RANGE,
    check_bench_values,
)

__all__ = ["MODEL_SCALE_LIMIT", "MIN_SAMPLE_PERIOD", "MAX_SAMPLE_PERIOD", "MAX_REFERENCE_SAMPLES", "check_design_model",
           "check_reference_times", "check_run_length", "MAX_SPEED", "POLE_STEP_RANGE", "LAG_STEP_RANGE",
           "MAX_ANGLE_NOISE", "BENCH_RULES", "check_bench_flags"]

#: The largest magnitude of a model's a, b, friction and bias (and 1 / it the smallest nonzero b):
#: beyond it squares and products of the design leave a float's range; no motor is near it.
MODEL_SCALE_LIMIT = 1e100

#: The largest time of a reference, in samples: the device counts samples in 32 bits.
MAX_REFERENCE_SAMPLES = 2**32 - 1


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def check_bench_flags(args: Any) -> None:
    """The simulated bench's flags (``motorid simulate``, ``motorid demo``) within :data:`BENCH_RULES`
    (:func:`motorsim.ranges.check_bench_values`, the rules a scenario's keys and a ``fake://`` URL's keys are held
    to as well); else the first they break as a :class:`CommandError` naming the flag, the rule and the value.

    The sample period and the run length first (the pole's and the lag's ranges are in sample periods), then the
    motor's values in flag order.  What a knob's own dataclass refuses (a pole <= 0, a jitter of 1) is refused there.
    """
    names = ("sample_period", "duration", "a", "b", "duty_limit", "bias", "initial_speed", "counts_per_rev",
             "friction", "static_friction", "dead_zone", "electrical_time_constant", "angle_noise")
    check_bench_values({n: getattr(args, n) for n in names if getattr(args, n, None) is not None}, _flag,
                       CommandError)


def check_design_model(model: Any, source: str = "the model") -> Any:
    """``model`` (a, b, friction, bias) if each is finite and within :data:`MODEL_SCALE_LIMIT`; else CommandError.

    Its ``sample_period`` must be in :data:`MIN_SAMPLE_PERIOD`...:data:`MAX_SAMPLE_PERIOD` (checked first: a
    controller's gains and reference follow from it, and a period of hours makes them fail for reasons it would
    not name).
    """
    dt = float(model.sample_period)
    if not MIN_SAMPLE_PERIOD <= dt <= MAX_SAMPLE_PERIOD:
        raise CommandError(f"--sample-period must be in {MIN_SAMPLE_PERIOD:g}...{MAX_SAMPLE_PERIOD:.6g} s (the device "
                           f"takes it in µs, 32 bits), got {dt!r}")
    for name in ("a", "b", "friction", "bias"):
        value = float(getattr(model, name, 0.0) or 0.0)
        if not (math.isfinite(value) and abs(value) <= MODEL_SCALE_LIMIT):
            raise CommandError(f"{source}: {name} must be finite and within +-{MODEL_SCALE_LIMIT:g}, got {value!r}")
    b = float(model.b)
    if not abs(b) >= 1 / MODEL_SCALE_LIMIT:
        raise CommandError(f"{source}: b must be nonzero, at least {1 / MODEL_SCALE_LIMIT:g} in magnitude, got {b!r}")
    return model


def check_reference_times(reference: Any, sample_period: float) -> Any:
    """``reference`` if its times (a step's or trapezoid's) are >= 0 and fit the device's sample counter."""
    for name in ("at_time", "ramp_time", "hold_time"):
        value = float(getattr(reference, name, 0.0) or 0.0)
        if not (math.isfinite(value) and 0 <= value <= MAX_REFERENCE_SAMPLES * sample_period):
            raise CommandError(f"--reference {reference.describe()}: its {name} must be in 0..."
                               f"{MAX_REFERENCE_SAMPLES * sample_period:.6g} s ({MAX_REFERENCE_SAMPLES} samples of "
                               f"{sample_period:g} s), got {value!r}")
    return reference


def check_run_length(duration: float, sample_period: float, flag: str = "--duration") -> float:
    """``duration`` if it covers at least 2 samples of ``sample_period``."""
    if not (math.isfinite(duration) and duration >= 2 * sample_period):
        raise CommandError(f"{flag} must cover at least 2 samples of {sample_period:g} s, got {duration!r} s")
    return duration
