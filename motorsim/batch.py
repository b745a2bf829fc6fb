"""The bench simulated for many repetitions at once: one row of a 2-D array per repetition.

What a scenario sweep (:mod:`scenarios.sweep`) runs instead of one :class:`~motorsim.rig.SimRig`
run per repetition when the setting allows it:

* the plant is the exact ZOH model of ``Motor(a, b).discretise(dt)`` (the same
  matrices ``control.sample_system`` computes, here in closed form from
  :func:`motorsim.plant.zoh_matrices`), run along the rows by
  ``scipy.signal.lfilter`` (speed) and a cumulative sum (angle);
* the encoder floors ``(angle + noise) counts_per_rev / 2 pi`` like
  :class:`motorsim.sensors.Encoder`, with each row's noise drawn from that row's
  own generator, so a row equals ``SimRig(...).run(...)`` with the same generator;
* speed is the backward difference of the counts (``motorsim.recording``'s alignment).

Only what the engine runs exactly is batchable (:func:`is_batchable`): the first-order motor
``b/(s + a)`` with a dead zone and an input delay (static maps of the known duty), uniform and
complete samples.  Anything else the plant carries (Coulomb or static friction, a bias, an
electrical lag, or a part added later) is refused, never dropped: the sweep then runs the setting
one repetition at a time through the exact simulator.  The estimators that fit these rows at
once are :mod:`identify.fits.batch`'s.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .checks import ParameterError, ParameterTypeError
from .plant import Motor, Plant, delayed_duty, zoh_matrices

__all__ = ["is_batchable", "unbatchable_parts", "BATCHED_PARTS", "simulate_batch", "encoder_counts_batch",
           "speed_batch"]


#: The parts of a :class:`~motorsim.plant.Motor` the batch engine runs exactly; every other field must be at
#: its neutral default, so a part the engine does not know (one added to ``Motor`` later too) is refused.
BATCHED_PARTS = frozenset({"a", "b", "dead_zone", "input_delay"})


def unbatchable_parts(motor: Plant) -> list[str]:
    """The fields of ``motor`` the batch engine cannot run (set away from their neutral default), in field order;
    a plant of another structure than the first-order motor's is refused whole (its type's name first)."""
    other = [] if isinstance(motor, Motor) else [type(motor).__name__]
    return other + [f.name for f in dataclasses.fields(motor)  # type: ignore[arg-type]
                    if f.name not in BATCHED_PARTS and getattr(motor, f.name) != f.default]


def is_batchable(motor: Plant, *, jitter: float = 0.0, drop_rate: float = 0.0) -> bool:
    """True when a setting can go through the batch engine exactly: a first-order plant (a dead zone and an
    input delay allowed, nothing else, :func:`unbatchable_parts`), uniform and complete samples."""
    return not unbatchable_parts(motor) and jitter == 0 and drop_rate == 0


def simulate_batch(motor: Plant, duty: np.ndarray, sample_period: float, *,
                   initial_speed: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH simulation of every row of ``duty`` at once.

    Parameters
    ----------
    motor : Plant
        A first-order plant (:func:`is_batchable`; any other refused by name); dead zone and delay are applied.
    duty : ndarray, shape (n_samples,) or (repetitions, n_samples)
        Duty of each run; ``duty[..., k]`` is held from sample k to k+1.
    sample_period : float
        Uniform sample period in s.
    initial_speed : float
        Speed at the first sample, rad/s (angle starts at 0).

    Returns
    -------
    angle, speed : ndarray, same shape as ``duty``
        Angle in rad and speed in rad/s at the sample instants.

    Notes
    -----
    ``speed[k+1] = e speed[k] + g v[k]`` and ``angle[k+1] = angle[k] + p speed[k] + q v[k]``
    with ``e = exp(-a dt)``, ``g = (b/a)(1 - e)``, ``p = (1 - e)/a``, ``q = (b/a)(dt - p)``,
    the entries of the ZOH-discretised state-space model; the angle recursion sums in
    closed form to ``angle[k] = (speed[0] - speed[k])/a + (b dt/a) sum_{j<k} v[j]``.
    """
    if not isinstance(motor, Plant):
        raise ParameterTypeError(f"motor must be a plant (a Motor), got {type(motor).__name__}")
    parts = unbatchable_parts(motor)
    if parts:
        said = ', '.join(f'{p} = {getattr(motor, p)!r}' if hasattr(motor, p) else f'a {p} plant' for p in parts)
        raise ParameterError(f"motor must be the first-order motor (with at most a dead zone and an input delay) for "
                             f"the batch engine, got {said}: simulate it run by run (motorsim.simulate)")
    assert isinstance(motor, Motor)             # unbatchable_parts refuses every other plant
    u = np.asarray(duty, dtype=float)
    if u.ndim not in (1, 2) or u.shape[-1] < 2:
        raise ParameterError(f"duty must have shape (n_samples,) or (repetitions, n_samples) with n_samples >= 2, "
                         f"got {u.shape}")
    if motor.input_delay or motor.dead_zone:
        u2 = np.atleast_2d(u)
        u = np.stack([motor.drive(delayed_duty(row, motor.input_delay, 0.0)) for row in u2]).reshape(u.shape)
    e, g, _, _ = (float(x) for x in zoh_matrices(motor.a, motor.b, sample_period))
    v = u[..., :-1]
    speed = np.empty(u.shape)
    angle = np.empty(u.shape)
    speed[..., 0] = initial_speed
    angle[..., 0] = 0.0
    zi = np.full(u.shape[:-1] + (1,), e * initial_speed)
    from scipy.signal import lfilter  # imported when used: it costs most of `import control`
    speed[..., 1:], _ = lfilter([g], [1.0, -e], v, axis=-1, zi=zi)
    # Summing angle[k+1] = angle[k] + p speed[k] + q v[k] with p = (1 - e)/a and
    # (1 - e) speed[k] = speed[k] - speed[k+1] + g v[k] telescopes to
    # angle[k] = (speed[0] - speed[k])/a + (b dt / a) sum_{j<k} v[j]  (exact; the sum of
    # integer duties is exact in floating point).
    np.cumsum(v, axis=-1, out=angle[..., 1:])
    angle[..., 1:] *= motor.b * sample_period / motor.a
    angle[..., 1:] += (initial_speed - speed[..., 1:]) / motor.a
    return angle, speed


def encoder_counts_batch(angle: np.ndarray, counts_per_rev: int, angle_noise: float = 0.0,
                         rngs=None) -> np.ndarray:
    """Encoder counts (as exact float integers) of each row of ``angle``.

    Row ``r`` gets noise ``rngs[r].normal(0, angle_noise, n_samples)``, the same draw
    :meth:`motorsim.sensors.Encoder.counts` makes with that generator.

    Parameters
    ----------
    angle : ndarray, shape (repetitions, n_samples)
        Angle in rad.
    counts_per_rev : int
        Counts per revolution.
    angle_noise : float
        Standard deviation of the angle noise in rad (0: none, ``rngs`` unused).
    rngs : sequence of numpy.random.Generator, optional
        One generator per row; required when ``angle_noise > 0``.
    """
    angle = np.atleast_2d(angle)
    if angle_noise > 0:
        if rngs is None or len(rngs) != angle.shape[0]:
            raise ParameterError(f"rngs must hold one Generator per repetition ({angle.shape[0]}) when angle_noise > 0")
        noisy = np.empty(angle.shape)
        for r, rng in enumerate(rngs):
            noisy[r] = angle[r] + rng.normal(0.0, angle_noise, angle.shape[1])
        angle = noisy
    else:
        angle = angle.copy()
    angle *= counts_per_rev / (2.0 * math.pi)
    return np.floor(angle, out=angle)


def speed_batch(counts: np.ndarray, counts_per_rev: int, sample_period: float) -> np.ndarray:
    """Backward-differenced speed in rad/s of each row (``nan`` in column 0), as ``Recording.speed_rad_s``
    computes it (to rounding: here from exact count differences and the nominal period)."""
    speed = np.empty(counts.shape)
    speed[..., 0] = np.nan
    # Differences of integer counts are exact; one product per sample then rounds once.
    np.subtract(counts[..., 1:], counts[..., :-1], out=speed[..., 1:])
    speed[..., 1:] *= 2.0 * math.pi / (counts_per_rev * sample_period)
    return speed
