"""Recordings made the way real rigs make them, for the screens that judge real files.

Each writer copies what a kind of real recording has and a clean simulation lacks, stated in its
docstring: a lab's coarse encoder read on a jittered clock and differenced to a speed, commutator
ripple, a speed estimate's start-up, a robot loop's jitter and the pauses between SysId tests.
The plant under them is known exactly, so a test can say both "accepted" and "right".
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from motorsim import Motor
from motorsim.plant import simulate

__all__ = ["lab_run", "write_lab_csv", "sysid_tests", "write_sysid_wpilog", "LAB_A", "LAB_B", "LAB_VOLTS"]

#: The lab motor: a in 1/s, b in (rad/s^2)/V, its supply in V (steady speed 12 V x b/a = 204 rad/s).
LAB_A, LAB_B, LAB_VOLTS = 12.0, 200.0, 12.0


def lab_run(volts: np.ndarray, *, dt: float = 1e-3, counts_per_rev: int = 1000, clock_jitter: float = 5e-5,
            ripple: float = 0.03, startup: bool = False, initial_speed: float = 0.0,
            seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and measured speed (rad/s) of the lab motor under ``volts``, as a lab's logger gives them.

    The speed is what a 1 kHz logger computes from a 1000-count encoder: the counts read at instants
    that jitter by ``clock_jitter`` s (a task woken late), differenced and divided by the interval the
    logger measured, so it moves in steps of about 2 pi / (N h) = 6.3 rad/s, a count or two either way;
    the shaft carries commutator ripple of ``ripple`` of its speed at 7 times the rotation (a
    7-slot armature).  ``startup``: the speed's first two values are the differencing's start-up
    (the counter's value before the run taken as zero: a whole turn in the first sample, half of it
    in the second, as a speed filter initialised at rest leaves them).
    """
    rng = np.random.default_rng(seed)
    n = len(volts)
    t = np.arange(n) * dt
    read = t + rng.uniform(0, clock_jitter, n)
    traj = simulate(Motor(LAB_A, LAB_B), volts, t, initial_speed=initial_speed)
    angle = np.interp(read, t, traj.angle)
    angle = angle + ripple / 7 * np.sin(7 * angle)            # position-dependent speed ripple
    counts = np.floor(angle * counts_per_rev / (2 * math.pi))
    speed = np.r_[0.0, np.diff(counts) * 2 * math.pi / counts_per_rev / np.diff(read)]
    if startup:
        speed[1:3] += np.array([0.3, 0.15]) * LAB_B / LAB_A * LAB_VOLTS
    return t, speed


def write_lab_csv(path: Path, volts: np.ndarray, *, time_unit: str = "s", **kwargs) -> Path:
    """``lab_run`` as a lab's CSV: ``time,voltage,speed_rad_s`` (time in ``time_unit``: s or ms)."""
    t, speed = lab_run(volts, **kwargs)
    scale = {"s": 1.0, "ms": 1e3}[time_unit]
    rows = "\n".join(f"{scale * ti:.6f},{u:.4f},{w:.6f}" for ti, u, w in zip(t, volts, speed))
    path.write_text("time,voltage,speed_rad_s\n" + rows + "\n")
    return path


# --- SysId on a robot -------------------------------------------------------------------------------

#: The FRC flywheel: a in 1/s, b in (rad/s^2)/V (kV = a/b = 0.12 V/(rad/s), kA = 1/b = 0.015 V/(rad/s^2)).
FLY_A, FLY_B, FLY_KS = 8.0, 1 / 0.015, 0.0


def sysid_tests(*, period: float = 0.005, jitter: float = 1e-3, pause: float = 3.0, seed: int = 0
                ) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """SysId's four tests on the flywheel, as a robot loop logs them: ``(name, time s, volts, speed rad/s)``.

    Quasistatic ramps of 1 V/s for 8 s and dynamic steps of 7 V for 2.5 s, forward and reverse,
    ``pause`` s apart (the robot disabled in between, the wheel coasting down to rest); the loop
    wakes every ``period`` s late by up to ``jitter`` s (uniform), and each row holds the voltage
    applied since the previous row and the speed measured at its own instant.
    """
    rng = np.random.default_rng(seed)
    motor = Motor(FLY_A, FLY_B)
    out = []
    start = 1.0
    for name, length, law in (("quasistatic-forward", 8.0, lambda s: 1.0 * s),
                              ("quasistatic-reverse", 8.0, lambda s: -1.0 * s),
                              ("dynamic-forward", 2.5, lambda s: 7.0 + 0 * s),
                              ("dynamic-reverse", 2.5, lambda s: -7.0 + 0 * s)):
        k = np.arange(int(round(length / period)))
        t = k * period + rng.uniform(0, jitter, len(k))
        t[0] = 0.0
        u = np.round(law(t), 4)
        traj = simulate(motor, u, t)
        speed = traj.speed + rng.normal(0, 0.05, len(k))      # 0.05 rad/s of measurement noise
        out.append((name, start + t, u, speed))
        start += length + pause
    return out


def write_sysid_wpilog(path: Path, **kwargs) -> Path:
    """:func:`sysid_tests` as ``SysIdRoutineLog`` writes them (wpiutil's own writer): the state entry,
    ``voltage-drive`` in Volt, ``velocity-drive`` in Rotation per Second, ``position-drive``."""
    import wpiutil
    from wpiutil.log import DoubleLogEntry, StringLogEntry
    log = wpiutil.DataLogWriter(str(path))
    us = lambda s: int(round(1e6 * s))                        # noqa: E731
    state = StringLogEntry(log, "sysid-test-state-drive", us(0.5))
    volts = DoubleLogEntry(log, "voltage-drive", "Volt", us(0.5))
    position = DoubleLogEntry(log, "position-drive", "Rotation", us(0.5))
    velocity = DoubleLogEntry(log, "velocity-drive", "Rotation per Second", us(0.5))
    state.append("none", us(0.5))
    angle = 0.0
    for name, t, u, speed in sysid_tests(**kwargs):
        state.append(name, us(t[0]))
        for k in range(len(t)):
            angle += speed[k] * (t[k] - t[k - 1]) if k else 0.0
            volts.append(float(u[k]), us(t[k]))
            position.append(angle / (2 * math.pi), us(t[k]))
            velocity.append(float(speed[k]) / (2 * math.pi), us(t[k]))
        state.append("none", us(t[-1] + 0.01))
    log.flush()
    log.stop()
    return path
