"""One interface for the simulator and the bench: ``Rig.run(experiment) -> Recording``.

An :class:`Experiment` says what to do (excitation, sample period, duration, duty
limit); a rig does it and returns a :class:`~motorsim.recording.Recording`.  A
:class:`~motorsim.control.ClosedLoopExperiment` runs a controller instead of an
excitation: the duty is computed at each sample from the counts just read.
:class:`SimRig` is the simulated bench; ``hardware.SerialRig`` is the Arduino one.
Nothing here is simulation-specific except :class:`SimRig` itself.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Protocol, runtime_checkable

import numpy as np

from .checks import ParameterError, ParameterTypeError, check_int, check_real
from .control import ClosedLoopExperiment
from .excitation import DUTY_LIMIT, Excitation
from .fixed_point import ControlLoop
from .knobs import Knob, knob, knobs_of
from .plant import Motor, Plant, simulate
from .recording import Recording
from .recursion import first_order_filter
from .sensors import Encoder

__all__ = ["Experiment", "Rig", "SimRig", "bench_knobs", "jittered_times", "motor_metadata", "recorded_knobs",
           "kept_samples", "MAX_SAMPLES"]

#: The most samples an experiment may ask for (the device counts them in 32 bits): beyond it
#: ``duration / sample_period`` is no sample count (1e308 s overflowed to infinity).
MAX_SAMPLES = 2**32


@dataclasses.dataclass(frozen=True)
class Experiment:
    """What a rig should run.

    Parameters
    ----------
    excitation : Excitation
        The duty waveform (generated on board by the bench firmware).
    sample_period : float
        Nominal sample period in s, > 0.
    duration : float
        Length of the run in s; the run has ``round(duration / sample_period)`` samples.
    duty_limit : int
        Duty clamp, 0...255 (default 255).
    """

    excitation: Excitation
    sample_period: float = knob(0.005, unit="s", help="nominal sample period, > 0")
    duration: float = knob(10.0, unit="s", help="length of the run")
    duty_limit: int = knob(DUTY_LIMIT, unit="duty", help="duty clamp, 0...255")

    def __post_init__(self):
        if not isinstance(self.excitation, Excitation):
            raise ParameterTypeError(f"excitation must be an Excitation, got {type(self.excitation).__name__}")
        object.__setattr__(self, "sample_period", check_real("sample_period", self.sample_period, positive=True))
        object.__setattr__(self, "duration", check_real("duration", self.duration, positive=True))
        object.__setattr__(self, "duty_limit", check_int("duty_limit", self.duty_limit, 0, DUTY_LIMIT))
        if not self.duration / self.sample_period < MAX_SAMPLES:
            raise ParameterError(f"duration must be under {MAX_SAMPLES:g} samples of {self.sample_period!r} s, "
                                 f"got {self.duration!r} s")
        if self.n_samples < 2:
            raise ParameterError(f"duration must cover at least 2 samples of {self.sample_period!r} s, "
                             f"got {self.duration!r} s")
        self.duty()  # validate the excitation against this sample period (Nyquist, ...)

    @property
    def n_samples(self) -> int:
        """Number of samples, ``round(duration / sample_period)``."""
        return int(round(self.duration / self.sample_period))

    def duty(self) -> np.ndarray:
        """The duty sequence every rig applies (int64, length ``n_samples``)."""
        return self.excitation.duty(self.n_samples, self.sample_period, self.duty_limit)

    def metadata(self) -> dict[str, str]:
        """Metadata lines describing this experiment, for the recording."""
        return {"excitation": self.excitation.describe(), "duty_limit": str(self.duty_limit),
                "duration": repr(self.duration)}


@runtime_checkable
class Rig(Protocol):
    """Anything that runs an :class:`Experiment` and returns its :class:`Recording`."""

    def run(self, experiment: Experiment | ClosedLoopExperiment) -> Recording:
        ...


@dataclasses.dataclass(frozen=True)
class SimRig:
    """The simulated bench.

    Parameters
    ----------
    motor : Plant
        The plant: a :class:`~motorsim.plant.Motor` (with any friction, dead zone, bias, input delay,
        electrical lag) or any structure's plant (:class:`~motorsim.plant.Plant`).
    encoder : Encoder
        Counts per revolution, offset and angle noise (default: the article's 16667-count encoder).
    jitter : float
        Timing jitter as a fraction of the sample period: each sample instant is
        ``k dt + U(-jitter, jitter) dt / 2``, so intervals vary by up to ``+-jitter dt``;
        0 <= jitter < 1 (default 0).  The recording's ``time_s`` holds the true instants.
    drop_rate : float
        Probability that a sample is lost on the way to the host (its row is missing,
        ``seq`` shows the gap); 0 <= drop_rate < 1.
    initial_speed : float
        Speed at the first sample in rad/s.
    record_speed : bool
        Also record the true instantaneous speed at each sample (``speed_rad_s``), as an
        ideal tachometer would; estimators then use it instead of differenced counts.
    disturbance : float
        A slowly varying random torque, as the acceleration it gives in rad/s^2 (its RMS; default 0:
        none): an AR(1) sequence ``d[k+1] = r d[k] + disturbance sqrt(1 - r^2) e[k]``,
        ``r = exp(-sample_period / disturbance_time)``, ``e`` standard normal, ``d[0] = 0``, held
        over each sample interval and entering the motor as its ``bias`` does.  In closed loop the
        controller feeds it back.
    disturbance_time : float
        Correlation time of the disturbance in s, > 0 (default 0.1).
    rng : numpy.random.Generator, optional
        Source of noise, jitter, drops and disturbance; required when any of them is nonzero.
    """

    motor: Plant
    encoder: Encoder = dataclasses.field(default_factory=Encoder)
    jitter: float = knob(0.0, unit="sample periods", help="timing jitter, 0 <= jitter < 1", recorded=True)
    drop_rate: float = knob(0.0, unit="", help="probability that a sample is lost, 0 <= drop_rate < 1",
                            recorded=True)
    initial_speed: float = knob(0.0, unit="rad/s", help="speed at the first sample", recorded=True)
    record_speed: bool = knob(False, unit="", help="also record the true speed (an ideal tachometer)",
                              recorded=True)
    disturbance: float = 0.0
    disturbance_time: float = 0.1
    rng: np.random.Generator | None = None

    def __post_init__(self):
        if not isinstance(self.motor, Plant):
            raise ParameterTypeError(f"motor must be a plant (a Motor), got {type(self.motor).__name__}")
        if not isinstance(self.encoder, Encoder):
            raise ParameterTypeError(f"encoder must be an Encoder, got {type(self.encoder).__name__}")
        jitter = check_real("jitter", self.jitter, nonnegative=True)
        if jitter >= 1:
            raise ParameterError(f"jitter must be < 1 (a fraction of the sample period), got {jitter!r}")
        drop = check_real("drop_rate", self.drop_rate, nonnegative=True)
        if drop >= 1:
            raise ParameterError(f"drop_rate must be < 1, got {drop!r}")
        object.__setattr__(self, "jitter", jitter)
        object.__setattr__(self, "drop_rate", drop)
        object.__setattr__(self, "initial_speed", check_real("initial_speed", self.initial_speed))
        object.__setattr__(self, "disturbance", check_real("disturbance", self.disturbance, nonnegative=True))
        object.__setattr__(self, "disturbance_time", check_real("disturbance_time", self.disturbance_time,
                                                                positive=True))
        needs_rng = jitter > 0 or drop > 0 or self.encoder.angle_noise > 0 or self.disturbance > 0
        if needs_rng and not isinstance(self.rng, np.random.Generator):
            raise ParameterTypeError(f"rng must be a numpy.random.Generator when noise, jitter, drops or a "
                                     f"disturbance are set, got {self.rng!r}")

    def run(self, experiment: Experiment | ClosedLoopExperiment) -> Recording:
        """Simulate ``experiment`` and return what the bench would record.

        Parameters
        ----------
        experiment : Experiment or ClosedLoopExperiment
            What to run; in closed loop the controller's integer step computes each duty
            from the counts read at that sample, and the recording gains the ``reference`` column.

        Examples
        --------
        >>> from motorsim import Sine
        >>> rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10, 200), sample_period=0.005, duration=1.0))
        >>> len(rec), rec.counts[:5].tolist(), rec.metadata["true_a"]
        (200, [0, 0, 0, 4, 12], '25.0')
        """
        if isinstance(experiment, ClosedLoopExperiment):
            return self._run_closed_loop(experiment)
        if not isinstance(experiment, Experiment):
            raise ParameterTypeError(f"experiment must be an Experiment, got {type(experiment).__name__}")
        n, dt = experiment.n_samples, experiment.sample_period
        duty = experiment.duty()
        k = np.arange(n)
        time = jittered_times(n, dt, self.jitter, self.rng)
        if self.disturbance > 0:   # the torque changes every sample: the per-sample loop, replaying the duty
            noise = self._angle_noise(n)
            _, counts, true_speed = _closed_loop(self.motor, self.encoder, _Replay(duty), time, noise,
                                                 self.initial_speed, self._disturbance(n, dt))
        else:
            traj = simulate(self.motor, duty, time, initial_speed=self.initial_speed)
            counts, true_speed = self.encoder.counts(traj.angle, self.rng), traj.speed
        keep = kept_samples(n, self.drop_rate, self.rng)
        meta = {"source": "SimRig", **experiment.metadata(), **motor_metadata(self.motor),
                **recorded_knobs(self.encoder), **recorded_knobs(self), **self._disturbance_metadata()}
        speed = true_speed[keep] if self.record_speed else None
        return Recording(time=time[keep], duty=duty[keep], sample_period=dt, counts=counts[keep],
                         speed=speed, seq=k[keep], counts_per_rev=self.encoder.counts_per_rev, metadata=meta)

    def _run_closed_loop(self, experiment: ClosedLoopExperiment) -> Recording:
        """The closed-loop run: encoder, controller step and exact plant interval, sample by sample."""
        n, dt = experiment.n_samples, experiment.sample_period
        time = jittered_times(n, dt, self.jitter, self.rng)
        noise = self._angle_noise(n)
        loop = experiment.controller.start(experiment.reference_samples(), experiment.duty_limit)
        duty, counts, speed = _closed_loop(self.motor, self.encoder, loop, time, noise, self.initial_speed,
                                           self._disturbance(n, dt))
        keep = kept_samples(n, self.drop_rate, self.rng)
        k = np.arange(n)
        meta = {"source": "SimRig", **experiment.metadata(), **motor_metadata(self.motor),
                **recorded_knobs(self.encoder), **recorded_knobs(self), **self._disturbance_metadata()}
        return Recording(time=time[keep], duty=duty[keep], sample_period=dt, counts=counts[keep],
                         speed=speed[keep] if self.record_speed else None, seq=k[keep],
                         counts_per_rev=self.encoder.counts_per_rev, metadata=meta,
                         reference=experiment.reference_values()[keep])


    def _angle_noise(self, n: int) -> np.ndarray:
        """The encoder's angle noise at ``n`` samples in rad (zeros without noise)."""
        if self.encoder.angle_noise > 0 and self.rng is not None:
            return self.rng.normal(0.0, self.encoder.angle_noise, n)
        return np.zeros(n)

    def _disturbance(self, n: int, sample_period: float) -> np.ndarray | None:
        """The AR(1) torque over each of the ``n`` sample intervals in rad/s^2, or None without one."""
        if self.disturbance == 0 or self.rng is None:
            return None
        r = math.exp(-sample_period / self.disturbance_time)
        e = self.rng.standard_normal(n) * self.disturbance * math.sqrt(1.0 - r * r)
        e[0] = 0.0
        return first_order_filter(r, e)

    def _disturbance_metadata(self) -> dict[str, str]:
        """The disturbance's settings as metadata lines, when there is one."""
        if self.disturbance == 0:
            return {}
        return {"disturbance": repr(self.disturbance), "disturbance_time": repr(self.disturbance_time)}


@dataclasses.dataclass(frozen=True)
class _Replay:
    """A loop that applies a fixed duty sequence (an open-loop run through the per-sample loop)."""

    duty: np.ndarray

    def step(self, k: int, counts: int) -> int:
        return int(self.duty[k])


def _closed_loop(motor: Plant, encoder: Encoder, loop: ControlLoop | _Replay, time: np.ndarray,
                 noise: np.ndarray, initial_speed: float, disturbance: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Duty, counts and true speed of a closed-loop run, each interval exact (:class:`~motorsim.plant.Stepper`).

    ``disturbance`` (rad/s^2, one value per sample interval) adds to the motor's bias.  Behind an
    electrical lag the current starts at 0 (as :func:`~motorsim.plant.simulate`'s with no duty before).
    """
    n = len(time)
    duty = np.zeros(n, dtype=np.int64)
    counts = np.zeros(n, dtype=np.int64)
    speed = np.zeros(n)
    scale, offset = encoder.counts_per_rev / (2.0 * math.pi), encoder.count_offset
    pending = [0] * motor.input_delay
    stepper = motor.stepper(np.diff(time))
    state = motor.initial_state(0.0, initial_speed)
    for k in range(n):
        th, w = state[0], state[1]
        counts[k] = c = math.floor((th + noise[k]) * scale) + offset
        speed[k] = w
        duty[k] = u = loop.step(k, c)
        if k == n - 1:
            break
        pending.append(u)
        state = stepper.step(k, state, pending.pop(0), 0.0 if disturbance is None else float(disturbance[k]))
    return duty, counts, speed


def motor_metadata(motor: Plant) -> dict[str, str]:
    """The motor's knobs as recording metadata ``true_NAME``: the required ones (``a``, ``b``)
    always, the others when nonzero.

    Examples
    --------
    >>> motor_metadata(Motor(25.0, 3.0, bias=0.5))
    {'true_a': '25.0', 'true_b': '3.0', 'true_bias': '0.5'}
    """
    out = {}
    if not isinstance(motor, Motor):        # another structure's plant: its values, a and b always
        values = {**motor.values(), "input_delay": motor.input_delay}
        return {f"true_{name}": repr(value) for name, value in values.items() if name in ("a", "b") or value}
    for k in knobs_of(Motor):
        value = getattr(motor, k.name)
        if k.required or value:
            out[f"true_{k.name}"] = repr(value)
    return out


def recorded_knobs(obj: object) -> dict[str, str]:
    """The knobs of ``obj`` (an Encoder, a SimRig) declared ``recorded=True``, as metadata ``NAME: repr``."""
    return {k.name: repr(getattr(obj, k.name)) for k in knobs_of(type(obj)) if k.recorded}


def bench_knobs() -> tuple[Knob, ...]:
    """Every bench knob: the fields of Motor, Encoder, SimRig and Experiment declared with ``knob``.

    Names are unique across the four classes; see :mod:`motorsim.knobs`.
    """
    out = knobs_of(Motor) + knobs_of(Encoder) + knobs_of(SimRig) + knobs_of(Experiment)
    names = [k.name for k in out]
    if len(set(names)) != len(names):  # pragma: no cover - a programming error caught by the tests
        raise RuntimeError(f"bench knob names must be unique, got {names}")
    return out


def kept_samples(n_samples: int, drop_rate: float, rng: np.random.Generator | None) -> np.ndarray:
    """Which samples reach the host (bool mask): each but the first is lost with probability ``drop_rate``.

    ``rng`` may be None when ``drop_rate`` is 0.
    """
    keep = np.ones(n_samples, dtype=bool)
    if drop_rate > 0:
        if rng is None:
            raise ParameterTypeError("rng must be a numpy.random.Generator when drop_rate > 0, got None")
        keep[1:] = rng.random(n_samples - 1) >= drop_rate
    return keep


def jittered_times(n_samples: int, sample_period: float, jitter: float,
                   rng: np.random.Generator | None) -> np.ndarray:
    """Sample instants ``k dt + U(-jitter, jitter) dt / 2``, shifted so the first is 0 (s).

    ``rng`` may be None when ``jitter`` is 0.
    """
    t = np.arange(n_samples) * sample_period
    if jitter:
        if rng is None:
            raise ParameterTypeError("rng must be a numpy.random.Generator when jitter > 0, got None")
        t = t + rng.uniform(-0.5, 0.5, n_samples) * jitter * sample_period
        t -= t[0]
    return t
