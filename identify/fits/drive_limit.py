"""``oe-drive-limit``: output error of the motor behind a driver that clips the duty it is sent.

The structure (:class:`identify.model_structures.drive_map.DriveLimit`) is
``d omega/dt = -a omega + b clip(u, -L, L) + d``: the linear motor driven by the clipped duty, so its fit is
:func:`identify.fits.asymmetry.fit_mapped`'s Gauss--Newton on ``(a, b, L, d)`` with the drive map ``b clip(u, L)``
(derivatives ``clip(u, L)`` and ``b sign(u)`` where ``|u| > L``).  The cost is not smooth in ``L`` where it crosses a
level the duty takes, so the fit starts from several limits (quantiles of ``|u|``) and keeps the best.

The default fits it only where its answer's low / high drive part check finds the gain materially lower at high
drive (:mod:`identify.default.evidence`).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

from ..data import DEFAULT_INPUT_DELAY, prepare_segments
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from .asymmetry import MappedFit, fit_mapped
from .oe_common import linear_start

__all__ = ["fit_output_error_drive_limit", "clipping", "STRUCTURE", "START_QUANTILES"]

#: The structure's name.
STRUCTURE = "drive-limit"
#: Quantiles of the drive's magnitude (non-zero samples) the limit starts from.
START_QUANTILES = (0.5, 0.7, 0.85, 0.95)


def clipping(u: np.ndarray, gains: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The drive map ``b clip(u, -L, L)`` (``gains = (b, L)``) and its derivatives by ``b`` and ``L``."""
    b, limit = float(gains[0]), float(gains[1])
    c = np.clip(u, -limit, limit)
    return b * c, [c, b * np.where(np.abs(u) > limit, np.sign(u), 0.0)]


def _valid(theta: np.ndarray) -> bool:
    return bool(theta[0] > 0 and theta[2] > 0)


def _fit(recs: list[Recording], delay: int, a: float, b: float, bias: float, covariance: str = "auto") -> Estimate:
    """The fit at ``delay``, started from ``a``, ``b``, ``bias`` and each of :data:`START_QUANTILES`' limits."""
    drive = np.abs(np.concatenate([s.drive for s in prepare_segments(recs, delay)] or [np.zeros(0)]))
    moving = drive[drive > 0]
    if len(np.unique(moving)) < 3:
        raise NotIdentifiableError("a drive limit needs a drive of several magnitudes, got at most two: run at "
                                   "several amplitudes (a sine or a multisine)")
    best: MappedFit | None = None
    for q in START_QUANTILES:
        limit = float(np.quantile(moving, q))
        start = np.array([a, b * float(np.mean(moving)) / float(np.mean(np.minimum(moving, limit))), limit, bias])
        try:
            found = fit_mapped(recs, delay, start, clipping, "a drive limit", _valid, covariance)
        except (NotIdentifiableError, ValueError, ArithmeticError, np.linalg.LinAlgError):
            continue
        if best is None or found.rss < best.rss:
            best = found
    if best is None:
        raise NotIdentifiableError("no fit with a drive limit converged: the data do not show one")
    a, b, limit, d = (float(x) for x in best.theta)
    return Estimate(method="oe-drive-limit", a=a, b=b, n_samples=best.n_samples, sample_period=recs[0].sample_period,
                    residual_rms=math.sqrt(best.rss / best.n_samples), fit_percent=best.fit_percent,
                    covariance=best.covariance, param_names=("a", "b", "drive_limit", "bias"),
                    extra={"drive_limit": limit, "bias": d, "input_delay": delay}, residual_unit=best.residual_unit,
                    input_unit=recs[0].input_unit, input_limit=recs[0].input_limit, structure=STRUCTURE,
                    covariance_method=best.covariance_method)


def fit_output_error_drive_limit(recordings: Recording | Sequence[Recording], *,
                                 input_delay: int | str = DEFAULT_INPUT_DELAY, covariance: str = "auto") -> Estimate:
    """Output-error fit of the motor behind a driver that clips the duty at ``drive_limit`` (``oe-drive-limit``).

    ``d omega/dt = -a omega + b clip(u, -drive_limit, drive_limit) + d`` (module docstring), exact under the
    zero-order hold, on the encoder angle (or the speed column).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled: one set of parameters, an initial speed (and angle offset) per gap-free segment; the drive must take
        several magnitudes.
    input_delay : int or "auto"
        Whole samples, or ``"auto"`` (default): the delay ``oe`` with a bias chooses.
    covariance : {"auto", "gauss-newton"}
        As :func:`identify.fits.asymmetry.fit_output_error_asymmetric`'s.

    Returns
    -------
    Estimate
        Structure ``drive-limit``: ``a``, ``b`` (the gain below the limit), ``extra`` ``drive_limit`` (input units)
        and ``bias``; the covariance over ``("a", "b", "drive_limit", "bias")``.

    Raises
    ------
    NotIdentifiableError
        Too short, a drive of one or two magnitudes, or no fit converged.

    Examples
    --------
    A driver that delivers at most 150 of a duty commanded up to 200, noise-free:

    >>> import numpy as np
    >>> from identify import fit
    >>> from identify.model_structures import structure
    >>> from motorsim import Recording
    >>> t = np.arange(3000) * 0.005
    >>> duty = np.round(170 * np.sin(10 * t) + 30 * np.sin(53 * t)).astype(int)
    >>> truth = {"a": 25.0, "b": 3.0, "drive_limit": 150.0, "bias": 0.0}
    >>> angle = structure("drive-limit").response(truth, duty, t).angle
    >>> est = fit(Recording(time=t, duty=duty, sample_period=0.005, angle=angle), "oe-drive-limit", input_delay=0)
    >>> print(f"a = {est.a:.6f}, b = {est.b:.6f}, limit {est.extra['drive_limit']:.6f}")
    a = 25.000000, b = 3.000000, limit 150.000000
    """
    recs, delay, start = linear_start(recordings, input_delay, covariance, 4)
    return _fit(recs, delay, start.a, start.b, float(start.extra.get("bias", 0.0)), covariance)
