"""Recordings made ready for the estimators: pooling, gap-free segments, excitation checks.

Every estimator starts here: :func:`as_recordings` accepts one recording or
several of the same motor, :func:`check_input_delay` the ``input_delay`` option,
:func:`check_excitation` refuses data that cannot determine ``a`` and ``b`` (and
says what to record instead), and :func:`prepare_segments` cuts the recordings at
dropped samples into :class:`Segment` objects holding the delayed duty and the
measured angle (or speed).
"""
from __future__ import annotations

import dataclasses
import math
import os
import warnings
from typing import Any, Sequence

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int
from motorsim.recording import Recording

from .errors import NotIdentifiableError

__all__ = ["as_recordings", "counts_behind_speed", "MAX_COUNTS_PER_SAMPLE", "check_input_delay", "check_excitation",
           "check_speed_agrees", "check_constant_input_runs", "ConstantInputTurnWarning", "check_output_moves",
           "check_input_changes", "check_length", "ConstantInputWarning", "one_input_level", "POOL_PERIOD_RTOL",
           "prepare_segments", "first_rows", "delayed_segments", "Segment", "MIN_SEGMENT_SAMPLES", "residual_unit",
           "saturation_note", "CLOSED_LOOP_SATURATED_SHARE", "declared_input_delay"]

#: Shortest segment (samples) an estimator uses; shorter ones carry almost no information.
MIN_SEGMENT_SAMPLES = 4
_SATURATION_SHARE = 0.5   # warn when the duty sits at its limit for more than this share


def as_recordings(recordings: Recording | Sequence[Recording]) -> list[Recording]:
    """Accept one Recording or a sequence of them; check they share a sample period and input unit.

    Periods that differ by at most :data:`POOL_PERIOD_RTOL` (the tests of one routine logged on one
    jittered loop) are pooled at their median, and a warning says so.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Runs of one motor, to be pooled.

    Returns
    -------
    list of Recording
    """
    if isinstance(recordings, Recording):
        recordings = [recordings]
    if isinstance(recordings, (str, bytes, os.PathLike)):
        raise ParameterTypeError(f"recordings must be a Recording or a sequence of them, got the path {recordings!r}: "
                                 "read it first (motorsim.read_recording)")
    try:
        recs = list(recordings)
    except TypeError:
        raise ParameterTypeError("recordings must be a Recording or a sequence of them, got "
                                 f"{type(recordings).__name__}") from None
    if not recs:
        raise ParameterError("recordings must hold at least one Recording, got none")
    for i, r in enumerate(recs):
        if not isinstance(r, Recording):
            raise ParameterTypeError(f"recordings[{i}] must be a Recording, got {type(r).__name__}")
    recs = _common_period(recs)
    units = {r.input_unit for r in recs}
    if len(units) > 1:
        raise ParameterError(f"recordings must share one input_unit to be pooled, got {sorted(units)}")
    return [counts_behind_speed(r) or r for r in recs]


#: Largest relative difference of the sample periods of recordings pooled at one period (the tests of one
#: routine on one loop differ by microseconds: their medians of a jittered clock).
POOL_PERIOD_RTOL = 0.005
#: ... or, when every recording's clock jitters, by at most the least of their jitters (half their intervals'
#: range), up to this share: their medians move within it.
POOL_PERIOD_JITTER_LIMIT = 0.05


def _jitter(rec: Recording) -> float:
    """Half the range of a non-uniform clock's intervals relative to its period (0 on a uniform clock), at most
    :data:`POOL_PERIOD_JITTER_LIMIT`: medians of such clocks differ by as much without being other rates."""
    try:
        low, high = float(rec.metadata["time_step_min"]), float(rec.metadata["time_step_max"])
    except (KeyError, ValueError):
        return 0.0
    return min(POOL_PERIOD_JITTER_LIMIT, max(0.0, (high - low) / 2 / rec.sample_period))


def _common_period(recs: list[Recording]) -> list[Recording]:
    """``recs`` at one sample period: their own when they share it; when they differ by at most
    :data:`POOL_PERIOD_RTOL` (or the least jitter of their clocks, :func:`_jitter`), the median of the
    periods weighted by samples (said by a warning when they differ by more than 1e-6 of it); refused
    beyond."""
    dts = sorted({r.sample_period for r in recs})
    if len(dts) == 1:
        return recs
    weights = np.array([len(r) for r in recs], dtype=float)
    periods = np.array([r.sample_period for r in recs])
    order = np.argsort(periods)
    cumulative = np.cumsum(weights[order])
    common = float(periods[order][np.searchsorted(cumulative, cumulative[-1] / 2)])
    spread = max(abs(dts[0] / common - 1), abs(dts[-1] / common - 1))
    if spread > max(POOL_PERIOD_RTOL, min(_jitter(r) for r in recs)):
        raise ParameterError(f"recordings must share one sample_period (within {100 * POOL_PERIOD_RTOL:g} %, or "
                             "the jitter of their clocks) to be "
                             f"pooled, got {[float(f'{d:.6g}') for d in dts]} s: resample them to one rate first")
    if spread > 1e-6:
        warnings.warn(f"the recordings' sample periods differ by up to {100 * spread:.2g} % ({dts[0]:.6g} to "
                      f"{dts[-1]:.6g} s, medians of their clocks): pooled at {common:.6g} s", UserWarning,
                      stacklevel=4)
    return [r if r.sample_period == common else dataclasses.replace(r, sample_period=common) for r in recs]


#: Largest speed, in encoder counts per sample, of a speed column read as a backward difference of counts:
#: beyond it the grid is more likely the file's printed resolution than an encoder's steps.
MAX_COUNTS_PER_SAMPLE = 1000
#: Relative tolerance of a differenced speed's values on their grid (a file prints six or more digits).
_GRID_RTOL = 2e-6


def counts_behind_speed(recording: Recording) -> Recording | None:
    """The recording as the encoder counts its speed column differences, or None when it is not that.

    A speed column computed as the backward difference of encoder counts, ``(n_k - n_(k-1)) q`` with
    ``q = 2 pi / (N h)``, takes only whole multiples of one step ``q``: every value is ``m q`` for an
    integer ``m`` of at most :data:`MAX_COUNTS_PER_SAMPLE`.  Fitted as a speed, its rounding (a whole
    count per sample) looks like large noise; the counts behind it, recovered by summing the steps,
    give the answer as exactly as the encoder itself.  Recognised only on a speed-only recording with
    a uniform clock and no gaps, at least 20 non-zero values and three or more distinct steps; the
    returned recording holds the counts (``counts_per_rev`` ``N`` when ``2 pi / (q h)`` is a whole
    number, else the angle) and says so in its metadata (``speed_from_counts``).
    """
    if recording.speed is None or recording.angle is not None or recording.counts is not None:
        return None
    speed = recording.speed
    h = recording.sample_period
    if len(speed) < 20 or recording.has_gaps:
        return None
    steps = np.diff(recording.time)
    if not np.all(np.abs(steps - h) <= 1e-9 * h):
        return None
    first = 1 if not math.isfinite(float(speed[0])) else 0
    values = speed[first:]
    if not np.all(np.isfinite(values)):
        return None
    moving = np.abs(values[values != 0])
    if len(moving) < 20:
        return None
    q = float(moving.min())
    m = values / q
    whole = np.round(m)
    if float(np.max(np.abs(whole))) > MAX_COUNTS_PER_SAMPLE or len(np.unique(np.abs(whole))) < 3:
        return None
    if not np.all(np.abs(m - whole) <= _GRID_RTOL * np.maximum(1.0, np.abs(m))):
        return None
    counts = np.zeros(len(speed), dtype=np.int64)
    counts[first:] = np.cumsum(whole.astype(np.int64)) - (whole[0] if first == 0 else 0)
    per_rev = 2 * math.pi / (q * h)
    meta = {**recording.metadata, "speed_from_counts": f"steps of {q:.6g} rad/s"}
    if abs(per_rev - round(per_rev)) <= 1e-4 * per_rev and round(per_rev) >= 1:
        meta["speed_from_counts"] += f" (one count of {round(per_rev)} per revolution per sample)"
        return dataclasses.replace(recording, speed=None, counts=counts, counts_per_rev=int(round(per_rev)),
                                   metadata=meta)
    return dataclasses.replace(recording, speed=None, angle=counts * (q * h), metadata=meta)


#: The input delay of an estimator that can search for it, when none is given: ``"auto"``, the shortest delay
#: (0 ... 10 samples, the range widened while the best fit is at its top) within the noise of the best.  Decided
#: here alone: every such estimator's signature, ``identify.fit`` and ``motorid identify --method`` take it
#: from here, so the same request gives the same answer in Python and on the command line.  A missed delay
#: biases a fit by far more than the search costs (a 2-sample delay fitted at 0 reads ``a`` 20 % low).
DEFAULT_INPUT_DELAY = "auto"


def check_input_delay(input_delay: Any) -> int | str:
    """The ``input_delay`` option of an estimator: ``"auto"`` or an integer >= 0 (samples).

    Parameters
    ----------
    input_delay : int or "auto"
        The value to check.

    Returns
    -------
    int or "auto"
    """
    if isinstance(input_delay, str):
        if input_delay != "auto":
            raise ParameterError(f"input_delay must be 'auto' or an integer >= 0 samples, got {input_delay!r}")
        return input_delay
    return check_int("input_delay", input_delay, lo=0, allow_integral_float=False)


@dataclasses.dataclass(frozen=True)
class Segment:
    """One gap-free stretch of a recording, ready for a model.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Sample instants in s.
    drive : ndarray, shape (n,)
        Input reaching the motor (delayed duty), held from ``time[k]`` to ``time[k+1]``.
    output : ndarray, shape (n,)
        Measured angle in rad (``kind == "angle"``) or speed in rad/s.
    kind : str
        ``"angle"`` or ``"speed"``.
    uniform : bool
        Whether ``time`` is uniformly spaced.
    recording : int
        Index of the recording the segment comes from.
    start : int
        Row of the recording where the segment starts.
    """

    time: np.ndarray
    drive: np.ndarray
    output: np.ndarray
    kind: str
    uniform: bool
    recording: int
    start: int

    def rows(self, lo: int, hi: int) -> "Segment":
        """Rows ``lo ... hi - 1`` of the segment, a segment of their own (its ``start`` the row of the first)."""
        return dataclasses.replace(self, time=self.time[lo:hi], drive=self.drive[lo:hi], output=self.output[lo:hi],
                                   start=self.start + int(lo))

    def initial_speed_guess(self) -> float:
        """Speed near the first sample from the data (rad/s)."""
        if self.kind == "speed":
            return float(self.output[0])
        m = min(3, len(self.time) - 1)
        return float((self.output[m] - self.output[0]) / (self.time[m] - self.time[0]))


def first_rows(segments: Sequence[Segment], rows: int) -> list[Segment]:
    """The first rows of each segment, about ``rows`` in all, each keeping its share (at least 3);
    the segments as they are when they hold no more than ``rows``."""
    total = sum(len(seg.time) for seg in segments)
    if total <= rows:
        return list(segments)
    out = []
    for seg in segments:
        m = max(3, len(seg.time) * rows // total)
        out.append(seg.rows(0, m))
    return out


def residual_unit(segments: Sequence[Segment]) -> str:
    """``"rad"`` when every segment holds angle, ``"rad/s"`` when every one holds speed, else ``"mixed"``."""
    kinds = {s.kind for s in segments}
    return "rad" if kinds == {"angle"} else ("rad/s" if kinds == {"speed"} else "mixed")


def _is_uniform(t: np.ndarray) -> bool:
    h = np.diff(t)
    return len(h) > 0 and bool(np.all(np.abs(h - h[0]) <= 1e-9 * h[0]))


def _measured_output(rec: Recording, rows: slice = slice(None)) -> tuple[np.ndarray, str]:
    """The measured angle of ``rows`` (``"angle"``) when the recording has one, else their speed (``"speed"``)."""
    angle = rec.measured_angle(rows)
    if angle is not None:
        return angle, "angle"
    if rec.speed is None:   # a Recording always holds angle, counts or speed
        raise ParameterError("recording holds neither angle, counts nor speed")
    return rec.speed[rows], "speed"


def declared_input_delay(recordings: Recording | Sequence[Recording]) -> int:
    """The input delay, in samples, every recording's device declares (metadata ``input_delay_samples``), else 0."""
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    declared = []
    for r in recs:
        try:
            declared.append(max(0, int(str(r.metadata.get("input_delay_samples", "0")))))
        except ValueError:
            declared.append(0)
    return min(declared, default=0)


def prepare_segments(recordings: Sequence[Recording], input_delay: int = 0, skip: int = 0,
                     rows: int | None = None) -> list[Segment]:
    """Split recordings at gaps into segments, delaying the duty by ``input_delay`` samples.

    Within a segment the duty ``input_delay`` samples earlier is unknown for the
    first ``input_delay`` rows, so each segment starts at row ``max(input_delay, skip)``;
    segments shorter than :data:`MIN_SEGMENT_SAMPLES` are left out.

    Parameters
    ----------
    recordings : sequence of Recording
        The runs, already checked by :func:`as_recordings`.
    input_delay : int
        Input delay in samples, >= 0.
    skip : int
        Rows to leave out at the start of every segment (at least ``input_delay`` are).
    rows : int, optional
        Keep only the first rows of each segment, about ``rows`` in all: ``first_rows(segments,
        rows)``, without converting the rows left out (a selection on the start of a long file
        costs the start, not the file).

    Returns
    -------
    list of Segment
    """
    _check_delay_fits(recordings, input_delay)
    first = max(input_delay, skip)
    pieces = []                       # (recording, its segment, the segment's first row)
    for i, rec in enumerate(recordings):
        row = 0
        for seg in rec.segments():
            if len(seg) - first >= MIN_SEGMENT_SAMPLES:
                pieces.append((i, seg, row))
            row += len(seg)
    total = sum(len(seg) - first for _, seg, _ in pieces)
    out = []
    for i, seg, row in pieces:
        n = len(seg)
        stop = n if rows is None or total <= rows else first + max(3, (n - first) * rows // total)
        output, kind = _measured_output(recordings[i], slice(row + first, row + stop))
        drive = seg.duty[first - input_delay:stop - input_delay]
        t = seg.time[first:stop]
        if kind == "speed" and not np.all(np.isfinite(output)):
            raise ParameterError(f"{recordings[i].name(i)} has non-finite speed values")
        out.append(Segment(time=t, drive=np.asarray(drive, float), output=np.asarray(output, float),
                           kind=kind, uniform=_is_uniform(t), recording=i, start=row + first))
    return out


def delayed_segments(recordings: Sequence[Recording], delays: Sequence[int], skip: int,
                     rows: int) -> dict[int, list[Segment]]:
    """``first_rows(prepare_segments(recordings, d, skip=skip), rows)`` for every ``d`` in ``delays``.

    Every delay is at most ``skip``, so every delay's segments hold the same rows and differ only
    in their drive: the recordings are split, converted and checked once, and each delay takes its
    drive from the duty ``d`` rows earlier.

    Parameters
    ----------
    recordings : sequence of Recording
        The runs, already checked by :func:`as_recordings`.
    delays : sequence of int
        Input delays in samples, each in ``0 ... skip``.
    skip : int
        Rows left out at the start of every segment.
    rows : int
        Rows kept in all (:func:`first_rows`).
    """
    if not delays:
        return {}
    if min(delays) < 0 or max(delays) > skip:
        raise ParameterError(f"delays must lie in 0 ... skip = {skip}, got {min(delays)} ... {max(delays)}")
    _check_delay_fits(recordings, max(delays))    # the rule grows with the delay: the largest decides
    base = prepare_segments(recordings, 0, skip=skip, rows=rows)
    return {d: [dataclasses.replace(seg, drive=np.asarray(
        recordings[seg.recording].duty[seg.start - d:seg.start - d + len(seg.time)], float)) for seg in base]
        for d in delays}


#: A fixed input delay must leave this many times its own length of samples in the longest gap-free run.
DELAY_SHARE = 3


def _check_delay_fits(recordings: Sequence[Recording], input_delay: int) -> None:
    """Refuse an input delay the data cannot hold: the fit would pair the duty with the wrong samples."""
    if not input_delay:
        return
    longest = max((len(seg) for rec in recordings for seg in rec.segments()), default=0)
    if input_delay >= longest:
        raise NotIdentifiableError(f"input_delay {input_delay} samples is not shorter than the longest gap-free run "
                                   f"({longest} samples): no sample has its delayed duty; check the delay")
    if DELAY_SHARE * input_delay > longest - input_delay:
        raise NotIdentifiableError(f"input_delay {input_delay} samples leaves {longest - input_delay} of the longest "
                                   f"run's {longest} samples, fewer than {DELAY_SHARE} times the delay: a fit would "
                                   "be meaningless; check the delay or record a longer run")


def check_input_changes(recordings: Sequence[Recording]) -> np.ndarray:
    """Refuse recordings whose input is zero or constant throughout (not persistently exciting).

    Returns the pooled input.
    """
    duty = recordings[0].duty if len(recordings) == 1 else np.concatenate([r.duty for r in recordings])
    constant = bool(len(duty) and duty.min() == duty.max())     # two reductions, no temporary arrays
    if constant and duty[0] == 0:
        raise NotIdentifiableError(f"{_names(recordings)}: input is zero throughout: it is not persistently "
                                   "exciting; "
                                   "use a sine, multisine or PRBS")
    if constant:
        unit = recordings[0].input_unit
        if any(_has_transient(r) for r in recordings):      # a step from rest: said once, by the screening
            return duty
        raise NotIdentifiableError(f"{_names(recordings)}: input is constant ({duty[0]:g} {unit} throughout) and "
                                   "the speed holds no "
                                   "transient: it is not persistently exciting, a and b cannot be separated "
                                   "(a step recorded after the motor settled; pool it with the routine's other "
                                   "tests, or record from before the step); use a sine, multisine or PRBS")
    return duty


class ConstantInputWarning(UserWarning):
    """The input is constant throughout; a and b come from the speed's transient (a step from rest) alone."""


#: Rows of a run of constant input whose speed is judged for a transient (its first ones: a step's transient).
TRANSIENT_ROWS = 20_000


def one_input_level(recordings: Sequence[Recording]) -> float | None:
    """The input level every recording holds throughout (SysId's dynamic test alone), or None."""
    if not recordings or not all(len(r) for r in recordings):
        return None
    levels = {float(v) for r in recordings for v in (r.duty.min(), r.duty.max())}
    return levels.pop() if len(levels) == 1 else None


def _has_transient(rec: Recording) -> bool:
    """Whether ``rec``'s speed moves one way, beyond its noise and rounding, in a gap-free run.

    Under one constant input a motor's speed that moves from where it started towards where the
    input drives it (a step from rest, SysId's dynamic test) separates ``a`` (the transient's rate)
    from ``b`` (where it goes); a speed already settled holds only their ratio.  The run is judged as
    :func:`check_constant_input_runs` judges a turn: smoothed, its rise or fall beyond
    :data:`RUN_NOISE_FACTOR` noise deviations or two rounding steps, and beyond a quarter of the
    speed's largest magnitude (the transient, not a drift of a settled speed).
    """
    n = min(len(rec), TRANSIENT_ROWS)
    if n < RUN_SKIP + RUN_MIN:
        return False
    speed = rec.measured_speed()[:n]
    seq = rec.seq[:n]
    cuts = np.flatnonzero(np.diff(seq) != 1) + 1
    for w in np.split(speed, cuts):
        w = w[RUN_SKIP:]
        w = w[np.isfinite(w)]
        if len(w) < RUN_MIN:
            continue
        rise, fall, noise = run_turns(w)
        if max(rise, fall) > max(noise, 0.25 * float(np.max(np.abs(w)))):
            return True
    return False


def _names(recordings: Sequence[Recording]) -> str:
    """How a message names pooled recordings: each one's :meth:`~motorsim.Recording.name`."""
    if len(recordings) == 1:
        return recordings[0].name()
    return ", ".join(r.name(i) for i, r in enumerate(recordings))


def check_length(recordings: Sequence[Recording], n_params: int = 2) -> None:
    """Refuse recordings with fewer than ``3 n_params + 4`` samples in all: too short for any fit."""
    total = sum(len(r) for r in recordings)
    if total < 3 * n_params + 4:
        raise NotIdentifiableError(f"{_names(recordings)}: recording is too short: {total} samples for {n_params} "
                                   "parameters; "
                                   f"record at least {3 * n_params + 4} (a few time constants) samples")


def check_excitation(recordings: Sequence[Recording], n_params: int = 2) -> None:
    """Raise :class:`NotIdentifiableError` (or warn) when the data cannot determine the parameters.

    Checks, in order: enough samples, a duty that changes, an encoder that moves,
    and (warning only) a duty saturated for most of the run.

    Parameters
    ----------
    recordings : sequence of Recording
        The runs, already checked by :func:`as_recordings`.
    n_params : int
        Parameters the estimator fits (sets the shortest acceptable record).
    """
    check_length(recordings, n_params)
    check_input_changes(recordings)
    largest = [max(float(r.duty.max()), -float(r.duty.min())) if len(r) else 0.0 for r in recordings]
    k = int(np.argmax(largest))
    name = recordings[k].name(k if len(recordings) > 1 else None) if largest[k] > INPUT_SCALE_LIMIT else \
        _names(recordings)
    _check_input_scale(largest[k], recordings[0].input_unit, name)
    for i, r in enumerate(recordings):
        check_output_moves(r, r.name(i))
        check_speed_agrees(r, r.name(i))
        _warn_saturation(i, r)


#: How far apart (a factor) the speed column and the speed differenced from the angle or counts may be
#: before they contradict each other: far beyond a tachometer's error, far below the factors of a wrong
#: unit (rpm 9.55, rev/s 6.28, deg/s 57.3) or a counts_per_rev off by the quadrature decoding (2, 4).
SPEED_AGREEMENT = 1.5


def check_speed_agrees(rec: Recording, name: str = "recording") -> None:
    """Refuse a recording whose speed column and angle (or counts) say different things.

    Where both move together (correlation above 0.9), the speed column's size against the
    backward difference of the angle must be within :data:`SPEED_AGREEMENT` (and of the same
    sign): a speed in rpm beside counts, or a ``counts_per_rev`` 4 times off, would otherwise give
    a ``b`` off by that factor from the angle while the speed column says otherwise.
    """
    if rec.speed is None:
        return
    angle = rec.measured_angle()
    if angle is None or len(angle) < 3:
        return
    step = np.diff(rec.seq) == 1
    differenced = np.diff(angle)[step] / np.diff(rec.time)[step]
    column = 0.5 * (rec.speed[1:] + rec.speed[:-1])[step]     # the mean speed over each interval
    if len(column) < 3 or not differenced.any() or not column.any():
        return
    corr = float(np.corrcoef(column, differenced)[0, 1])
    if not abs(corr) > 0.9:
        return
    ratio = math.copysign(float(np.linalg.norm(column) / np.linalg.norm(differenced)), corr)
    if not 1 / SPEED_AGREEMENT <= ratio <= SPEED_AGREEMENT:
        source = ("angle_rad" if rec.angle is not None
                  else f"counts (counts_per_rev {rec.counts_per_rev})")
        raise NotIdentifiableError(f"{name}: speed_rad_s and {source} contradict each other: the speed column "
                                   f"is {ratio:.3g} x the speed differenced from the {source.split()[0]}; one of "
                                   "them is in another unit (rpm is 9.55 x, rev/s 6.28 x) or counts_per_rev is "
                                   "wrong: fix the file")


#: Samples of a run of constant recorded input left out at its start beyond the input delay (the backward
#: difference's sample, a fast electrical pole's), and the samples at least left after them for a run to be judged.
RUN_SKIP, RUN_MIN = 3, 8
#: Share of the speed's range by which the speed must both rise and fall within a run to be counted as turning,
#: and the share by which one run alone must turn to be refused (below it, one run is said; a load, a supply that
#: sags do that too).
RUN_SHARE, RUN_REFUSE_SHARE = 0.1, 0.25
#: A run is smoothed by a running mean over this share of its samples before its rises and falls are measured:
#: noise, the encoder's rounding and ripple faster than that are no turn of the motor's speed.
RUN_SMOOTHING = 1 / 16
#: Noise standard deviations (of the smoothed speed) a rise and a fall must both exceed: the extremes of
#: Gaussian noise over a run of 10^6 independent samples stay within 5 of them either way.
RUN_NOISE_FACTOR = 10.0
#: Rows checked (the first of the recording): the check is per run, and a few thousand runs tell.
RUN_ROWS = 200_000


class ConstantInputTurnWarning(UserWarning):
    """The speed turns by a modest share of its range while the recorded input stays constant."""


def _run_noise(w: np.ndarray) -> tuple[float, float]:
    """The speed noise's standard deviation in a run (second differences, robust) and its rounding step."""
    d2 = np.diff(w, 2)
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6) if len(d2) else 0.0
    steps = np.abs(np.diff(w))
    steps = steps[steps > 0]
    return sigma, float(steps.min()) if len(steps) else 0.0


def run_turns(w: np.ndarray) -> tuple[float, float, float]:
    """The rise and fall of a run's speed smoothed over :data:`RUN_SMOOTHING` of it, and the noise they
    are judged against (:data:`RUN_NOISE_FACTOR` smoothed standard deviations, or two rounding steps)."""
    width = max(1, int(len(w) * RUN_SMOOTHING))
    if width > 1:                     # a running mean by cumulative sums: linear in the run, whatever its width
        total = np.concatenate([[0.0], np.cumsum(w - w[0])])
        smooth = (total[width:] - total[:-width]) / width + w[0]
    else:
        smooth = w
    rise = float(np.max(smooth - np.minimum.accumulate(smooth)))
    fall = float(np.max(np.maximum.accumulate(smooth) - smooth))
    sigma, step = _run_noise(w)
    return rise, fall, max(RUN_NOISE_FACTOR * sigma / math.sqrt(width), 2 * step)


def _more(turns: list) -> str:
    return f" (and in {len(turns) - 1} more such runs)" if len(turns) > 1 else ""


def check_constant_input_runs(rec: Recording, name: str = "recording", input_delay: int = 0) -> None:
    """Refuse a recording whose speed both rises and falls while its recorded input stays constant.

    Under a constant input the first-order motor (with its friction, bias and dead zone alike) is a
    one-dimensional autonomous system: its speed moves one way, towards one value.  A speed that
    rises and falls by more than :data:`RUN_SHARE` of its range within runs of constant recorded
    input (after their first ``input_delay`` + :data:`RUN_SKIP` samples, while they still answer the
    input before) answers an input the log does not hold: a duty logged flat at +-60 while the motor
    received +-200, say, which would give a confident, wrong ``b``.  It is refused when it does so
    in two runs or more, or by more than :data:`RUN_REFUSE_SHARE` of its range; one run that turns
    by less (a load, a supply that sags) is said by a :class:`ConstantInputTurnWarning` and the fit
    goes on.  So it goes on, said the same way, where a torque of the angle learned from the rest of
    the run explains every turn (:func:`identify.checks.angle_turns.angle_torque_explains`): gravity on
    an arm, a spring, an unbalanced load turn the speed under a constant input too.

    What a real step response holds is not counted: the run is smoothed over :data:`RUN_SMOOTHING`
    of its samples first (noise, the encoder's rounding, commutator ripple), and a rise or fall
    within :data:`RUN_NOISE_FACTOR` noise standard deviations of the smoothed speed, or two of
    its rounding steps, is no turn.

    Parameters
    ----------
    rec : Recording
        The run.
    name : str
        How the message names it.
    input_delay : int
        The input delay of the model fitted to it, in samples.
    """
    skip = int(input_delay) + RUN_SKIP
    n = min(len(rec), RUN_ROWS)
    if n < skip + RUN_MIN:
        return
    u, seq = rec.duty[:n], rec.seq[:n]
    change = np.flatnonzero((np.diff(u) != 0) | (np.diff(seq) != 1)) + 1
    starts, ends = np.r_[0, change], np.r_[change, n]
    long = (ends - starts) >= skip + RUN_MIN
    if not long.any():
        return
    speed = rec.measured_speed()[:n]
    finite = speed[np.isfinite(speed)]
    if len(finite) < 2:
        return
    span = float(np.ptp(finite))
    floor = 0.0
    if rec.counts is not None and rec.counts_per_rev:     # beyond the encoder's rounding, many times over
        floor = 10 * 2 * math.pi / rec.counts_per_rev / rec.sample_period
    turns, runs = [], []
    for start, end in zip(starts[long], ends[long]):
        w = speed[start + skip:end]
        w = w[np.isfinite(w)]
        if len(w) < RUN_MIN:
            continue
        rise, fall, noise = run_turns(w)
        if min(rise, fall) > max(noise, floor, RUN_SHARE * span):
            runs.append((start + skip, end, max(floor, RUN_SHARE * span)))
            turns.append((min(rise, fall), f"{name}: while the recorded input stays at {u[start]:g} {rec.input_unit} "
                                           f"(seq {int(seq[start])}...{int(seq[end - 1])}) the speed rises by "
                                           f"{rise:.3g} and falls by {fall:.3g} rad/s"))
    if not turns:
        return
    largest, where = max(turns)
    from .checks.angle_turns import angle_torque_explains
    refused = len(turns) > 1 or largest > RUN_REFUSE_SHARE * span
    if refused and angle_torque_explains(rec, runs, input_delay, run_turns):
        warnings.warn(f"{where}{_more(turns)}: a torque of the angle (gravity on an arm, a spring, an unbalanced "
                      "load), learned from the rest of the run, explains it; the fit goes on, and its checks judge "
                      "the model", ConstantInputTurnWarning, stacklevel=3)
        return
    if refused:
        raise NotIdentifiableError(
            f"{where}{_more(turns)}; a motor under a constant input moves one way, so the input logged is not the "
            "input it received (clipped or scaled in the log?): record the input the drive applied")
    warnings.warn(f"{where}, {100 * largest / span:.0f} % of its range, in this one run; a motor under a constant "
                  "input moves one way: a load, a supply that sags, a slow ripple? the fit goes on; look at its "
                  "residuals there", ConstantInputTurnWarning, stacklevel=3)


#: The largest input magnitude a fit takes, in the input's unit (and 1 / it the smallest): b and its
#: variance scale with its inverse square, which leaves a float's range for inputs far beyond any drive's.
INPUT_SCALE_LIMIT = 1e100


def _check_input_scale(largest: float, unit: str, name: str = "recording") -> None:
    """Refuse an input whose magnitude no unit of a drive gives (``duty x 1e-300``): b**2 would overflow."""
    if not 1 / INPUT_SCALE_LIMIT <= largest <= INPUT_SCALE_LIMIT:
        raise NotIdentifiableError(f"{name}: input's largest magnitude must be in {1 / INPUT_SCALE_LIMIT:g}..."
                                   f"{INPUT_SCALE_LIMIT:g} {unit}, got {largest:g}: no drive's input is that "
                                   "far from 1; give the input in its real unit (duty, V, %)")


def check_output_moves(r: Recording, name: str = "recording") -> None:
    """Refuse a recording whose measured output (counts, angle or speed) never changes, naming it ``name``."""
    if r.angle is None and r.counts is not None and len(r.counts):
        low, high = int(r.counts.min()), int(r.counts.max())
        if low != high and max(-low, high) < 1 << 51:
            return     # whole counts that differ below 2**51 give angles that differ: no angle formed to see it
    y, kind = _measured_output(r)
    if len(y) and y.min() == y.max():
        what, stuck = ("encoder count", f"{r.counts[0]}") if r.counts is not None else (kind, f"{y[0]:g}")
        raise NotIdentifiableError(f"{name}: the {what} never changes (stuck at {stuck}): the "
                                   "encoder is stuck or the motor did not move; check the wiring and "
                                   "that the duty exceeds the motor's dead zone")


def _warn_saturation(i: int, r: Recording) -> None:
    limit = r.input_limit
    share = 0.0
    # no duty reaches the limit: a share of 0 without a pass over the column
    if r.input_unit == "duty" and limit is not None and len(r) and max(r.duty.max(), -r.duty.min()) >= limit:
        share = float(np.mean(np.abs(r.duty) >= limit))
    if share > _SATURATION_SHARE:
        warnings.warn(f"{r.name(i)}: the duty sits at its limit +-{limit:g} for {100 * share:.0f} % of "
                      "the samples; the motor sees a square wave and the estimate rests on few "
                      "transitions: lower the amplitude", UserWarning, stacklevel=4)
    elif r.reference is None and (runs := r.saturated_runs()):
        # open loop only: a controller's duty at the limit is its own choice, not a clipped excitation
        warnings.warn(f"{r.name(i)}: the duty is clipped at its limit +-{limit:g} in {len(runs)} run(s), "
                      f"{sum(n for _, n in runs)} samples (the first from row {runs[0][0]}): the input the "
                      "excitation asked for did not reach the motor there; the samples stay in the fit (the "
                      "recorded duty is the one applied); lower the amplitude if the fit or its residuals look "
                      "wrong", UserWarning, stacklevel=4)


#: Share of a closed-loop run's samples at the input limit above which :func:`saturation_note` speaks.
CLOSED_LOOP_SATURATED_SHARE = 0.10


def saturation_note(recordings: Sequence[Recording]) -> str | None:
    """How many samples sit at the input limit, and why they stay in the fit; None when none do.

    Samples in runs at the limit (:meth:`motorsim.Recording.saturated_runs`) are counted over
    the open-loop recordings, and over a closed-loop one only when they are more than
    :data:`CLOSED_LOOP_SATURATED_SHARE` of it (a controller at its limit for a few samples of a
    step is its own choice, not a clipped excitation).

    They are *kept* in the fit, deliberately.  Every rig motorid knows records the duty it
    applied, clamp included (``SimRig``, the firmware, ``fake://``), so at the limit the model
    ``b u`` is as right as anywhere: an exact fit stays exact with them.  Leaving them out would
    cut every run at each clipped stretch and throw away the transitions into and out of it,
    which carry the information about ``a``.  They are wrong only when the driver delivers less
    than the recorded duty at its limit (a supply that sags); the note says so.

    Examples
    --------
    >>> import numpy as np
    >>> from motorsim import Recording
    >>> duty = np.clip(np.round(300 * np.sin(np.arange(400) * 0.05)), -255, 255)
    >>> rec = Recording(time=np.arange(400) * 0.005, duty=duty, sample_period=0.005,
    ...                 counts=np.arange(400), counts_per_rev=400, metadata={"duty_limit": "255"})
    >>> saturation_note([rec])[:63]
    '136 of the 400 samples (34 %) sit at the input limit +-255 duty'
    """
    total = sum(len(r) for r in recordings)
    counted = 0
    runs = 0
    for r in recordings:
        found = r.saturated_runs()
        n = sum(length for _, length in found)
        if r.reference is not None and n <= CLOSED_LOOP_SATURATED_SHARE * len(r):
            continue
        counted += n
        runs += len(found)
    if not counted:
        return None
    limit = recordings[0].input_limit
    return (f"{counted} of the {total} samples ({100 * counted / total:.2g} %) sit at the input limit "
            f"+-{limit:g} {recordings[0].input_unit} in {runs} run(s): kept in the fit, as the recorded input "
            "is the one the motor received; if the driver gives less than that at its limit, lower the "
            "amplitude")
