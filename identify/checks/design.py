"""Experiment design: the sine that pins down a and b best, and a multisine for the frequency response.

For a sine ``A sin(omega t)`` held by the PWM, :func:`identify.checks.uncertainty.cramer_rao_bound`
gives the smallest covariance any unbiased estimator of ``(a, b)`` can reach from the
encoder angle (noise and quantisation).  :func:`design_sine` scans the frequency on a
logarithmic grid from two cycles per run to 0.8 of the Nyquist frequency, refines
around the best, and picks the amplitude: the criterion is the sum of the squared
relative standard errors,

    J(omega, A) = (se_a / a)^2 + (se_b / b)^2,

and with noise that does not depend on the signal the bound scales as ``1/A^2``, so
the largest amplitude within the duty limit wins (checked, not assumed: every
amplitude on a short list is evaluated at the best frequency).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from motorsim.checks import ParameterError, check_int, check_real
from motorsim.excitation import MAX_ODD_LINES, OddMultisine, Sine
from motorsim.plant import first_order_coefficients
from motorsim.rig import Experiment
from motorsim.sensors import DEFAULT_COUNTS_PER_REV

from .uncertainty import cramer_rao_bound

__all__ = ["SineDesign", "DesignPoint", "design_sine", "predicted_stderr", "ARTICLE_FREQUENCIES",
           "ARTICLE_AMPLITUDE", "MultisineDesign", "design_multisine"]

#: The article's four sine frequencies in rad/s (eqs. 29-32), amplitude 200.
ARTICLE_FREQUENCIES = (10.0, 20.0, 30.0, 40.0)
#: The article's sine amplitude in duty units.
ARTICLE_AMPLITUDE = 200


@dataclasses.dataclass(frozen=True)
class DesignPoint:
    """Predicted standard errors of one sine experiment.

    Attributes
    ----------
    frequency : float
        rad/s.
    amplitude : int
        Duty units.
    stderr_a, stderr_b : float
        Cramér-Rao standard errors (1/s and (rad/s^2)/duty).
    a, b : float
        The guesses they are evaluated at.
    """

    frequency: float
    amplitude: int
    stderr_a: float
    stderr_b: float
    a: float
    b: float

    @property
    def relative_stderr(self) -> dict[str, float]:
        """``stderr / |value|`` of a and b."""
        return {"a": self.stderr_a / abs(self.a), "b": self.stderr_b / abs(self.b)}

    @property
    def criterion(self) -> float:
        """``(se_a/a)^2 + (se_b/b)^2`` (dimensionless; smaller is better)."""
        r = self.relative_stderr
        try:
            return r["a"] ** 2 + r["b"] ** 2
        except OverflowError:          # beyond a float's range: no design is judged by it
            return math.inf


@dataclasses.dataclass(frozen=True)
class SineDesign:
    """The result of :func:`design_sine`.

    Attributes
    ----------
    best : DesignPoint
        The recommended frequency and amplitude.
    scan : tuple of DesignPoint
        Every frequency evaluated at the best amplitude, sorted by frequency.
    amplitudes : tuple of DesignPoint
        Every amplitude evaluated at the best frequency.
    article : tuple of DesignPoint
        The article's four sines (200 sin(omega t), omega = 10...40 rad/s) for comparison.
    sample_period, duration, counts_per_rev, angle_noise, duty_limit
        The bench the design is for.
    """

    best: DesignPoint
    scan: tuple
    amplitudes: tuple
    article: tuple
    sample_period: float
    duration: float
    counts_per_rev: int
    angle_noise: float
    duty_limit: int

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {"best": dataclasses.asdict(self.best), "article": [dataclasses.asdict(p) for p in self.article],
                "amplitudes": [dataclasses.asdict(p) for p in self.amplitudes],
                "scan": [dataclasses.asdict(p) for p in self.scan], "sample_period": self.sample_period,
                "duration": self.duration, "counts_per_rev": self.counts_per_rev,
                "angle_noise": self.angle_noise, "duty_limit": self.duty_limit}


def predicted_stderr(a: float, b: float, frequency: float, amplitude: int, sample_period: float,
                     duration: float, *, counts_per_rev: int = DEFAULT_COUNTS_PER_REV, angle_noise: float = 0.0,
                     duty_limit: int = 255) -> DesignPoint:
    """Cramér-Rao standard errors of ``(a, b)`` for the bench's sine ``amplitude sin(frequency t)``.

    The duty is the integer sequence the firmware applies (:func:`motorsim.excitation.Sine`).

    Parameters
    ----------
    a, b : float
        The pole (1/s) and gain ((rad/s^2)/duty) the bound is evaluated at.
    frequency : float
        rad/s.
    amplitude : int
        Duty units.
    sample_period, duration : float
        s.
    counts_per_rev : int
        Encoder resolution.
    angle_noise : float
        Standard deviation of the angle noise in rad.
    duty_limit : int
        Largest duty magnitude.
    """
    exp = Experiment(Sine(frequency, amplitude), sample_period, duration, duty_limit)
    bound = cramer_rao_bound(a, b, exp.duty(), sample_period, counts_per_rev=counts_per_rev,
                             angle_noise=angle_noise)
    se = bound.stderr()
    return DesignPoint(float(frequency), int(amplitude), se["a"], se["b"], float(a), float(b))


def _checked_guesses(a, b, sample_period, duration, angle_noise, duty_limit, counts_per_rev) -> tuple:
    """The arguments every design shares, checked: ``(a, b, sample_period, duration, angle_noise, ...)``."""
    a = check_real("a", a, positive=True)
    b = check_real("b", b)
    if b == 0:
        raise ParameterError(f"b must be nonzero, got {b!r}")
    return (a, b, check_real("sample_period", sample_period, positive=True),
            check_real("duration", duration, positive=True),
            # below 1e100 rad: its square (the noise variance) stays a float (1e308 overflowed)
            check_real("angle_noise", angle_noise, nonnegative=True, below=1e100),
            check_int("duty_limit", duty_limit, 1, 255),
            check_int("counts_per_rev", counts_per_rev, 1, 2**31 - 1))


def design_sine(a: float, b: float, sample_period: float, *, counts_per_rev: int = DEFAULT_COUNTS_PER_REV,
                angle_noise: float = 0.0, duration: float = 10.0, duty_limit: int = 255,
                n_frequencies: int = 48) -> SineDesign:
    """Recommend the sine frequency and amplitude that minimise the Cramér-Rao bound of a and b.

    Parameters
    ----------
    a, b : float
        Rough guesses of the pole (1/s, > 0) and gain ((rad/s^2)/duty, nonzero).
    sample_period : float
        s, > 0.
    counts_per_rev : int
        Encoder resolution.
    angle_noise : float
        Standard deviation of the angle noise in rad, >= 0.
    duration : float
        Length of the run in s.
    duty_limit : int
        Largest duty magnitude, 1...255.
    n_frequencies : int
        Points of the logarithmic frequency scan, >= 8.

    Returns
    -------
    SineDesign
    """
    a, b, sample_period, duration, angle_noise, duty_limit, counts_per_rev = _checked_guesses(
        a, b, sample_period, duration, angle_noise, duty_limit, counts_per_rev)
    n_frequencies = check_int("n_frequencies", n_frequencies, 8, 10_000)
    if duration / sample_period < 20:
        raise ParameterError(f"duration must cover at least 20 samples of {sample_period!r} s, got {duration!r} s")
    lo = 2 * 2 * math.pi / duration               # two cycles per run
    hi = 0.8 * math.pi / sample_period            # 0.8 of the Nyquist frequency
    if lo >= hi:
        raise ParameterError(f"duration {duration!r} s is too short for sample_period {sample_period!r} s: "
                         "no sine fits two cycles below the Nyquist frequency")

    def at(f, amp):
        return predicted_stderr(a, b, f, amp, sample_period, duration, counts_per_rev=counts_per_rev,
                                angle_noise=angle_noise, duty_limit=duty_limit)

    grid = np.geomspace(lo, hi, n_frequencies)
    scan = [at(f, duty_limit) for f in grid]
    criteria = [p.criterion for p in scan]
    if not any(math.isfinite(c) for c in criteria):
        raise ParameterError(f"guesses a = {a:g} 1/s, b = {b:g} (rad/s^2)/duty: the predicted standard errors are "
                             "not finite at any frequency (the motor moves less than the encoder resolves, or the "
                             "numbers are beyond a float's range): give the guesses of a real motor")
    k = int(np.argmin(criteria))
    # refine between the neighbours of the best grid frequency
    fine = np.geomspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 17)[1:-1]
    scan += [at(f, duty_limit) for f in fine]
    scan.sort(key=lambda p: p.frequency)
    best_f = min(scan, key=lambda p: p.criterion).frequency
    amps = sorted({duty_limit, *(int(round(duty_limit * x)) for x in (0.25, 0.5, 0.75))} - {0})
    amplitudes = [at(best_f, amp) for amp in amps]
    best = min(amplitudes, key=lambda p: p.criterion)
    article = [at(f, min(ARTICLE_AMPLITUDE, duty_limit)) for f in ARTICLE_FREQUENCIES if f < math.pi / sample_period]
    return SineDesign(best, tuple(scan), tuple(amplitudes), tuple(article), sample_period, duration,
                      counts_per_rev, angle_noise, duty_limit)


@dataclasses.dataclass(frozen=True)
class MultisineDesign:
    """An odd random-phase multisine for a frequency response over a band, with its predicted precision.

    Attributes
    ----------
    excitation : OddMultisine
        The recommended excitation (``excitation.describe()`` is its command-line form).
    periods : int
        Whole periods in the run (the first is cut as transient by the estimators).
    duration : float
        Run length in s, ``periods`` whole periods.
    band : tuple of float
        Lowest and highest excited frequency in rad/s.
    stderr_a, stderr_b : float
        Cramér-Rao standard errors of ``a`` (1/s) and ``b`` from the run.
    line_stderr : float
        Predicted relative standard error of the frequency response at its worst excited line
        (periods after the transient averaged), from the angle noise and the encoder's rounding.
    a, b : float
        The guesses the prediction is evaluated at.
    """

    excitation: OddMultisine
    periods: int
    duration: float
    band: tuple[float, float]
    stderr_a: float
    stderr_b: float
    line_stderr: float
    a: float
    b: float

    def to_dict(self) -> dict:
        """JSON-ready fields."""
        return {"excitation": self.excitation.describe(), "periods": self.periods, "duration": self.duration,
                "band": list(self.band), "stderr_a": self.stderr_a, "stderr_b": self.stderr_b,
                "line_stderr": self.line_stderr}


def _multisine_amplitude(period: int, max_harmonic: int, duty_limit: int) -> int:
    """The largest line amplitude whose realisation (seed 1) stays within the duty limit."""
    unit = OddMultisine(period, max_harmonic, 100, 1).duty(period, 1.0, 32767)
    amplitude = max(1, min(1023, int(100 * duty_limit / max(np.abs(unit).max(), 1))))
    while amplitude > 1 and np.abs(OddMultisine(period, max_harmonic, amplitude, 1).duty(period, 1.0, 32767)).max() \
            > duty_limit:
        amplitude -= 1
    return amplitude


def _multisine_period(lo: float, dt: float, n_samples: int, duration: float) -> int:
    """The shortest power of two of samples (16 at least) whose fundamental reaches ``lo`` while three periods
    fit the run; a run too short for three periods is refused."""
    period = 16
    while 2 * math.pi / (period * dt) > lo and 2 * period * 3 <= n_samples and period < 65536:
        period *= 2
    if 3 * period > n_samples:
        raise ParameterError(f"duration must hold at least 3 periods of {period} samples "
                             f"({3 * period * dt:.4g} s), got {duration!r} s")
    return period


def design_multisine(a: float, b: float, sample_period: float, *, counts_per_rev: int = DEFAULT_COUNTS_PER_REV,
                     angle_noise: float = 0.0, duration: float = 10.0, duty_limit: int = 255,
                     band: tuple[float, float] | None = None, precision: float | None = None) -> MultisineDesign:
    """Recommend an odd random-phase multisine for the frequency response, and predict its precision.

    The period is the shortest power of two of samples whose fundamental reaches the band's low
    end while at least three periods fit the run (one is cut as transient); the odd lines run up
    to the band's high end (at most :data:`~motorsim.excitation.MAX_ODD_LINES` of them); the line
    amplitude is the largest that keeps the duty within ``duty_limit``.  The response's noise at a
    line is that of the interval-mean speed ``(theta_{k+1} - theta_k)/dt`` with the angle's noise
    ``sigma^2 = angle_noise^2 + q^2/12`` (``q`` one count): ``|e^{j omega dt} - 1|^2 sigma^2 / dt^2``
    per sample, averaged over a period's ``N`` samples and the periods after the transient.

    Parameters
    ----------
    a, b : float
        Rough guesses of the pole (1/s, > 0) and gain ((rad/s^2)/duty, nonzero).
    sample_period : float
        s, > 0.
    counts_per_rev : int
        Encoder resolution.
    angle_noise : float
        Standard deviation of the angle noise in rad, >= 0.
    duration : float
        Longest run in s.
    duty_limit : int
        Largest duty magnitude, 1...255.
    band : tuple of float, optional
        Lowest and highest frequency in rad/s (default ``a/10 ... 10 a``, at most 0.8 of Nyquist).
    precision : float, optional
        Target relative standard error of the response at every line; the run is then the fewest
        periods that reach it (at most ``duration``).

    Returns
    -------
    MultisineDesign

    Examples
    --------
    >>> d = design_multisine(25.0, 3.0, 0.005, angle_noise=1e-3)
    >>> d.excitation.describe(), d.periods, round(d.line_stderr, 3)
    ('odd-multisine:512,101,17,1,3', 3, 0.067)
    """
    a, b, dt, duration, angle_noise, duty_limit, counts_per_rev = _checked_guesses(
        a, b, sample_period, duration, angle_noise, duty_limit, counts_per_rev)
    nyquist = math.pi / dt
    lo, hi = band if band is not None else (a / 10.0, 10.0 * a)
    lo, hi = check_real("band", lo, positive=True), min(check_real("band", hi, positive=True), 0.8 * nyquist)
    if lo >= hi:
        raise ParameterError(f"band must run from a lower to a higher frequency below 0.8 of Nyquist "
                             f"({0.8 * nyquist:.4g} rad/s), got {band!r}")
    n_samples = int(duration / dt)
    period = _multisine_period(lo, dt, n_samples, duration)
    w0 = 2 * math.pi / (period * dt)
    max_harmonic = int(hi / w0)
    max_harmonic = min(max_harmonic - (1 - max_harmonic % 2), 2 * MAX_ODD_LINES - 1, period // 2 - 1)
    max_harmonic = max(max_harmonic, 1)
    amplitude = _multisine_amplitude(period, max_harmonic, duty_limit)
    ex = OddMultisine(period, max_harmonic, amplitude, 1)
    omega = ex.line_frequencies(dt)
    e, p, _ = first_order_coefficients(a, dt)
    g = np.abs(b * p / (np.exp(1j * omega * dt) - e))
    sigma2 = angle_noise**2 + (2 * math.pi / counts_per_rev) ** 2 / 12
    per_period = period * np.abs(np.exp(1j * omega * dt) - 1) ** 2 * sigma2 / dt**2   # |V| noise power per period
    u_line = amplitude * period / 2

    def worst(periods_averaged: int) -> float:
        return float(np.max(np.sqrt(per_period / periods_averaged) / (g * u_line)))

    periods = n_samples // period
    if precision is not None:
        precision = check_real("precision", precision, positive=True)
        periods = next((p for p in range(3, periods + 1) if worst(p - 1) <= precision), periods)
    run = ex.duty(periods * period, dt, duty_limit)
    se = cramer_rao_bound(a, b, run, dt, counts_per_rev=counts_per_rev, angle_noise=angle_noise).stderr()
    return MultisineDesign(ex, periods, periods * period * dt, (float(omega.min()), float(omega.max())),
                           se["a"], se["b"], worst(periods - 1), a, b)
