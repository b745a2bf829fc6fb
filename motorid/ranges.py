"""The range every design number passes where a command takes it: a model, a reference, a run length.

A number can be finite and still break the arithmetic that follows it: ``b = 1e-308`` gives
gains of 0 and a feedforward of ``inf``, a step at ``1e308`` s has no sample index, a run of
0.001 s at 5 ms has no sample.  Each check here refuses such a value in one line naming the
parameter, the rule and the value, before any design or run starts.
"""
from __future__ import annotations

import math
from typing import Any

from motorid.arguments import CommandError

__all__ = ["MODEL_SCALE_LIMIT", "MIN_SAMPLE_PERIOD", "MAX_SAMPLE_PERIOD", "MAX_REFERENCE_SAMPLES", "check_design_model",
           "check_reference_times", "check_run_length"]

#: The largest magnitude of a model's a, b, friction and bias (and 1 / it the smallest nonzero b):
#: beyond it squares and products of the design leave a float's range; no motor is near it.
MODEL_SCALE_LIMIT = 1e100

#: The longest sample period a controller is designed for, in s: the device takes it in µs, in 32 bits.
MAX_SAMPLE_PERIOD = (2**32 - 1) * 1e-6
#: The shortest, in s: one µs, the device's unit (1e-320 s made the PI gains divide by zero).
MIN_SAMPLE_PERIOD = 1e-6

#: The largest time of a reference, in samples: the device counts samples in 32 bits.
MAX_REFERENCE_SAMPLES = 2**32 - 1


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
