"""Identify until confident: an experiment that designs its next block from what it has learned.

:func:`run_until` drives any rig (anything with ``run(experiment) -> Recording``: the simulated
bench, the emulated or the real Arduino) in rounds:

1. **Opening.**  Without a guess, ranging runs from rest: a slow half-sine of duty (up from 0 to
   an amplitude and back) doubling its amplitude until the shaft clearly turns, or until the next
   doubling would leave the speed or travel budget.  The duty where the counts first move is the
   break-away duty; the default estimator on the ranging runs gives a first rough ``a`` and ``b``.
   With a guess (``guess=(a, b)``) the opening is one short sine designed for it.
2. **Rounds.** The default estimator (:func:`identify.fit`) on every run so far; when both 95 %
   intervals of ``a`` and ``b`` lie within ``+-target`` % of their values, the structure is a clear
   choice and the runs would hold ``a`` and ``b`` within the target even with a driver lag or a dead
   time left free (:func:`lag_free_reach`), stop. Otherwise choose the next block: two lines
   (:data:`_SHAPES`: the second at 3-15 times the first; frequency and shape, the largest amplitude
   the duty limit and the budgets allow) or, once a run of more than one duty magnitude is in and
   no travel budget is set, a PRBS of the largest duty the speed budget allows (the bit's hold
   chosen; :func:`_blocks`), whose predicted intervals, with the lag free, reach the
   target soonest, judged over the plausible ``a`` of the interval so far; the block lasts as long
   as the prediction says it takes (at most three times the motor time so far, and the budget left).
   While the choice of structure is not clear, every other block is an odd multisine over ``a/10 ...
   10 a`` (:func:`~identify.checks.design.design_multisine`): the evidence that separates the
   candidates.
3. **Stopping early**, saying why: the time budget is spent (and which parameter is short by how
   much), the model fails (the estimator refuses the data, or its intervals are not finite), or a
   part the target needs cannot be excited within the limits (the motor does not turn at the duty
   limit; the budgets leave no amplitude above the break-away duty).

The prediction is the Fisher information of the linear first-order model at the current
estimate (angle sensitivities of each run, its initial speed and encoder offset profiled out),
summed over runs; its scale (the noise, any widening) is calibrated by the fit's own intervals:
``h_next = h_now sqrt(diag((I_past + I_block)^-1) / diag(I_past^-1))``.

**The answer and its intervals.**  Where the default answers with a first-order motor but the runs
show a lag shorter than the quarter sample it fits (:func:`sub_sample_lag`), the second-order fit's
``a`` and ``b`` are the round's.  Each round's standard errors are widened by :data:`SIMULTANEOUS`
(1.144): each interval is a 97.5 % one, so that the two hold ``a`` and ``b`` at once with at least
95 % (Bonferroni's inequality; Dunn, "Multiple comparisons among means", JASA 56, 1961) -- the stop
needs both, and two correlated 95 % intervals hold both in 90-95 % of runs.  The final answer, where
it has no lag of its own, has the standard errors of ``a`` and ``b`` a fit with the lag left free
would give (:func:`lag_widened`; the stop asks those within the target already).  No further widening is
made for stopping on the data: the rule stops when the intervals are *narrow* enough, a function of
the information and the noise's scale, not of where the estimate lies, which is the fixed-width
rule of Chow and Robbins ("On the asymptotic theory of fixed-width sequential confidence intervals
for the mean", Ann. Math. Statist. 36, 1965), whose intervals keep their level as the width
shrinks; a union bound over the rounds (a confidence sequence) is what a rule stopping on the
estimate's *value* needs (spending ``0.05 / (k (k + 1))`` over rounds ``k``: at the third round
each interval 1.37 times as wide as this one, 1.9 times the motor time).  ``motorid bench coverage
--until`` measures the coverage this gives.

Every run is kept in one :class:`~motorsim.recording.Recording` (:attr:`UntilResult.recording`):
the runs follow each other with a gap of ``seq`` between them, so each is its own segment (its
own initial state) for every estimator, and ``identify.fit(result.fitted_recording)`` reproduces the
final estimate (its covariance before the widenings; :func:`judge` on the same runs gives the round's
answer and reaches; ``oe-electrical``, started from the answer's pole, where a sub-sample lag was taken).
"""
from __future__ import annotations

import dataclasses
import math
import statistics
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int, check_real
from motorsim.excitation import Excitation, Sine
from motorsim.recording import Recording
from motorsim.rig import Experiment

from .errors import NotIdentifiableError
from .estimate import Estimate
from .fits.sensitivity import zoh_response

__all__ = ["run_until", "UntilResult", "UntilRound", "join_runs", "information", "DEFAULT_MAX_TIME",
           "STOP_REASONS", "check_target", "lag_free_reach", "judge", "Judgement", "sub_sample_lag", "simultaneous",
           "lag_widened", "SIMULTANEOUS", "FixedDesign", "design_fixed", "fixed_design_time"]

#: Default motor-time budget in s.
DEFAULT_MAX_TIME = 60.0
#: Why a run stops: the target met, or the reason it cannot be.
STOP_REASONS = ("target", "budget", "model", "limits", "rounds")
#: Samples of ``seq`` left out between runs in the joined recording (each run its own segment).
RUN_GAP = 1
_LEVEL = 0.95
_Z = statistics.NormalDist().inv_cdf(0.5 + _LEVEL / 2)
#: Standard errors are widened by this factor: each interval at ``1 - 0.05/2``, so that the 95 %
#: intervals of ``a`` and ``b`` hold both at once with at least 95 % (Bonferroni), as the stop needs both.
SIMULTANEOUS = statistics.NormalDist().inv_cdf(1 - (1 - _LEVEL) / 4) / _Z
_MAX_ROUNDS = 40
_GROWTH = 3.0          # a block lasts at most this many times the motor time so far
_MARGIN = 1.08         # blocks run this much longer than predicted: one more round costs more
_AIM = 0.8             # a block bringing all the information is designed to bring the intervals to this
                       # share of the target (the prediction is the linear model's, and friction or a lag
                       # take some of the information); one adding a share of it, to 1 - (1 - _AIM) x share
_AIM_MOST = 0.95       # and at most this share of the target: a prediction a few % short is one more round
_PARAMS = ("a", "b")


@dataclasses.dataclass(frozen=True)
class UntilRound:
    """One round: the run made and the estimate on every run so far.

    Attributes
    ----------
    index : int
        1, 2, ...
    phase : str
        ``"ranging"``, ``"opening"`` (a sine for the user's guess) or ``"design"``.
    excitation : str
        The run's excitation (``Excitation.describe()``).
    duration : float
        Motor time of this run in s.
    motor_time : float
        Motor time of every run so far in s.
    why : str
        Why this excitation was chosen.
    estimate : Estimate or None
        The default estimator on every run so far (None when it refused the data).
    intervals : dict
        95 % interval ``(low, high)`` of ``a`` and ``b`` (empty without an estimate).
    reach : dict
        Largest relative distance of each interval's ends from its value, in % (``inf`` when unknown).
    clear : bool or None
        Whether the default called its structure a clear choice.
    predicted : dict
        The reach this round's design predicted for ``a`` and ``b``, in % (empty for the opening).
    lag_free : dict
        The reach of ``a`` and ``b`` had the fit allowed a driver lag or dead time
        (:func:`lag_free_reach`), in %: what the stopping rule asks to be within the target too.
    """

    index: int
    phase: str
    excitation: str
    duration: float
    motor_time: float
    why: str
    estimate: Estimate | None
    intervals: Mapping[str, tuple[float, float]]
    reach: Mapping[str, float]
    clear: bool | None
    predicted: Mapping[str, float]
    lag_free: Mapping[str, float] = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready fields (the estimate's values, not the whole estimate)."""
        est = self.estimate
        return {"round": self.index, "phase": self.phase, "excitation": self.excitation,
                "duration_s": self.duration, "motor_time_s": self.motor_time, "why": self.why,
                "a": None if est is None else est.a, "b": None if est is None else est.b,
                "structure": None if est is None else est.structure,
                "input_delay": None if est is None else est.input_delay,
                "intervals": {k: list(v) for k, v in self.intervals.items()},
                "reach_pct": {k: _finite_or_none(v) for k, v in self.reach.items()},
                "predicted_reach_pct": {k: _finite_or_none(v) for k, v in self.predicted.items()},
                "lag_free_reach_pct": {k: _finite_or_none(v) for k, v in self.lag_free.items()},
                "clear": self.clear}

    def line(self, target: float) -> str:
        """One progress line: excitation, motor time, the intervals against the target."""
        head = f"round {self.index:2d} {self.phase:<8s} {self.excitation:<30s} {self.duration:7.3g} s " \
               f"(total {self.motor_time:.4g} s)"
        if self.estimate is None:
            return f"{head}: no estimate yet ({self.why})"
        parts = [f"{k} = {self.estimate.value(k):.5g} ±{_pct(self.reach[k])}" for k in _PARAMS]
        clear = "clear" if self.clear else "not clear"
        return f"{head}: {', '.join(parts)} (target ±{target:g} %; {self.estimate.structure}, {clear})"


@dataclasses.dataclass(frozen=True)
class UntilResult:
    """What :func:`run_until` found.

    Attributes
    ----------
    reached : bool
        Both intervals within the target and the structure a clear choice.
    stop : str
        One of :data:`STOP_REASONS`: ``"target"``, ``"budget"`` (time budget spent),
        ``"model"`` (the estimator refused the data or gave no finite interval), ``"limits"``
        (a part the target needs cannot be excited within the limits), ``"rounds"``.
    reason : str
        The stop in words: which parameter is short, by how much, and why.
    estimate : Estimate or None
        The final estimate on every run (None when the estimator refused them all).
    recording : Recording
        Every run, one after the other (:func:`join_runs`).
    rounds : tuple of UntilRound
    target : float
        The target in %.
    motor_time : float
        Motor time of every run in s.
    breakaway : float or None
        Duty where the shaft first turned in the ranging runs (None with a guess).
    fitted_recording : Recording
        The runs the estimate is made on, joined: ``identify.fit(result.fitted_recording)``
        reproduces :attr:`estimate`.
    fitted_from : int
        Index of the first run the estimates use: the ranging half-sines (slow ramps from rest, where
        the encoder's rounding is most of the signal) find the break-away duty and the amplitude, and
        are left out of the fits once another run follows them.
    """

    reached: bool
    stop: str
    reason: str
    estimate: Estimate | None
    recording: Recording
    rounds: tuple[UntilRound, ...]
    target: float
    motor_time: float
    breakaway: float | None
    fitted_from: int = 0
    fitted_recording: Recording | None = None

    @property
    def clear(self) -> bool:
        """Whether the final structure is a clear choice."""
        return bool(self.rounds and self.rounds[-1].clear)

    def to_dict(self) -> dict:
        """JSON-ready summary with every round."""
        return {"reached": self.reached, "stop": self.stop, "reason": self.reason, "target_pct": self.target,
                "motor_time_s": self.motor_time, "breakaway_duty": self.breakaway, "clear": self.clear,
                "fitted_from_run": self.fitted_from + 1,
                "rounds": [r.to_dict() for r in self.rounds]}


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _pct(x: float) -> str:
    return f"{x:.3g} %" if math.isfinite(x) else "? %"


def check_target(target: Any) -> float:
    """The target in %: a real number in (0, 100)."""
    value = check_real("target", target, positive=True)
    if not value < 100:
        raise ParameterError(f"target must be a percentage in (0, 100), got {target!r}")
    return value


def _reach(est: Estimate, level: float = _LEVEL) -> tuple[dict, dict]:
    """Intervals of a and b and the largest relative distance of their ends from the values (%)."""
    ci = est.confidence_interval(level)
    out, reach = {}, {}
    for k in _PARAMS:
        lo, hi = ci[k]
        v = float(est.value(k))
        out[k] = (float(lo), float(hi))
        r = 100 * max(v - lo, hi - v) / abs(v) if v != 0 else math.inf
        reach[k] = r if math.isfinite(r) else math.inf
    return out, reach


# --------------------------------------------------------------------------------------------- information

def information(a: float, b: float, duty: np.ndarray, sample_period: float, input_delay: int = 0,
                lag: bool = False, nuisance: Sequence[str] = ()) -> np.ndarray:
    """Fisher information of ``(a, b)`` from one run's encoder angle, per unit angle-noise variance.

    The run's initial speed and encoder offset are profiled out (the Schur complement of the
    full information); ``duty[k]`` is held over sample ``k`` after ``input_delay`` samples of 0.
    With ``lag``, the information is of ``(a, b, tau)``: ``tau`` a driver lag ``1/(tau s + 1)`` (or,
    the same to first order, a dead time) in front of the motor, at ``tau = 0``, where the angle's
    sensitivity to it is minus the speed (``d/dtau b/(s (s + a)(tau s + 1)) = -b/(s + a)``).
    ``nuisance`` names parameters of the model's own (:data:`NUISANCE`), shared by every run, whose
    rows and columns follow (sum the runs' informations, then profile them out with :func:`_profiled`):
    ``"bias"`` (a constant acceleration), ``"friction"`` (Coulomb friction, ``-c sign(omega)``, the
    linear model's speed's sign averaged over each sample), ``"dead_zone"`` (``-b d sign(u)``): friction
    and a dead zone take the information of slow and small runs most, which a prediction from the linear
    model alone leaves in.

    Returns
    -------
    ndarray, shape (2, 2), or (3, 3) with ``lag``; a row and column more per column of ``nuisance``
    """
    u = np.asarray(duty, dtype=float)
    if input_delay:
        u = np.concatenate([np.zeros(input_delay), u[:len(u) - input_delay]])
    t = np.arange(len(u)) * sample_period
    resp = zoh_response(a, b, u, t, 0.0, uniform=True)
    S = resp.angle_sensitivity
    cols = [S[:, 0], S[:, 1]] + ([-resp.speed] if lag else []) + [S[:, 2], np.ones(len(u))]
    if "bias" in nuisance or "friction" in nuisance:
        cols.append(S[:, 3])
    if "friction" in nuisance:
        cols.append(zoh_response(a, 1.0, -_mean_direction(resp.speed), t, 0.0, uniform=True,
                                 sensitivities=False).angle)
    if "dead_zone" in nuisance:
        cols.append(zoh_response(a, b, -np.sign(u), t, 0.0, uniform=True, sensitivities=False).angle)
    # the run's own initial speed and encoder offset last, profiled out here; the shared nuisance before them
    shared = len(cols) - (p := 3 if lag else 2) - 2
    cols = cols[:p] + cols[p + 2:] + cols[p:p + 2]
    J = np.column_stack(cols)
    full = J.T @ J
    p += shared
    A, B, C = full[:p, :p], full[:p, p:], full[p:, p:]
    try:
        out = A - B @ np.linalg.solve(C, B.T)
    except np.linalg.LinAlgError:
        return A
    return out if np.all(np.isfinite(out)) else A


def _mean_direction(speed: np.ndarray) -> np.ndarray:
    """The mean of ``sign(omega)`` over each sample interval (the speed taken linear within it): where
    Coulomb friction acts, held as the drive is."""
    w0, w1 = speed, np.append(speed[1:], speed[-1])
    out = np.sign(w0 + w1)
    cross = (w0 * w1 < 0)
    phi = np.where(cross, w0 / np.where(cross, w0 - w1, 1.0), 0.0)     # the share of the interval before it
    out = np.where(cross, np.sign(w0) * phi + np.sign(w1) * (1 - phi), out)
    return np.where((w0 == 0) & (w1 != 0), np.sign(w1) / 2, np.where((w1 == 0) & (w0 != 0), np.sign(w0) / 2, out))


#: Parameters of a structure that :func:`information` profiles out where the estimate has them.
NUISANCE = ("bias", "friction", "dead_zone")


def _nuisance(est: Estimate | None) -> tuple[str, ...]:
    """The estimate's parameters among :data:`NUISANCE` (static friction counts as friction)."""
    if est is None:
        return ()
    names = set(est.param_names)
    if "static_friction" in names:
        names.add("friction")
    return tuple(k for k in NUISANCE if k in names)


def _profiled(info: np.ndarray, lag_free: bool = True) -> np.ndarray:
    """The (2, 2) information of ``(a, b)`` from one of ``(a, b, tau, shared nuisance...)``: the nuisance
    unknown, ``tau`` unknown (``lag_free``) or known to be 0."""
    keep = [0, 1] + [i for i in range(3, len(info))] if not lag_free and len(info) > 2 else list(range(len(info)))
    m = info[np.ix_(keep, keep)]
    if len(m) == 2:
        return m
    A, B, C = m[:2, :2], m[:2, 2:], m[2:, 2:]
    try:
        out = A - B @ np.linalg.solve(C, B.T)
    except np.linalg.LinAlgError:
        out = A - B @ np.linalg.pinv(C) @ B.T
    return out if np.all(np.isfinite(out)) else A


def _variances(info: np.ndarray) -> np.ndarray:
    try:
        return np.diag(np.linalg.inv(info))
    except np.linalg.LinAlgError:
        return np.full(2, math.inf)


# --------------------------------------------------------------------------------------------- joining

_SUMMED = ("samples_expected", "samples_received", "samples_lost", "samples_ticked", "host_link_frames_lost",
           "device_samples_dropped", "host_rx_errors")


def join_runs(runs: Sequence[Recording], descriptions: Sequence[str] | None = None) -> Recording:
    """The runs as one recording: each after the previous with a gap of ``seq``, so each is its own segment.

    ``time_s`` runs on: a run's first sample is ``(RUN_GAP + 1)`` sample periods after the previous
    run's last, as its ``seq`` is.  The first run's metadata is kept; the loss counters a serial
    rig records are summed, ``excitation`` names every run's, ``duration`` is the motor time.
    """
    if not runs:
        raise ParameterError("runs must hold at least one Recording, got none")
    dt = runs[0].sample_period
    times, duties, counts, seqs, speeds = [], [], [], [], []
    next_seq = 0
    for r in runs:
        if r.sample_period != dt:
            raise ParameterError(f"runs must share one sample_period, got {dt!r} and {r.sample_period!r}")
        seq = r.seq - r.seq[0] + next_seq
        seqs.append(seq)
        times.append(r.time - r.time[0] + next_seq * dt)
        duties.append(r.duty)
        if r.counts is None:
            raise ParameterError("runs must record encoder counts")
        counts.append(r.counts)
        speeds.append(r.speed)
        next_seq = int(seq[-1]) + 1 + RUN_GAP
    meta = dict(runs[0].metadata)
    for key in _SUMMED:
        if all(key in r.metadata for r in runs):
            meta[key] = str(sum(int(r.metadata[key]) for r in runs))
    if "samples_lost" in meta and "samples_ticked" in meta:
        meta["loss_fraction"] = repr(int(meta["samples_lost"]) / max(int(meta["samples_ticked"]), 1))
    if descriptions is None:
        descriptions = [r.metadata.get("excitation", "?") for r in runs]
    meta["excitation"] = " ; ".join(descriptions)
    meta["runs"] = str(len(runs))
    meta["duration"] = repr(sum(float(r.metadata.get("duration", len(r) * dt)) for r in runs))
    speed = None if any(x is None for x in speeds) else np.concatenate([x for x in speeds if x is not None])
    return Recording(time=np.concatenate(times), duty=np.concatenate(duties), sample_period=dt,
                     counts=np.concatenate(counts), speed=speed, seq=np.concatenate(seqs),
                     counts_per_rev=runs[0].counts_per_rev, metadata=meta)


# --------------------------------------------------------------------------------------------- the loop

@dataclasses.dataclass
class _State:
    runs: list
    descriptions: list
    rounds: list
    motor_time: float = 0.0
    halfsines: int = 0

    @property
    def fitted_from(self) -> int:
        """The first run the fits use: after the ranging half-sines once another run follows them."""
        return self.halfsines if len(self.runs) > self.halfsines else 0

    @property
    def fitted(self) -> list:
        return self.runs[self.fitted_from:]


def _fit(recording: Recording, fit_options: Mapping[str, Any]) -> tuple[Estimate | None, str]:
    from . import fit
    try:
        return fit(recording, outliers="keep", **fit_options), ""
    except (NotIdentifiableError, ParameterError) as exc:
        return None, str(exc)
    except (ArithmeticError, np.linalg.LinAlgError) as exc:      # a numerical failure on data this poor
        return None, f"the fit failed ({type(exc).__name__}: {exc})"


#: Structures without friction: behind them a significant sub-sample lag is taken whatever the residuals.
_LAGLESS = ("linear", "bias")
#: A sub-sample lag is taken when its time constant is this many standard errors above 0 (the 1 %
#: level, two-sided, of the default's own checks).
_LAG_Z = statistics.NormalDist().inv_cdf(0.995)
#: Lags (in samples) the second-order fit starts from at the answer's own pole.
_LAG_STARTS = (0.05, 0.1, 0.2, 0.4, 1.0)


def sub_sample_lag(recording: Recording, est: Estimate) -> Estimate | None:
    """The second-order fit of ``recording`` where it shows a lag the default's answer leaves out, else None.

    The default makes ``second-order`` a candidate only when its lag is at least a quarter sample,
    and fits the first-order motor otherwise; but a lag ``tau`` (or a dead time of a fraction of a
    sample, the same to first order) seen through a first-order model moves its pole to about
    ``a / (1 + a tau)``: 1.2 % at ``a`` = 20 1/s and ``tau`` = 0.6 ms, 13 % at 150 1/s and 1 ms, far
    more than the intervals a run to +-1 % gives.  ``oe-electrical`` (``b / ((s + a)(tau s + 1))``)
    at the chosen delay is fitted, and taken when its ``tau`` is more than :data:`_LAG_Z` standard
    errors above 0 (and off the search's lower bound): its ``a`` and ``b`` hold whether the rig has a lag or
    a fractional dead time.  Behind an answer with friction or a dead zone (which can stand in for a
    lag's distortion: a = 108 for 117 1/s behind 0.64 ms, called clear), the lag is taken only where it
    fits the runs at least as well without them.
    """
    from .fits.electrical import fit_electrical_from
    if est.structure == "second-order" or _has_lag(est):
        return None
    a0, h = float(est.a), recording.sample_period
    # started from the answer's own pole too: from the regression's start alone the search can end on the two
    # poles equal (a = 44.5 and tau = 22 ms for a = 20.4 behind 0.63 ms), missing the short lag
    starts = [(a0, 1 / (k * h)) for k in _LAG_STARTS] if math.isfinite(a0) and a0 > 0 else []
    try:
        lagged = fit_electrical_from(recording, input_delay=int(est.input_delay), starts=starts)
    except (NotIdentifiableError, ParameterError, ArithmeticError, np.linalg.LinAlgError):
        return None
    tau = float(lagged.value("electrical_time_constant"))
    se = float(lagged.stderr().get("electrical_time_constant", math.nan))
    from .fits.electrical import TAU_BOUNDS_SAMPLES
    floor = 2 * TAU_BOUNDS_SAMPLES[0] * recording.sample_period      # a fit at its search's bound found no lag
    if not (math.isfinite(tau) and math.isfinite(se) and se > 0 and tau > max(_LAG_Z * se, floor)):
        return None
    if not all(math.isfinite(float(x)) for x in (lagged.a, lagged.b)) or lagged.a <= 0:
        return None
    if est.structure not in _LAGLESS and not (lagged.residual_unit == est.residual_unit
                                              and lagged.residual_rms <= est.residual_rms):
        return None         # friction or a dead zone fits the runs better than a lag without them
    return lagged


@dataclasses.dataclass(frozen=True)
class Judgement:
    """What the stopping rule sees on a set of runs (:func:`judge`).

    Attributes
    ----------
    estimate : Estimate or None
        The answer, its covariance widened by :data:`SIMULTANEOUS` (None: the estimator refused the runs).
    clear : bool or None
        Whether the default called its structure a clear choice.
    intervals, reach, lag_free : dict
        The answer's 95 % intervals of ``a`` and ``b``, their reach in %, and the reach with a lag left free.
    problem : str
        Why the estimator refused the runs ("" when it did not).
    structure : str
        The default's structure (before a sub-sample lag replaced its ``a`` and ``b``).
    lag_ms : float or None
        The sub-sample lag taken, in ms (None where none was).
    first_order_a : float
        The default's ``a`` where a sub-sample lag replaced it (nan otherwise).
    """

    estimate: Estimate | None
    clear: bool | None
    intervals: Mapping[str, tuple[float, float]]
    reach: Mapping[str, float]
    lag_free: Mapping[str, float]
    problem: str = ""
    structure: str = ""
    lag_ms: float | None = None
    first_order_a: float = math.nan

    def within(self, target: float) -> bool:
        """The stopping rule: both intervals, and both with a lag left free, within ``+-target`` %, and clear."""
        return bool(self.estimate is not None and self.clear
                    and all(self.reach[k] <= target and self.lag_free.get(k, 0) <= target for k in _PARAMS))

    @property
    def worst(self) -> float:
        """The largest of the reaches and the lag-free reaches, in % (``inf`` without an estimate)."""
        return max([*self.reach.values(), *self.lag_free.values()], default=math.inf)


def judge(runs: Sequence[Recording], fit_options: Mapping[str, Any] | None = None,
          descriptions: Sequence[str] | None = None) -> Judgement:
    """The answer :func:`run_until` gives on ``runs`` and what its stopping rule sees in it.

    The default estimator on the runs joined (:func:`join_runs`); the second-order fit where the runs show
    a sub-sample lag the answer leaves out (:func:`sub_sample_lag`); the covariance widened by
    :data:`SIMULTANEOUS`; the reach of both intervals, and with a lag left free (:func:`lag_free_reach`).
    ``motorid bench until`` judges its fixed experiments with it, so that they meet the same rule.
    """
    options = dict(fit_options or {})
    joined = join_runs(runs, descriptions)
    est, problem = _fit(joined, options)
    if est is None:
        inf = {k: math.inf for k in _PARAMS}
        return Judgement(None, None, {}, inf, dict(inf), problem)
    clear = bool(est.selection.clear) if est.selection is not None else True
    structure, lag_ms, first_a = est.structure, None, math.nan
    lagged = None if "method" in options else sub_sample_lag(joined, est)
    if lagged is not None:
        lag_ms, first_a = 1e3 * float(lagged.value("electrical_time_constant")), float(est.a)
        est = lagged
    est = simultaneous(est)
    intervals, reach = _reach(est)
    return Judgement(est, clear, intervals, reach, lag_free_reach(runs, est, reach), "", structure, lag_ms, first_a)


def simultaneous(est: Estimate) -> Estimate:
    """The estimate with its covariance scaled by :data:`SIMULTANEOUS` squared: 95 % intervals for ``a``
    and ``b`` at once (the ranges of candidates the data cannot rule out kept as they are)."""
    if est.covariance is None:
        return est
    return dataclasses.replace(est, covariance=np.asarray(est.covariance, dtype=float) * SIMULTANEOUS ** 2)


def lag_widened(est: Estimate, reach: Mapping[str, float], lag_free: Mapping[str, float]) -> Estimate:
    """The answer with the standard errors of ``a`` and ``b`` widened to those with a lag left free.

    A first-order answer whose runs do not rule out a driver lag (or a fraction of a sample's dead time)
    holds ``a`` and ``b`` only as well as a fit with the lag free would: such a lag, too small to be
    told from noise, still moves the first-order ``a`` by about ``a^2 tau``.  The stop already asks
    that the lag-free reach (:func:`lag_free_reach`) be within the target, so the wider intervals cost
    no motor time; each standard error is scaled by ``lag_free / reach`` (at least 1), the
    correlations kept.  An answer with a lag of its own, or without a covariance, is returned as it is.
    """
    if est.covariance is None or _has_lag(est):
        return est
    scale = np.ones(len(est.param_names))
    for k in _PARAMS:
        r, f = reach.get(k, math.nan), lag_free.get(k, math.nan)
        if math.isfinite(r) and math.isfinite(f) and r > 0 and f > r:
            scale[est.param_names.index(k)] = f / r
    if np.all(scale == 1):
        return est
    cov = np.asarray(est.covariance, dtype=float) * np.outer(scale, scale)
    return dataclasses.replace(est, covariance=cov)


def _breakaway(run: Recording, delay: int) -> float | None:
    """Duty at which the counts first move clearly from where they started (None if never).

    "Clearly": a running median of five counts more than three counts, and more than six times
    the counts' own noise (from the differences of the first 20 samples, at rest), from the start.
    """
    c = np.asarray(run.counts, dtype=float)
    if len(c) < 10:
        return None
    d = np.diff(c[:20])
    noise = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2)
    smooth = np.array([np.median(c[max(0, k - 2):k + 3]) for k in range(len(c))])
    moved = np.flatnonzero(np.abs(smooth - np.median(c[:5])) > max(3.0, 6 * noise))
    if len(moved) == 0:
        return None
    k = max(int(moved[0]) - 1 - delay, 0)
    return float(np.abs(run.duty[:k + 1]).max())


def _turned(run: Recording, amplitude: float, breakaway: float | None) -> bool:
    """Whether a ranging half-sine up to ``amplitude`` turned the shaft clearly: over 20 counts, and the
    counts moving before 0.85 of the amplitude or a radian of travel.

    A slow motor behind friction is first seen moving well after it breaks away (the angle grows as the
    square of the time): a radian of travel is a clear turn however late the counts were seen moving.
    """
    counts = np.asarray(run.counts)
    moved = abs(int(counts.max()) - int(counts.min()))
    travel = 2 * math.pi * moved / (run.counts_per_rev or 1)
    return moved > 20 and breakaway is not None and (breakaway < 0.85 * amplitude or travel >= 1.0)


def _peak_speed(run: Recording) -> float:
    """Largest differenced speed of a run in rad/s."""
    angle = 2 * math.pi * np.asarray(run.counts, float) / (run.counts_per_rev or 1)
    if len(angle) < 2:
        return 0.0
    return float(np.max(np.abs(np.diff(angle))) / run.sample_period)


def _travel(run: Recording) -> float:
    angle = 2 * math.pi * np.asarray(run.counts, float) / (run.counts_per_rev or 1)
    return float(angle.max() - angle.min())


def run_until(rig: Any, target: float, *, sample_period: float = 0.005, duty_limit: int = 255,
              max_time: float = DEFAULT_MAX_TIME, max_speed: float | None = None, max_travel: float | None = None,
              guess: tuple[float, float] | None = None, fit_options: Mapping[str, Any] | None = None,
              input_delay: int = 0, max_rounds: int = _MAX_ROUNDS,
              on_round: Callable[[UntilRound], None] | None = None,
              run: Callable[[Any, Experiment], Recording] | None = None) -> UntilResult:
    """Run experiments on ``rig`` until the 95 % intervals of ``a`` and ``b`` are within ``+-target`` %.

    Parameters
    ----------
    rig : Rig
        Anything with ``run(experiment) -> Recording`` (``SimRig``, ``hardware.SerialRig`` opened).
    target : float
        Half-width of both intervals in % of their values, in (0, 100).
    sample_period : float
        s, > 0.
    duty_limit : int
        Largest duty magnitude, 1...255.
    max_time : float
        Motor-time budget in s, > 0 (every run counts, the ranging too).
    max_speed : float, optional
        Largest shaft speed the runs may ask for, rad/s (> 0): the amplitude of every block
        keeps the model's steady speed within it.
    max_travel : float, optional
        Largest swing of the shaft angle in rad (> 0): sines are kept within it (the ranging too).
    guess : (a, b), optional
        A first ``a`` (1/s, > 0) and ``b`` (nonzero) replacing the ranging.
    fit_options : mapping, optional
        Options of ``identify.fit`` on every round (``{"input_delay": 1}`` for a rig whose delay is known).
    input_delay : int
        The rig's known input delay in samples, for the ranging's break-away duty (the fits find their own).
    max_rounds : int
        Rounds after which the run stops however far it got.
    on_round : callable, optional
        Called with each :class:`UntilRound` as it is made.
    run : callable, optional
        ``run(rig, experiment) -> Recording`` (default ``rig.run(experiment)``): a command passes
        one that shows the samples as they arrive.

    Returns
    -------
    UntilResult

    Examples
    --------
    >>> from identify.adaptive import run_until
    >>> from motorsim import Encoder, Motor, SimRig
    >>> import numpy as np
    >>> rig = SimRig(Motor(25.0, 3.0), Encoder(1000, angle_noise=2e-3), rng=np.random.default_rng(1))
    >>> result = run_until(rig, 1.0)
    >>> result.reached, result.stop, all(r <= 1.0 for r in result.rounds[-1].reach.values())
    (True, 'target', True)
    """
    target = check_target(target)
    sample_period = check_real("sample_period", sample_period, positive=True)
    duty_limit = check_int("duty_limit", duty_limit, 1, 255)
    max_time = check_real("max_time", max_time, positive=True)
    if not math.isfinite(max_time):
        raise ParameterError(f"max_time must be a finite number of seconds, got {max_time!r}")
    if max_speed is not None:
        max_speed = check_real("max_speed", max_speed, positive=True)
    if max_travel is not None:
        max_travel = check_real("max_travel", max_travel, positive=True)
    if guess is not None:
        if not isinstance(guess, (tuple, list)) or len(guess) != 2:
            raise ParameterTypeError(f"guess must be a pair (a, b), got {guess!r}")
        ga = check_real("guess a", guess[0], positive=True)
        gb = check_real("guess b", guess[1])
        if gb == 0:
            raise ParameterError(f"guess b must be nonzero, got {guess[1]!r}")
        guess = (ga, gb)
    input_delay = check_int("input_delay", input_delay, 0, 1000)
    max_rounds = check_int("max_rounds", max_rounds, 1, 10_000)
    loop = _Loop(rig, target, sample_period, duty_limit, max_time, max_speed, max_travel, guess,
                 dict(fit_options or {}), input_delay, max_rounds, on_round,
                 run if run is not None else (lambda r, e: r.run(e)))
    return loop.opening() or loop.rounds()


@dataclasses.dataclass
class _Loop:
    """The state and the steps of :func:`run_until` (arguments already checked)."""

    rig: Any
    target: float
    sample_period: float
    duty_limit: int
    max_time: float
    max_speed: float | None
    max_travel: float | None
    guess: tuple[float, float] | None
    fit_options: dict
    input_delay: int
    max_rounds: int
    on_round: Callable[[UntilRound], None] | None
    runner: Callable[[Any, Experiment], Recording]
    state: _State = dataclasses.field(default_factory=lambda: _State([], [], []))
    breakaway: float | None = None

    @property
    def min_block(self) -> float:
        return max(0.25, 40 * self.sample_period)

    def do(self, phase: str, excitation: Excitation, duration: float, why: str, predicted: Mapping[str, float],
           halfsine: bool = False) -> UntilRound:
        """Run one block, fit the runs so far, record and report the round."""
        state, dt = self.state, self.sample_period
        n = max(int(round(duration / dt)), 20)
        rec = self.runner(self.rig, Experiment(excitation, dt, n * dt, self.duty_limit))
        state.runs.append(rec)
        state.descriptions.append(excitation.describe())
        state.halfsines += bool(halfsine)
        state.motor_time += n * dt
        first = state.fitted_from
        j = judge(state.fitted, self.fit_options, state.descriptions[first:])
        est, clear, intervals, reach, lag_free = j.estimate, j.clear, j.intervals, j.reach, j.lag_free
        if j.lag_ms is not None:
            why = f"{why}; the runs show a lag of {j.lag_ms:.2g} ms ({1e-3 * j.lag_ms / dt:.2g} sample) behind the " \
                  f"'{j.structure}' answer (a = {j.first_order_a:.5g}): the second-order fit's a and b"
        if j.problem:
            why = f"{why}; the estimator refused the runs so far: {j.problem}"
        rnd = UntilRound(len(state.rounds) + 1, phase, excitation.describe(), n * dt, state.motor_time, why, est,
                         intervals, reach, clear, dict(predicted), lag_free)
        state.rounds.append(rnd)
        if self.on_round is not None:
            self.on_round(rnd)
        return rnd

    def finish(self, stop: str, reason: str) -> UntilResult:
        state = self.state
        last = next((r for r in reversed(state.rounds) if r.estimate is not None), None)
        est = None if last is None else lag_widened(last.estimate, last.reach, last.lag_free)
        recording = join_runs(state.runs, state.descriptions) if state.runs else None
        fitted = join_runs(state.fitted, state.descriptions[state.fitted_from:]) if state.runs else None
        return UntilResult(stop == "target", stop, reason, est, recording, tuple(state.rounds),  # type: ignore
                           self.target, state.motor_time, self.breakaway, state.fitted_from, fitted)

    def opening(self) -> UntilResult | None:
        """The ranging (or the guess's sine); a result when it already has to stop."""
        if self.guess is not None:
            ga, gb = self.guess
            f = min(max(ga, 2 * 2 * math.pi / 1.0), 0.8 * math.pi / self.sample_period)
            amp = _amplitude(ga, gb, f, self.duty_limit, self.max_speed, self.max_travel)
            length = max(self.min_block, min(2.0, 6 * 2 * math.pi / f))
            self.do("opening", Sine(f, amp), length, f"opening: a sine at the guess's corner a = {ga:.4g} 1/s", {})
            return None
        amplitude = max(8, self.duty_limit // 8)
        while True:
            length = max(self.min_block, 0.5)
            if self.state.motor_time + length > self.max_time:
                return self.finish("budget", f"the time budget of {self.max_time:g} s was spent on ranging: the "
                                             f"shaft did not turn clearly up to duty {amplitude}")
            ex = Sine(math.pi / length, amplitude)            # half a sine: up from 0 and back
            self.do("ranging", ex, length, f"ranging: half a sine up to duty {amplitude}", {}, halfsine=True)
            if self._ranged(self.state.runs[-1], amplitude) or amplitude >= self.duty_limit:
                break
            amplitude = min(2 * amplitude, self.duty_limit)
        if self.breakaway is None:
            return self.finish("limits", f"the shaft did not turn at any duty up to {amplitude} (duty limit "
                                         f"{self.duty_limit}): a and b cannot be excited; check the motor's supply "
                                         f"and wiring, or raise the duty limit")
        last = self.state.rounds[-1]
        if last.estimate is None or max(last.reach.values()) > 50:
            self._broadband(last, amplitude)
        return None

    def _ranged(self, run: Recording, amplitude: int) -> bool:
        """Note the break-away duty; whether the shaft turned clearly or the budgets say stop doubling."""
        ba = _breakaway(run, self.input_delay)
        if ba is not None and self.breakaway is None:
            self.breakaway = ba
        turned = _turned(run, amplitude, ba)
        over = (self.max_speed is not None and _peak_speed(run) > 0.5 * self.max_speed) or \
               (self.max_travel is not None and _travel(run) > 0.5 * self.max_travel)
        return turned or over

    def _broadband(self, last: UntilRound, amplitude: int) -> None:
        """A slow half-sine shows b/a; a PRBS at the amplitude the budgets allow shows a."""
        from motorsim.excitation import PRBS
        level = float(self.duty_limit - 2)
        if last.estimate is not None and last.estimate.a > 0:
            gain = abs(last.estimate.b / last.estimate.a)
            if self.max_speed is not None:
                level = min(level, self.max_speed / gain)
            if self.max_travel is not None:      # a bit of 10 ms moves the shaft at most gain * level * 0.01
                level = min(level, self.max_travel / (20 * gain * 0.01))
        floor = amplitude if self.breakaway is None else self.breakaway + 1
        level = min(int(max(floor, min(level, self.duty_limit))), self.duty_limit)
        length = max(self.min_block, 0.5)
        if self.state.motor_time + length <= self.max_time:
            self.do("ranging", PRBS(level, -level, 7, max(1, int(round(0.01 / self.sample_period))), 1), length,
                    f"ranging: a PRBS of duty ±{level} for a first a (a slow half-sine shows b/a only)", {})

    def rounds(self) -> UntilResult:
        """Fit, check, design, run: until the target or a reason to stop."""
        since_multisine = 0
        while True:
            stop = self._stop()
            if isinstance(stop, UntilResult):
                return stop
            a0, b0 = stop
            last = self.state.rounds[-1]
            left = self.max_time - self.state.motor_time
            if last.clear is False and since_multisine >= 1 and last.estimate is not None:
                since_multisine = 0
                block = _multisine_block(a0, b0, self.sample_period, self.duty_limit,
                                         min(left, max(2.0, self.state.motor_time)), self.max_speed)
                if block is not None:
                    self.do("design", block[0], block[1], "the structure is not a clear choice: a multisine over "
                                                          "a/10 ... 10 a for the evidence between the candidates", {})
                    continue
            since_multisine += 1
            design = _design_block(self.state, last, a0, b0, self.target, self.sample_period, self.duty_limit, left,
                                   self.max_speed, self.max_travel, self.min_block, self.fit_options, self.breakaway)
            if isinstance(design, str):
                return self.finish("limits", design)
            ex, length, predicted, why = design
            self.do("design", ex, length, why, predicted)

    def _stop(self) -> UntilResult | tuple[float, float]:
        """The result when the loop stops here, else the ``(a, b)`` to design the next block for."""
        state, target = self.state, self.target
        last = state.rounds[-1]
        est = last.estimate
        if est is not None and all(last.reach[k] <= target and last.lag_free.get(k, 0) <= target for k in _PARAMS) \
                and last.clear:
            return self.finish("target", f"both 95 % intervals within ±{target:g} % after {state.motor_time:.4g} s "
                                         f"of motor time (a ±{_pct(last.reach['a'])}, b ±{_pct(last.reach['b'])}); "
                                         f"the structure '{est.structure}' is a clear choice")
        if len(state.rounds) >= self.max_rounds:
            return self.finish("rounds", _short(last, target, f"stopped after {self.max_rounds} rounds"))
        if self.max_time - state.motor_time < self.min_block:
            return self.finish("budget", _short(last, target, f"the time budget of {self.max_time:g} s is spent"))
        if est is None:
            if len(state.rounds) >= 3 and all(r.estimate is None for r in state.rounds[-3:]):
                return self.finish("model", f"the estimator refused the runs three rounds running: {last.why}")
            return self.guess if self.guess is not None else (10.0, 1.0)
        a0, b0 = float(est.a), float(est.b)
        if not (math.isfinite(a0) and math.isfinite(b0)) or a0 <= 0 or b0 == 0:
            return self.finish("model", f"the fitted model has a = {a0:.4g} 1/s, b = {b0:.4g}: not a stable "
                                        f"first-order motor to design for")
        speed = None if self.breakaway is None else self.breakaway * abs(b0) / a0
        if speed is not None and self.max_speed is not None and speed > self.max_speed:
            return self.finish("limits", f"the break-away duty {self.breakaway:g} already drives the shaft at about "
                                         f"{speed:.3g} rad/s, above the speed budget {self.max_speed:g} rad/s: no "
                                         f"amplitude above break-away stays within it")
        return a0, b0


def _short(last: UntilRound, target: float, head: str) -> str:
    """Which parameter is short of the target and by how much, and whether the model is clear."""
    if last.estimate is None:
        return f"{head}; the estimator refused the runs ({last.why})"
    short = [f"{k} ±{_pct(last.reach[k])} (target ±{target:g} %)" for k in _PARAMS if last.reach[k] > target]
    parts = [head]
    if short:
        parts.append("short: " + ", ".join(short))
    lag = [f"{k} ±{_pct(last.lag_free[k])}" for k in _PARAMS
           if last.reach[k] <= target < last.lag_free.get(k, 0)]
    if lag:
        parts.append("with a driver lag or dead time allowed for, " + ", ".join(lag) + " (the runs do not yet rule "
                     "out a lag that would move them)")
    if not last.clear:
        parts.append(f"the structure '{last.estimate.structure}' is not a clear choice (a candidate the data cannot "
                     f"rule out remains)")
    return "; ".join(parts)


def _amplitude(a: float, b: float, frequency: float, duty_limit: int, max_speed: float | None,
               max_travel: float | None) -> int:
    """The largest sine amplitude within the duty limit whose steady speed and swing keep the budgets."""
    amp = float(duty_limit - 2 if duty_limit > 10 else duty_limit)     # the integer sine stays off the clamp
    gain = abs(b) / math.hypot(a, frequency)          # rad/s per duty at this frequency
    if max_speed is not None:
        amp = min(amp, max_speed / gain)
    if max_travel is not None:
        # the swing 2 A gain / w, and the drift of the start from rest (at most as much again)
        amp = min(amp, max_travel * frequency / (4 * gain))
    return int(max(1, min(duty_limit, math.floor(amp))))


def _design_block(state: _State, last: UntilRound, a: float, b: float, target: float, dt: float,
                  duty_limit: int, left: float, max_speed: float | None, max_travel: float | None,
                  min_block: float, fit_options: Mapping[str, Any], breakaway: float | None
                  ) -> tuple[Excitation, float, dict, str] | str:
    """The next sine and its length, or why none within the limits can help.

    The reach of each interval after a block is predicted as its reach now times
    ``sqrt(var(I_past + I_block) / var(I_past))`` at each plausible ``a`` (the interval's ends
    while it is wide, ``b`` moved with it so that ``b/a`` stays); the sine chosen reaches the target
    soonest at the worst of them.
    """
    est = last.estimate
    delay = int(est.input_delay) if est is not None else int(fit_options.get("input_delay", 0) or 0)
    # the chosen fit's own standard errors (not widened by candidates it cannot rule out): the noise's scale
    own = est.stderr() if est is not None else {}
    reach_now = np.array([100 * _Z * own.get(k, math.nan) / abs(v) for k, v in zip(_PARAMS, (a, b))])
    if not np.all(np.isfinite(reach_now)):
        # no interval yet: the encoder's rounding, ten times over, as the noise
        cpr = state.runs[-1].counts_per_rev or 16667
        sigma2 = 10 * (2 * math.pi / cpr) ** 2 / 12
        info = sum((information(a, b, r.duty, dt, delay) for r in state.fitted), np.zeros((2, 2)))
        var = _variances(info)
        reach_now = np.where(np.isfinite(var) & (var >= 0),
                             100 * _Z * np.sqrt(sigma2 * np.abs(var)) / np.abs([a, b]), 1e3)
    a_set = _plausible_poles(est, last, a)
    extra = _nuisance(est)
    size = 3 + len(extra) + ("bias" not in extra and "friction" in extra)
    pasts = [sum((information(aa, b * aa / a, r.duty, dt, delay, lag=True, nuisance=extra) for r in state.fitted),
                 np.zeros((size, size))) for aa in a_set]
    lagged = _has_lag(est)
    # the share rule where the intervals are the fit's own; while the structure is not clear they are
    # widened over candidates the prediction (from the fit's own errors) does not see: 0.8 of the target
    share = bool(last.clear)
    hi_f = 0.8 * math.pi / dt
    best = None
    for ex, amp, unit in _blocks(a, b, max(0.2, min(a_set) / 20), dt, duty_limit, max_speed, max_travel,
                                 min_block, left, breakaway, 1 + (97 * len(state.runs)) % 4095,
                                 prbs=any(not d.startswith("prbs:") for d in state.descriptions[state.fitted_from:])):
        duty = ex.duty(max(int(round(unit / dt)), 20), dt, duty_limit)
        worst_time, worst_reach = 0.0, np.zeros(2)
        for aa, past in zip(a_set, pasts):
            blk = information(aa, b * aa / a, duty, dt, delay, lag=True, nuisance=extra)
            sec, reach = _time_to_target(past, blk, unit, reach_now, target if share else _AIM * target, left,
                                         lagged, aim=_AIM if share else 1.0)
            sec = max(sec, unit)
            worst_time, worst_reach = max(worst_time, sec), np.maximum(worst_reach, reach)
        key = (worst_time, float(np.max(worst_reach)))
        if best is None or key < best[0]:
            best = (key, ex, amp, unit, worst_reach)
    if best is None:
        return (f"no sine within the limits drives the shaft above its break-away duty {breakaway:g}: "
                f"the speed or travel budget leaves amplitudes of at most "
                f"{_amplitude(a, b, hi_f, duty_limit, max_speed, max_travel)}; raise the speed or travel budget")
    (sec, _), ex, amp, unit, reach = best
    cap = max(_GROWTH * state.motor_time, unit)
    length = max(min(sec * _MARGIN, cap, left), unit)
    what = _what(ex)
    if math.isfinite(sec) and sec * _MARGIN <= length + 1e-9:
        why = f"{what}: predicted to reach ±{target:g} % in {sec:.3g} s"
    elif math.isfinite(sec):
        why = f"{what}: predicted to reach ±{target:g} % in {sec:.3g} s (this block {length:.3g} s, at most " \
              f"{_GROWTH:g} times the motor time so far)"
    else:
        why = f"{what}: the fastest toward ±{target:g} %, not reached in the {left:.3g} s left"
    if not math.isfinite(sec) or length < sec * _MARGIN:
        # the reach predicted after the block actually run
        duty = ex.duty(max(int(round(unit / dt)), 20), dt, duty_limit)
        reach = np.max([_time_to_target(p, information(aa, b * aa / a, duty, dt, delay, lag=True, nuisance=extra), unit,
                                        reach_now,
                                        target, length, lagged, fixed=True)[1] for aa, p in zip(a_set, pasts)], axis=0)
    return ex, length, {k: float(r) for k, r in zip(_PARAMS, reach)}, why


def _blocks(a: float, b: float, lowest: float, dt: float, duty_limit: int, max_speed: float | None,
            max_travel: float | None, min_block: float, left: float, breakaway: float | None, seed: int = 1,
            sines: bool = False, frequencies: int = 28, prbs: bool = True):
    """The blocks a round may run, each with its amplitude and the length its information is judged on.

    Two lines of each shape (:data:`_SHAPES`; with ``sines``, one line too) on a logarithmic grid from
    ``lowest`` to 0.8 of the Nyquist frequency, at the largest amplitude the duty limit and the budgets
    allow, judged on two periods (and the transient, ``1/a``); and a PRBS of the largest level the duty
    limit and the speed budget allow, each bit held :data:`_PRBS_HOLDS` samples, judged on 40 bits.  The
    PRBS carries twice the RMS duty of two lines of half the duty each and steps that show a lag: over
    the loop's rigs it pins ``a`` and ``b`` with the lag free in a third to a tenth of the time.  A
    travel budget leaves it out (its angle wanders as a random walk), and so does ``prbs`` False: the loop
    runs one only after a run of more than one duty magnitude, since one magnitude cannot tell the gain from
    the default's dead-zone candidate (after a PRBS alone, `b` +-5.7 % and not clear where `a` was +-0.4 %).
    """
    from motorsim.excitation import PRBS
    hi_f = 0.8 * math.pi / dt
    for f in np.geomspace(lowest, hi_f, frequencies):
        amp = _amplitude(a, b, f, duty_limit, max_speed, max_travel)
        unit = max(min_block, 2 * 2 * math.pi / f, 1.0 / a)     # two periods, the transient
        if (breakaway is not None and amp <= breakaway) or unit > left:
            continue
        for ratio, upper in (((1, 0.0),) if sines else ()) + _SHAPES:
            if ratio > 3 and ratio * f >= hi_f:
                continue
            line = float(f"{f:.4g}")
            yield (Sine(line, amp) if ratio == 1 else _two_tone(line, amp, hi_f, ratio, upper)), amp, unit
    if max_travel is not None or not prbs:
        return
    level = float(duty_limit - 2 if duty_limit > 10 else duty_limit)
    if max_speed is not None:
        level = min(level, max_speed * a / abs(b))
    level_i = int(max(1, min(duty_limit, math.floor(level))))
    if breakaway is not None and level_i <= breakaway:
        return
    for hold in _PRBS_HOLDS:
        unit = max(min_block, 1.0 / a, 40 * hold * dt)
        if unit <= left:
            yield PRBS(level_i, -level_i, 12, hold, seed), level_i, unit


#: Samples each bit of a PRBS block is held.
_PRBS_HOLDS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)


def _plausible_poles(est: Any, last: UntilRound, a: float) -> list[float]:
    """The poles a block is designed for: ``a``, and its interval's ends (within 4 times) while that is wide; a
    quarter and four times ``a`` before any fit."""
    a_set = [a]
    if est is not None and last.intervals:
        lo, hi = last.intervals["a"]
        if math.isfinite(lo) and math.isfinite(hi) and (hi > 1.2 * a or lo < a / 1.2):
            a_set = [max(lo, a / 4), a, min(hi, 4 * a)]
    else:
        a_set = [a / 4, a, 4 * a]
    return sorted({x for x in a_set if x > 0})


#: The two lines a block may be: the upper line at this many times the lower, with this share of the duty.
#: A lag left free is told from ``a`` by the phase the upper line adds: over 2 s of angle data at 10 mrad
#: (``information``, the lag free) the best of the shapes with equal lines needs 0.49 (``a`` 20 1/s),
#: 0.34 (117), 0.54 (9.5) of the time of the third harmonic at a third of the duty, which slow motors
#: (``a`` 2.6 and 3.6: 1.2 and 1.1 times as long) keep.  Lines with the upper one larger still (2/3)
#: left the default's friction and dead-zone candidates within the noise, not clear, more often.
_SHAPES = ((3, 1 / 3), (3, 1 / 2), (5, 1 / 2), (9, 1 / 2), (15, 1 / 2))


def _two_tone(frequency: float, amplitude: int, highest: float, ratio: int = 3, upper: float = 1 / 3) -> Excitation:
    """The block's excitation: the line ``frequency`` and one at ``ratio`` times it with the share ``upper`` of
    the amplitude (where that passes ``highest``: the second line at ``frequency / ratio`` instead).

    One sine fits a first-order model exactly whatever the plant behind it (a lag, friction or a
    delay move its gain and phase at that one frequency only), so the default could not tell them
    apart, and a lag left free would leave ``a`` and ``b`` unknown; a second line gives the
    evidence, for some of the information about ``a`` and ``b``.
    """
    from motorsim.excitation import Multisine
    if amplitude < 6:
        return Sine(frequency, amplitude)
    upper_freq = float(f"{ratio * frequency:.4g}")
    up = int(round(amplitude * upper))
    if upper_freq >= highest:
        return Multisine((float(f"{frequency / ratio:.4g}"), frequency), (up, amplitude - up), (0.0, 0.0))
    return Multisine((frequency, upper_freq), (amplitude - up, up), (0.0, 0.0))


# --------------------------------------------------------------------------------------------- fixed experiments

@dataclasses.dataclass(frozen=True)
class FixedDesign:
    """The fixed experiment :func:`design_fixed` chooses for a known motor.

    Attributes
    ----------
    excitation : Excitation
        A sine, or two lines of one of the loop's shapes (:data:`_SHAPES`).
    duration : float
        The run's length in s.
    reach : dict
        The Cramér-Rao reach of ``a`` and ``b`` (%): the 95 % half-widths for both at once
        (:data:`SIMULTANEOUS`) with a driver lag left free, from the angle noise and the encoder's rounding.
    """

    excitation: Excitation
    duration: float
    reach: Mapping[str, float]


def design_fixed(a: float, b: float, sample_period: float, duration: float, *, input_delay: int = 0,
                 nuisance: Sequence[str] = (), duty_limit: int = 255, angle_noise: float = 0.0,
                 counts_per_rev: int | None = None, sines: bool = False) -> FixedDesign:
    """The one fixed experiment of the loop's family that pins ``a`` and ``b`` best in ``duration`` s.

    The family is what :func:`run_until` may run as a first block: two lines of one of its shapes
    (:data:`_SHAPES`), at the largest amplitude the duty limit allows (with ``sines``, one line too: one line
    fits a first-order model whatever the plant behind it, so the default seldom calls its structure clear on
    it, though the bound, which knows the structure, may prefer it; a PRBS, which the loop runs only after
    a run of more than one duty magnitude, cannot tell the gain from a dead zone alone); the frequency on a logarithmic
    grid from two periods per run to 0.8 of the Nyquist frequency.  The criterion is the stopping
    rule's: the larger relative Cramér-Rao standard error of ``a`` and ``b`` with a driver lag left free
    and ``nuisance`` (:data:`NUISANCE`) unknown (:func:`information`, the run's initial state profiled
    out).  Runs longer than 8 s are judged on their first 8 s, the information scaled by the length.
    """
    a = check_real("a", a, positive=True)
    b = check_real("b", b)
    dt = check_real("sample_period", sample_period, positive=True)
    duration = check_real("duration", duration, positive=True)
    if b == 0:
        raise ParameterError(f"b must be nonzero, got {b!r}")
    n_all = max(int(round(duration / dt)), 20)
    n = min(n_all, max(int(round(8.0 / dt)), 20))
    best = None
    for ex, _, _ in _blocks(a, b, max(2 * 2 * math.pi / (n_all * dt), min(0.2, a / 20)), dt, duty_limit, None, None,
                            0.0, math.inf, None, sines=sines, frequencies=40, prbs=False):
        info = information(a, b, ex.duty(n, dt, duty_limit), dt, input_delay, lag=True, nuisance=nuisance)
        var = _variances(_profiled(info * (n_all / n)))
        worst = float(np.max(var / np.square([a, b]))) if np.all(np.isfinite(var)) and np.all(var > 0) else math.inf
        if best is None or worst < best[0]:
            best = (worst, ex, var)
    assert best is not None
    _, ex, var = best
    sigma2 = angle_noise ** 2 + ((2 * math.pi / counts_per_rev) ** 2 / 12 if counts_per_rev else 0.0)
    reach = {k: 100 * _Z * SIMULTANEOUS * math.sqrt(sigma2 * v) / abs(x) if math.isfinite(v) and v > 0 else math.inf
             for k, v, x in zip(_PARAMS, var, (a, b))}
    return FixedDesign(ex, n_all * dt, reach)


def fixed_design_time(a: float, b: float, sample_period: float, target: float, longest: float,
                      **options: Any) -> FixedDesign:
    """The shortest :func:`design_fixed` predicted to reach ``target`` % (at most ``longest`` s).

    The length is bisected on a logarithmic scale, each length's experiment designed for it (the
    best frequency and shape change with the length: a short run spends its information on the
    transient); ``longest`` s's design where even that is predicted short of the target.
    """
    lo, hi = max(40 * sample_period, 0.2), float(longest)
    d = design_fixed(a, b, sample_period, hi, **options)
    if not max(d.reach.values()) <= target:
        return d
    for _ in range(12):
        mid = math.sqrt(lo * hi)
        m = design_fixed(a, b, sample_period, mid, **options)
        if max(m.reach.values()) <= target:
            hi, d = mid, m
        else:
            lo = mid
        if hi / lo < 1.03:
            break
    return d

def _what(ex: Excitation) -> str:
    from motorsim.excitation import PRBS
    if isinstance(ex, PRBS):
        return f"a PRBS of duty ±{ex.high}, bits held {ex.hold} samples"
    freqs: tuple = getattr(ex, "frequencies", ())
    amps: tuple = getattr(ex, "amplitudes", ())
    if len(freqs) == 1:
        return f"sine at {freqs[0]:.4g} rad/s, duty {amps[0]}"
    return "lines at " + ", ".join(f"{f:.4g}" for f in freqs) + " rad/s, duty " + "+".join(str(x) for x in amps)


def _time_to_target(past: np.ndarray, blk: np.ndarray, unit: float, reach_now: np.ndarray, target: float,
                    left: float, lagged: bool = True, fixed: bool = False, aim: float = 1.0
                    ) -> tuple[float, np.ndarray]:
    """Seconds of a block (information ``blk`` per ``unit`` s, growing in proportion) until both reaches
    are within ``target`` %, and the reaches then (``inf`` s and the reaches after ``left`` s when it is
    not enough; with ``fixed``, the reaches after ``left`` s).

    With ``aim`` below 1, a reach must come within ``target (1 - (1 - aim) s)``, ``s`` the share of the
    information the block brings (``1 - (reach after / reach before)^2``), and at most :data:`_AIM_MOST`
    of it (``aim`` 1: within ``target``): the runs so far are measured (their reach is the fit's own),
    the block's share is predicted, so a block that brings almost all the information aims at ``aim``
    of the target, one that adds a little to runs already near it close to the target.

    ``past`` and ``blk`` are informations of ``(a, b, tau)`` (:func:`information` with ``lag``); the
    reaches predicted are those with the lag unknown, scaled from ``reach_now``, the fit's own: of a
    model with a lag (``lagged``) or of one without, whose reach is that of the lag known to be 0.
    """
    var_now = _variances(_profiled(past, lag_free=lagged))

    def reach(seconds: float) -> np.ndarray:
        ratio = _variances(_profiled(past + blk * (seconds / unit))) / np.where(var_now > 0, var_now, 1)
        return reach_now * np.sqrt(np.clip(np.where(np.isfinite(ratio), ratio, 1.0), 0.0, None))

    if fixed:
        return left, reach(left)
    before = reach(0.0)

    def within(r: np.ndarray) -> bool:
        if aim >= 1:
            return bool(np.all(r <= target))
        share = 1 - np.square(np.where(np.isfinite(before) & (before > 0), r / np.where(before > 0, before, 1), 0.0))
        return bool(np.all(r <= target * np.minimum(_AIM_MOST, 1 - (1 - aim) * np.clip(share, 0.0, 1.0))))

    if not within(reach(left)):
        return math.inf, reach(left)
    lo, hi = 0.0, left
    for _ in range(40):
        mid = (lo + hi) / 2
        if within(reach(mid)):
            hi = mid
        else:
            lo = mid
    return hi, reach(hi)


def _has_lag(est: Estimate | None) -> bool:
    """Whether the estimate's structure has a lag of its own (its intervals already allow for one)."""
    return est is not None and "electrical_time_constant" in est.param_names


def lag_free_reach(runs: Sequence[Recording], est: Estimate, reach: Mapping[str, float]) -> dict[str, float]:
    """The reach of ``a`` and ``b`` (%) had the fit allowed a driver lag (or a dead time) it did not.

    A structure without a lag holds ``a`` and ``b`` as well as the runs pin a lag of zero; its
    intervals would be wider by ``sqrt(var(lag unknown) / var(lag 0))`` (:func:`information`, at the
    estimate) with the lag free.  A structure with a lag has its own intervals.  ``inf`` when the
    information is singular.
    """
    if _has_lag(est) or not runs:
        return dict(reach)
    dt = runs[0].sample_period
    a, b = float(est.a), float(est.b)
    if not (math.isfinite(a) and math.isfinite(b)) or a <= 0:
        return {k: math.inf for k in _PARAMS}
    parts = [information(a, b, r.duty, dt, int(est.input_delay), lag=True, nuisance=_nuisance(est)) for r in runs]
    info = np.sum(parts, axis=0)
    base, free = _variances(_profiled(info, lag_free=False)), _variances(_profiled(info))
    out = {}
    for i, k in enumerate(_PARAMS):
        ratio = free[i] / base[i] if base[i] > 0 and math.isfinite(free[i]) else math.inf
        out[k] = reach[k] * math.sqrt(max(ratio, 1.0)) if math.isfinite(ratio) else math.inf
    return out


def _multisine_block(a: float, b: float, dt: float, duty_limit: int, length: float,
                     max_speed: float | None) -> tuple[Excitation, float] | None:
    """An odd multisine over ``a/10 ... 10 a`` for about ``length`` s, or None when none fits."""
    from .checks.design import design_multisine
    try:
        d = design_multisine(a, b, dt, duration=max(length, 0.5), duty_limit=duty_limit)
    except ParameterError:
        return None
    return d.excitation, d.duration
