"""Whether the torque a disturbance model calls a load follows the input: then it is no load.

Where no output-error model answers an open-loop run, the default fits ``pem-disturbance``, whose torque
disturbance is a state that follows whatever torque changes over the run (a load switched on, a drag that comes
and goes).  It follows a misfit of the drive just as readily: a driver that clips the duty or limits its current
takes torque away exactly when the input is large, and the disturbance hands it back, so ``b`` comes out the gain
of the small inputs with an interval that knows nothing of the large ones.

A load does not know the input.  :func:`disturbance_follows_input` takes the torque the answer leaves
unexplained, in the integrated form of ``dω/dt = -a ω + b u + τ(t)`` over windows of :data:`WINDOW` samples,

    ``∫τ = Δω + a Δθ - b h Σ u``

(the angle and the logged input as regressors, the speed's noise on the left; a speed differenced from the angle
is taken half a sample earlier, where it is the speed), and fits it by a torque that is
constant over each of :data:`TIME_BLOCKS` stretches of the run (any load that changes slower than that) plus a
change of gain ``δb u`` and a curve of it ``c |u| u / U`` (``U`` the largest input).  Where the two input
columns are not zero (Wald test with the Newey--West covariance, level :data:`FOLLOW_LEVEL`) and the gain they
imply at a small or the full input differs from ``b`` by more than
:data:`~identify.default.comparison.MATERIAL`, the disturbance follows the input: the answer is not clear, and
``b``'s interval is widened to hold those gains.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
from scipy import special

from motorsim.recording import Recording

from ..checks.angle_turns import recorded_angle, whole_windows
from ..checks.uncertainty import newey_west_covariance
from ..comparison import MATERIAL
from ..estimate import Estimate

__all__ = ["disturbance_follows_input", "InputFollowing", "WINDOW", "TIME_BLOCKS", "FOLLOW_LEVEL"]

#: Samples per window of the integrated form (as in :mod:`identify.checks.angle_turns`).
WINDOW = 8
#: Stretches of the run over each of which a load is let be any constant.
TIME_BLOCKS = 10
#: Level of the Wald test that the disturbance holds no share of the input.
FOLLOW_LEVEL = 0.01


class InputFollowing(NamedTuple):
    """What :func:`disturbance_follows_input` found: the test's p-value and the gains at a small and the full input."""

    p_value: float
    small_gain: float
    full_gain: float
    follows: bool


def _rows(rec: Recording, a: float, b: float, delay: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The windows' unexplained torque integrals and their design columns (``Σu h``, ``Σ|u|u/U h``, per block
    ``Σh``), or None where too few windows are whole."""
    theta = recorded_angle(rec)
    n = len(rec)
    if theta is None or n < 4 * WINDOW or not np.all(np.isfinite(theta)):
        return None
    w = np.asarray(rec.measured_speed(), dtype=float)
    u = np.asarray(rec.duty, dtype=float)
    u = np.r_[np.zeros(delay), u[:n - delay]] if delay else u
    top = float(np.max(np.abs(u)))
    if top == 0:
        return None
    h = np.r_[np.diff(rec.time), 0.0]
    block = np.minimum((np.arange(n) * TIME_BLOCKS) // n, TIME_BLOCKS - 1)
    cols = np.column_stack([u * h, np.abs(u) * u / top * h] + [h * (block == j) for j in range(TIME_BLOCKS)])
    sums = np.vstack([np.zeros(cols.shape[1]), np.cumsum(cols, axis=0)])[:n]
    if rec.speed is None:
        # a speed differenced from the angle is the mean over the interval before its row, the speed half a sample
        # earlier: the angle and the sums are taken there too (else the window's torque holds h/2 of dω/dt, which
        # follows the input)
        theta = np.r_[theta[0], 0.5 * (theta[1:] + theta[:-1])]
        sums = sums - 0.5 * np.vstack([np.zeros(cols.shape[1]), cols[:-1]])
    starts, ends, keep = whole_windows(rec.seq, w, 1, WINDOW)
    if int(keep.sum()) < 10 * cols.shape[1]:
        return None
    s, e = starts[keep], ends[keep]
    design = sums[e] - sums[s]
    torque = (w[e] - w[s]) + a * (theta[e] - theta[s]) - b * design[:, 0]
    return torque, design


def disturbance_follows_input(recs: Sequence[Recording], est: Estimate) -> InputFollowing | None:
    """Whether ``est``'s unexplained torque follows the input (module docstring); None where it cannot be judged."""
    a, b = float(est.a), float(est.b)
    found = [f for f in (_rows(r, a, b, int(est.input_delay)) for r in recs) if f is not None]
    if not found or not (math.isfinite(a) and math.isfinite(b)) or b == 0:
        return None
    torque = np.concatenate([f[0] for f in found])
    design = _stacked(found)
    present = np.any(design != 0, axis=0)
    present[:2] = True
    design = design[:, present]
    coef, *_ = np.linalg.lstsq(design, torque, rcond=None)
    resid = torque - design @ coef
    lag = int(min(max(4 * (len(torque) / 100) ** (2 / 9), 1), len(torque) / 10))
    cov = newey_west_covariance(design, resid, 2, lag)
    if not np.all(np.isfinite(cov)):
        return None
    beta = coef[:2]
    try:
        wald = float(beta @ np.linalg.solve(cov, beta))
    except np.linalg.LinAlgError:
        return None
    p = float(special.chdtrc(2, wald))        # chi-square survival, without importing scipy.stats
    small, full = b + float(beta[0]), b + float(beta[0] + beta[1])
    material = max(abs(small - b), abs(full - b)) > MATERIAL * abs(b)
    return InputFollowing(p, small, full, p < FOLLOW_LEVEL and material)


def _stacked(found: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The recordings' designs one under the other, each with its own time blocks (a load of its own run)."""
    blocks = sum(f[1].shape[1] - 2 for f in found)
    out, col = [], 0
    for _, d in found:
        k = d.shape[1] - 2
        part = np.zeros((len(d), 2 + blocks))
        part[:, :2] = d[:, :2]
        part[:, 2 + col:2 + col + k] = d[:, 2:]
        out.append(part)
        col += k
    return np.vstack(out)
