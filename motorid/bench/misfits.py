"""Plants one step past every registered structure, for ``motorid bench coverage``.

Each maker integrates a motor ``dω/dt = -a ω + b u`` (``a`` = :data:`A`, ``b`` = :data:`B` where the plant
has one value) with one thing no registered structure describes — a driver that limits its current, a load
switched on partway, a duty clipped below the one logged, friction that weakens with speed, forward and
reverse gains that differ, a motor warming over the run, a speed column timed between encoder edges, a
gearbox's backlash, cogging torque, an arm lifted against gravity, a slow quasi-static ramp — and records
what a bench would: the logged duty held over each sample, encoder counts (or the speed column a firmware
prints).

The integration is classical Runge--Kutta on :data:`SUBSTEPS` sub-steps of every sample (the duty held
over the sample, as the bench holds it), which is exact to far below the encoder's resolution for these
smooth forces (the Stribeck friction is smoothed over 0.05 rad/s).  The default's answer on these plants
can be right only by luck of the structure; what ``motorid bench coverage`` asks of it is to be right or
not clear (:data:`TRUTH` gives each plant's ``a`` and ``b``, a range where they drift or differ by
direction).
"""
from __future__ import annotations

import functools
import math
from typing import Callable, NamedTuple, Tuple

import numpy as np

__all__ = ["MISFITS", "TRUTH", "SUBSTEPS", "A", "B", "random_rig", "RANDOM_KINDS"]

#: The motor's own ``a`` (1/s) and ``b`` ((rad/s^2)/duty).
A, B = 25.0, 3.0
#: Runge--Kutta sub-steps per sample.
SUBSTEPS = 8

Accel = Callable[[float, float, float, float], float]


def _integrate(accel: Accel, duty: np.ndarray, h: float, substeps: int = SUBSTEPS) -> tuple[np.ndarray, np.ndarray]:
    """Angle and speed at every sample of ``dθ/dt = ω, dω/dt = accel(t, θ, ω, u)``, ``u`` held over each sample,
    from rest at 0."""
    n = len(duty)
    theta = np.zeros(n)
    omega = np.zeros(n)
    th = w = 0.0
    dt = h / substeps
    for k in range(n - 1):
        u = float(duty[k])
        t = k * h
        for _ in range(substeps):
            k1t, k1w = w, accel(t, th, w, u)
            k2t, k2w = w + 0.5 * dt * k1w, accel(t + 0.5 * dt, th + 0.5 * dt * k1t, w + 0.5 * dt * k1w, u)
            k3t, k3w = w + 0.5 * dt * k2w, accel(t + 0.5 * dt, th + 0.5 * dt * k2t, w + 0.5 * dt * k2w, u)
            k4t, k4w = w + dt * k3w, accel(t + dt, th + dt * k3t, w + dt * k3w, u)
            th += dt * (k1t + 2 * k2t + 2 * k3t + k4t) / 6
            w += dt * (k1w + 2 * k2w + 2 * k3w + k4w) / 6
            t += dt
        theta[k + 1] = th
        omega[k + 1] = w
    return theta, omega


def _multisine_duty(time: np.ndarray, seed: int, frequencies=(3.0, 11.0, 37.0, 90.0),
                    amplitudes=(60, 55, 45, 40)) -> np.ndarray:
    """An integer multisine duty, its phases drawn from ``seed``."""
    phases = np.random.default_rng(10_000 + seed).uniform(0, 2 * np.pi, len(frequencies))
    u = sum(a * np.sin(w * time + p) for w, a, p in zip(frequencies, amplitudes, phases))
    return np.round(np.asarray(u)).astype(np.int64)


def _steps_duty(time: np.ndarray, seed: int, hold: float = 0.25) -> np.ndarray:
    """Random duty levels among +-60...220, each held ``hold`` s: steps and reversals."""
    rng = np.random.default_rng(20_000 + seed)
    levels = rng.integers(60, 221, size=int(time[-1] / hold) + 2) * rng.choice([-1, 1], size=int(time[-1] / hold) + 2)
    return levels[(time / hold).astype(int)].astype(np.int64)


def _record(time, duty, theta, seed: int, counts_per_rev: int, angle_noise: float = 1e-4, metadata=None):
    """Encoder counts of ``theta`` (Gaussian angle noise, floored), as the bench's recordings hold them."""
    from motorsim import Recording
    rng = np.random.default_rng(seed)
    noisy = theta + rng.normal(0.0, angle_noise, len(theta))
    counts = np.floor(noisy * counts_per_rev / (2 * np.pi)).astype(np.int64)
    return Recording(time=time, duty=duty, sample_period=float(time[1] - time[0]), counts=counts,
                     counts_per_rev=counts_per_rev, metadata=metadata or {})


def _run(accel: Accel, duty_of: Callable, seed: int, h: float, duration: float, counts_per_rev: int):
    time = np.arange(int(round(duration / h))) * h
    duty = duty_of(time, seed)
    theta, _ = _integrate(accel, duty, h)
    return _record(time, duty, theta, seed, counts_per_rev)


def current_limit(seed: int):
    """A driver that limits its current: the electrical torque ``b u - 0.8 a ω`` (back-EMF's share of ``a``)
    clipped at 700 rad/s^2, active at steps and reversals; random steps, 2 ms, 2048 counts, 8 s."""
    def accel(t, th, w, u):
        return min(max(B * u - 0.8 * A * w, -700.0), 700.0) - 0.2 * A * w
    return _run(accel, _steps_duty, seed, 0.002, 8.0, 2048)


def load_switched_on(seed: int):
    """A constant load torque of 120 rad/s^2 switched on halfway through a multisine; 1 ms, 1000 counts, 8 s."""
    def accel(t, th, w, u):
        return -A * w + B * u - (120.0 if t >= 4.0 else 0.0)
    return _run(accel, _multisine_duty, seed, 0.001, 8.0, 1000)


def clipped_duty(seed: int):
    """The driver clips the duty at +-150 where the file logs up to +-200: a sine of 10 rad/s with a faster one
    on top; 5 ms, 4096 counts, 10 s."""
    def duty_of(time, seed):
        phase = np.random.default_rng(30_000 + seed).uniform(0, 2 * np.pi)
        return np.round(170 * np.sin(10 * time + phase) + 30 * np.sin(53 * time)).astype(np.int64)

    def accel(t, th, w, u):
        return -A * w + B * min(max(u, -150.0), 150.0)
    return _run(accel, duty_of, seed, 0.005, 10.0, 4096)


def stribeck(seed: int):
    """Friction that weakens with speed: 40 rad/s^2 sliding, 100 at rest (Stribeck speed 3 rad/s), smoothed over
    0.05 rad/s; a sine of 5 rad/s, amplitude 200, with a faster one on top; 5 ms, 1000 counts, 8 s."""
    def duty_of(time, seed):
        phase = np.random.default_rng(40_000 + seed).uniform(0, 2 * np.pi)
        return np.round(170 * np.sin(5 * time + phase) + 30 * np.sin(41 * time)).astype(np.int64)

    def accel(t, th, w, u):
        return -A * w + B * u - (40.0 + 60.0 * math.exp(-(w / 3.0) ** 2)) * math.tanh(w / 0.05)
    return _run(accel, duty_of, seed, 0.005, 8.0, 1000)


#: Forward and reverse gains of :func:`asymmetric_gain`: forward 11 % above reverse, around :data:`B`.
B_FORWARD, B_REVERSE = B * 1.052, B / 1.055


def asymmetric_gain(seed: int):
    """The forward gain 11 % above the reverse one (driver or gearbox); multisine, 2 ms, 2000 counts, 8 s."""
    def accel(t, th, w, u):
        return -A * w + (B_FORWARD if u > 0 else B_REVERSE) * u
    return _run(accel, _multisine_duty, seed, 0.002, 8.0, 2000)


#: Drift of :func:`warming`: ``a`` and ``b`` fall by this share over the run.
WARMING = 0.05


def warming(seed: int):
    """The motor warming over 20 s: ``a`` and ``b`` fall linearly by 5 %; multisine, 5 ms, 1000 counts."""
    def accel(t, th, w, u):
        f = 1.0 - WARMING * t / 20.0
        return f * (-A * w + B * u)
    return _run(accel, _multisine_duty, seed, 0.005, 20.0, 1000)


def edge_timed_speed(seed: int):
    """A speed column as firmware prints it from the time between the last two encoder edges (360 counts, a
    20 MHz... 1 us timer; 0 when no edge came for 50 ms), no counts; multisine, 2 ms, 8 s."""
    from motorsim import Recording
    h, cpr = 0.002, 360
    time = np.arange(4000) * h
    duty = _multisine_duty(time, seed)
    sub = 40
    theta, _ = _integrate(lambda t, th, w, u: -A * w + B * u, np.repeat(duty, sub), h / sub, substeps=1)
    rng = np.random.default_rng(seed)
    counts = np.floor((theta + rng.normal(0, 1e-4, len(theta))) * cpr / (2 * np.pi)).astype(np.int64)
    fine_t = np.arange(len(theta)) * (h / sub)
    step = 2 * np.pi / cpr
    speed = np.zeros(len(time))
    last_edge, prev_edge, direction = -1.0, -1.0, 0.0
    for j in range(1, len(counts)):
        if counts[j] != counts[j - 1]:
            prev_edge, last_edge = last_edge, fine_t[j]
            direction = float(np.sign(counts[j] - counts[j - 1]))
        if j % sub == 0:
            k = j // sub
            fresh = last_edge >= 0 and prev_edge >= 0 and fine_t[j] - last_edge < 0.05
            speed[k] = round(direction * step / (last_edge - prev_edge), 3) if fresh else 0.0
    return Recording(time=time, duty=duty, sample_period=h, speed=speed)


def backlash(seed: int):
    """A gearbox's backlash of 0.02 rad between the motor and the encoder on the output (the output follows only
    once the play is taken up); a sine of 8 rad/s with a faster one, 2 ms, 4096 counts, 8 s."""
    def duty_of(time, seed):
        phase = np.random.default_rng(50_000 + seed).uniform(0, 2 * np.pi)
        return np.round(160 * np.sin(8 * time + phase) + 40 * np.sin(61 * time)).astype(np.int64)
    h = 0.002
    time = np.arange(4000) * h
    duty = duty_of(time, seed)
    theta, _ = _integrate(lambda t, th, w, u: -A * w + B * u, duty, h)
    out = np.empty_like(theta)
    y, play = 0.0, 0.02
    for k, x in enumerate(theta):
        y = min(max(y, x - play / 2), x + play / 2)
        out[k] = y
    return _record(time, duty, out, seed, 4096)


def cogging(seed: int):
    """Cogging torque of 40 rad/s^2 at 12 cycles per turn; multisine, 2 ms, 2048 counts, 8 s."""
    def accel(t, th, w, u):
        return -A * w + B * u - 40.0 * math.sin(12 * th)
    return _run(accel, _multisine_duty, seed, 0.002, 8.0, 2048)


def gravity_arm(seed: int):
    """An arm lifted against gravity: a torque of 80 sin(θ) rad/s^2; slow random steps, 2 ms, 2048 counts, 8 s."""
    def accel(t, th, w, u):
        return -A * w + B * u - 80.0 * math.sin(th)
    return _run(accel, functools.partial(_steps_duty, hold=0.4), seed, 0.002, 8.0, 2048)


def slow_ramp(seed: int):
    """A slow ramp of the duty, 0 to 200 over 20 s (4 % of full scale per second) as a lab's quasi-static test
    runs it, through Coulomb friction of 60 rad/s^2 (smoothed over 0.05 rad/s); a speed column with noise of
    0.2 rad/s, printed to 0.01, at 10 ms."""
    from motorsim import Recording
    h = 0.01
    time = np.arange(2000) * h
    duty = np.round(10.0 * time).astype(np.int64)

    def accel(t, th, w, u):
        return -A * w + B * u - 60.0 * math.tanh(w / 0.05)
    _, omega = _integrate(accel, duty, h, substeps=20)
    speed = np.round(omega + np.random.default_rng(seed).normal(0.0, 0.2, len(omega)), 2)
    return Recording(time=time, duty=duty, sample_period=h, speed=speed)


#: class name -> recording maker ``(seed) -> Recording``.
MISFITS: dict[str, Callable[[int], object]] = {
    "current limit at steps": current_limit,
    "load switched on halfway": load_switched_on,
    "driver clips the duty": clipped_duty,
    "friction weakening with speed": stribeck,
    "forward gain 11 % above reverse": asymmetric_gain,
    "motor warming over the run": warming,
    "speed timed between edges": edge_timed_speed,
    "gearbox backlash": backlash,
    "cogging torque": cogging,
    "arm against gravity": gravity_arm,
    "slow ramp through friction": slow_ramp,
}

#: class name -> ``((a_low, a_high), (b_low, b_high))``: the plant's ``a`` and ``b``, a range where they differ
#: along the run or by direction; every other class has ``a`` = :data:`A`, ``b`` = :data:`B`.
TRUTH: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "forward gain 11 % above reverse": ((A, A), (B_REVERSE, B_FORWARD)),
    "motor warming over the run": ((A * (1 - WARMING), A), (B * (1 - WARMING), B)),
}


def _random_duty(kind: str, time: np.ndarray, rng: np.random.Generator, amp: float) -> np.ndarray:
    """An integer duty of amplitude ``amp``: one sine of the article's 10-40 rad/s, a multisine, random steps, a
    binary PRBS or a chirp."""
    if kind == "sine":
        return np.round(amp * np.sin(rng.choice([10.0, 20.0, 30.0, 40.0]) * time + rng.uniform(0, 2 * np.pi))).astype(
            np.int64)
    if kind == "multisine":
        freqs, phases = rng.uniform(0.5, 80, 4), rng.uniform(0, 2 * np.pi, 4)
        x = sum(np.sin(f * time + p) for f, p in zip(freqs, phases))
        return np.round(amp * x / np.max(np.abs(x))).astype(np.int64)
    if kind in ("steps", "prbs"):
        hold = rng.uniform(0.1, 0.6) if kind == "steps" else rng.uniform(0.02, 0.2)
        n = int(time[-1] / hold) + 2
        levels = rng.integers(-int(amp), int(amp) + 1, n) if kind == "steps" else amp * rng.choice([-1, 1], n)
        return np.round(levels[(time / hold).astype(int)]).astype(np.int64)
    top = rng.uniform(30, 150)                # a chirp from 0.5 rad/s up
    return np.round(amp * np.sin(0.5 * time + (top - 0.5) * time ** 2 / (2 * time[-1]))).astype(np.int64)


class _Drawn(NamedTuple):
    """What :func:`random_rig` drew before the thing past the structures: the motor, the run and its input."""

    rng: np.random.Generator
    a: float
    b: float
    amp: float
    duration: float
    binary: bool

    @property
    def top_speed(self) -> float:
        return self.b * self.amp / self.a

    @property
    def level(self) -> float:
        """The magnitude of a binary input's duty (the amplitude rounded to a whole duty)."""
        return float(round(self.amp))


Misfit = Tuple[Accel, Tuple[float, float], Tuple[float, float]]


def _current_limit(d: _Drawn) -> Misfit:
    share, limit = d.rng.uniform(0.5, 0.95), d.rng.uniform(0.3, 0.8) * d.b * d.amp
    return (lambda t, th, w, u: min(max(d.b * u - share * d.a * w, -limit), limit) - (1 - share) * d.a * w,
            (d.a, d.a), (d.b, d.b))


def _load_switched_on(d: _Drawn) -> Misfit:
    on, load = d.rng.uniform(0.3, 0.7) * d.duration, d.rng.uniform(0.1, 0.4) * d.b * d.amp
    return lambda t, th, w, u: -d.a * w + d.b * u - (load if t >= on else 0.0), (d.a, d.a), (d.b, d.b)


def _clipped_duty(d: _Drawn) -> Misfit:
    clip = d.rng.uniform(0.6, 0.9) * d.amp
    gain = d.b * min(clip, d.level) / d.level if d.binary else d.b   # one magnitude: one gain, the clipped one
    return lambda t, th, w, u: -d.a * w + d.b * min(max(u, -clip), clip), (d.a, d.a), (gain, gain)


def _stribeck(d: _Drawn) -> Misfit:
    sliding = d.rng.uniform(0.05, 0.2) * d.b * d.amp
    rest, knee = sliding * d.rng.uniform(1.5, 3), d.rng.uniform(0.02, 0.2) * d.top_speed
    smooth = 0.002 * d.top_speed + 1e-3

    def accel(t, th, w, u):
        return -d.a * w + d.b * u - (sliding + (rest - sliding) * math.exp(-(w / knee) ** 2)) * math.tanh(w / smooth)
    return accel, (d.a, d.a), (d.b, d.b)


def _asymmetric(d: _Drawn) -> Misfit:
    ratio = d.rng.uniform(1.05, 1.25)
    forward, reverse = d.b * math.sqrt(ratio), d.b / math.sqrt(ratio)
    return lambda t, th, w, u: -d.a * w + (forward if u > 0 else reverse) * u, (d.a, d.a), (reverse, forward)


def _warming(d: _Drawn) -> Misfit:
    drift = d.rng.uniform(0.03, 0.10)
    return (lambda t, th, w, u: (1 - drift * t / d.duration) * (-d.a * w + d.b * u),
            (d.a * (1 - drift), d.a), (d.b * (1 - drift), d.b))


def _cogging(d: _Drawn) -> Misfit:
    torque, cycles = d.rng.uniform(0.05, 0.3) * d.b * d.amp, int(d.rng.integers(4, 24))
    return lambda t, th, w, u: -d.a * w + d.b * u - torque * math.sin(cycles * th), (d.a, d.a), (d.b, d.b)


def _gravity(d: _Drawn) -> Misfit:
    weight = d.rng.uniform(0.1, 0.5) * d.b * d.amp
    return lambda t, th, w, u: -d.a * w + d.b * u - weight * math.sin(th), (d.a, d.a), (d.b, d.b)


def _drag(d: _Drawn) -> Misfit:
    drag = d.rng.uniform(0.2, 1.0) * d.a / d.top_speed
    # a: the drag's slope over the speeds the drive could reach
    return (lambda t, th, w, u: -d.a * w - drag * w * abs(w) + d.b * u,
            (d.a, d.a + 2 * drag * d.top_speed), (d.b, d.b))


def _sagging(d: _Drawn) -> Misfit:
    sag = d.rng.uniform(0.1, 0.4)
    return (lambda t, th, w, u: -d.a * w + d.b * u / (1 + sag * abs(u) / d.amp),
            (d.a, d.a), ((d.b / (1 + sag * d.level / d.amp),) * 2 if d.binary else (d.b / (1 + sag), d.b)))


def _curved(d: _Drawn) -> Misfit:
    power = d.rng.uniform(0.7, 1.4)
    ends = (d.b, d.b * 0.25 ** (power - 1))           # the gain torque / duty from a quarter of the amplitude up
    return (lambda t, th, w, u: -d.a * w + d.b * d.amp * math.copysign((abs(u) / d.amp) ** power, u),
            (d.a, d.a), (d.b * (d.level / d.amp) ** (power - 1),) * 2 if d.binary else (min(ends), max(ends)))


def _linear(d: _Drawn) -> Misfit:
    return lambda t, th, w, u: -d.a * w + d.b * u, (d.a, d.a), (d.b, d.b)


#: What :func:`random_rig` adds to the motor, one per seed: its name and its maker from the drawn motor.
RANDOM_KINDS: dict[str, Callable[[_Drawn], Misfit]] = {
    "current limit": _current_limit, "load switched on": _load_switched_on, "clipped duty": _clipped_duty,
    "Stribeck friction": _stribeck, "asymmetric gain": _asymmetric, "warming": _warming, "cogging": _cogging,
    "gravity": _gravity, "quadratic drag": _drag, "sagging supply": _sagging, "curved driver": _curved,
    "backlash": _linear,            # the play is the encoder's, on the output: the motor is linear
}


def random_rig(seed: int):
    """A bench drawn from ``seed``, one step past every registered structure, and the ``a`` and ``b`` it has.

    ``a`` from 3 to 120 1/s, ``b / a`` from 0.05 to 0.5 per duty, 1-10 ms, 4-12 s, 360-16667 counts, an input
    of one kind (:func:`_random_duty`) and amplitude 120-220, and one of :data:`RANDOM_KINDS` at a drawn
    severity.  Returns ``(recording, ((a_low, a_high), (b_low, b_high)))``: the plant's ``a`` and ``b``, a range
    where they drift or depend on the direction, the duty or the speed (over the run's own inputs: a binary
    input's one magnitude has one gain).  The recording's ``metadata["plant"]`` names the kind and the input.
    """
    rng = np.random.default_rng(seed)
    a = float(np.exp(rng.uniform(np.log(3), np.log(120))))
    b = float(a * np.exp(rng.uniform(np.log(0.05), np.log(0.5))))
    h = float(rng.choice([0.001, 0.002, 0.005, 0.01]))
    duration = float(rng.uniform(4, 12))
    cpr = int(rng.choice([360, 1000, 2048, 4096, 16667]))
    shape = str(rng.choice(["sine", "multisine", "steps", "prbs", "chirp"]))
    amp = float(rng.uniform(120, 220))
    time = np.arange(int(duration / h)) * h
    duty = _random_duty(shape, time, rng, amp)
    kind = list(RANDOM_KINDS)[int(rng.integers(len(RANDOM_KINDS)))]
    accel, a_range, b_range = RANDOM_KINDS[kind](_Drawn(rng, a, b, amp, duration, shape == "prbs"))
    theta, _ = _integrate(accel, duty, h)
    if kind == "backlash":
        play = rng.uniform(0.005, 0.05)
        out, y = np.empty_like(theta), 0.0
        for k, x in enumerate(theta):
            y = min(max(y, x - play / 2), x + play / 2)
            out[k] = y
        theta = out
    return (_record(time, duty, theta, seed, cpr, metadata={"plant": f"{kind}, input {shape}"}),
            (a_range, b_range))
