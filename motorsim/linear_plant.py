"""``LinearPlant``: a linear structure's plant from its continuous system alone.

A structure whose dynamics are linear writes one method, :meth:`LinearPlant.matrices`: its
continuous ``A`` and ``B`` over the state ``[angle, speed, own...]``, where ``angle`` is the
measured angle, ``speed`` its derivative, and nothing depends on the angle (no spring to ground):
``A[:, 0] = 0``, ``angle' = speed``.  Everything else follows, exactly, from that system:

* the exact discretisation over a held sample (zero-order hold): the matrix exponential of
  ``[[A, B], [0, 0]] h`` (:meth:`LinearPlant.sampled`), split into the angle's increment
  ``angle' - angle = P x + R u`` and the rest ``x' = Ad x + Bd u`` (``x`` the state without the angle);
* one step per sample (:class:`LinearStepper`, what a closed loop and ``fake://`` run);
* the simulation (:meth:`LinearPlant.run`): on a uniform clock the modes of ``Ad`` each by one
  first-order filter pass (``scipy.signal.lfilter``), else, or where ``Ad``'s eigenvectors are
  nearly parallel, the exact step per interval;
* the averaged speed's discrete model (:meth:`LinearPlant.speed_polynomials`) a controller is
  judged on, and the frequency response (:meth:`LinearPlant.frequency_response`);
* the free and forced responses an estimator fits on a recording's segment (:meth:`LinearPlant.columns`).

The first-order part a controller is designed on is :class:`~motorsim.plant.Motor` with the
plant's ``a`` and ``b`` (:meth:`LinearPlant.first_order`).
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from .checks import ParameterError, check_real
from .plant import RECURSION_RTOL, Motor, Plant, Stepper, Trajectory

if TYPE_CHECKING:
    import control

__all__ = ["LinearPlant", "LinearStepper", "Sampled"]


@dataclasses.dataclass(frozen=True)
class Sampled:
    """A linear plant over one held sample ``h``: ``x' = Ad x + Bd u``, ``angle' = angle + P x + R u``
    (``x`` the state without the angle, speed first)."""

    Ad: np.ndarray
    Bd: np.ndarray
    P: np.ndarray
    R: float


class LinearPlant(Plant):
    """A plant whose dynamics are a linear continuous system (module docstring); subclasses are frozen
    dataclasses with their values as fields (``a`` and ``b`` first) and ``input_delay``."""

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``A`` (n x n) and ``B`` (n,) of the continuous system over ``[angle, speed, own...]``."""
        raise NotImplementedError

    def values(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in dataclasses.fields(self)  # type: ignore[arg-type]
                if f.name != "input_delay"}

    def first_order(self) -> Motor:
        """The first-order motor with this plant's ``a`` and ``b`` (and delay): what a design is made on."""
        v = self.values()
        return Motor(v["a"], v["b"], input_delay=self.input_delay)

    def _checked(self) -> tuple[np.ndarray, np.ndarray]:
        A, B = (np.asarray(m, dtype=float) for m in self.matrices())
        n = len(A)
        if A.shape != (n, n) or B.shape != (n,) or n < 2:
            raise ParameterError(f"matrices() must give A (n x n) and B (n,), n >= 2, got {A.shape} and {B.shape}")
        if np.any(A[:, 0]) or A[0, 1] != 1 or np.any(A[0, 2:]) or B[0]:
            raise ParameterError("the first state must be the measured angle, the integral of the second (the "
                                 "speed), and nothing may depend on it")
        return A, B

    def state_space(self) -> control.StateSpace:
        import control
        A, B = self._checked()
        n = len(A)
        C = np.zeros((2, n))
        C[0, 0] = C[1, 1] = 1.0
        return control.ss(A, B[:, None], C, np.zeros((2, 1)), states=list(self.state_names()), inputs=["duty"],
                          outputs=["angle", "speed"])

    def sampled(self, h: float) -> Sampled:
        """The exact zero-order-hold step over ``h`` s (:class:`Sampled`)."""
        from scipy.linalg import expm
        A, B = self._checked()
        n = len(A)
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n] = A, B
        E = expm(M * h)
        return Sampled(E[1:n, 1:n], E[1:n, n].copy(), E[0, 1:n].copy(), float(E[0, n]))

    def stepper(self, intervals) -> Stepper:
        return LinearStepper(self, intervals)

    def run(self, duty: np.ndarray, time: np.ndarray, intervals: np.ndarray, *, initial_speed: float,
            initial_angle: float, duty_before: float) -> Trajectory:
        x0 = np.asarray(self.initial_state(0.0, initial_speed)[1:], dtype=float)    # the plant's own rule
        angle, x = self.response(duty, time, intervals, x0)
        return Trajectory(time, angle + initial_angle, x[:, 0].copy())

    def response(self, duty: np.ndarray, time: np.ndarray, intervals: np.ndarray, x0: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The angle (from 0) and the state without the angle (n_samples x (n - 1)) from ``x0``, ``duty[k]``
        held over ``intervals[k]``."""
        n = len(time)
        u = np.asarray(duty, dtype=float)[:-1]
        x = np.empty((n, len(x0)))
        x[0] = x0
        h = np.asarray(intervals, dtype=float)
        if n > 1 and float(h.max() - h.min()) <= RECURSION_RTOL * float(h[0]):
            s = self.sampled(float(h[0]))
            if not self._modal(s, u, x):
                for k in range(n - 1):
                    x[k + 1] = s.Ad @ x[k] + s.Bd * u[k]
            steps = x[:-1] @ s.P + s.R * u
        else:
            steps = np.empty(n - 1)
            for k in range(n - 1):
                s = self.sampled(float(h[k]))
                x[k + 1] = s.Ad @ x[k] + s.Bd * u[k]
                steps[k] = s.P @ x[k] + s.R * u[k]
        angle = np.zeros(n)
        np.cumsum(steps, out=angle[1:])
        return angle, x

    @staticmethod
    def _modal(s: Sampled, u: np.ndarray, x: np.ndarray) -> bool:
        """``x[k+1] = Ad x[k] + Bd u[k]`` by the modes of ``Ad``, each one filter pass; False (nothing done)
        where the eigenvectors are too near parallel for it to be exact to rounding."""
        from scipy.signal import lfilter
        lam, V = np.linalg.eig(s.Ad)
        if not np.linalg.cond(V) < 1e6:
            return False
        Vi = np.linalg.inv(V)
        g = Vi @ s.Bd
        w0 = Vi @ x[0]
        modes = np.empty((len(x), len(lam)), dtype=complex)
        modes[0] = w0
        for i, li in enumerate(lam):
            out, _ = lfilter([1.0], [1.0, -li], g[i] * u, zi=[li * w0[i]])
            modes[1:, i] = out
        x[1:] = (modes[1:] @ V.T).real
        return True

    def columns(self, time: np.ndarray, drive: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """The output's columns on a segment: the forced response (zero state) and one free response per state
        besides the angle (and, for the angle, a constant): the output is ``forced + free @ initial``."""
        h = np.diff(time)
        m = len(self.state_names()) - 1
        fast = self._modal_columns(time, drive, kind, h)
        if fast is not None:
            return fast
        angle, x = self.response(drive, time, h, np.zeros(m))
        forced = angle if kind == "angle" else x[:, 0]
        free = []
        zero = np.zeros(len(time))
        for i in range(m):
            e = np.zeros(m)
            e[i] = 1.0
            fa, fx = self.response(zero, time, h, e)
            free.append(fa if kind == "angle" else fx[:, 0])
        if kind == "angle":
            free.append(np.ones(len(time)))
        return forced, np.column_stack(free)

    def _modal_columns(self, time: np.ndarray, drive: np.ndarray, kind: str, h: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`columns` on a uniform clock by the modes of ``Ad``: the free responses ``Ad^k e_i`` as powers
        of its eigenvalues, the forced one by one filter pass per mode; None where that is not exact."""
        from scipy.signal import lfilter
        n = len(time)
        if n < 2 or not float(h.max() - h.min()) <= RECURSION_RTOL * float(h[0]):
            return None
        s = self.sampled(float(h[0]))
        lam, V = np.linalg.eig(s.Ad)
        if not (np.linalg.cond(V) < 1e6 and np.all(np.abs(lam) <= 1.0 + 1e-12)):
            return None
        Vi = np.linalg.inv(V)
        u = np.asarray(drive, dtype=float)[:-1]
        g = Vi @ s.Bd
        modes = np.zeros((n, len(lam)), dtype=complex)
        for i, li in enumerate(lam):
            modes[1:, i] = lfilter([1.0], [1.0, -li], g[i] * u)
        row = s.P @ V if kind == "angle" else V[0]            # what one mode adds to the output (angle: per step)
        powers = lam[None, :] ** np.arange(n)[:, None]         # lam^k
        if kind == "angle":
            forced = np.zeros(n)
            np.cumsum((modes[:-1] @ row).real + s.R * u, out=forced[1:])
            free = np.zeros((n, len(lam) + 1))
            free[1:, :-1] = np.cumsum(((powers[:-1] * row[None, :]) @ Vi).real, axis=0)
            free[:, -1] = 1.0
            return forced, free
        return (modes @ row).real, ((powers * row[None, :]) @ Vi).real

    def speed_polynomials(self, sample_period: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """``num(z)/(z den(z))`` from the drive to the averaged speed: ``y_{k+1} = (P x_k + R u_k)/h``, so
        ``num = (P adj(zI - Ad) Bd + R det(zI - Ad)) scale / h`` and ``den = det(zI - Ad)``."""
        from scipy.signal import ss2tf
        h = check_real("sample_period", sample_period, positive=True)
        s = self.sampled(h)
        num, den = ss2tf(s.Ad, s.Bd[:, None], s.P[None, :], [[s.R]])
        return np.asarray(num[0], dtype=float) * (scale / h), np.asarray(den, dtype=float)

    def frequency_response(self, sample_period: float, omega, *, output: str = "angle",
                           input_delay: int = 0) -> np.ndarray:
        """The exact zero-order-hold response from the input at ``omega`` rad/s (complex): ``"speed"`` the
        sampled speed, ``"angle"`` the mean speed over the interval the input is held; ``z^-input_delay``."""
        if output not in ("angle", "speed"):
            raise ParameterError(f"output must be one of angle, speed, got {output!r}")
        h = check_real("sample_period", sample_period, positive=True)
        s = self.sampled(h)
        z = np.exp(1j * np.asarray(omega, dtype=float) * h)
        eye = np.eye(len(s.Ad))
        out = np.empty(z.shape, dtype=complex)
        for i, zi in np.ndenumerate(z):
            x = np.linalg.solve(zi * eye - s.Ad, s.Bd)
            out[i] = x[0] if output == "speed" else (s.P @ x + s.R) / h
        return out * z ** (-int(input_delay))


class LinearStepper(Stepper):
    """A linear plant's exact step per sample interval (:class:`~motorsim.plant.Stepper`'s contract: the state
    ``(angle, speed, own...)``; an added acceleration ``torque`` enters as ``torque / b`` of drive)."""

    def __init__(self, plant: LinearPlant, intervals) -> None:
        h = np.atleast_1d(np.asarray(intervals, dtype=float))
        self.motor = plant                      # type: ignore[assignment]
        self._h = h.tolist()
        self._b = float(plant.values()["b"])
        self._sampled: dict[float, Sampled] = {}

    def step(self, k: int, state: tuple[float, ...], duty: float, torque: float = 0.0) -> tuple[float, ...]:
        h = self._h[k]
        s = self._sampled.get(h)
        if s is None:
            s = self._sampled[h] = self.motor.sampled(h)      # type: ignore[attr-defined]
        u = float(duty) + (torque / self._b if torque else 0.0)
        x = np.asarray(state[1:], dtype=float)
        angle = state[0] + float(s.P @ x) + s.R * u
        new = s.Ad @ x + s.Bd * u
        return (angle, *(float(v) for v in new))
