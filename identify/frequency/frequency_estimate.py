"""Frequency response duty -> speed from recordings, with a confidence bound and coherence at each frequency.

Which speed.  A ``speed`` column (a tachometer, a lab's own speed) is used as it is: its
response is the sampled speed's, ``G(z) = (b/a)(1 - e) / (z - e)`` with ``e = exp(-a dt)``
and ``z = exp(j omega dt)`` (the exact ZOH model).  An angle or encoder counts are turned
into the *mean speed over the interval in which the duty is held*,
``v_k = (theta_{k+1} - theta_k) / dt``, aligned with ``u_k`` (the recording's alignment rule).
That is the forward difference, not the recording's backward one: the backward difference
lags the duty by one sample, while the forward one is centred where the duty acts, so the
half sample the zero-order hold delays and the half sample the averaging advances cancel and
the phase compares with ``b / (j omega + a)`` without the lag.  Its exact ZOH model follows
from ``theta_{k+1} = theta_k + dt phi1(a dt) omega_k + b dt^2 phi2(a dt) u_k``
(``identify.fits.sensitivity``)::

    G_v(z) = phi1(a dt) G(z) + b dt phi2(a dt)

so :meth:`FrequencyResponse.model_response` gives either model exactly, and at the lines of
a periodic input the estimate equals it to rounding (``(z - 1)/dt`` times the angle's
response; no approximation of a derivative is involved).

Three estimators, chosen from the excitation recorded in the metadata (``method="auto"``):

* ``periodic`` (an :class:`~motorsim.excitation.OddMultisine`, or a PRBS over at least
  ``transient_periods + 2`` of its periods): whole periods after
  ``transient_periods`` are cut, each period's DFT taken, the output averaged over periods;
  the variance at each line is the period-to-period variance of the output divided by the
  number of periods (Pintelon & Schoukens, *System Identification: A Frequency Domain
  Approach*, 2nd ed. 2012, sec. 2.4 and 7.2).  Exact at the excited lines.
* ``sines`` (a sine or a multisine of the article's kind, whose period need not be a whole
  number of samples): least squares on the angle with an offset, a drift and a cosine and
  sine at each frequency the device realised (or on the speed with an offset), the
  variance from the residual (Ljung, *System Identification*, 2nd ed. 1999, sec. 6.2, FRA).
  One run per frequency pools into one response.
* ``welch`` (anything else: PRBS, chirp, a lab's file): Hann-windowed segments with
  half overlap, ``G = S_uy / S_uu``, coherence ``|S_uy|^2 / (S_uu S_yy)`` and the bound of
  Bendat & Piersol, *Random Data*, 4th ed. 2010, eq. 9.90; the resolution is one bin,
  ``2 pi / (segment dt)``.  Only lines whose input power is spread over at least
  :data:`MIN_SEGMENTS_PER_LINE` segments (the participation ratio ``(sum P)^2 / sum P^2`` of the
  segments' input power at that line) are kept: a step's power, or the step of a sine plus a
  step, sits in one or two segments, where the coherence is 1 by construction and the phase
  unwraps to nonsense.  A run with no such line (a step, a constant) is refused with that reason.

A noise-free coarse encoder under a periodic input rounds the same angles every period: that
error repeats, so period-to-period variation cannot see it and the bound leaves it out (real
angle noise, or a slow drift of the motor, makes it vary and it is then counted).

The bound at each frequency is a disk in the complex plane: the true response lies within
``radius`` of ``response`` with probability ``level`` (a circular complex Gaussian error
whose variance is estimated with ``dof`` degrees of freedom: ``radius^2 = s^2 F(2, dof)``).
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from motorsim.checks import ParameterError, check_int, check_real
from motorsim.excitation import MAX_AMPLITUDE, PRBS, Multisine, OddMultisine, parse_excitation
from motorsim.recording import Recording

from ..data import as_recordings
from ..errors import NotIdentifiableError
from ..fits.zoh_response import OUTPUTS, zoh_speed_response

if TYPE_CHECKING:
    import control

    from ..estimate import Estimate

__all__ = ["FrequencyResponse", "ModelResponse", "frequency_response", "zoh_speed_response", "ESTIMATORS", "OUTPUTS",
           "periodic_spectra", "excitation_of", "excitation_period", "MIN_SEGMENTS_PER_LINE"]

#: The estimators ``frequency_response(method=...)`` accepts.
ESTIMATORS = ("auto", "periodic", "sines", "welch")
@dataclasses.dataclass(frozen=True)
class FrequencyResponse:
    """An estimated frequency response duty -> speed, with its bound and coherence.

    Attributes
    ----------
    omega : ndarray, shape (n,)
        Angular frequencies in rad/s, increasing.
    response : ndarray of complex, shape (n,)
        Response in (rad/s)/duty (per input unit).
    variance : ndarray, shape (n,)
        ``E |response - true|^2``, estimated, in ((rad/s)/duty)^2.
    dof : ndarray, shape (n,)
        Degrees of freedom of ``variance`` (``inf`` when it is known).
    coherence : ndarray, shape (n,)
        Magnitude-squared coherence of input and output, 0 ... 1.
    sample_period : float
        Sample period in s.
    output : str
        ``"angle"`` (interval-mean speed from the angle or counts) or ``"speed"`` (the speed column).
    method : str
        ``"periodic"``, ``"sines"`` or ``"welch"`` (several when recordings were pooled, comma-separated).
    resolution : float
        Frequency resolution in rad/s (``welch``'s bin; 0 for estimates exact at their lines).
    input_unit : str
        Unit of the input (``duty`` on the bench).
    """

    omega: np.ndarray
    response: np.ndarray
    variance: np.ndarray
    dof: np.ndarray
    coherence: np.ndarray
    sample_period: float
    output: str = "angle"
    method: str = "periodic"
    resolution: float = 0.0
    input_unit: str = "duty"

    def __post_init__(self):
        n = len(np.atleast_1d(self.omega))
        for name in ("omega", "response", "variance", "dof", "coherence"):
            arr = np.array(getattr(self, name), dtype=complex if name == "response" else float).reshape(-1)
            if len(arr) != n:
                raise ParameterError(f"{name} must have the length of omega ({n}), got {len(arr)}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.output not in OUTPUTS:
            raise ParameterError(f"output must be one of {', '.join(OUTPUTS)}, got {self.output!r}")

    def __len__(self) -> int:
        return len(self.omega)

    def radius(self, level: float = 0.95) -> np.ndarray:
        """Radius of the confidence disk around ``response`` at ``level`` (same unit as ``response``)."""
        from scipy import stats
        level = check_real("level", level, positive=True)
        if level >= 1:
            raise ParameterError(f"level must be in (0, 1), got {level!r}")
        dof = np.where(np.isfinite(self.dof), self.dof, 1e12)
        return np.sqrt(self.variance * stats.f.ppf(level, 2, np.maximum(dof, 1.0)))

    def gain_db(self) -> np.ndarray:
        """Gain ``20 log10 |response|`` in dB."""
        return 20.0 * np.log10(np.abs(self.response))

    def phase_deg(self) -> np.ndarray:
        """Phase in degrees, unwrapped along frequency."""
        return np.degrees(np.unwrap(np.angle(self.response)))

    def gain_bounds_db(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper gain in dB of the confidence disk (lower ``-inf`` when the disk holds 0)."""
        mag, r = np.abs(self.response), self.radius(level)
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(np.maximum(mag - r, 0.0)), 20.0 * np.log10(mag + r)

    def phase_bounds_deg(self, level: float = 0.95) -> np.ndarray:
        """Half-width in degrees of the phase bound of the disk (180 when the disk holds 0)."""
        ratio = self.radius(level) / np.abs(self.response)
        return np.where(ratio < 1, np.degrees(np.arcsin(np.minimum(ratio, 1.0))), 180.0)

    def model_response(self, a: float, b: float, input_delay: int = 0) -> np.ndarray:
        """The exact ZOH response of ``b/(s + a)`` at ``omega`` for this response's output."""
        return zoh_speed_response(a, b, self.sample_period, self.omega, output=self.output, input_delay=input_delay)

    def covers(self, response: np.ndarray, level: float = 0.95) -> np.ndarray:
        """Whether each value of ``response`` (shape (n,)) lies inside the confidence disk."""
        return np.abs(np.asarray(response) - self.response) <= self.radius(level)

    def model_of(self, estimate: Estimate, name: str | None = None) -> ModelResponse:
        """An estimate's model at these frequencies, with its variance from the estimate's covariance.

        The linear part of the estimate's structure with its input delay
        (:meth:`~identify.model_structures.ModelStructure.frequency_response`: ``b/(s + a)``, or both
        poles of ``second-order``; friction, bias and dead zone have no frequency response).  The
        variance is ``J C J^H`` with ``J`` the derivatives of the response with respect to the
        structure's response parameters that the covariance holds (central differences) and ``C``
        their covariance.
        """
        model, delay = estimate.model_structure(), estimate.input_delay
        values = estimate.values()

        def response(v: dict[str, float]) -> np.ndarray:
            return model.frequency_response(v, self.sample_period, self.omega, output=self.output, input_delay=delay)
        g = response(values)
        variance = np.zeros(len(g))
        if estimate.covariance is not None:
            names = [n for n in model.response_parameters if n in estimate.param_names]
            index = [estimate.param_names.index(n) for n in names]
            cov = np.asarray(estimate.covariance)[np.ix_(index, index)]
            jac = []
            for n in names:
                h = 1e-6 * max(abs(values[n]), 1e-9)
                up = response({**values, n: values[n] + h})
                down = response({**values, n: values[n] - h})
                jac.append((up - down) / (2 * h))
            J = np.column_stack(jac)
            variance = np.einsum("ni,ij,nj->n", J, cov, J.conj()).real
        return ModelResponse(name or estimate.method, self.omega, g, np.maximum(variance, 0.0))

    def departures(self, model: ModelResponse, level: float = 0.95) -> np.ndarray:
        """Frequencies (rad/s) where ``model`` lies outside this response's confidence disk."""
        return self.omega[~self.covers(model.response, level)]

    def frequency_response_data(self) -> control.FrequencyResponseData:
        """The response as ``control.FrequencyResponseData`` (omega in rad/s, discrete time ``dt``)."""
        import control
        return control.FrequencyResponseData(self.response, self.omega, dt=self.sample_period)

    def to_dict(self, level: float = 0.95) -> dict[str, Any]:
        """A JSON-ready table: frequency, gain, phase, their bounds and the coherence per line."""
        low, high = self.gain_bounds_db(level)
        return {"output": self.output, "method": self.method, "sample_period": self.sample_period,
                "resolution": self.resolution, "level": level, "input_unit": self.input_unit,
                "omega": self.omega.tolist(), "gain_db": self.gain_db().tolist(),
                "gain_low_db": [None if not np.isfinite(x) else float(x) for x in low],
                "gain_high_db": high.tolist(), "phase_deg": self.phase_deg().tolist(),
                "phase_bound_deg": self.phase_bounds_deg(level).tolist(), "coherence": self.coherence.tolist()}


@dataclasses.dataclass(frozen=True)
class ModelResponse:
    """A model's response at the frequencies of a :class:`FrequencyResponse`, with its variance.

    Attributes
    ----------
    name : str
        What the model is (the estimator's name, or a file).
    omega : ndarray, shape (n,)
        Angular frequencies in rad/s.
    response : ndarray of complex, shape (n,)
        The model's response in (rad/s)/duty.
    variance : ndarray, shape (n,)
        ``E |response - model with the true parameters|^2`` from the parameters' covariance.
    """

    name: str
    omega: np.ndarray
    response: np.ndarray
    variance: np.ndarray

    def radius(self, level: float = 0.95) -> np.ndarray:
        """Radius of the model's confidence disk at ``level`` (a circular Gaussian approximation)."""
        level = check_real("level", level, positive=True)
        if level >= 1:
            raise ParameterError(f"level must be in (0, 1), got {level!r}")
        return np.sqrt(self.variance * -math.log(1.0 - level))


def excitation_of(recording: Recording):
    """The excitation a recording's metadata names (``excitation: KIND:ARGS``), or None."""
    spec = recording.metadata.get("excitation")
    if not spec:
        return None
    try:
        return parse_excitation(spec)
    except ValueError:
        return None


def _output(rec: Recording) -> tuple[str, np.ndarray]:
    """``("speed", speed column)`` or ``("angle", measured angle)``."""
    if rec.speed is not None:
        return "speed", np.asarray(rec.speed, dtype=float)
    angle = rec.measured_angle()
    if angle is None:  # pragma: no cover - a Recording always has one of the three
        raise NotIdentifiableError("the recording has no speed, angle or counts")
    return "angle", np.asarray(angle, dtype=float)


def _require_contiguous(rec: Recording, what: str) -> None:
    if rec.has_gaps:
        raise NotIdentifiableError(f"{what} needs gap-free samples; this recording has gaps in seq "
                                   f"(use the gap-free parts, Recording.segments(), one by one)")


def periodic_spectra(rec: Recording, period: int, transient_periods: int = 1) -> tuple[np.ndarray, np.ndarray, str]:
    """DFT per period of the duty and the speed, whole periods after the transient.

    Returns
    -------
    U, Y : ndarray of complex, shape (P, period // 2 + 1)
        ``rfft`` of each period's duty and speed (interval-mean speed from the angle, or the
        speed column; see the module docstring).
    output : str
        ``"angle"`` or ``"speed"``.
    """
    _require_contiguous(rec, "a periodic estimate")
    output, y = _output(rec)
    u = np.asarray(rec.duty, dtype=float)
    if output == "angle":
        y = np.diff(y) / rec.sample_period  # v_k, aligned with u_k
        u = u[:-1]
    # the last whole periods: with the angle, v ends one sample early, so the windows end there (a window
    # shifted by a sample shifts the phase of U and Y alike and leaves Y/U as it is)
    n_periods = rec.n_samples // period - transient_periods
    if n_periods < 2:
        raise NotIdentifiableError(f"a periodic estimate needs at least 2 whole periods of {period} samples after "
                                   f"{transient_periods} transient period(s), got {n_periods}; record longer")
    stop = len(u)
    start = stop - n_periods * period
    U = np.fft.rfft(u[start:stop].reshape(n_periods, period), axis=1)
    Y = np.fft.rfft(y[start:stop].reshape(n_periods, period), axis=1)
    return U, Y, output


@dataclasses.dataclass(frozen=True)
class _Lines:
    omega: np.ndarray
    response: np.ndarray
    variance: np.ndarray
    dof: np.ndarray
    coherence: np.ndarray
    output: str
    method: str
    resolution: float = 0.0


def excitation_period(ex) -> tuple[int, np.ndarray] | None:
    """``(period in samples, excited harmonics)`` of a periodic excitation, or None.

    An odd multisine repeats every ``period`` samples and excites its odd lines; a PRBS repeats
    every ``(2**order - 1) hold`` samples and excites every harmonic its spectrum does not null
    (those above a thousandth of the largest line).
    """
    if isinstance(ex, OddMultisine):
        return ex.period, np.array(ex.excited_harmonics())
    if isinstance(ex, PRBS):
        period = ((1 << ex.order) - 1) * ex.hold
        spectrum = np.abs(np.fft.rfft(ex.duty(period, 1.0, MAX_AMPLITUDE)))
        spectrum[0] = 0.0
        if period % 2 == 0:
            spectrum[-1] = 0.0
        return period, np.flatnonzero(spectrum > 1e-3 * spectrum.max())
    return None


def _periodic(rec: Recording, period: int, k: np.ndarray, transient_periods: int) -> _Lines:
    U, Y, output = periodic_spectra(rec, period, transient_periods)
    P = U.shape[0]
    u_mean = U[:, k].mean(axis=0)
    y_k = Y[:, k]
    y_mean = y_k.mean(axis=0)
    y_var = np.sum(np.abs(y_k - y_mean) ** 2, axis=0) / (P - 1)   # one period's variance
    g = y_mean / u_mean
    variance = y_var / P / np.abs(u_mean) ** 2
    coherence = np.abs(y_mean) ** 2 / np.mean(np.abs(y_k) ** 2, axis=0)
    return _Lines(2.0 * math.pi * k / (period * rec.sample_period), g, variance, np.full(len(k), 2.0 * (P - 1)),
                  coherence, output, "periodic")


def _sines(rec: Recording, ex: Multisine, transient_periods: int) -> _Lines:
    dt = rec.sample_period
    comps = ex.components(dt)
    omega = np.array([inc / 2.0**32 * 2.0 * math.pi / dt for _, _, inc in comps])  # realised frequencies
    output, y = _output(rec)
    k = np.asarray(rec.seq, dtype=float)
    skip = transient_periods * 2.0 * math.pi / omega.min() / dt
    keep = k - k[0] >= skip
    k, y, u = k[keep], y[keep], np.asarray(rec.duty, dtype=float)[keep]
    cols = [np.ones_like(k)] + ([k - k.mean()] if output == "angle" else [])
    n_fixed = len(cols)
    for w in omega:
        cols += [np.cos(w * dt * k), np.sin(w * dt * k)]
    X = np.column_stack(cols)
    if len(k) < 2 * X.shape[1]:
        raise NotIdentifiableError(f"a sine fit needs at least {2 * X.shape[1]} samples after the transient "
                                   f"({transient_periods} period(s) of the lowest frequency), got {len(k)}")
    q, r = np.linalg.qr(X)
    cy = np.linalg.solve(r, q.T @ y)
    cu = np.linalg.solve(r, q.T @ u)
    resid = y - X @ cy
    dof = len(k) - X.shape[1]
    s2 = float(resid @ resid) / dof
    rinv = np.linalg.inv(r)
    cov = s2 * (rinv @ rinv.T)
    idx = n_fixed + 2 * np.arange(len(omega))
    Yc = cy[idx] - 1j * cy[idx + 1]
    Uc = cu[idx] - 1j * cu[idx + 1]
    var_y = np.maximum(cov[idx, idx] + cov[idx + 1, idx + 1], _coloured_variance(resid, omega * dt))
    factor = np.ones(len(omega), dtype=complex)
    if output == "angle":
        factor = (np.exp(1j * omega * dt) - 1.0) / dt   # angle -> interval-mean speed, exact
    g = Yc / Uc * factor
    variance = var_y / np.abs(Uc) ** 2 * np.abs(factor) ** 2
    n_cycles = np.maximum(omega * dt * len(k) / (2.0 * math.pi), 1.0)
    coherence = np.abs(Yc) ** 2 / (np.abs(Yc) ** 2 + var_y * n_cycles)
    return _Lines(omega, g, variance, np.full(len(omega), float(dof)), coherence, output, "sines")


#: Bins of the residual's periodogram on each side of a line whose mean power gives the line's noise
#: (:func:`_coloured_variance`), and the bins next to the line left out of them (the fit took its own).
NOISE_BINS, NOISE_GUARD = 12, 2


def _coloured_variance(resid: np.ndarray, phase_steps: np.ndarray) -> np.ndarray:
    """The variance of a sine's fitted complex amplitude at each line from the residual's own spectrum near it.

    The least-squares covariance takes the residual as white; an angle's residual is not (the answer
    to the duty's rounding and to a load, integrated: its power rises steeply towards low frequencies),
    and under such noise a line's amplitude varies as ``4 S(omega) / N``, ``S`` the residual's power
    spectral density at the line: the mean of a Hann-windowed periodogram over :data:`NOISE_BINS` bins on
    either side (the :data:`NOISE_GUARD` nearest left out).  ``phase_steps``: ``omega dt`` of each line."""
    n = len(resid)
    if n < 8 * NOISE_BINS:
        return np.zeros(len(phase_steps))
    window = np.hanning(n)
    spectrum = np.abs(np.fft.rfft((resid - resid.mean()) * window)) ** 2 / float(window @ window)
    centre = np.rint(phase_steps * n / (2.0 * math.pi)).astype(int)
    out = np.zeros(len(phase_steps))
    for i, c in enumerate(centre):
        near = np.r_[np.arange(c - NOISE_BINS, c - NOISE_GUARD), np.arange(c + NOISE_GUARD + 1, c + NOISE_BINS + 1)]
        near = near[(near > 0) & (near < len(spectrum))]
        if len(near):
            out[i] = 4.0 * float(spectrum[near].mean()) / n
    return out


#: Least number of Welch segments (participation ratio of the input's power across them) a line's input power
#: must come from for the line to be kept: fewer is a transient, whose coherence is 1 by construction.
MIN_SEGMENTS_PER_LINE = 3.0
#: A Welch line is kept only when its input power is at least this share of its larger neighbour's: a Hann
#: window leaks a quarter of a line's power (half its amplitude) into each neighbour, with some margin.
LEAKAGE_FRACTION = 0.3


def _jackknife_variance(Uf: np.ndarray, Yf: np.ndarray, n_eff: float) -> np.ndarray:
    """The variance of ``sum conj(U) Y / sum |U|^2`` over segments by the jackknife (each segment left out in turn),
    scaled from the segments to their effective number ``n_eff`` (overlapping segments are not independent).

    Unlike the coherence's formula it sees what varies from segment to segment however it arises: a
    transient that leaks into a segment from the input before it, an encoder's rounding that follows the
    input, a load that comes and goes; an estimate whose coherence is near 1 is no longer taken on trust."""
    n_seg = Uf.shape[0]
    if n_seg < 3:
        return np.zeros(Uf.shape[1])
    cross = np.conj(Uf) * Yf
    power = np.abs(Uf) ** 2
    left_cross = cross.sum(axis=0) - cross
    left_power = power.sum(axis=0) - power
    with np.errstate(divide="ignore", invalid="ignore"):
        g = left_cross / left_power
        spread = np.sum(np.abs(g - g.mean(axis=0)) ** 2, axis=0) * (n_seg - 1) / n_seg
    return np.where(np.isfinite(spread), spread * n_seg / n_eff, np.inf)


#: The leakage of a segment of ``N`` samples is estimated as this share of the difference between the estimates
#: from segments of ``N/2`` and of ``N``: a segment's transient (the response to the input before it, cut by the
#: window) leaks an error that falls as ``1/N``, so the half segments' is twice the whole ones', their difference
#: once it.  (A window's smoothing bias falls as ``1/N^2``, a third; measured, the transient dominates: a third
#: left 7-13 % of a robot log's lines outside at low noise, the whole difference 6-7 %.)
LEAKAGE_SHARE = 1.0


def _leakage_variance(u: np.ndarray, y: np.ndarray, segment: int, spectra,
                      whole: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The squared leakage of the Welch estimate at each bin of a ``segment``-sample segment, estimated from the data.

    A finite window smooths the response over its bandwidth, weighted by the input's spectrum, and
    lets each segment's transient leak into its bins: an error the noise's variance and the segments'
    spread do not hold, and which stays as the noise goes (a true model fell outside the noise-only
    bound at 19 % of a random-step run's lines at 5e-4 rad/s of noise, 40 % of a robot log's).  The
    estimate from half-length segments carries the same error, larger; their difference, interpolated
    to this segment's bins, less the two estimates' own noise variance, measures it (Richardson's
    extrapolation): :data:`LEAKAGE_SHARE` of it.  ``whole``: the whole segments' estimate and its noise
    variance (:func:`_h1`)."""
    half = segment // 2
    n = len(u)
    if half < 8 or (n - half) // (half // 2) + 1 < 3:
        return np.zeros(segment // 2 + 1)
    from scipy import signal
    hop = half // 2
    idx = np.arange(half)[None, :] + hop * np.arange((n - half) // hop + 1)[:, None]
    window = signal.get_window("hann", half)
    Uh, Yh = spectra(u, idx, window), spectra(y, idx, window)
    k = np.arange(segment // 2 + 1)
    at = 2 * np.arange(half // 2 + 1)
    (gh, vh), (g, v) = _h1(Uh, Yh), whole
    fine = np.interp(k, at, gh.real) + 1j * np.interp(k, at, gh.imag)
    with np.errstate(invalid="ignore"):
        # the two estimates' own noise taken out of their difference: what is left is the window's
        out = LEAKAGE_SHARE ** 2 * np.maximum(np.abs(fine - g) ** 2 - v - np.interp(k, at, vh), 0.0)
    return np.where(np.isfinite(out), out, 0.0)


def _h1(Uf: np.ndarray, Yf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The H1 estimate over the segments' spectra and its noise variance (coherence's formula, Welch's overlap)."""
    n_seg = Uf.shape[0]
    suu, syy = np.mean(np.abs(Uf) ** 2, axis=0), np.mean(np.abs(Yf) ** 2, axis=0)
    suy = np.mean(np.conj(Uf) * Yf, axis=0)
    n_eff = n_seg / (1.0 + 2.0 * HANN_OVERLAP_CORRELATION ** 2 * (1.0 - 1.0 / n_seg))
    with np.errstate(divide="ignore", invalid="ignore"):
        g = suy / suu
        coherence = np.clip(np.abs(suy) ** 2 / (suu * syy), 0.0, 1.0)
        v = (1.0 - coherence) / coherence * np.abs(g) ** 2 / (n_eff - 1.0)
    return g, v


#: Correlation of the squared spectra of two Hann-windowed segments that overlap by half (Welch 1967, table 1).
HANN_OVERLAP_CORRELATION = 0.167


def _welch(rec: Recording, segment: int | None) -> _Lines:
    from scipy import signal
    _require_contiguous(rec, "a broadband (welch) estimate")
    output, y = _output(rec)
    u = np.asarray(rec.duty, dtype=float)
    if output == "angle":
        y = np.diff(y) / rec.sample_period
        u = u[:-1]
    n = len(u)
    if segment is None:
        segment = max(64, 1 << int(round(math.log2(max(n / 16, 1)))))
    segment = check_int("segment", segment, 8)
    if segment > n:
        raise NotIdentifiableError(f"segment must be at most the {n} samples of the recording, got {segment}")
    hop = segment // 2
    n_seg = (n - segment) // hop + 1
    window = signal.get_window("hann", segment)
    idx = np.arange(segment)[None, :] + hop * np.arange(n_seg)[:, None]

    def spectra(x: np.ndarray, idx: np.ndarray = idx, window: np.ndarray = window) -> np.ndarray:
        seg = x[idx]
        seg = seg - seg.mean(axis=1, keepdims=True)
        return np.fft.rfft(seg * window, axis=1)

    Uf, Yf = spectra(u), spectra(y)
    leakage = _leakage_variance(u, y, segment, spectra, _h1(Uf, Yf))
    suu = np.mean(np.abs(Uf) ** 2, axis=0)
    syy = np.mean(np.abs(Yf) ** 2, axis=0)
    suy = np.mean(np.conj(Uf) * Yf, axis=0)
    lines = slice(1, segment // 2)   # no DC, no Nyquist bin
    suu, syy, suy = suu[lines], syy[lines], suy[lines]
    ok = suu > 0
    g = np.where(ok, suy / np.where(ok, suu, 1.0), 0.0)
    coherence = np.where(ok, np.abs(suy) ** 2 / np.where(ok, suu * syy, 1.0), 0.0)
    coherence = np.clip(coherence, 0.0, 1.0)
    # Bendat & Piersol eq. 9.90 with the effective number of averages of half-overlapped Hann segments: Welch
    # (1967) gives the variance of their mean as (1 + 2 rho^2 (1 - 1/K)) / K of one segment's, rho = 0.167 the
    # overlap correlation of a Hann window at 50 %: 0.95 of an average per segment, not 1.9 (which counted each
    # overlapped segment twice and halved the variance)
    n_eff = n_seg / (1.0 + 2.0 * HANN_OVERLAP_CORRELATION ** 2 * (1.0 - 1.0 / n_seg))
    with np.errstate(divide="ignore", invalid="ignore"):
        variance = np.where(coherence > 0, (1.0 - coherence) / coherence * np.abs(g) ** 2 / (n_eff - 1.0), np.inf)
        variance = np.maximum(variance, _jackknife_variance(Uf[:, lines], Yf[:, lines], n_eff))
        variance = variance + leakage[lines]
    omega = 2.0 * math.pi * np.arange(segment // 2 + 1)[lines] / (segment * rec.sample_period)
    resolution = 2.0 * math.pi / (segment * rec.sample_period)
    # A line whose input power comes from a few segments only (a step, the step of a sine-plus-step, a
    # chirp's edges) is a transient, not a stationary spectrum: its coherence is 1 by construction and
    # its bound meaningless. Such lines are left out; a run that keeps none is refused.
    power = np.abs(Uf[:, lines]) ** 2
    carried = power.sum(axis=0) ** 2 / np.maximum((power ** 2).sum(axis=0), np.finfo(float).tiny)
    # A line with less input power than a Hann window leaks into it from a neighbour (a quarter of the
    # neighbour's) carries that neighbour's response, not its own: a sine's side bins.
    total = suu
    neighbour = np.maximum(np.r_[0.0, total[:-1]], np.r_[total[1:], 0.0])
    own = total >= LEAKAGE_FRACTION * neighbour
    keep = ok & np.isfinite(variance) & (carried >= MIN_SEGMENTS_PER_LINE) & own
    if not keep.any() and not carried.any():
        raise NotIdentifiableError("the input does not change within any segment (a constant, or a step at the "
                                   "start): it excites no frequency; fit this run in the time domain with "
                                   "motorid identify")
    if not keep.any():
        raise NotIdentifiableError(
            f"the input is not stationary: at every frequency its power comes from fewer than "
            f"{MIN_SEGMENTS_PER_LINE:g} of the {n_seg} segments (at most {float(carried.max(initial=0.0)):.2g}), "
            "as a step or another transient gives; a frequency response needs an input that excites its "
            "frequencies all along the run (a multisine, PRBS, sine or chirp): fit this run in the time domain "
            "with motorid identify")
    return _Lines(omega[keep], g[keep], variance[keep], np.full(int(keep.sum()), 2.0 * (n_eff - 1.0)),
                  coherence[keep], output, "welch", resolution)


def _choose(rec: Recording, method: str, transient_periods: int):
    ex = excitation_of(rec)
    periodic = excitation_period(ex)
    if periodic is not None and rec.n_samples // periodic[0] - transient_periods < 2:
        periodic = None   # too few periods: a PRBS shorter than 3 periods is broadband data
    if method == "auto":
        if periodic is not None:
            return "periodic", periodic
        if isinstance(ex, Multisine):
            return "sines", ex
        return "welch", ex
    if method == "periodic":
        if periodic is None:
            raise NotIdentifiableError(f"method 'periodic' needs a recording of an odd-multisine or PRBS excitation "
                                       f"with at least {transient_periods + 2} whole periods, got excitation "
                                       f"{rec.metadata.get('excitation', 'not recorded')!r} over {rec.n_samples} "
                                       f"samples")
        return method, periodic
    if method == "sines" and not isinstance(ex, Multisine):
        raise NotIdentifiableError(f"method 'sines' needs a recording of a sine or multisine excitation, "
                                   f"got excitation {rec.metadata.get('excitation', 'not recorded')!r}")
    return method, ex


def _pool(parts: Sequence[_Lines]) -> _Lines:
    """Lines of several recordings as one response; equal frequencies averaged by inverse variance."""
    omega = np.concatenate([p.omega for p in parts])
    order = np.argsort(omega, kind="stable")
    cat = {f: np.concatenate([getattr(p, f) for p in parts])[order]
           for f in ("omega", "response", "variance", "dof", "coherence")}
    groups = np.concatenate([[True], ~np.isclose(np.diff(cat["omega"]), 0.0, atol=0.0, rtol=0.0)
                             & (np.abs(np.diff(cat["omega"])) > 1e-12 * cat["omega"][1:])])
    gid = np.cumsum(groups) - 1
    n = gid[-1] + 1 if len(gid) else 0
    weight = 1.0 / np.maximum(cat["variance"], np.finfo(float).tiny)
    wsum = np.bincount(gid, weight, n)
    response = (np.bincount(gid, (weight * cat["response"]).real, n)
                + 1j * np.bincount(gid, (weight * cat["response"]).imag, n)) / wsum
    outputs = {p.output for p in parts}
    if len(outputs) > 1:
        raise NotIdentifiableError("recordings with a speed column and recordings without one measure different "
                                   "speeds (sampled vs interval mean); pool only one kind")
    methods = ",".join(dict.fromkeys(p.method for p in parts))
    return _Lines(cat["omega"][groups], response, 1.0 / wsum, np.bincount(gid, cat["dof"], n),
                  np.bincount(gid, cat["coherence"] * weight, n) / wsum, outputs.pop(), methods,
                  max(p.resolution for p in parts))


def frequency_response(recordings: Recording | Sequence[Recording], *, method: str = "auto",
                       transient_periods: int = 1, segment: int | None = None) -> FrequencyResponse:
    """Frequency response duty -> speed of recordings, with its bound and coherence per frequency.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        One run, or several (one per frequency, realisations of a multisine, ...) pooled into one
        response; lines at the same frequency are averaged by inverse variance.
    method : {"auto", "periodic", "sines", "welch"}
        The estimator (module docstring); ``"auto"`` picks it from each recording's ``excitation``
        metadata: ``periodic`` for an odd multisine or a PRBS of enough periods, ``sines`` for a sine or
        multisine, ``welch`` else.
    transient_periods : int
        Periods of the excitation (of its lowest frequency, for ``sines``) cut at the start of each
        run as transient, default 1.
    segment : int, optional
        ``welch``'s segment length in samples (default about a sixteenth of the run, a power of two).

    Returns
    -------
    FrequencyResponse
        ``frequency_response_data()`` gives the ``control.FrequencyResponseData``; ``radius(level)``,
        ``coherence`` and ``variance`` its bounds.

    Raises
    ------
    NotIdentifiableError
        Too short a run, gaps where the estimator needs whole periods or segments, or an excitation
        the chosen method cannot use.

    Examples
    --------
    >>> from motorsim import Experiment, Motor, OddMultisine, SimRig
    >>> ex = OddMultisine(period=256, max_harmonic=31, amplitude=20)
    >>> rig = SimRig(Motor(25.0, 3.0), record_speed=True)   # an ideal tachometer
    >>> frf = frequency_response(rig.run(Experiment(ex, sample_period=0.005, duration=256 * 0.005 * 4)))
    >>> frf.method, len(frf), frf.output
    ('periodic', 11, 'speed')
    >>> bool(np.allclose(frf.response, frf.model_response(25.0, 3.0), rtol=1e-9, atol=0))
    True
    """
    if method not in ESTIMATORS:
        raise ParameterError(f"method must be one of {', '.join(ESTIMATORS)}, got {method!r}")
    transient_periods = check_int("transient_periods", transient_periods, 0)
    recs = as_recordings(recordings)
    parts = []
    for rec in recs:
        chosen, ex = _choose(rec, method, transient_periods)
        if segment is not None and chosen != "welch":
            raise ParameterError(f"segment applies to method 'welch' only, and method {chosen!r} was chosen "
                                 f"(method={method!r}); got segment={segment!r}: drop it or choose method='welch'")
        if chosen == "periodic":
            period, harmonics = ex
            parts.append(_periodic(rec, period, harmonics, transient_periods))
        elif chosen == "sines":
            parts.append(_sines(rec, ex, transient_periods))
        else:
            parts.append(_welch(rec, segment))
    pooled = _pool(parts)
    dts = {r.sample_period for r in recs}
    if len(dts) > 1:
        raise NotIdentifiableError(f"recordings pooled into one response must share their sample period, "
                                   f"got {sorted(dts)}")
    return FrequencyResponse(pooled.omega, pooled.response, pooled.variance, pooled.dof, pooled.coherence,
                             recs[0].sample_period, pooled.output, pooled.method, pooled.resolution,
                             recs[0].input_unit)
