"""Reference trajectories from integrators that are not the estimators' own closed form.

``expm_trajectory`` steps ``[angle, speed, 1]`` with ``scipy.linalg.expm`` of the
augmented matrix over each (possibly jittered) interval, with an optional constant
acceleration ``bias``; ``control_trajectory`` uses python-control's ZOH
discretisation and ``forced_response`` (uniform time); ``quantised_recording``
floors an angle to encoder counts and wraps it in a Recording.  The tests get this
module from the ``reference`` fixture (``conftest.py``), which loads it by path.
"""
import math

import control
import numpy as np
from scipy.linalg import expm

from motorsim.recording import Recording

__all__ = ["expm_trajectory", "control_trajectory", "quantised_recording"]


def expm_trajectory(a, b, duty, time, *, initial_speed=0.0, bias=0.0):
    """Angle (rad) and speed (rad/s) at ``time`` with ``duty[k]`` held on [time[k], time[k+1])."""
    n = len(time)
    x = np.array([0.0, initial_speed])
    angle, speed = np.zeros(n), np.zeros(n)
    speed[0] = initial_speed
    for k in range(n - 1):
        m = np.zeros((3, 3))
        m[0, 1] = 1.0
        m[1, 1] = -a
        m[1, 2] = b * duty[k] + bias
        x = (expm(m * (time[k + 1] - time[k])) @ np.array([x[0], x[1], 1.0]))[:2]
        angle[k + 1], speed[k + 1] = x
    return angle, speed


def control_trajectory(a, b, duty, sample_period, *, initial_speed=0.0):
    """The same on a uniform clock with python-control (``sample_system`` + ``forced_response``)."""
    sys = control.sample_system(control.ss([[0, 1], [0, -a]], [[0], [b]], np.eye(2), np.zeros((2, 1))),
                                sample_period, "zoh")
    out = control.forced_response(sys, U=np.asarray(duty, float), X0=[0.0, initial_speed]).outputs
    return out[0], out[1]


def quantised_recording(angle, duty, time, sample_period, counts_per_rev, *, seq=None, offset=12345,
                        metadata=None):
    """A Recording of floored counts (plus an arbitrary encoder offset)."""
    counts = np.floor(np.asarray(angle) * counts_per_rev / (2 * math.pi)).astype(np.int64) + offset
    keep = slice(None) if seq is None else seq
    return Recording(time=np.asarray(time)[keep], duty=np.asarray(duty)[keep], sample_period=sample_period,
                     counts=counts[keep], counts_per_rev=counts_per_rev,
                     seq=None if seq is None else np.asarray(seq), metadata=metadata or {})
