"""Model quality: simulate an identified model on a recording and score it.

:func:`model_output` and :func:`model_residuals` simulate an :class:`~identify.estimate.Estimate`
on the gap-free segments of a recording, each segment's initial state fitted;
:func:`segment_fit_percent` is the NRMSE fit every estimator reports.

:func:`validate` gives a :class:`ValidationReport` for a (held-out) recording:
NRMSE fit of the simulated speed with the fitted initial state, and the two
classical residual tests (Ljung, *System Identification*, 2nd ed., sec. 16.6):
the residual autocorrelation (whiteness: is anything left to model?) and the
residual-input cross-correlation (is some input dynamics missing?), each with its
95 % band ``+-1.96 / sqrt(N)`` and a portmanteau (Ljung–Box) p-value.
"""
from __future__ import annotations

import dataclasses
import math
import weakref
from typing import Sequence

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int, check_real
from motorsim.plant import Motor, delay_at, simulate
from motorsim.recording import Recording
from motorsim.sensors import backward_difference

from ..data import MIN_SEGMENT_SAMPLES, Segment, counts_behind_speed, prepare_segments, residual_unit
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..model_structures.first_order import INITIAL_WINDOW_TIME_CONSTANTS
from ..model_structures.first_order import initial_state_rule as structure_initial_state_rule
from ..sums import dot, sum_squares

__all__ = ["nrmse_fit", "simulated_speed", "fit_percent", "segment_speeds", "segment_fit_percent",
           "model_output", "model_residuals", "ValidationReport", "validate", "autocorrelation",
           "cross_correlation", "initial_state_rule", "INITIAL_WINDOW_TIME_CONSTANTS"]


def nrmse_fit(measured, simulated) -> float:
    """NRMSE fit in %: ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)``.

    Parameters
    ----------
    measured, simulated : array_like
        ``y`` and ``y_sim``, same shape; pairs with a nan in either are skipped.
    """
    y = np.asarray(measured, dtype=float)
    ys = np.asarray(simulated, dtype=float)
    if y.shape != ys.shape:
        raise ParameterError(f"measured and simulated must have equal shapes, got {y.shape} and {ys.shape}")
    ok = np.isfinite(y) & np.isfinite(ys)
    if ok.sum() < 2:
        return math.nan
    y, ys = y[ok], ys[ok]
    dev, err = y - y.mean(), y - ys
    spread = math.sqrt(sum_squares(dev))
    if spread == 0:
        return math.nan
    return float(100.0 * (1.0 - math.sqrt(sum_squares(err)) / spread))


def simulated_speed(a: float, b: float, recording: Recording, *, input_delay: int = 0) -> np.ndarray:
    """Measured-comparable speed of the model ``b/(s+a)`` on each gap-free segment.

    The model is simulated exactly (ZOH) from the measured speed at the segment's
    second sample, and its angle is differenced like the encoder's, so the result
    is the model's average speed over each interval (``nan`` where the measurement is).

    Parameters
    ----------
    a, b : float
        The model.
    recording : Recording
        Supplies the duty, the time and the measured initial speed of each segment.
    input_delay : int
        Samples of input delay of the model.
    """
    out = np.full(len(recording), np.nan)
    start = 0
    motor = Motor(a, b, input_delay=input_delay) if a > 0 and b != 0 and math.isfinite(a) and math.isfinite(b) else None
    for seg in recording.segments():
        n = len(seg)
        if motor is not None and n >= 3:
            measured = seg.measured_speed()
            traj = simulate(motor, seg.duty[1:], seg.time[1:], initial_speed=float(measured[1]),
                            duty_before=float(seg.duty[0]))
            out[start + 2:start + n] = backward_difference(traj.angle, seg.time[1:])[1:] \
                if seg.speed is None else traj.speed[1:]
        start += n
    return out


def fit_percent(a: float, b: float, recordings: Sequence[Recording], *, input_delay: int = 0) -> float:
    """NRMSE fit (%) of the model's simulated speed against the measured speed, pooled.

    Parameters
    ----------
    a, b : float
        The model.
    recordings : sequence of Recording
        Pooled.
    input_delay : int
        Samples of input delay of the model.
    """
    meas = np.concatenate([r.measured_speed() for r in recordings])
    sim = np.concatenate([simulated_speed(a, b, r, input_delay=input_delay) for r in recordings])
    return nrmse_fit(meas, sim)


def segment_speeds(segment: Segment, model: np.ndarray) -> tuple[slice, np.ndarray, np.ndarray]:
    """Measured and model speed on one segment, and the recording rows they belong to.

    Parameters
    ----------
    segment : Segment
        The data.
    model : ndarray, shape (n,)
        The model's output on the segment, in the segment's kind (angle or speed).

    Returns
    -------
    rows : slice
        Rows of the recording.
    measured, simulated : ndarray
        Speed in rad/s: for angle segments the average over each interval
        (differenced angle, one value fewer), for speed segments the speed itself.
    """
    if segment.kind == "angle":
        dt = np.diff(segment.time)
        rows = slice(segment.start + 1, segment.start + len(segment.time))
        return rows, np.diff(segment.output) / dt, np.diff(model) / dt
    return slice(segment.start, segment.start + len(segment.time)), segment.output, model


def segment_fit_percent(segments: Sequence[Segment], models: Sequence[np.ndarray]) -> float:
    """NRMSE fit (%) of the models' speed against the measured speed, pooled over segments.

    Parameters
    ----------
    segments : sequence of Segment
        The data.
    models : sequence of ndarray
        The model's output on each segment (angle or speed, as the segment).
    """
    speeds = [segment_speeds(seg, model) for seg, model in zip(segments, models)]
    return nrmse_fit(np.concatenate([m for _, m, _ in speeds]), np.concatenate([s for _, _, s in speeds]))


def initial_state_rule(estimate: Estimate) -> str:
    """How :func:`model_output` finds the initial state of each segment for this estimate (one line)."""
    return structure_initial_state_rule(estimate.values())


def _segment_model(estimate: Estimate, seg: Segment) -> np.ndarray:
    """The estimate's native output (angle or speed) on one segment: its structure's
    (:meth:`identify.structures.ModelStructure.segment_output`)."""
    return estimate.model_structure().segment_output(estimate.values(), seg)


def model_output(estimate: Estimate, recording: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The estimate's speed on ``recording`` with each segment's initial state fitted.

    Held-out validation uses this: the initial speed and offset of the test data
    are unknown.  With ``a``, ``b``, ``bias`` fixed the linear model is linear in
    them, so they are solved exactly by least squares; the friction model's initial
    speed is fitted on a short window at the start of each segment, from the measured
    speed (:func:`initial_state_rule`).

    Parameters
    ----------
    estimate : Estimate
        Any method's estimate (``extra`` ``input_delay``, ``bias``, ``friction``,
        ``dead_zone`` are honoured).
    recording : Recording
        The data.

    Returns
    -------
    measured, simulated : ndarray, shape (n,)
        Speed in rad/s, aligned row by row (``nan`` where undefined): for angle
        recordings both are the average speed over each interval (differenced
        angle), for speed-only recordings the speed itself.
    """
    return _speeds(len(recording), _models(estimate, recording))


def _models(estimate: Estimate, recording: Recording) -> list[tuple[Segment, np.ndarray]]:
    """Every segment of ``recording`` with the estimate's output on it (:func:`_segment_model`); a speed column
    that differences encoder counts as the counts, as the estimators see it
    (:func:`identify.data.counts_behind_speed`).

    The estimate's input delay is a time: counted at the recording's sample period (refused
    when it is not a whole number of its samples, :func:`motorsim.plant.delay_at`).  The model a
    fit kept on this very recording with these very values (:func:`keep_models`), or that this function made for
    them last, is not simulated again; the arrays are read-only.
    """
    delay = delay_at(estimate.input_delay, estimate.sample_period, recording.sample_period)
    source = counts_behind_speed(recording) or recording
    key = _model_key(estimate, delay)
    for store in (_kept_models, _made_models):
        kept = store.get(source)
        if kept is not None and kept[0] == key:
            return list(kept[1])
    pairs = [(seg, _segment_model(estimate, seg)) for seg in prepare_segments([source], delay)]
    if any(k != key for k, _ in _made_models.values()):
        _made_models.clear()
    for _, model in pairs:
        model.setflags(write=False)
    _made_models[source] = (key, tuple(pairs))
    return list(pairs)


#: The model of the last fit that kept one (:func:`keep_models`), by recording: ``(key, [(segment, model), ...])``.
#: Weak keys: an entry goes with its recording.
_kept_models: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: The model :func:`_models` simulated last (for one estimate's values, on every recording it was asked for), kept
#: alike: the checks that follow a fit that keeps none (a friction model's part checks, then its outlier check)
#: simulate it once.
_made_models: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _model_key(estimate: Estimate, delay: int) -> tuple:
    """What a segment's model is a function of besides the recording: the structure, its values, the delay."""
    values = tuple(sorted((k, float(v)) for k, v in estimate.values().items()))
    return estimate.structure, values, int(delay)


def keep_models(estimate: Estimate, recordings: Sequence[Recording], segments: Sequence[Segment],
                models: Sequence[np.ndarray]) -> None:
    """Keep a fit's model on its segments, for the checks that follow it on the same recordings (the part
    checks of :mod:`identify.default.consistency` ask :func:`_models` for the chosen fit's model on every row).

    ``segments`` are :func:`identify.data.prepare_segments` of ``recordings`` at the estimate's input delay
    (each naming its recording by index) and ``models`` the estimate's output on each, its initial state (and
    an angle's offset) by least squares as :func:`_segment_model` finds it: the same numbers to rounding.  Only the
    last fit's models are kept (those of a 10^6-row recording are 8 MB); they are made read-only.
    """
    _kept_models.clear()
    key = _model_key(estimate, estimate.input_delay)
    for i, rec in enumerate(recordings):
        pairs = []
        for seg, model in zip(segments, models):
            if seg.recording == i:
                model.setflags(write=False)
                pairs.append((dataclasses.replace(seg, recording=0), model))
        _kept_models[rec] = (key, tuple(pairs))


def _speeds(n: int, models: list[tuple[Segment, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Measured and model speed row by row over ``n`` rows (:func:`model_output`)."""
    meas = np.full(n, np.nan)
    sim = np.full(n, np.nan)
    for seg, model in models:
        rows, measured, simulated = segment_speeds(seg, model)
        meas[rows] = measured
        sim[rows] = simulated
    return meas, sim


def model_residuals(estimate: Estimate, recording: Recording) -> tuple[np.ndarray, np.ndarray, str]:
    """Residuals in the recording's native output, the input aligned with them, and their unit.

    Angle recordings give angle residuals in rad (what the encoder measures; the
    differenced speed would add a lag-one correlation of its own), speed-only
    recordings speed residuals in rad/s.  Segments are concatenated.

    Parameters
    ----------
    estimate : Estimate
        Any method's estimate (as for :func:`model_output`).
    recording : Recording
        The data.
    """
    return _residuals(estimate, _models(estimate, recording))


def _residuals(estimate: Estimate, models: list[tuple[Segment, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, str]:
    """:func:`model_residuals` of the segments' outputs."""
    if not models:
        raise NotIdentifiableError("recording is too short to validate: no gap-free stretch of "
                                   f"{MIN_SEGMENT_SAMPLES + estimate.input_delay} samples")
    segments = [seg for seg, _ in models]
    return (np.concatenate([seg.output - model for seg, model in models]),
            np.concatenate([seg.drive for seg in segments]), residual_unit(segments))


def autocorrelation(x, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation ``r(k) = sum x_t x_{t+k} / sum x_t^2`` for ``k = 0 ... max_lag``.  Its sums go through
    :mod:`identify.sums` (not a threaded BLAS dot product).
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    den = sum_squares(x)
    n = len(x)
    if den == 0:
        return np.full(max_lag + 1, np.nan)
    return np.array([dot(x[:n - k], x[k:]) / den for k in range(max_lag + 1)])


def cross_correlation(x, u, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``r(k) = sum x_{t+k} u_t / sqrt(sum x^2 sum u^2)``, ``k = -max_lag ... max_lag``."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    u = np.asarray(u, dtype=float) - np.mean(u)
    den = math.sqrt(float(x @ x) * float(u @ u))
    n = len(x)
    if den == 0:
        return np.full(2 * max_lag + 1, np.nan)
    out = []
    for k in range(-max_lag, max_lag + 1):
        out.append(float(x[k:] @ u[:n - k]) / den if k >= 0 else float(x[:n + k] @ u[-k:]) / den)
    return np.array(out)


@dataclasses.dataclass(frozen=True, eq=False)
class ValidationReport:
    """How well an estimate explains a recording (see the module docstring).

    Attributes
    ----------
    fit_percent : float
        NRMSE fit in % of the simulated speed on the recording (initial state as ``initial_state``).
    measured_speed, simulated_speed : ndarray, shape (n,)
        rad/s, row-aligned with the recording (``nan`` where undefined).
    time : ndarray, shape (n,)
        Sample instants in s.
    residual : ndarray
        Residual in ``residual_unit`` (angle for encoder recordings), segments concatenated.
    lags : ndarray
        ``0 ... max_lag`` for ``autocorrelation``.
    autocorrelation : ndarray
        Residual autocorrelation at ``lags``.
    cross_lags, cross_correlation : ndarray
        Lags ``-max_lag ... max_lag`` and the residual-input cross-correlation.
    band : float
        95 % band of both correlations, ``1.96 / sqrt(N)``.
    whiteness_p, independence_p : float
        p-values of the Ljung–Box test of the autocorrelation (lags 1..max_lag) and
        of ``N r^T R_u^{-1} r`` for the cross-correlation ``r`` (``R_u`` the input's
        autocorrelation matrix, pseudo-inverted; Ljung eq. 16.53); small values
        reject "white" / "independent of the input".
    residual_unit : str
    initial_state : str
        How the initial state of each segment was found (:func:`initial_state_rule`).
    input_unit : str
        Unit of the recording's input (the estimate's, which :func:`validate` checks).
    largest_input : float
        Largest input magnitude in the recording, in ``input_unit``.
    input_limit : float or None
        The recording's input limit in ``input_unit`` (None when unknown).
    """

    fit_percent: float
    time: np.ndarray
    measured_speed: np.ndarray
    simulated_speed: np.ndarray
    residual: np.ndarray
    lags: np.ndarray
    autocorrelation: np.ndarray
    cross_lags: np.ndarray
    cross_correlation: np.ndarray
    band: float
    whiteness_p: float
    independence_p: float
    residual_unit: str
    initial_state: str = ""
    input_unit: str = "duty"
    largest_input: float = math.nan
    input_limit: float | None = None

    def __repr__(self) -> str:
        return (f"ValidationReport(fit_percent={self.fit_percent:.4g}, whiteness_p={self.whiteness_p:.3g}, "
                f"independence_p={self.independence_p:.3g}, n_samples={len(self.time)})")

    def _lines(self) -> list[tuple[str, str]]:
        white = "white" if self.is_white() else "NOT white (the model misses dynamics or friction)"
        indep = "independent of the input" if self.independence_p >= 0.05 else "CORRELATED with the input"
        limit = "" if self.input_limit is None else f" (limit +-{self.input_limit:g} {self.input_unit})"
        return [("fit", f"{self.fit_percent:.2f} % (NRMSE of the simulated speed; {self.initial_state})"),
                ("residual", f"{white}: Ljung-Box p = {self.whiteness_p:.3g}, "
                             f"{100 * self.share_outside_band:.0f} % of lags outside +-{self.band:.3g}"),
                ("residual", f"{indep}: p = {self.independence_p:.3g}"),
                ("input", f"up to {self.largest_input:.4g} {self.input_unit}{limit}"),
                ("samples", f"{len(self.time)}")]

    def __str__(self) -> str:
        """The fit, the two residual tests and the input, one line each (no arrays)."""
        return "\n".join(f"{name:<9} {text}" for name, text in self._lines())

    def _repr_html_(self) -> str:
        """The same lines as :meth:`__str__`, as an HTML table (notebooks)."""
        import html
        rows = "".join(f"<tr><th>{html.escape(n)}</th><td>{html.escape(t)}</td></tr>" for n, t in self._lines())
        return f"<table><caption>validation</caption>{rows}</table>"

    @property
    def share_outside_band(self) -> float:
        """Share of autocorrelation lags ``1 ... max_lag`` outside the 95 % band."""
        r = self.autocorrelation[1:]
        return float(np.mean(np.abs(r) > self.band)) if len(r) else math.nan

    def is_white(self, level: float = 0.05) -> bool:
        """Residual whiteness is not rejected at ``level`` (Ljung–Box)."""
        return bool(self.whiteness_p >= level)

    def summary(self) -> dict:
        """JSON-ready figures (``motorid identify --validate ... --json``)."""
        return {"validation_fit_percent": self.fit_percent, "whiteness_p": self.whiteness_p,
                "independence_p": self.independence_p, "autocorrelation_outside_band": self.share_outside_band,
                "max_abs_cross_correlation": float(np.nanmax(np.abs(self.cross_correlation))),
                "correlation_band": self.band, "initial_state": self.initial_state}


def validate(estimate: Estimate, recording: Recording, *, max_lag: int = 25) -> ValidationReport:
    """Simulate ``estimate`` on ``recording`` (a held-out run, or the training run) and test its residuals.

    Parameters
    ----------
    estimate : Estimate
        Any method's estimate (``extra`` ``input_delay``, ``bias``, ``friction``, ``dead_zone`` are honoured).
    recording : Recording
        The data to explain.
    max_lag : int
        Largest lag of the correlation tests, >= 1 (default 25).

    Returns
    -------
    ValidationReport
    """
    if not isinstance(recording, Recording):
        raise ParameterTypeError(f"recording must be a Recording, got {type(recording).__name__}")
    max_lag = check_int("max_lag", max_lag, lo=1, allow_integral_float=False)
    for name, value in (("a", estimate.a), ("b", estimate.b), *((f"extra['{k}']", estimate.extra[k])
                                                              for k in ("friction", "bias", "dead_zone")
                                                              if k in estimate.extra)):
        check_real(f"estimate.{name}", value)     # a model with a = nan simulates nan: nothing to validate
    if recording.input_unit != estimate.input_unit:
        raise ParameterError(f"recording input_unit must be the estimate's ({estimate.input_unit}), "
                         f"got {recording.input_unit!r}: a model of one input unit cannot explain another")
    models = _models(estimate, recording)     # simulated once for both the speeds and the residuals
    meas, sim = _speeds(len(recording), models)
    res, inp, unit = _residuals(estimate, models)
    n = len(res)
    lag = int(min(max_lag, max(1, n // 4)))
    ac = autocorrelation(res, lag)
    cc = cross_correlation(res, inp, lag)
    k = np.arange(1, lag + 1)
    q_white = n * (n + 2) * float(np.sum(ac[1:] ** 2 / (n - k)))
    # cross-correlation test (Ljung 1999, eq. 16.53): N r^T R_u^{-1} r, R_u the input's autocorrelation
    # (Toeplitz over the 2 lag + 1 lags); a sine's R_u is singular, so the degrees of freedom are its rank
    ru = autocorrelation(inp, 2 * lag)
    from scipy.linalg import toeplitz  # imported when used: slow to import
    R = toeplitz(ru[:2 * lag + 1])
    vals, vecs = np.linalg.eigh(R)
    keep = vals > 1e-8 * vals.max()
    proj = vecs[:, keep].T @ cc
    q_cross = n * float(np.sum(proj ** 2 / vals[keep]))
    dof_cross = int(keep.sum())
    from scipy.special import chdtrc  # the chi-square survival function, lighter than scipy.stats
    return ValidationReport(fit_percent=nrmse_fit(meas, sim), time=recording.time, measured_speed=meas,
                            simulated_speed=sim, residual=res, lags=np.arange(lag + 1), autocorrelation=ac,
                            cross_lags=np.arange(-lag, lag + 1), cross_correlation=cc, band=1.96 / math.sqrt(n),
                            whiteness_p=float(chdtrc(lag, q_white)),
                            independence_p=float(chdtrc(dof_cross, q_cross)), residual_unit=unit,
                            initial_state=initial_state_rule(estimate), input_unit=recording.input_unit,
                            largest_input=float(np.max(np.abs(recording.duty))) if len(recording) else math.nan,
                            input_limit=recording.input_limit)
