"""The motor: ``d omega/dt + a omega = b u`` as a python-control model, and its exact simulation.

The PWM holds each duty for one sample interval, so the exact discrete model is
the zero-order-hold (ZOH) discretisation.  The state is ``[angle, speed]``:
angle is the integral of speed, which makes encoder counts exact functions of
the simulated state.

Over an interval of length ``h`` with constant drive ``v`` (ZOH, exact)::

    e      = exp(-a h)
    speed' = e speed + (b/a)(1 - e) v
    angle' = angle + ((1 - e)/a) speed + (b/a)(h - (1 - e)/a) v

With Coulomb friction ``c`` the speed obeys ``d omega/dt = -a omega + b v - c sign(omega) + d``
piecewise; :func:`simulate` integrates it exactly, event by event (zero
crossings and sticking when ``|b v + d| <= c`` at rest).  With static friction ``c_s > c``
(stiction) the shaft at rest breaks away only when ``|b v + d| > c_s``, and a speed that
reaches zero sticks while ``|b v + d| <= c_s``.
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from .checks import ParameterError, ParameterTypeError, check_int, check_real, real_array
from .knobs import knob, knobs_of
from .recursion import first_order_filter

if TYPE_CHECKING:
    import control

__all__ = ["Plant", "Motor", "register_structures", "registered_structures", "structure_plant", "named_plant",
           "further_parameters", "Trajectory", "simulate", "zoh_matrices", "delayed_duty", "delay_at", "RECURSION_RTOL",
           "ZOH_BLOCK", "lag_coefficients", "lag_response", "LagResponse", "first_order_coefficients", "Stepper",
           "speed_coefficients"]


class Plant:
    """The one plant type: a model structure's dynamics, with its values and an input delay.

    Everything that simulates, steps, samples or designs takes a plant and asks it: the simulator
    (:func:`simulate`), the closed loops of :class:`~motorsim.rig.SimRig` and ``fake://`` (its
    :meth:`stepper`), the batch sweeps (:func:`motorsim.batch.unbatchable_parts`: what the batch engine cannot
    run is refused by name), control design (:class:`motorsim.control.PlantModel` is a plant sampled for a
    controller), the robustness draws (:meth:`replace` with drawn values) and the running estimate
    (:func:`speed_coefficients`).  No caller restates a step.

    :class:`Motor` is the first-order motor's family (friction, bias, dead zone, stiction, an
    electrical lag).  A structure with other dynamics subclasses :class:`LinearPlant` (a linear
    structure: its continuous system is all it writes) or this class, as a frozen dataclass whose
    fields are its values and ``input_delay``; its model structure in ``identify`` returns it.

    The measured outputs are the angle and the speed: a state (:meth:`initial_state`,
    :meth:`stepper`) starts with them, the plant's own states after.
    """

    input_delay: int = 0

    def values(self) -> dict[str, float]:
        """Every value of the plant by name, the input delay apart: ``a`` and ``b`` first, the first-order
        part's pole (1/s) and gain ((rad/s^2) per input unit), which every structure has."""
        raise NotImplementedError

    def replace(self, **changes) -> "Plant":
        """This plant with some values (or its ``input_delay``) changed, checked as any new plant."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]

    def first_order(self) -> "Motor":
        """The first-order motor a design is made on (its ``a``, ``b``, friction and bias; every other part
        left to the full plant, which judges the design)."""
        raise NotImplementedError

    @property
    def is_linear(self) -> bool:
        """Whether the plant is linear in its input (a delay keeps it linear)."""
        return True

    def state_names(self) -> tuple[str, ...]:
        """Names of the state: ``angle``, ``speed``, then the plant's own."""
        return ("angle", "speed")

    def initial_state(self, angle: float = 0.0, speed: float = 0.0) -> tuple[float, ...]:
        """A state with this angle and speed, at rest otherwise (the plant's own states 0)."""
        return (float(angle), float(speed)) + (0.0,) * (len(self.state_names()) - 2)

    def state_space(self) -> control.StateSpace:
        """The continuous system of the linear part: input ``duty``, outputs ``angle`` and ``speed``."""
        raise NotImplementedError

    def discretise(self, sample_period: float) -> control.StateSpace:
        """The exact ZOH model at ``sample_period`` s, via ``control.sample_system``."""
        import control
        sample_period = check_real("sample_period", sample_period, positive=True)
        return control.sample_system(self.state_space(), sample_period, method="zoh")

    def stepper(self, intervals) -> "Stepper":
        """The plant's state advanced one sample interval at a time, each exact (see :class:`Stepper`)."""
        raise NotImplementedError

    def run(self, duty: np.ndarray, time: np.ndarray, intervals: np.ndarray, *, initial_speed: float,
            initial_angle: float, duty_before: float) -> Trajectory:
        """The exact run under ``duty`` (already delayed; ``duty[k]`` held over ``intervals[k]``) from the
        state at ``time[0]``, ``duty_before`` what was held before it: :func:`simulate`'s work on checked,
        non-empty arrays."""
        raise NotImplementedError

    def speed_polynomials(self, sample_period: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator in ``z`` from the drive to the averaged speed
        ``y_k = (angle_k - angle_{k-1}) / h``: ``y(z)/v(z) = num(z) / (z den(z))``, no input delay."""
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Motor(Plant):
    """A PWM-driven DC motor, ``d omega/dt + a omega = b u`` (plus optional non-idealities).

    Parameters
    ----------
    a : float
        Pole in 1/s, > 0.
    b : float
        Gain in (rad/s^2) per duty unit (per input unit), nonzero.
    friction : float, optional
        Coulomb friction ``c`` in rad/s^2, >= 0 (default 0): the term ``-c sign(omega)``,
        and the motor sticks at rest while ``|b u + bias| <= c``.
    bias : float, optional
        Constant acceleration ``d`` in rad/s^2 (default 0), e.g. a driver offset or load.
    dead_zone : float, optional
        Duty magnitude below which the driver delivers nothing, >= 0 (default 0);
        outside it the drive is ``u - sign(u) dead_zone``.
    input_delay : int, optional
        Whole samples between a duty being commanded and reaching the motor, >= 0.
    electrical_time_constant : float, optional
        Time constant ``tau_e`` in s of a first-order lag between the drive and the motor's torque
        (the winding's ``L/R``, a driver's filter), >= 0 (default 0: none).  With it the linear
        part is ``b / ((s + a)(tau_e s + 1))``; not combined with Coulomb friction.
    static_friction : float, optional
        Static friction ``c_s`` in rad/s^2 (stiction): the force ``|b u + bias|`` the shaft at rest needs
        to break away, and below which a speed reaching zero sticks; 0 (default) or ``>= friction``.
        0 means none: the motor breaks away at the friction level (:attr:`breakaway`).
    """

    a: float = knob(unit="1/s", help="pole a of d omega/dt + a omega = b u, > 0")
    b: float = knob(unit="(rad/s^2)/duty", help="gain b of d omega/dt + a omega = b u, nonzero")
    friction: float = knob(0.0, unit="rad/s^2", help="Coulomb friction c, >= 0")
    bias: float = knob(0.0, unit="rad/s^2", help="constant acceleration d (driver offset, load)")
    dead_zone: float = knob(0.0, unit="duty", help="duty magnitude the driver does not deliver, >= 0")
    input_delay: int = knob(0, unit="samples", help="whole samples between command and motor, >= 0")
    electrical_time_constant: float = knob(0.0, unit="s", help="time constant of the lag between the drive and "
                                           "the torque (electrical pole 1/tau_e), >= 0")
    static_friction: float = knob(0.0, unit="rad/s^2", help="static friction (stiction): the force the shaft at rest "
                                  "needs to break away, 0 (none: the friction level) or >= friction")

    def __post_init__(self):
        object.__setattr__(self, "a", check_real("a", self.a, positive=True))
        b = check_real("b", self.b)
        if b == 0:
            raise ParameterError(f"b must be nonzero, got {self.b!r}")
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "friction", check_real("friction", self.friction, nonnegative=True))
        object.__setattr__(self, "bias", check_real("bias", self.bias))
        object.__setattr__(self, "dead_zone", check_real("dead_zone", self.dead_zone, nonnegative=True))
        object.__setattr__(self, "input_delay", check_int("input_delay", self.input_delay, 0, 10**6))
        tau = check_real("electrical_time_constant", self.electrical_time_constant, nonnegative=True)
        object.__setattr__(self, "electrical_time_constant", tau)
        static = check_real("static_friction", self.static_friction, nonnegative=True)
        if 0 < static < self.friction:
            raise ParameterError(f"static_friction must be 0 (none) or >= friction ({self.friction!r} rad/s^2), "
                                 f"got {self.static_friction!r}")
        object.__setattr__(self, "static_friction", static)
        if tau > 0 and self.breakaway > 0:
            raise ParameterError(f"electrical_time_constant must be 0 when friction is set (the simulator does not "
                                 f"combine a lag with Coulomb friction), got {self.electrical_time_constant!r} s "
                                 f"with friction {self.friction!r}, static_friction {self.static_friction!r}")

    @property
    def breakaway(self) -> float:
        """The force (rad/s^2) above which the shaft at rest moves: the static friction, else the friction."""
        return max(self.static_friction, self.friction)

    @property
    def is_linear(self) -> bool:
        """True when friction, static friction, bias and dead zone are all zero (delay keeps it linear)."""
        return self.breakaway == 0 and self.bias == 0 and self.dead_zone == 0

    @property
    def static_gain(self) -> float:
        """Steady-state speed per input unit, ``b / a``."""
        return self.b / self.a

    def transfer_function(self) -> control.TransferFunction:
        """``b / (s + a)`` from duty to speed (``b / ((s + a)(tau_e s + 1))`` with an electrical time
        constant; delay and non-idealities omitted)."""
        import control
        tau = self.electrical_time_constant
        return control.tf([self.b], [tau, 1.0 + tau * self.a, self.a] if tau else [1.0, self.a])

    def state_space(self) -> control.StateSpace:
        """States ``[angle, speed]`` (and ``current``, in input units, with an electrical time constant),
        input duty, outputs ``[angle, speed]`` (linear part)."""
        import control
        tau = self.electrical_time_constant
        if tau:
            A3 = [[0.0, 1.0, 0.0], [0.0, -self.a, self.b], [0.0, 0.0, -1.0 / tau]]
            C3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
            return control.ss(A3, [[0.0], [0.0], [1.0 / tau]], C3, np.zeros((2, 1)),
                              states=["angle", "speed", "current"], inputs=["duty"], outputs=["angle", "speed"])
        A = [[0.0, 1.0], [0.0, -self.a]]
        B = [[0.0], [self.b]]
        return control.ss(A, B, np.eye(2), np.zeros((2, 1)),
                          states=["angle", "speed"], inputs=["duty"], outputs=["angle", "speed"])

    def discretise(self, sample_period: float) -> control.StateSpace:
        """The exact ZOH model at ``sample_period`` s, via ``control.sample_system``."""
        import control
        sample_period = check_real("sample_period", sample_period, positive=True)
        return control.sample_system(self.state_space(), sample_period, method="zoh")

    def drive(self, duty: np.ndarray) -> np.ndarray:
        """The drive ``v`` that reaches the motor: dead zone applied (delay not)."""
        u = np.asarray(duty, dtype=float)
        if self.dead_zone == 0:
            return u
        return np.where(np.abs(u) <= self.dead_zone, 0.0, u - np.sign(u) * self.dead_zone)

    def values(self) -> dict[str, float]:
        """``a``, ``b`` and every part (the input delay apart), zero ones included."""
        return {name: float(getattr(self, name)) for name in _MOTOR_VALUES}

    def first_order(self) -> "Motor":
        """This motor without its electrical lag: the first-order part a design is made on."""
        return dataclasses.replace(self, electrical_time_constant=0.0) if self.electrical_time_constant else self

    def state_names(self) -> tuple[str, ...]:
        """``angle``, ``speed`` and, behind an electrical lag, ``current`` (the lagged drive, input units)."""
        return ("angle", "speed", "current") if self.electrical_time_constant else ("angle", "speed")

    def initial_state(self, angle: float = 0.0, speed: float = 0.0) -> tuple[float, ...]:
        """``(angle, speed, current)``, the current 0 (what :class:`Stepper` takes, with or without a lag)."""
        return (float(angle), float(speed), 0.0)

    def stepper(self, intervals) -> "Stepper":
        """One exact step per sample interval (:class:`Stepper`)."""
        return Stepper(self, intervals)

    def run(self, duty: np.ndarray, time: np.ndarray, intervals: np.ndarray, *, initial_speed: float,
            initial_angle: float, duty_before: float) -> Trajectory:
        """The exact run: behind the lag by :func:`lag_response`, linear by the ZOH recursion, with friction by
        its exact event step (compiled, :mod:`motorsim.compiled`)."""
        t, h = time, intervals
        v = self.drive(duty)[:-1]
        n = len(t)
        angle = np.empty(n)
        speed = np.empty(n)
        angle[0], speed[0] = initial_angle, initial_speed
        if self.electrical_time_constant > 0:
            before = float(self.drive(np.array([duty_before]))[0])
            run = lag_response(self.a, self.b, 1.0 / self.electrical_time_constant, self.bias, np.append(v, 0.0), t,
                               initial_speed=initial_speed, initial_current=before)
            return Trajectory(t, run.angle + initial_angle, run.speed)
        if self.breakaway == 0:
            drive = v + self.bias / self.b if self.bias else v
            if _nearly_uniform_zoh(self.a, self.b, h, drive, speed, angle):
                return Trajectory(t, angle, speed)
            e, g, p, q = zoh_matrices(self.a, self.b, h)
            _linear_recursion(e, g * drive, speed, initial_speed)
            angle[1:] = initial_angle + np.cumsum(p * speed[:-1] + q * drive)
            return Trajectory(t, angle, speed)
        from .compiled import friction_run
        friction_run(float(self.a), self.b * np.asarray(v, dtype=float) + self.bias, float(self.friction), h,
                     speed, angle, float(self.breakaway))
        return Trajectory(t, angle, speed)

    def speed_coefficients(self, sample_period: float, scale: float = 1.0) -> tuple[float, float, float, float]:
        """``(e, g, beta1, beta2)`` of the first-order part's averaged speed over ``sample_period``
        (:func:`speed_coefficients`), times ``scale`` (counts per sample per rad/s for a controller)."""
        return speed_coefficients(self.a, self.b, sample_period, scale)

    def speed_polynomials(self, sample_period: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator in ``z`` from the drive to the averaged speed
        ``y_k = (angle_k - angle_{k-1}) / h``, every linear part included, without the factor ``1/z`` of the
        difference and without the input delay: ``y(z)/v(z) = num(z) / (z den(z))``, in rad/s times ``scale``.

        First order: ``num = (beta1, beta2)``, ``den = (1, -e)`` (:func:`speed_coefficients`).  Behind an
        electrical lag, with the state ``[omega, i]`` and the coefficients ``e_a, e_c, p, r, q, s`` of
        :func:`lag_coefficients` over one sample, ``omega' = e_a omega + b q i + b (p - q) v``,
        ``i' = e_c i + (1 - e_c) v`` and ``angle' - angle = p omega + b s i + b (r - s) v``, so
        ``num(z) = (scale / h) (p ((z - e_c) b (p - q) + b q (1 - e_c)) + b s (1 - e_c)(z - e_a)
        + b (r - s)(z - e_a)(z - e_c))`` over ``den = (z - e_a)(z - e_c)``: both poles exact.
        """
        h = check_real("sample_period", sample_period, positive=True)
        if not self.electrical_time_constant:
            e, _, b1, b2 = self.speed_coefficients(h, scale)
            return np.array([b1, b2]), np.array([1.0, -e])
        b = self.b
        e_a, e_c, p, r, q, s = (float(x) for x in lag_coefficients(self.a, 1.0 / self.electrical_time_constant, h))
        den = np.asarray(np.polymul([1.0, -e_a], [1.0, -e_c]))
        num = np.polyadd(np.polyadd(p * b * np.array([p - q, -e_c * (p - q) + q * (1.0 - e_c)]),
                                    b * s * (1.0 - e_c) * np.array([1.0, -e_a])), b * (r - s) * den)
        return num * (scale / h), den


#: :class:`Motor`'s values besides the input delay, in the order of its fields.
_MOTOR_VALUES = ("a", "b", "friction", "bias", "dead_zone", "electrical_time_constant", "static_friction")


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A simulated run.

    Attributes
    ----------
    time : ndarray
        Sample instants in s.
    angle : ndarray
        Angle in rad at each instant.
    speed : ndarray
        Speed in rad/s at each instant.
    """

    time: np.ndarray
    angle: np.ndarray
    speed: np.ndarray


def zoh_matrices(a: float, b: float, h) -> tuple:
    """Closed-form ZOH coefficients for intervals ``h`` (scalar or array).

    Returns ``(e, g, p, q)`` with ``speed' = e speed + g v`` and
    ``angle' = angle + p speed + q v``.
    """
    h = np.asarray(h, dtype=float)
    e = np.exp(-a * h)
    one_minus = -np.expm1(-a * h)
    g = b / a * one_minus
    p = one_minus / a
    q = b / a * (h - p)
    return e, g, p, q


def delay_at(input_delay: int, sample_period: float, new_sample_period: float) -> int:
    """The input delay of ``input_delay`` samples at ``sample_period``, in samples at ``new_sample_period``.

    A delay is a time: ``input_delay sample_period`` seconds, the same at every sample period.
    It is kept exactly or refused: a time that is not a whole number of the new samples (to a
    relative 1e-6) has no delay line at that sample period, and rounding it would design or
    judge a different motor.

    Parameters
    ----------
    input_delay : int
        Delay in samples at ``sample_period``, >= 0.
    sample_period : float
        The sample period the delay was counted at, in s, > 0.
    new_sample_period : float
        The sample period to count it at, in s, > 0.

    Raises
    ------
    motorsim.checks.ParameterError
        The delay is not a whole number of samples at ``new_sample_period``.

    Examples
    --------
    >>> delay_at(4, 0.005, 0.001)          # 20 ms
    20
    >>> delay_at(1, 0.005, 0.002)          # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    motorsim.checks.ParameterError: input_delay 1 sample at 0.005 s (0.005 s) is 2.5 samples at 0.002 s, ...
    """
    input_delay = check_int("input_delay", input_delay, 0, 10**6)
    sample_period = check_real("sample_period", sample_period, positive=True)
    new_sample_period = check_real("new_sample_period", new_sample_period, positive=True)
    if input_delay == 0 or new_sample_period == sample_period:
        return input_delay
    samples = input_delay * sample_period / new_sample_period
    whole = round(samples)
    if whole < 1 or abs(samples - whole) > 1e-6 * samples:
        seconds = input_delay * sample_period
        plural = "" if input_delay == 1 else "s"
        raise ParameterError(f"input_delay {input_delay} sample{plural} at {sample_period!r} s "
                             f"({seconds:.6g} s) is {samples:.6g} samples at {new_sample_period!r} s, not a whole "
                             f"number: choose a sample period that divides {seconds:.6g} s (e.g. {sample_period!r} s)")
    return int(whole)


def delayed_duty(duty: np.ndarray, delay: int, before: float) -> np.ndarray:
    """``duty`` shifted ``delay`` samples later, the first ``delay`` samples held at ``before``."""
    if delay == 0:
        return duty
    out = np.empty_like(duty)
    out[:delay] = before
    out[delay:] = duty[: len(duty) - delay] if delay < len(duty) else out[delay:]
    return out


def _all_finite(x: np.ndarray) -> bool:
    """Whether every value is finite: a finite sum says so in one pass without a temporary (a sum that
    overflows, of large finite values, is checked value by value)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if math.isfinite(float(np.sum(x))):
            return True
    return bool(np.all(np.isfinite(x)))


def simulate(motor: Plant, duty, time, *, initial_speed: float = 0.0, initial_angle: float = 0.0,
             duty_before: float = 0.0) -> Trajectory:
    """Simulate the motor exactly under zero-order-hold duty.

    Parameters
    ----------
    motor : Motor
        The plant.
    duty : array_like, shape (n,)
        ``duty[k]`` is applied from ``time[k]`` until ``time[k+1]`` (the last one is not used).
    time : array_like, shape (n,)
        Strictly increasing sample instants in s (uniform or not).
    initial_speed, initial_angle : float
        State at ``time[0]``.
    duty_before : float
        Duty that was applied before ``time[0]``, fed through ``motor.input_delay``.

    Returns
    -------
    Trajectory
        ``angle[k]`` and ``speed[k]`` at ``time[k]``.

    Examples
    --------
    A step of 100 duty units from rest: the speed rises towards ``b/a * 100 = 12`` rad/s.

    >>> t = np.arange(5) * 0.01
    >>> simulate(Motor(25.0, 3.0), np.full(5, 100), t).speed.round(3).tolist()
    [0.0, 2.654, 4.722, 6.332, 7.585]
    """
    if not isinstance(motor, Plant):
        raise ParameterTypeError(f"motor must be a plant (a Motor), got {type(motor).__name__}")
    u = real_array("duty", duty)
    t = real_array("time", time)
    if u.ndim != 1 or t.shape != u.shape:
        raise ParameterError(f"duty and time must be 1-D of equal length, got shapes {u.shape} and {t.shape}")
    if not (_all_finite(u) and _all_finite(t)):
        raise ParameterError("duty and time must be finite")
    h = np.diff(t)
    if len(h) and not float(h.min()) > 0:
        raise ParameterError("time must be strictly increasing")
    n = len(t)
    if n == 0:
        return Trajectory(t, np.empty(0), np.empty(0))
    return motor.run(delayed_duty(u, motor.input_delay, duty_before), t, h, initial_speed=initial_speed,
                     initial_angle=initial_angle, duty_before=duty_before)


def lag_coefficients(a: float, c: float, h) -> tuple:
    """Closed-form ZOH coefficients of the motor behind a first-order electrical lag, intervals ``h``.

    The drive ``v`` reaches the motor through ``di/dt = c (v - i)`` (``c = 1/tau_e``), and
    ``d omega/dt = -a omega + b i + d``.  Over an interval with ``v`` held:
    ``i' = e_c i + (1 - e_c) v`` and, with ``e_a = exp(-a h)``,

    ``omega' = e_a omega + (1 - e_a)/a (b v + d) + b q (i - v)``,
    ``angle' = angle + p omega + r (b v + d) + b s (i - v)``

    where ``q = (e_c - e_a)/(a - c)``, ``p = (1 - e_a)/a``, ``r = (h - p)/a`` and
    ``s = ((1 - e_c)/c - p)/(a - c)`` (the integral of ``q`` over the interval).  Near ``a = c``
    both quotients are taken in the form that keeps their limits exact
    (``q -> h e_a``, ``s -> (p - h e_a)/a``).

    Returns
    -------
    e_a, e_c, p, r, q, s : ndarray or float
    """
    h = np.asarray(h, dtype=float)
    e_a = np.exp(-a * h)
    e_c = np.exp(-c * h)
    p = -np.expm1(-a * h) / a
    r = (h - p) / a
    x = (a - c) * h
    small = np.abs(x) < 1e-5
    f_c = -np.expm1(-c * h) / c
    if not np.any(small):        # no interval near a = c: the general forms alone (the same numbers as below)
        return e_a, e_c, p, r, e_a * h * (np.expm1(x) / x), (f_c - p) / (a - c)
    # q = e_a h expm1(x)/x; the series 1 + x/2 + x^2/6 where x is small
    phi = np.where(small, 1 + x / 2 + x * x / 6, np.expm1(x) / np.where(small, 1.0, x))
    q = e_a * h * phi
    # s = integral of q: (F(c) - F(a))/(a - c) with F(y) = (1 - exp(-y h))/y; near a = c, -F'(m) at the midpoint
    m = 0.5 * (a + c)
    deriv = (h * np.exp(-m * h) * m + np.expm1(-m * h)) / (m * m)          # F'(m)
    s = np.where(small, -deriv, (f_c - p) / np.where(small, 1.0, a - c))
    return e_a, e_c, p, r, q, s


def speed_coefficients(a: float, b: float, h: float, scale: float = 1.0) -> tuple[float, float, float, float]:
    """The first-order motor's averaged speed ``y_k = (angle_k - angle_{k-1}) / h`` over a held sample ``h``:
    ``(e, g, beta1, beta2)`` with ``y_{k+1} = e y_k + beta1 v_k + beta2 v_{k-1}`` and ``g = beta1 + beta2``
    the sampled speed's gain, each times ``scale``.

    From :func:`zoh_matrices` (``speed' = e speed + g v``, ``angle' = angle + p speed + q v``):
    ``beta1 = q / h``, ``beta2 = (p g - e q) / h``.  The one place this model is written: the
    controllers' (:meth:`motorsim.control.PlantModel.speed_coefficients`, ``scale`` their counts per
    sample per rad/s) and ``motorid live``'s running estimate (:mod:`identify.fits.recursive`) take it from here.

    Examples
    --------
    >>> e, g, b1, b2 = speed_coefficients(25.0, 3.0, 0.01)
    >>> round(b1 + b2 - g, 15)
    0.0
    """
    e, g, p, q = (float(x) for x in zoh_matrices(a, b, h))
    return e, g * scale, q / h * scale, (p * g - e * q) / h * scale


def first_order_coefficients(a: float, h: float) -> tuple[float, float, float]:
    """The first-order motor's exact step over ``h`` s with its drive held, per unit drive: ``(e, p, r)``.

    ``speed' = e speed + p f`` and ``angle' = angle + p speed + r f`` for a held acceleration
    ``f = b v + d``, with ``e = exp(-a h)``, ``p = (1 - e)/a`` (by ``expm1``: exact for small
    ``a h``) and ``r = (h - p)/a``.  The one place these scalars are written: the estimators that
    need the step's coefficients (``iv``'s filter, ``iv-reference``, the prediction-error filter,
    the friction fit's start) take them from here, :func:`zoh_matrices` is their array form with
    ``b`` in, and :class:`Stepper` runs the state one sample at a time.

    Examples
    --------
    >>> [round(x, 6) for x in first_order_coefficients(25.0, 0.01)]
    [0.778801, 0.008848, 4.6e-05]
    """
    e = math.exp(-a * h)
    p = -math.expm1(-a * h) / a
    return e, p, (h - p) / a


class Stepper:
    """The plant's state advanced one sample interval at a time, each interval exact (zero-order hold).

    What every per-sample loop runs (a closed loop on :class:`~motorsim.rig.SimRig`, the emulated
    device of ``fake://``, :meth:`identify.Estimate.io_system`), so none of them restates the
    plant: the first-order motor by :func:`zoh_matrices`, behind an electrical lag by
    :func:`lag_coefficients`, with Coulomb or static friction by :func:`simulate` over the
    interval (its exact event step).  The state is ``(angle, speed, current)``: the current (the
    lagged drive, in input units) is 0 without an electrical lag.  The input delay is the
    caller's (its delay line): ``duty`` is what reaches the motor now; the dead zone is applied here.

    Parameters
    ----------
    motor : Motor
        The plant.
    intervals : array_like
        The sample intervals in s (one per step ``k``); a scalar for a uniform clock (``k`` then 0).
    """

    def __init__(self, motor: Motor, intervals) -> None:
        if not isinstance(motor, Motor):
            raise ParameterTypeError(f"motor must be a Motor, got {type(motor).__name__}")
        h = np.atleast_1d(np.asarray(intervals, dtype=float))
        self.motor = motor
        self._h = h.tolist()
        if motor.electrical_time_constant > 0:
            self._kind = "lag"
            self._coefficients = list(zip(*(np.broadcast_to(x, h.shape).tolist()
                                            for x in lag_coefficients(motor.a, 1.0 / motor.electrical_time_constant,
                                                                      h))))
        elif motor.breakaway == 0:
            self._kind = "linear"
            self._coefficients = list(zip(*(x.tolist() for x in zoh_matrices(motor.a, motor.b, h))))
        else:
            self._kind = "friction"
            self._bare = dataclasses.replace(motor, dead_zone=0.0, input_delay=0)

    def step(self, k: int, state: tuple[float, ...], duty: float, torque: float = 0.0) -> tuple[float, ...]:
        """The state after interval ``k`` with ``duty`` held (and an added acceleration ``torque``, rad/s^2)."""
        m = self.motor
        angle, speed, current = state
        v = float(duty)
        if m.dead_zone and v:  # Motor.drive, on one sample
            v = 0.0 if abs(v) <= m.dead_zone else v - math.copysign(m.dead_zone, v)
        if self._kind == "lag":
            e_a, e_c, p, r, q, s = self._coefficients[k]
            force, lag = m.b * v + m.bias + torque, m.b * (current - v)
            return (angle + p * speed + r * force + s * lag, e_a * speed + p * force + q * lag,
                    e_c * current + (1.0 - e_c) * v)
        if torque:
            v += torque / m.b
        if self._kind == "linear":
            e, g, p, q = self._coefficients[k]
            v += m.bias / m.b
            return angle + p * speed + q * v, e * speed + g * v, 0.0
        traj = simulate(self._bare, [v, v], [0.0, self._h[k]], initial_speed=speed, initial_angle=angle)
        return float(traj.angle[1]), float(traj.speed[1]), 0.0


@dataclasses.dataclass(frozen=True)
class LagResponse:
    """:func:`lag_response`'s run: angle (rad, from 0), speed (rad/s) and current (input units) at each instant."""

    angle: np.ndarray
    speed: np.ndarray
    current: np.ndarray


def lag_response(a: float, b: float, c: float, bias: float, drive, time, *, initial_speed: float = 0.0,
                 initial_current: float = 0.0) -> LagResponse:
    """Exact ZOH run of the motor behind an electrical lag (:func:`lag_coefficients`).

    Parameters
    ----------
    a, b : float
        The motor's pole (1/s) and gain.
    c : float
        The electrical pole ``1/tau_e`` in 1/s, > 0.
    bias : float
        Constant acceleration ``d`` in rad/s^2.
    drive : array_like, shape (n,)
        ``drive[k]`` held from ``time[k]`` to ``time[k+1]`` (the last is not used).
    time : array_like, shape (n,)
        Strictly increasing instants in s.
    initial_speed, initial_current : float
        State at ``time[0]`` (the current in input units: the drive it has settled to).

    Returns
    -------
    LagResponse
    """
    v = np.asarray(drive, dtype=float)[:-1]
    t = np.asarray(time, dtype=float)
    n = len(t)
    speed, current, angle = np.empty(n), np.empty(n), np.zeros(n)
    if n == 0:
        return LagResponse(angle, speed, current)
    h = np.diff(t)
    e_a, e_c, p, r, q, s = lag_coefficients(a, c, h)
    current[0], speed[0] = initial_current, initial_speed
    _linear_recursion(np.broadcast_to(e_c, h.shape).copy(), (1 - e_c) * v, current, initial_current)
    lag = current[:-1] - v
    force = p * (b * v + bias) + b * q * lag
    _linear_recursion(np.broadcast_to(e_a, h.shape).copy(), force, speed, initial_speed)
    np.cumsum(p * speed[:-1] + r * (b * v + bias) + b * s * lag, out=angle[1:])
    return LagResponse(angle, speed, current)


#: Largest relative spread of the per-interval decay factors ``exp(-a h_k)`` that the
#: linear recursion treats as a constant factor plus a correction (see :func:`_linear_recursion`).
#: A float time grid ``k * dt`` has intervals that differ by rounding (~1e-16 ``t_k / dt``
#: relative), far inside it; genuinely jittered clocks are far outside it.
RECURSION_RTOL = 1e-9


#: Samples per block of :func:`_nearly_uniform_zoh` (each block at least this long, so every filter pass is
#: ``lfilter``'s, as over the whole run): its few work arrays stay in a core's cache, where a long run streamed
#: whole through memory by each of a dozen array operations costs about a third more CPU time (10^5 samples),
#: more on a busy machine.
ZOH_BLOCK = 16384


def _nearly_uniform_zoh(a: float, b: float, h: np.ndarray, drive: np.ndarray, speed: np.ndarray,
                        angle: np.ndarray) -> bool:
    """The ZOH run when every interval is within :data:`RECURSION_RTOL` of ``h[0]`` (relative, and
    relative to ``1/a``); False (nothing done) otherwise.

    ``speed[0]`` and ``angle[0]`` hold the initial state.  Every coefficient is its
    value at ``h[0]`` plus its first-order change, ``dh_k = h_k - h[0]``
    (``de/dh = -a e``, ``dg/dh = b e``, ``dp/dh = e``, ``dq/dh = g``), the products of
    ``dh`` with the state taken at the next sample (which differs by ``O(dh)``); the
    neglected second order is at most ``RECURSION_RTOL^2`` relative, below rounding.  So no
    per-interval ``exp``: one first-order filter pass
    (:func:`motorsim.recursion.first_order_filter`) with the constant factor, one correction pass
    as in :func:`_linear_recursion` when the intervals differ, and a cumulative sum.  A long run
    goes through them in blocks of :data:`ZOH_BLOCK` samples, each pass and the sum carried from
    one block to the next: the same operations on every sample, in the same order, as one block.
    """
    if not len(h):
        return True
    h0 = float(h[0])
    # max |h - h0| without an array of the differences (subtracting h0 keeps the order: the same numbers)
    spread = max(float(h.max()) - h0, h0 - float(h.min()))
    if not (spread <= RECURSION_RTOL * h0 and abs(a) * spread <= RECURSION_RTOL):
        return False
    e0, g0, p0, q0 = (float(c) for c in zoh_matrices(a, b, h0))
    m = len(h)
    ends = list(range(ZOH_BLOCK, m - ZOH_BLOCK + 1, ZOH_BLOCK)) + [m]     # every block at least ZOH_BLOCK long
    longest = max(e - s for s, e in zip([0] + ends[:-1], ends))
    force, work, first, step, dh = (np.empty(longest) for _ in range(5))
    total = 0.0                                      # the cumulative sum of the steps so far
    first_state = float(speed[0])                    # the first pass's speed before the block
    start = 0
    for end in ends:
        n = end - start
        d, dhk, f, w, s1, st = drive[start:end], dh[:n], force[:n], work[:n], first[:n], step[:n]
        np.multiply(d, g0, out=f)
        if spread > 0:
            np.subtract(h[start:end], h0, out=dhk)
            # speed_{k+1} = e0 speed_k + g0 d_k + dh_k e0 (b d_k - a speed_k); the bracket times e0 is
            # b d_k - a speed_{k+1} to first order (a g0 = b (1 - e0)), taken from a first pass
            first_order_filter(e0, f, first_state, out=s1)
            first_state = float(s1[-1])
            np.multiply(d, b, out=w)
            np.multiply(s1, a, out=st)
            w -= st
            w *= dhk
            w += f
            f = w
        first_order_filter(e0, f, float(speed[start]), out=speed[start + 1:end + 1])
        np.multiply(speed[start:end], p0, out=st)
        st += np.multiply(d, q0, out=force[:n])
        if spread > 0:
            st += np.multiply(dhk, speed[start + 1:end + 1], out=work[:n])   # dh (e0 speed_k + g0 d_k), to first order
        if start:
            st[0] += total                           # the sum carried: the same additions as one long sum
        np.cumsum(st, out=angle[start + 1:end + 1])
        total = float(angle[end])
        angle[start + 1:end + 1] += angle[0]
        start = end
    return True


def _linear_recursion(e: np.ndarray, f: np.ndarray, out: np.ndarray, x0: float) -> None:
    """``out[0] = x0; out[k+1] = e[k] out[k] + f[k]``, without a Python loop when ``e`` is nearly constant.

    When every ``e[k]`` is within :data:`RECURSION_RTOL` (relative) of ``e[0]``, the
    recursion is rewritten as ``out[k+1] = e[0] out[k] + (f[k] + (e[k] - e[0]) out[k])``
    and solved by :func:`motorsim.recursion.first_order_filter` with the constant factor, the
    bracket evaluated at a first pass's ``out``.  The error of that first pass is ``O(RECURSION_RTOL)`` relative, and
    the bracket multiplies it by ``e[k] - e[0]`` again, so the second pass is exact to
    ``O(RECURSION_RTOL^2)``, i.e. to rounding (a test checks it against the loop to 1e-12).
    Bit-equal factors take one pass.
    """
    if len(e):
        e0 = e[0]
        de = e - e0
        spread = float(np.max(np.abs(de)))
        if spread <= RECURSION_RTOL * abs(e0):
            first_order_filter(e0, f, x0, out=out[1:])
            if spread > 0:
                de *= out[:-1]
                de += f
                first_order_filter(e0, de, x0, out=out[1:])
            return
        if _iterated_recursion(e, f, out, x0):
            return
    x = x0
    for k in range(len(e)):
        x = e[k] * x + f[k]
        out[k + 1] = x


#: The fixed-point form of :func:`_iterated_recursion` is used while its contraction factor
#: is below this; each pass then gains at least a factor 4, usually a thousand (a clock
#: jittered by 1e-3).
CONTRACTION_LIMIT = 0.25
#: Passes before :func:`_iterated_recursion` gives up (the caller then loops per sample).
MAX_PASSES = 30


def _iterated_recursion(e: np.ndarray, f: np.ndarray, out: np.ndarray, x0: float) -> bool:
    """``out[k+1] = e[k] out[k] + f[k]`` for factors that vary (a jittered clock), by fixed-point passes.

    With ``c`` the factors' midrange, ``out[k+1] = c out[k] + (f[k] + (e[k] - c) out[k])``
    is solved by :func:`motorsim.recursion.first_order_filter` with the constant ``c``, the bracket
    taken from the previous pass.  The error shrinks by ``rho = max|e - c| / (1 - |c|)`` per pass; passes stop
    when one changes nothing above 1e-15 of the largest value, so the result is the
    loop's to rounding (a test checks 1e-12).  Returns False, having done nothing
    useful, when ``rho`` exceeds :data:`CONTRACTION_LIMIT` or it does not settle.
    """
    lo, hi = float(np.min(e)), float(np.max(e))
    c = 0.5 * (lo + hi)
    de = e - c
    if not (abs(c) < 1 and 0.5 * (hi - lo) <= CONTRACTION_LIMIT * (1 - abs(c))):
        return False
    first_order_filter(c, f, x0, out=out[1:])
    for _ in range(MAX_PASSES):
        forcing = de * out[:-1]
        forcing += f
        new = first_order_filter(c, forcing, x0)
        change = float(np.max(np.abs(new - out[1:])))
        out[1:] = new
        if not change > 1e-15 * float(np.max(np.abs(new))):
            return bool(np.all(np.isfinite(new)))
    return False


#: Where the model structures come from: their registry lives above the bench (``identify`` registers its own on
#: import), and the bench imports nothing above it.
_STRUCTURE_REGISTRIES: list[Callable[[], Mapping[str, Any]]] = []


def register_structures(registry: Callable[[], Mapping[str, Any]]) -> None:
    """Make the model structures ``registry()`` returns (name -> structure) known to the bench: ``fake://``'s
    ``structure`` key builds its plant from them (:func:`structure_plant`)."""
    if registry not in _STRUCTURE_REGISTRIES:
        _STRUCTURE_REGISTRIES.append(registry)


def registered_structures() -> dict[str, Any]:
    """The model structures the bench knows by name (:func:`register_structures`), in registration order."""
    found: dict[str, Any] = {}
    for registry in _STRUCTURE_REGISTRIES:
        found.update(registry())
    return found


def structure_plant(structure: Any, given: Mapping[str, Any], input_delay: int = 0) -> Plant:
    """The plant of a model ``structure`` (``name``, ``param_names``, ``plant(values, input_delay)``) with the
    values ``given`` by name.

    A value for a parameter the structure does not have is refused by name (a shaft's stiffness given to a
    first-order motor would otherwise be dropped); one it has and is not given takes its neutral value or is
    asked for (the structure's own rule).
    """
    names = tuple(structure.param_names)
    extra = sorted(set(given) - set(names))
    if extra:
        raise ParameterError(f"{', '.join(extra)} {'is not a parameter' if len(extra) == 1 else 'are not parameters'} "
                             f"of the {structure.name} structure (its parameters: {', '.join(names)})")
    return structure.plant(dict(given), input_delay)


def further_parameters(structures: Mapping[str, Any]) -> tuple[str, ...]:
    """The parameters of the simulated ``structures`` (name -> structure) that are not knobs of :class:`Motor`, in
    order of first appearance: the further keys of a plant named by its structure (``fake://``, a scenario)."""
    motor = {k.name for k in knobs_of(Motor)}
    out: dict[str, None] = {}
    for s in structures.values():
        if getattr(s, "simulated", True):
            out.update((n, None) for n in s.param_names if n not in motor)
    return tuple(out)


def named_plant(structure: str, given: Mapping[str, Any], structures: Mapping[str, Any]) -> Plant:
    """The plant ``structure`` names with the values ``given`` (``input_delay`` among them).

    ``structure`` ``""``: the :class:`Motor` of the knobs given (a further parameter refused: it needs a structure
    that has it); else the registered structure's plant (:func:`structure_plant`; ``structures`` name -> structure).
    """
    values = dict(given)
    delay = values.pop("input_delay", 0)
    if not structure:
        further = sorted(set(values) - {k.name for k in knobs_of(Motor)})
        if further:
            raise ParameterError(f"{', '.join(further)} needs a structure that has it: set structure to one of "
                                 f"{[n for n, s in structures.items() if set(further) <= set(s.param_names)]}")
        return Motor(**values, input_delay=delay)
    if structure not in structures:
        raise ParameterError(f"structure must be one of {list(structures)}, got {structure!r}" + (
            "" if structures else " (no structure is registered: identify registers its own when imported)"))
    return structure_plant(structures[structure], values, delay)
