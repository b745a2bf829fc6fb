"""A fit screened for corrupted samples: the same for ``identify.fit`` and ``motorid identify``.

A row no motor can produce (:meth:`motorsim.recording.Recording.implausible_samples`) or an
isolated residual outlier after the fit (:func:`identify.checks.outliers.residual_outliers`) is a
corrupted sample: with ``outliers="refuse"`` (the default of :func:`identify.fit`) the fit is
refused with :class:`CorruptedSamplesError`, naming the recording and the rows' ``seq`` -- except
outliers among the first :data:`RUN_START_ROWS` samples of a run (a logger's or a speed filter's
start-up, which real recordings have): those are left out as gaps, reported, and said by a
:class:`RunStartWarning`; with
``outliers="drop"`` such rows are dropped as gaps, the fit is repeated, and every dropped row is
reported (:class:`DroppedSamples`); ``outliers="keep"`` fits the data as they are.  In every
case a run whose speed column contradicts its counts or angle (:func:`identify.data.check_speed_agrees`)
or whose output answers its recorded input one sample before it (an input logged late,
:func:`identify.checks.causality.check_input_leads`) is refused first, and one whose speed turns while
its recorded input stays constant, at the fitted delay (:func:`identify.data.check_constant_input_runs`).
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Callable, Sequence

import numpy as np

from motorsim.checks import ParameterError
from motorsim.recording import Recording

from ..data import (
    ConstantInputWarning,
    as_recordings,
    check_constant_input_runs,
    check_input_changes,
    check_length,
    check_output_moves,
    check_speed_agrees,
    one_input_level,
)
from ..errors import CorruptedSamplesError, NotIdentifiableError
from ..estimate import Estimate
from ..sums import single_threaded_blas
from .causality import check_input_leads

__all__ = ["DroppedSamples", "ScreenedFit", "screened_fit", "with_encoder", "OUTLIER_RULES", "RUN_START_ROWS",
           "RunStartWarning"]

#: What :func:`screened_fit` does with corrupted samples.
OUTLIER_RULES = ("refuse", "drop", "keep")
#: Rows at the start of a run (a recording's or a segment's after a gap) whose outliers are a start-up, not corruption.
RUN_START_ROWS = 5


class RunStartWarning(UserWarning):
    """A run's first samples stand out from the fit; they were left out of it (``outliers="refuse"``)."""


def _at_run_start(rec: Recording, row: int) -> bool:
    """Whether ``row`` is among the first :data:`RUN_START_ROWS` of its run (no gap in ``seq`` before it there)."""
    first = max(0, row - RUN_START_ROWS)
    return row < RUN_START_ROWS or bool(np.any(np.diff(rec.seq[first:row + 1]) != 1))


@dataclasses.dataclass(frozen=True)
class DroppedSamples:
    """Rows dropped from one recording before the fit, by ``seq``, and why."""

    recording: int
    seq: tuple[int, ...]
    reason: str

    def describe(self, name: str) -> str:
        """One line: ``name: seq 1, 2, ... (reason)``."""
        shown = ", ".join(map(str, self.seq[:10])) + (", ..." if len(self.seq) > 10 else "")
        return f"{name}: seq {shown} ({self.reason})"


def with_encoder(estimate: Estimate, recordings: Sequence[Recording]) -> Estimate:
    """``estimate`` naming the encoder its recordings were measured with (``counts_per_rev``), when they all
    hold counts of one encoder; as it is otherwise."""
    found = {r.counts_per_rev for r in recordings if r.counts is not None}
    if len(found) != 1 or any(r.counts is None for r in recordings) or None in found:
        return estimate
    return dataclasses.replace(estimate, counts_per_rev=found.pop())


#: The structures the default chooses among on recordings of one constant input level (:func:`_one_level_options`).
ONE_LEVEL_STRUCTURES = ("linear",)


def _one_level_options(recs: Sequence[Recording], estimator: Callable[..., Estimate],
                       options: dict[str, Any]) -> dict[str, Any]:
    """The default's options for recordings of one constant input level (said here, once): the structures
    whose ``b`` such data fix (:data:`ONE_LEVEL_STRUCTURES`).

    At one level ``u`` a bias ``d`` (or a friction, on a speed that never reverses) and ``b`` act as one
    constant, ``b u + d``: a structure fitting both (the second-order one always fits a bias) has no
    interval for either, and its arbitrary split of the two is no answer.
    """
    level = one_input_level(recs)
    if level is None:
        return options
    check_input_changes(recs)             # a level the motor had settled at is refused (no transient)
    warnings.warn(f"input is constant ({level:g} {recs[0].input_unit} throughout): a and b rest on the speed's "
                  "transient alone, and a friction or a bias cannot be told from b at one input level (SysId's "
                  "dynamic test alone); pool it with the routine's other tests, or record steps to several levels",
                  ConstantInputWarning, stacklevel=4)
    default = getattr(estimator, "__module__", "") == "identify.default.selection" and \
        getattr(estimator, "__name__", "") == "fit_selected"          # by name: selection imports this module's callers
    if default and "structures" not in options:
        return {**options, "structures": ONE_LEVEL_STRUCTURES}
    return options


def _one_level_answer(estimate: Estimate, recordings: Sequence[Recording]) -> Estimate:
    """The default's ``estimate`` honest about ``b`` when every recording holds one constant input level.

    At one input level ``u`` the data fix the transient's rate ``a`` and where the speed settles,
    ``(b u - c) / a``, but not ``b`` apart from a friction ``c`` (or a bias): a Coulomb friction,
    which opposes the motion, makes the motor's ``b`` larger in magnitude than the linear fit's.
    The interval of ``b`` is widened to unbounded on that side (its :attr:`Estimate.model_range`),
    the choice is not clear and a note says why.  Estimates of a named method (no selection), and
    recordings with more than one level, are returned as they are.
    """
    level = one_input_level(recordings)
    if estimate.selection is None or level is None:
        return estimate
    low, high = estimate.confidence_interval()["b"]
    span = (min(low, estimate.b), math.inf) if estimate.b >= 0 else (-math.inf, max(high, estimate.b))
    note = (f"one input level ({level:g} {estimate.input_unit}) throughout: the data fix a and b u - c = "
            f"{estimate.b * level:.4g} rad/s^2, not b apart from a friction or bias c; b's interval is open on the "
            "side a friction would move it; pool the routine's other tests (a ramp, steps to other levels) for b")
    selection = dataclasses.replace(estimate.selection, clear=False, doubt=estimate.selection.doubt or note)
    return dataclasses.replace(estimate, model_range={**estimate.model_range, "b": span}, selection=selection,
                               notes=(*estimate.notes, note))


def _refuse_inner_outliers(found: list[list[int]], recs: Sequence[Recording], reason: str) -> str:
    """Refuse the outliers inside runs (:class:`CorruptedSamplesError`); those at a run's start are said (a
    :class:`RunStartWarning`) and left to be dropped: returns the reason they are dropped for."""
    inner = [[k for k in rows if not _at_run_start(recs[i], k)] for i, rows in enumerate(found)]
    if any(inner):
        i = next(k for k, rows in enumerate(inner) if rows)
        raise CorruptedSamplesError(i, tuple(int(recs[i].seq[k]) for k in inner[i]), reason, recs[i].name(i))
    for i, rows in enumerate(found):
        if rows:
            seqs = ", ".join(str(int(recs[i].seq[k])) for k in rows)
            warnings.warn(f"{recs[i].name(i)}: the first samples of a run (seq {seqs}) stand out from the fit "
                          "(a logger's or a speed filter's start-up?): left out of it as gaps",
                          RunStartWarning, stacklevel=3)
    return f"{reason}, at the start of a run: a logger's start-up?"


@dataclasses.dataclass(frozen=True)
class ScreenedFit:
    """The estimate, the recordings it was fitted on (corrupted rows dropped), and what was dropped."""

    estimate: Estimate
    recordings: tuple[Recording, ...]
    dropped: tuple[DroppedSamples, ...]


def _fit_outliers(est: Estimate, recs: Sequence[Recording], fitted: bool = False) -> list[list[int]]:
    """The isolated residual outliers of every recording; ``fitted``: ``recs`` are the recordings
    ``est`` was fitted on, in order, so the fit's own residuals serve when it kept them."""
    from .outliers import residual_outliers
    kept = est.speed_residuals if fitted and est.speed_residuals is not None else None
    return [residual_outliers(est, rec, None if kept is None else kept[i]) for i, rec in enumerate(recs)]


def _confirmed(outliers: list[list[int]], recs: Sequence[Recording], estimator: Callable[..., Estimate],
               options: dict[str, Any]) -> list[list[int]]:
    """The rows that are still outliers under the model refitted without them.

    A corrupted sample can pull the first fit (an automatic input delay picking the wrong
    delay, say) so far that honest rows look like outliers too; the refit without the
    suspects is the model to judge them by.  Falls back to the first verdict when the refit
    clears every row.
    """
    trial = [rec.drop_rows(rows) if rows else rec for rec, rows in zip(recs, outliers)]
    try:
        again = _fit_outliers(estimator(trial, **options), recs)
    except NotIdentifiableError:
        return outliers
    confirmed = [sorted(set(first) & set(second)) for first, second in zip(outliers, again)]
    return confirmed if any(confirmed) else outliers


def screened_fit(recordings: Recording | Sequence[Recording], estimator: Callable[..., Estimate],
                 options: dict[str, Any] | None = None, *, outliers: str = "refuse", samples_checked: bool = False,
                 name: str = "") -> ScreenedFit:
    """Fit ``method`` on ``recordings`` screened for corrupted samples (module docstring).

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for every estimator.
    estimator : callable
        ``estimator(recordings, **options) -> Estimate`` (:func:`identify.method_function` of a name).
    options : dict, optional
        The estimator's keyword options.
    outliers : {"refuse", "drop", "keep"}
        What a corrupted sample does: refuse the fit (default), drop it as a gap and refit, or
        nothing (the fit as it is, no screening).
    samples_checked : bool
        The recordings were read with their rows checked
        (:func:`motorsim.reading.read_recording` ``check_samples=True`` refuses implausible rows):
        only the residual outliers are left to screen.
    name : str
        The method's name, for the messages.

    Returns
    -------
    ScreenedFit

    Raises
    ------
    CorruptedSamplesError
        (a ``ValueError``) With ``outliers="refuse"``: an implausible row or an isolated residual
        outlier, naming the recording (``recordings[i]``) and the rows' ``seq``.
    """
    if outliers not in OUTLIER_RULES:
        raise ParameterError(f"outliers must be one of {list(OUTLIER_RULES)}, got {outliers!r}")
    with single_threaded_blas():    # passes over the rows, each too short for BLAS threads to pay
        return _screened_fit(recordings, estimator, dict(options or {}), outliers, samples_checked, name)


def _screened_fit(recordings: Recording | Sequence[Recording], estimator: Callable[..., Estimate],
                  options: dict[str, Any], outliers: str, samples_checked: bool, name: str) -> ScreenedFit:
    """:func:`screened_fit` once its rule is checked."""
    recs = as_recordings(recordings)
    check_length(recs)               # a run of one or two rows is said to be too short, before what else it lacks
    for i, rec in enumerate(recs):   # every method's refusals, not only those of the methods that check
        try:
            check_output_moves(rec, rec.name(i))  # a stuck encoder...
        except NotIdentifiableError:
            check_input_changes(recs)             # ...unless the input never changed either: that is said first
            raise
        check_speed_agrees(rec, rec.name(i))      # a speed column in another unit than its counts
    check_input_leads(recs)      # an input logged late: a negative delay no model has
    options = _one_level_options(recs, estimator, options)
    if outliers == "keep":
        return ScreenedFit(_one_level_answer(with_encoder(estimator(recs, **options), recs), recs), tuple(recs), ())
    dropped: list[DroppedSamples] = []
    for i, rec in enumerate(recs):
        bad = [] if samples_checked else rec.implausible_samples()
        if not bad:
            continue
        if outliers == "refuse":
            raise CorruptedSamplesError(i, tuple(s.seq for s in bad), "implausible: " + bad[0].reason, rec.name(i))
        dropped.append(DroppedSamples(i, tuple(s.seq for s in bad), "implausible: " + bad[0].reason))
        recs[i] = rec.drop_rows(s.row for s in bad)
    est = estimator(recs, **options)
    for i, rec in enumerate(recs):        # a speed that turns under a constant recorded input: not the input it got
        check_constant_input_runs(rec, rec.name(i), est.input_delay)
    found = _fit_outliers(est, recs, fitted=True)
    if not any(found):
        return ScreenedFit(_one_level_answer(with_encoder(est, recs), recs), tuple(recs), tuple(dropped))
    found = _confirmed(found, recs, estimator, options)
    reason = f"isolated residual outliers after the {name} fit" if name else "isolated residual outliers after the fit"
    if outliers == "refuse":
        reason = _refuse_inner_outliers(found, recs, reason)
    for i, rows in enumerate(found):
        if rows:
            dropped.append(DroppedSamples(i, tuple(int(recs[i].seq[k]) for k in rows), reason))
            recs[i] = recs[i].drop_rows(rows)
    est = _one_level_answer(with_encoder(estimator(recs, **options), recs), recs)
    return ScreenedFit(est, tuple(recs), tuple(dropped))
