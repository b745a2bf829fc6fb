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

__all__ = ["MODEL_SCALE_LIMIT", "MIN_SAMPLE_PERIOD", "MAX_SAMPLE_PERIOD", "MAX_REFERENCE_SAMPLES", "check_design_model",
           "check_reference_times", "check_run_length", "MAX_SPEED", "POLE_STEP_RANGE", "LAG_STEP_RANGE",
           "MAX_ANGLE_NOISE", "BENCH_RULES", "check_bench_flags"]

#: The largest magnitude of a model's a, b, friction and bias (and 1 / it the smallest nonzero b):
#: beyond it squares and products of the design leave a float's range; no motor is near it.
MODEL_SCALE_LIMIT = 1e100

#: The longest sample period a controller is designed for, in s: the device takes it in µs, in 32 bits.
MAX_SAMPLE_PERIOD = (2**32 - 1) * 1e-6
#: The shortest, in s: one µs, the device's unit (1e-320 s made the PI gains divide by zero).
MIN_SAMPLE_PERIOD = 1e-6

#: The largest time of a reference, in samples: the device counts samples in 32 bits.
MAX_REFERENCE_SAMPLES = 2**32 - 1


#: The fastest shaft the simulated bench's flags may describe, rad/s: about a million rpm, which no motor reaches (the
#: fastest spindles turn a few hundred thousand); a drive or a bias past it is a mistyped number.
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

#: Each bench flag's range, as its help says it (:func:`check_bench_flags` applies them).
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


def check_bench_flags(args: Any) -> None:
    """The simulated bench's flags (``motorid simulate``, ``motorid demo``) within :data:`BENCH_RULES`; else the
    first they break as a :class:`CommandError` naming the flag, the rule and the value.

    The sample period and the run length first (the pole's and the lag's ranges are in sample periods), then the
    motor's values in flag order.  What a knob's own dataclass refuses (a pole <= 0, a jitter of 1) is refused there.
    """
    from motorsim.rig import MAX_SAMPLES
    h, duration = float(args.sample_period), float(args.duration)
    if not MIN_SAMPLE_PERIOD <= h <= MAX_SAMPLE_PERIOD:
        raise CommandError(f"--sample-period must be in {MIN_SAMPLE_PERIOD:g}...{MAX_SAMPLE_PERIOD:.6g} s (the device "
                           f"takes it in µs, 32 bits), got {h!r}")
    check_run_length(duration, h)
    if not duration / h < MAX_SAMPLES:
        raise CommandError(f"--duration must be under 2**32 samples of {h:g} s (the device counts them in 32 bits), "
                           f"got {duration!r} s ({duration / h:.3g} samples)")
    a, b = float(args.a), float(args.b)
    if a > 0 and not POLE_STEP_RANGE[0] <= a * h <= POLE_STEP_RANGE[1]:
        raise CommandError(f"--a times --sample-period must be within {POLE_STEP_RANGE[0]:g}...{POLE_STEP_RANGE[1]:g} "
                           f"(beyond, the exact step's exp(-a h) is no normal float; below, its angle term loses its "
                           f"digits), got a = {a!r} 1/s at {h:g} s: a h = {a * h:.3g}")
    if a <= 0 or b == 0:
        return                          # the motor's own rules refuse these, by name
    _check_speeds(args, a, b)
    _check_parts(args, a, h)


def _check_speeds(args: Any, a: float, b: float) -> None:
    """``--b``, ``--bias`` and ``--initial-speed`` within :data:`MAX_SPEED`; ``--b`` large enough to move a count."""
    limit, duration = float(getattr(args, "duty_limit", 255)), float(args.duration)
    settle = -math.expm1(-a * duration) / a       # the speed an acceleration of 1 reaches in the run, from rest
    top = abs(b) * limit * settle
    if top > MAX_SPEED:
        raise CommandError(f"--b must keep the top speed of the run, |b| x {limit:g} x (1 - exp(-a T)) / a, within "
                           f"{MAX_SPEED:g} rad/s (about a million rpm: no motor turns faster), got b = {b!r} at "
                           f"a = {a:g} 1/s over {duration:g} s: {top:.3g} rad/s")
    bias = float(getattr(args, "bias", 0.0))
    if abs(bias) * settle > MAX_SPEED:
        raise CommandError(f"--bias must keep the speed it drives the shaft to in the run, |bias| x (1 - exp(-a T)) / "
                           f"a, within {MAX_SPEED:g} rad/s (about a million rpm), got bias = {bias!r} at a = {a:g} 1/s "
                           f"over {duration:g} s: {abs(bias) * settle:.3g} rad/s")
    speed = float(getattr(args, "initial_speed", 0.0))
    if abs(speed) > MAX_SPEED:
        raise CommandError(f"--initial-speed must be within +-{MAX_SPEED:g} rad/s (about a million rpm), got {speed!r}")
    # the farthest the drive at its limit can turn the shaft in the run: at most the top speed, or b u t^2 / 2
    counts = int(getattr(args, "counts_per_rev", 0) or 0)
    reach = min(top * duration, abs(b) * limit * duration ** 2 / 2)
    if counts > 0 and limit > 0 and reach < 2 * math.pi / counts:
        raise CommandError(f"--b must move the encoder at least one count ({2 * math.pi / counts:.3g} rad) at the "
                           f"duty limit in the run, got b = {b!r}: at most {reach:.3g} rad in {duration:g} s at "
                           f"a = {a:g} 1/s")


def _check_parts(args: Any, a: float, h: float) -> None:
    """``--friction``, ``--static-friction``, ``--dead-zone``, ``--electrical-time-constant``, ``--angle-noise``."""
    for name in ("friction", "static_friction"):
        value = float(getattr(args, name, 0.0))
        if value > a * MAX_SPEED:
            raise CommandError(f"--{name.replace('_', '-')} must be at most a x {MAX_SPEED:g} rad/s = "
                               f"{a * MAX_SPEED:.6g} rad/s^2 (the pole's own torque at about a million rpm), "
                               f"got {value!r}")
    zone = float(getattr(args, "dead_zone", 0.0))
    if zone > 255:
        raise CommandError(f"--dead-zone must be at most 255 duty (the largest duty there is), got {zone!r}")
    tau = float(getattr(args, "electrical_time_constant", 0.0))
    if tau > 0 and not LAG_STEP_RANGE[0] <= h / tau <= LAG_STEP_RANGE[1]:
        raise CommandError(f"--electrical-time-constant must be 0 (none) or keep --sample-period / it within "
                           f"{LAG_STEP_RANGE[0]:g}...{LAG_STEP_RANGE[1]:g} ({h / LAG_STEP_RANGE[1]:.3g}..."
                           f"{h / LAG_STEP_RANGE[0]:.3g} s at {h:g} s), got {tau!r} s")
    noise = float(getattr(args, "angle_noise", 0.0))
    if noise > MAX_ANGLE_NOISE:
        raise CommandError(f"--angle-noise must be at most {MAX_ANGLE_NOISE:.6g} rad (one turn: a noisier angle is no "
                           f"encoder's), got {noise!r}")


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
