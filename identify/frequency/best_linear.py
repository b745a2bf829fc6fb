"""Best linear approximation and nonlinear distortion from odd random-phase multisines.

From ``M`` realisations (recordings of :class:`~motorsim.excitation.OddMultisine` with the same
period and lines, different seeds) of ``P`` periods each, the robust method of Pintelon &
Schoukens (*System Identification: A Frequency Domain Approach*, 2nd ed. 2012, sec. 3.7, and
Schoukens, Pintelon & Rolain, *Mastering System Identification in 100 Exercises*, 2012,
exercises 66-70) gives at each excited line

* the best linear approximation (BLA) ``G_BLA = mean_m (mean_p Y / U)``,
* its noise variance, from the period-to-period variation of each realisation, and
* its total variance, from the realisation-to-realisation variation (``M >= 2``); the excess
  over the noise is the stochastic nonlinear distortion,

and at the lines left out (odd detection lines, and the even lines, which an odd multisine
never excites) the output no linear motor would produce: the odd-order distortion (Coulomb
friction and a dead zone are odd nonlinearities) and the even-order distortion (asymmetries).
At a non-excited line the output is compared with the BLA's response to whatever the integer
duty's rounding put there, so that rounding is not mistaken for distortion, and with the
noise at that line: under a linear motor ``mean_m |D|^2 / mean_m s^2`` is ``F(2M, 2M(P-1))``.  From
encoder counts the noise is at least the encoder's rounding, which repeats every period on a
noise-free bench (so period-to-period variation cannot see it) but is no distortion of the motor.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence, cast

import numpy as np

from motorsim.checks import ParameterError, check_int, check_real
from motorsim.excitation import OddMultisine
from motorsim.recording import Recording

from ..data import as_recordings
from ..errors import NotIdentifiableError
from .frequency_estimate import FrequencyResponse, excitation_of, periodic_spectra

__all__ = ["BestLinearApproximation", "best_linear_approximation"]


def _check_level(level: float) -> float:
    level = check_real("level", level, positive=True)
    if level >= 1:
        raise ParameterError(f"level must be in (0, 1), got {level!r}")
    return level


@dataclasses.dataclass(frozen=True)
class BestLinearApproximation:
    """The BLA of a motor with its noise and nonlinear distortion levels.

    Attributes
    ----------
    frequency_response : FrequencyResponse
        The BLA at the excited lines; its variance is the total one (noise and distortion) when
        there are several realisations, else the noise's.
    noise_variance : ndarray, shape (n,)
        Variance of the BLA due to noise, at the excited lines, ((rad/s)/duty)^2.
    distortion_variance : ndarray, shape (n,)
        Variance of the BLA due to stochastic nonlinear distortion at the excited lines
        (``nan`` with one realisation).
    detection_omega : ndarray, shape (d,)
        Non-excited lines within the band, rad/s.
    detection_kind : ndarray of str, shape (d,)
        ``"odd"`` (a left-out odd line) or ``"even"``.
    distortion_power : ndarray, shape (d,)
        ``mean_m |Y - G_BLA U|^2`` at the detection lines, (rad/s)^2 per line (DFT units of one period).
    noise_power : ndarray, shape (d,)
        Noise power of the period-averaged output at the detection lines (same unit).
    output_power : float
        Mean power of the linear output ``|G_BLA U|^2`` per excited line (same unit).
    realisations, periods : int
        ``M`` and ``P``.
    """

    frequency_response: FrequencyResponse
    noise_variance: np.ndarray
    distortion_variance: np.ndarray
    detection_omega: np.ndarray
    detection_kind: np.ndarray
    distortion_power: np.ndarray
    noise_power: np.ndarray
    output_power: float
    realisations: int
    periods: int

    def _threshold(self, level: float, n_lines: int = 1) -> float:
        from scipy import stats
        m, p = self.realisations, self.periods
        return float(stats.f.ppf(_check_level(level), 2 * m * n_lines, 2 * m * (p - 1) * n_lines))

    def distorted_lines(self, level: float = 0.999, kind: str | None = None) -> np.ndarray:
        """Detection lines (rad/s) whose output exceeds the noise (an F test at ``level`` per line).

        Parameters
        ----------
        level : float
            Confidence of each line's test; the default 0.999 keeps false alarms to about one
            line in a thousand on a linear motor.
        kind : {"odd", "even"}, optional
            Only lines of this kind.
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = self.distortion_power / self.noise_power
        hit = ratio > self._threshold(level)
        if kind is not None:
            hit &= self.detection_kind == kind
        return self.detection_omega[hit]

    def is_linear(self, level: float = 0.99, kind: str | None = None) -> bool:
        """Whether the output at the detection lines, pooled, stays within the noise (F test at ``level``)."""
        sel = np.ones(len(self.detection_omega), bool) if kind is None else self.detection_kind == kind
        if not np.any(sel):
            return True
        ratio = float(self.distortion_power[sel].sum() / self.noise_power[sel].sum())
        return ratio <= self._threshold(level, int(sel.sum()))

    def distortion_db(self) -> np.ndarray:
        """Distortion at each detection line, in dB below (negative) the mean linear output per line.

        The noise's expected share is subtracted; a line with nothing beyond the noise gives
        the noise level instead (an upper bound).
        """
        excess = self.distortion_power - self.noise_power
        level = np.where(excess > self.noise_power, excess, self.noise_power)
        with np.errstate(divide="ignore"):
            return 10.0 * np.log10(level / self.output_power)

    def noise_db(self) -> np.ndarray:
        """Noise at each detection line in dB relative to the mean linear output per line."""
        with np.errstate(divide="ignore"):
            return 10.0 * np.log10(self.noise_power / self.output_power)

    def summary(self) -> str:
        """One line for a user: linear to within X dB over the band, or where the distortion is."""
        lo, hi = float(self.frequency_response.omega.min()), float(self.frequency_response.omega.max())
        band = f"{lo:.3g}-{hi:.3g} rad/s ({lo / (2 * math.pi):.3g}-{hi / (2 * math.pi):.3g} Hz)"
        if self.is_linear():
            worst = float(self.distortion_db().max()) if len(self.detection_omega) else float("nan")
            return f"linear to within {-worst:.0f} dB over {band}: distortion no larger than the noise"
        parts = []
        for kind, cause in (("odd", "friction or a dead zone; fit oe-friction"),
                            ("even", "an asymmetry (bias, direction-dependent gain)")):
            where = self.distorted_lines(kind=kind)
            if not self.is_linear(kind=kind) and len(where):
                db = self.distortion_db()[np.isin(self.detection_omega, where)].max()
                parts.append(f"{kind}-order distortion above the noise at {where.min():.3g}-{where.max():.3g} rad/s "
                             f"(up to {db:.0f} dB of the output): {cause}")
        worst = float(self.distortion_db().max())
        return "; ".join(parts) or (f"distortion above the noise over {band}, at no single line "
                                    f"(at most {worst:.0f} dB of the output)")

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready table of the BLA, its variances and the detection lines."""
        return {"bla": self.frequency_response.to_dict(), "noise_variance": self.noise_variance.tolist(),
                "distortion_variance": [None if not np.isfinite(x) else float(x) for x in self.distortion_variance],
                "detection_omega": self.detection_omega.tolist(), "detection_kind": self.detection_kind.tolist(),
                "distortion_db": self.distortion_db().tolist(), "noise_db": self.noise_db().tolist(),
                "realisations": self.realisations, "periods": self.periods, "linear": self.is_linear(),
                "summary": self.summary()}


def _common_excitation(recs: Sequence[Recording]) -> OddMultisine:
    exs = [excitation_of(r) for r in recs]
    for i, ex in enumerate(exs):
        if not isinstance(ex, OddMultisine):
            raise NotIdentifiableError(f"recording {i}: the best linear approximation needs odd-multisine runs, "
                                       f"got excitation {recs[i].metadata.get('excitation', 'not recorded')!r}")
    first = cast(OddMultisine, exs[0])
    for i, ex in enumerate(cast(list[OddMultisine], exs)):
        if (ex.period, ex.excited_harmonics()) != (first.period, first.excited_harmonics()):
            raise NotIdentifiableError(f"recording {i}: realisations must share the period and the lines, "
                                       f"got {ex.describe()!r} and {first.describe()!r}")
    if len({r.sample_period for r in recs}) > 1:
        raise NotIdentifiableError("realisations must share their sample period")
    return first


def _rounding_floor(counts_per_rev: int, period: int, dt: float, n_periods: int) -> np.ndarray:
    """Variance of the period-averaged output at each line from the encoder's rounding alone.

    A noise-free encoder rounds the same angles every period, so period-to-period variation does
    not see its error; counted as white angle noise of variance ``q^2/12`` (``q`` one count), the
    interval-mean speed carries ``|e^{j omega dt} - 1|^2 q^2 / (12 dt^2)`` per sample, ``period``
    times that per DFT line, divided by the periods averaged.
    """
    q = 2.0 * math.pi / counts_per_rev
    lines = np.arange(period // 2 + 1)
    diff = np.abs(np.exp(2j * math.pi * lines / period) - 1.0) ** 2
    return period * diff * q**2 / (12.0 * dt**2) / n_periods


def best_linear_approximation(recordings: Recording | Sequence[Recording], *,
                              transient_periods: int = 1) -> BestLinearApproximation:
    """The best linear approximation, noise and nonlinear distortion from odd-multisine runs.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        ``M`` realisations (seeds) of one odd multisine, each of at least ``transient_periods + 2``
        periods; the runs must share the period, lines and sample period.
    transient_periods : int
        Periods cut at the start of each run, default 1.

    Returns
    -------
    BestLinearApproximation

    Raises
    ------
    NotIdentifiableError
        A recording that is not an odd-multisine run, realisations that differ in period or
        lines, or too few periods.

    Examples
    --------
    >>> from motorsim import Encoder, Experiment, Motor, OddMultisine, SimRig
    >>> rigs = [SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(s)) for s in (1, 2)]
    >>> runs = [rig.run(Experiment(OddMultisine(1024, 63, 20, seed=s), sample_period=0.005, duration=1024 * 0.005 * 4))
    ...         for s, rig in zip((1, 2), rigs)]
    >>> bla = best_linear_approximation(runs)
    >>> bla.is_linear(), bla.summary()
    (True, 'linear to within ... dB over 1.23-77.3 rad/s (0.195-12.3 Hz): distortion no larger than the noise')
    """
    transient_periods = check_int("transient_periods", transient_periods, 0)
    recs = as_recordings(recordings)
    ex = _common_excitation(recs)
    spectra = [periodic_spectra(r, ex.period, transient_periods) for r in recs]
    outputs = {s[2] for s in spectra}
    if len(outputs) > 1:
        raise NotIdentifiableError("realisations must all have a speed column or all not")
    n_periods = min(s[0].shape[0] for s in spectra)
    M, P = len(recs), n_periods
    U = np.stack([s[0][-P:].mean(axis=0) for s in spectra])           # (M, lines)
    Ybar = np.stack([s[1][-P:].mean(axis=0) for s in spectra])
    s2 = np.stack([np.sum(np.abs(s[1][-P:] - s[1][-P:].mean(axis=0)) ** 2, axis=0) / (P - 1) / P
                   for s in spectra])                                  # noise variance of Ybar
    dt = recs[0].sample_period
    if outputs == {"angle"} and recs[0].counts_per_rev:
        s2 = np.maximum(s2, _rounding_floor(recs[0].counts_per_rev, ex.period, dt, P))
    k = np.array(ex.excited_harmonics())
    G = Ybar[:, k] / U[:, k]
    g = G.mean(axis=0)
    noise_var = np.sum(s2[:, k] / np.abs(U[:, k]) ** 2, axis=0) / M**2
    if M >= 2:
        total_var = np.sum(np.abs(G - g) ** 2, axis=0) / (M * (M - 1))
        distortion_var = np.maximum(total_var - noise_var, 0.0)
        variance, dof = total_var, np.full(len(k), 2.0 * (M - 1))
    else:
        distortion_var = np.full(len(k), np.nan)
        variance, dof = noise_var, np.full(len(k), 2.0 * (P - 1))
    omega = 2.0 * math.pi * k / (ex.period * dt)
    y_lin = g * U[:, k]
    coherence = np.mean(np.abs(y_lin) ** 2, axis=0) / np.mean(np.abs(y_lin) ** 2 + P * s2[:, k], axis=0)
    frf = FrequencyResponse(omega, g, variance, dof, coherence, dt, outputs.pop(), "bla", 0.0, recs[0].input_unit)

    detection = np.setdiff1d(np.arange(1, ex.max_harmonic + 2), k)
    kinds = np.where(detection % 2 == 1, "odd", "even")
    g_at = np.interp(detection, k, g.real) + 1j * np.interp(detection, k, g.imag)  # the BLA between lines
    d = Ybar[:, detection] - g_at * U[:, detection]
    return BestLinearApproximation(
        frf, noise_var, distortion_var, 2.0 * math.pi * detection / (ex.period * dt), kinds,
        np.mean(np.abs(d) ** 2, axis=0), np.mean(s2[:, detection], axis=0),
        float(np.mean(np.abs(y_lin) ** 2)), M, P)
