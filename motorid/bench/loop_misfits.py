"""Plants one step past every registered structure inside a feedback loop, for ``motorid bench coverage``.

Under a loop the default fits ``pem-disturbance`` (a torque disturbance as a state), and its answer is checked on the
data's own parts through its one-step prediction errors (:mod:`identify.default.innovation_checks`).  Each maker
runs a PD position loop (``u = 400 (r - θ) - 15 ω``, two slow sines) or a PI speed loop (``kp`` 3, ``ki`` 60, two
sines of 20 and 10 rad/s), both on the differenced counts, around a motor with one thing the structures lack —
Stribeck's friction, a forward gain above the reverse one, a gain that sags with the duty, a load switched on, a
motor warming — and a random torque of :data:`TORQUE` rad/s^2 RMS (correlation time 0.1 s) that the loop feeds
back; 2000 counts, 1 ms, 15 s.  The motor is integrated by classical Runge--Kutta on
:data:`~motorid.bench.misfits.SUBSTEPS` sub-steps of each held sample, the torque held over each sub-step.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .misfits import SUBSTEPS, A, B

__all__ = ["LOOP_MISFITS", "LOOP_TRUTH", "TORQUE"]

#: RMS of the random torque the loop feeds back, rad/s^2.
TORQUE = 15.0
#: Sample period (s), samples, counts per revolution.
H, SAMPLES, COUNTS = 0.001, 15_000, 2000


def _loop(accel: Callable[[float, float, float, float], float], seed: int, kind: str):
    """The recording of ``accel(t, θ, ω, u)`` (plus the random torque) under the loop ``kind`` (module docstring)."""
    from motorsim import Recording
    rng = np.random.default_rng(seed)
    dt = H / SUBSTEPS
    th = w = d = integral = 0.0
    prev = 0
    counts, duty = np.zeros(SAMPLES, np.int64), np.zeros(SAMPLES, np.int64)
    phase = rng.uniform(0, 2 * math.pi)
    for k in range(SAMPLES):
        t = k * H
        c = int(math.floor((th + rng.normal(0, 1e-4)) * COUNTS / (2 * math.pi)))
        counts[k] = c
        measured = (c - prev) * 2 * math.pi / COUNTS / H if k else 0.0
        prev = c
        if kind == "speed":
            error = 20 * math.sin(2 * math.pi * t) + 10 * math.sin(5.2 * math.pi * t + 1 + phase) - measured
            integral += error * H
            u = 3.0 * error + 60.0 * integral
        else:
            reference = 3 * math.sin(1.5 * t + phase) + 1.5 * math.sin(4.1 * t)
            u = 400.0 * (reference - c * 2 * math.pi / COUNTS) - 15.0 * measured
        duty[k] = u = int(round(min(max(u, -255), 255)))
        for _ in range(SUBSTEPS):
            d += -d / 0.1 * dt + TORQUE * math.sqrt(2 * dt / 0.1) * rng.normal()
            k1t, k1w = w, accel(t, th, w, u) + d
            k2t, k2w = w + 0.5 * dt * k1w, accel(t + 0.5 * dt, th + 0.5 * dt * k1t, w + 0.5 * dt * k1w, u) + d
            k3t, k3w = w + 0.5 * dt * k2w, accel(t + 0.5 * dt, th + 0.5 * dt * k2t, w + 0.5 * dt * k2w, u) + d
            k4t, k4w = w + dt * k3w, accel(t + dt, th + dt * k3t, w + dt * k3w, u) + d
            th += dt * (k1t + 2 * k2t + 2 * k3t + k4t) / 6
            w += dt * (k1w + 2 * k2w + 2 * k3w + k4w) / 6
            t += dt
    # no controller named: the default finds the loop in the data, as in a user's file
    return Recording(time=np.arange(SAMPLES) * H, duty=duty, sample_period=H, counts=counts, counts_per_rev=COUNTS)


def _coulomb(w: float) -> float:
    """Coulomb friction of 60 rad/s^2, smoothed over 0.05 rad/s."""
    return 60.0 * math.tanh(w / 0.05)


#: Forward gain over the reverse one; the share the gain sags by at full duty; the load (rad/s^2) and when; the warming.
ASYMMETRY, SAG, LOAD, LOAD_AT, WARMING = 1.15, 0.25, 150.0, 7.5, 0.08


def _stribeck(t, th, w, u):
    return -A * w + B * u - (40.0 + 60.0 * math.exp(-(w / 3.0) ** 2)) * math.tanh(w / 0.05)


def _asymmetric(t, th, w, u):
    return -A * w + (ASYMMETRY * B if u > 0 else B) * u - _coulomb(w)


def _sagging(t, th, w, u):
    return -A * w + B * u * (1 - SAG * abs(u) / 255) - _coulomb(w)


def _load(t, th, w, u):
    return -A * w + B * u - _coulomb(w) - (LOAD if t > LOAD_AT else 0.0)


def _warming(t, th, w, u):
    return (1 - WARMING * t / (H * SAMPLES)) * (-A * w + B * u) - _coulomb(w)


#: class name -> recording maker ``(seed) -> Recording``.
LOOP_MISFITS: dict[str, Callable[[int], object]] = {
    "Stribeck friction, position loop": lambda seed: _loop(_stribeck, seed, "position"),
    "forward gain 15 % above reverse, position loop": lambda seed: _loop(_asymmetric, seed, "position"),
    "gain sagging with the duty, speed loop": lambda seed: _loop(_sagging, seed, "speed"),
    "load switched on, position loop": lambda seed: _loop(_load, seed, "position"),
    "motor warming, position loop": lambda seed: _loop(_warming, seed, "position"),
}
#: class name -> ``((a_low, a_high), (b_low, b_high))``: the range the plant's ``a`` and ``b`` span (every other class:
#: ``A`` and ``B``).
LOOP_TRUTH: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "forward gain 15 % above reverse, position loop": ((A, A), (B, ASYMMETRY * B)),
    "gain sagging with the duty, speed loop": ((A, A), ((1 - SAG) * B, B)),
    "motor warming, position loop": (((1 - WARMING) * A, A), ((1 - WARMING) * B, B)),
}
