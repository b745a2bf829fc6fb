"""Model quality: simulate an identified model on a recording and score it."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.plant import Motor, simulate
from motorsim.recording import Recording
from motorsim.sensors import backward_difference

__all__ = ["nrmse_fit", "simulated_speed", "fit_percent"]


def nrmse_fit(measured, simulated) -> float:
    """NRMSE fit in %: ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)``.

    Parameters
    ----------
    measured, simulated : array_like
        ``y`` and ``y_sim``, same shape; pairs with a nan in either are skipped.
    """
    y = np.asarray(measured, dtype=float)
    ys = np.asarray(simulated, dtype=float)
    if y.shape != ys.shape:
        raise ValueError(f"measured and simulated must have equal shapes, got {y.shape} and {ys.shape}")
    ok = np.isfinite(y) & np.isfinite(ys)
    if ok.sum() < 2:
        return math.nan
    y, ys = y[ok], ys[ok]
    spread = np.linalg.norm(y - y.mean())
    if spread == 0:
        return math.nan
    return float(100.0 * (1.0 - np.linalg.norm(y - ys) / spread))


def simulated_speed(a: float, b: float, recording: Recording, *, input_delay: int = 0) -> np.ndarray:
    """Measured-comparable speed of the model ``b/(s+a)`` on each gap-free segment.

    The model is simulated exactly (ZOH) from the measured speed at the segment's
    second sample, and its angle is differenced like the encoder's, so the result
    is the model's average speed over each interval (``nan`` where the measurement is).

    Parameters
    ----------
    a, b : float
        The model.
    recording : Recording
        Supplies the duty, the time and the measured initial speed of each segment.
    input_delay : int
        Samples of input delay of the model.
    """
    out = np.full(len(recording), np.nan)
    start = 0
    motor = Motor(a, b, input_delay=input_delay) if a > 0 and b != 0 and math.isfinite(a) and math.isfinite(b) else None
    for seg in recording.segments():
        n = len(seg)
        if motor is not None and n >= 3:
            measured = seg.speed_rad_s()
            traj = simulate(motor, seg.duty[1:], seg.time[1:], initial_speed=float(measured[1]),
                            duty_before=float(seg.duty[0]))
            out[start + 2:start + n] = backward_difference(traj.angle, seg.time[1:])[1:] \
                if seg.speed is None else traj.speed[1:]
        start += n
    return out


def fit_percent(a: float, b: float, recordings: Sequence[Recording], *, input_delay: int = 0) -> float:
    """NRMSE fit (%) of the model's simulated speed against the measured speed, pooled.

    Parameters
    ----------
    a, b : float
        The model.
    recordings : sequence of Recording
        Pooled.
    input_delay : int
        Samples of input delay of the model.
    """
    meas = np.concatenate([r.speed_rad_s() for r in recordings])
    sim = np.concatenate([simulated_speed(a, b, r, input_delay=input_delay) for r in recordings])
    return nrmse_fit(meas, sim)
