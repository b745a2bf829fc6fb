"""The simulated bench's ranges: where a number of the bench still gives a run the arithmetic can hold.

A number can be finite and still break the arithmetic that follows it: a pole of ``4.3e9`` 1/s at 5 ms settles a
motor that moves no count, a drive of ``b = 1e300`` turns the shaft past any float.  :data:`BENCH_RULES` says each
rule; :func:`check_bench_values` applies them to the bench's values wherever they come from (``motorid simulate``'s
flags, a scenario's keys, a ``fake://`` URL's keys), each caller naming the values as its user wrote them.

Examples
--------
>>> check_bench_values({"a": 25.0, "b": 3.0, "sample_period": 0.005, "duration": 2.0})
>>> check_bench_values({"a": 25.0, "b": 3e6}, spell=lambda name: f"url key {name!r}")
Traceback (most recent call last):
...
motorsim.checks.ParameterError: url key 'b' must keep the top speed of the run, |b| x 255 x (1 - exp(-a T)) / a, \
within 100000 rad/s (about a million rpm: no motor turns faster), got b = 3000000.0 at a = 25 1/s over inf s: \
3.06e+07 rad/s
"""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping

from .checks import ParameterError

__all__ = ["MIN_SAMPLE_PERIOD", "MAX_SAMPLE_PERIOD", "MAX_SPEED", "POLE_STEP_RANGE", "LAG_STEP_RANGE",
           "MAX_ANGLE_NOISE", "MAX_RUN_SAMPLES", "BENCH_RULES", "check_bench_values"]

#: The longest sample period a controller is designed for, in s: the device takes it in µs, in 32 bits.
MAX_SAMPLE_PERIOD = (2**32 - 1) * 1e-6
#: The shortest, in s: one µs, the device's unit (1e-320 s made the PI gains divide by zero).
MIN_SAMPLE_PERIOD = 1e-6
#: The most samples a run may have: the device counts them in 32 bits.
MAX_RUN_SAMPLES = 2**32
#: The fastest shaft the simulated bench's values may describe, rad/s: about a million rpm, which no motor reaches
#: (the fastest spindles turn a few hundred thousand); a drive or a bias past it is a mistyped number.
MAX_SPEED = 1e5
#: The range of the pole times the sample period, ``a h``: above it ``exp(-a h)`` of the exact step leaves the normal
#: floats (it is 0 from 745); below it the step's angle term ``(h - (1 - exp(-a h))/a)/a`` loses its digits (measured
#: against 60-digit arithmetic over 2000 samples: 4e-11 relative at ``a h`` = 1e-9, 5e-8 at 1e-12, 5e-4 at 1e-16).
POLE_STEP_RANGE = (1e-9, 700.0)
#: The range of the sample period over an electrical time constant, ``h / tau_e``: the same ``exp(-h/tau_e)`` above;
#: below, the lag's step departs from python-control's matrix exponential (1.6e-11 relative at 1e-6, 2.8e-8 at 1e-9).
LAG_STEP_RANGE = (1e-6, 700.0)
#: The largest angle noise, rad: one turn (an angle noisier than that is no encoder's).
MAX_ANGLE_NOISE = 2 * math.pi

#: Each bench value's range, as the commands' help says it (:func:`check_bench_values` applies them).
BENCH_RULES = {
    "a": f"a x --sample-period within {POLE_STEP_RANGE[0]:g}...{POLE_STEP_RANGE[1]:g}",
    "b": f"the run's top speed abs(b) x the duty limit x (1 - exp(-a T)) / a at most {MAX_SPEED:g} rad/s (T the "
         "duration), and enough to move the encoder a count",
    "friction": f"at most a x {MAX_SPEED:g} rad/s",
    "bias": f"abs(bias) x (1 - exp(-a T)) / a at most {MAX_SPEED:g} rad/s",
    "dead_zone": "at most 255",
    "electrical_time_constant": f"--sample-period / it within {LAG_STEP_RANGE[0]:g}...{LAG_STEP_RANGE[1]:g}",
    "static_friction": f"at most a x {MAX_SPEED:g} rad/s",
    "angle_noise": f"at most {MAX_ANGLE_NOISE:.6g} rad (one turn)",
    "initial_speed": f"abs(initial speed) at most {MAX_SPEED:g} rad/s",
    "sample_period": f"{MIN_SAMPLE_PERIOD:g}...{MAX_SAMPLE_PERIOD:.6g} s",
    "duration": "2 samples to 2**32 samples",
}


def _value(values: Mapping[str, Any], name: str, default: float) -> float:
    value = values.get(name, default)
    return default if value is None else float(value)


def check_bench_values(values: Mapping[str, Any], spell: Callable[[str], str] = str,
                       error: type[Exception] = ParameterError) -> None:
    """``values`` (the bench's, by knob name: ``a``, ``b``, ``sample_period``, ``duration``, ...) within
    :data:`BENCH_RULES`; else the first they break as ``error`` naming the value as ``spell(name)`` writes it, the
    rule and the value.

    The sample period and the run length first (the pole's and the lag's ranges are in sample periods), then the
    motor's values.  A value not given is not checked; without a sample period the rules in sample periods are not
    made, and without a duration the run is taken as long as the motor needs to settle (``T`` infinite: the speeds
    are the steady ones).  What a knob's own class refuses (a pole <= 0, ``b`` = 0) is left to it.
    """
    s = spell
    h = _value(values, "sample_period", math.nan)
    duration = _value(values, "duration", math.inf)
    if not math.isnan(h):
        if not MIN_SAMPLE_PERIOD <= h <= MAX_SAMPLE_PERIOD:
            raise error(f"{s('sample_period')} must be in {MIN_SAMPLE_PERIOD:g}...{MAX_SAMPLE_PERIOD:.6g} s (the "
                        f"device takes it in µs, 32 bits), got {h!r}")
        if "duration" in values:
            if not (math.isfinite(duration) and duration >= 2 * h):
                raise error(f"{s('duration')} must cover at least 2 samples of {h:g} s, got {duration!r} s")
            if not duration / h < MAX_RUN_SAMPLES:
                raise error(f"{s('duration')} must be under 2**32 samples of {h:g} s (the device counts them in 32 "
                            f"bits), got {duration!r} s ({duration / h:.3g} samples)")
    a, b = _value(values, "a", math.nan), _value(values, "b", math.nan)
    if a > 0 and not math.isnan(h) and not POLE_STEP_RANGE[0] <= a * h <= POLE_STEP_RANGE[1]:
        raise error(f"{s('a')} times {s('sample_period')} must be within {POLE_STEP_RANGE[0]:g}..."
                    f"{POLE_STEP_RANGE[1]:g} (beyond, the exact step's exp(-a h) is no normal float; below, its angle "
                    f"term loses its digits), got a = {a!r} 1/s at {h:g} s: a h = {a * h:.3g}")
    if not a > 0 or b == 0 or math.isnan(b):
        return                          # the motor's own rules refuse these, by name
    _check_speeds(values, a, b, duration, s, error)
    _check_parts(values, a, h, s, error)


def _check_speeds(values: Mapping[str, Any], a: float, b: float, duration: float, s: Callable[[str], str],
                  error: type[Exception]) -> None:
    """``b``, ``bias`` and ``initial_speed`` within :data:`MAX_SPEED`; ``b`` large enough to move a count."""
    limit = _value(values, "duty_limit", 255.0)
    settle = -math.expm1(-a * duration) / a       # the speed an acceleration of 1 reaches in the run, from rest
    top = abs(b) * limit * settle
    if top > MAX_SPEED:
        raise error(f"{s('b')} must keep the top speed of the run, |b| x {limit:g} x (1 - exp(-a T)) / a, within "
                    f"{MAX_SPEED:g} rad/s (about a million rpm: no motor turns faster), got b = {b!r} at a = {a:g} "
                    f"1/s over {duration:g} s: {top:.3g} rad/s")
    bias = _value(values, "bias", 0.0)
    if abs(bias) * settle > MAX_SPEED:
        raise error(f"{s('bias')} must keep the speed it drives the shaft to in the run, |bias| x (1 - exp(-a T)) / "
                    f"a, within {MAX_SPEED:g} rad/s (about a million rpm), got bias = {bias!r} at a = {a:g} 1/s over "
                    f"{duration:g} s: {abs(bias) * settle:.3g} rad/s")
    speed = _value(values, "initial_speed", 0.0)
    if abs(speed) > MAX_SPEED:
        raise error(f"{s('initial_speed')} must be within +-{MAX_SPEED:g} rad/s (about a million rpm), got {speed!r}")
    # the farthest the drive at its limit can turn the shaft in the run: at most the top speed, or b u t^2 / 2
    counts = int(_value(values, "counts_per_rev", 0.0))
    reach = min(top * duration, abs(b) * limit * duration ** 2 / 2)
    if counts > 0 and limit > 0 and reach < 2 * math.pi / counts:
        raise error(f"{s('b')} must move the encoder at least one count ({2 * math.pi / counts:.3g} rad) at the duty "
                    f"limit in the run, got b = {b!r}: at most {reach:.3g} rad in {duration:g} s at a = {a:g} 1/s")


def _check_parts(values: Mapping[str, Any], a: float, h: float, s: Callable[[str], str],
                 error: type[Exception]) -> None:
    """``friction``, ``static_friction``, ``dead_zone``, ``electrical_time_constant``, ``angle_noise``."""
    for name in ("friction", "static_friction"):
        value = _value(values, name, 0.0)
        if value > a * MAX_SPEED:
            raise error(f"{s(name)} must be at most a x {MAX_SPEED:g} rad/s = {a * MAX_SPEED:.6g} rad/s^2 (the "
                        f"pole's own torque at about a million rpm), got {value!r}")
    zone = _value(values, "dead_zone", 0.0)
    if zone > 255:
        raise error(f"{s('dead_zone')} must be at most 255 duty (the largest duty there is), got {zone!r}")
    tau = _value(values, "electrical_time_constant", 0.0)
    if tau > 0 and not math.isnan(h) and not LAG_STEP_RANGE[0] <= h / tau <= LAG_STEP_RANGE[1]:
        raise error(f"{s('electrical_time_constant')} must be 0 (none) or keep {s('sample_period')} / it within "
                    f"{LAG_STEP_RANGE[0]:g}...{LAG_STEP_RANGE[1]:g} ({h / LAG_STEP_RANGE[1]:.3g}..."
                    f"{h / LAG_STEP_RANGE[0]:.3g} s at {h:g} s), got {tau!r} s")
    noise = _value(values, "angle_noise", 0.0)
    if noise > MAX_ANGLE_NOISE:
        raise error(f"{s('angle_noise')} must be at most {MAX_ANGLE_NOISE:.6g} rad (one turn: a noisier angle is no "
                    f"encoder's), got {noise!r}")
