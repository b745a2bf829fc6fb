"""Candidate models compared by the evidence: the simplest one within the noise of the best.

The machinery of the model choice, shared by the default estimator
(:mod:`identify.default.selection`: input delay x structure) and by the estimators' own
``input_delay="auto"`` (``oe``, ``oe-friction``: the delay alone, each ranked by its own fits).
The callers fit the candidates; this module scores and chooses, and imports no estimator.

The criterion
-------------
Residuals of real benches are coloured (encoder rounding that stays put while the shaft is
slow, unmodelled dynamics), so the white-noise likelihood ratio, AIC or BIC would call tiny
improvements significant and pick the biggest model or the longest delay (the failure this
module replaces: a delay of 10 samples "better" than 0 by 0.01 point of fit).  Instead each
candidate ``c`` is compared with the best fit (least residual sum ``S*``, residuals ``r*``) along
the one direction that separates them, ``Delta = r_c - r*``:

    T_c = (S_c - S*) |Delta|^2 / V_c,      V_c = sum_blocks (Delta_j . r*_j)^2

``V_c`` is the batch-means (Newey--West with :data:`BLOCKS` blocks) estimate of the variance
of ``Delta . e`` under the noise actually present: with white noise ``T_c`` is the classic
``(S_c - S*)/sigma^2``; where the noise is slow along ``Delta`` (a ridge where a lag and a
delay look alike, a coarse encoder on a slow sine) ``V_c`` grows and the two models become
indistinguishable, as they are.  ``c`` is *within the noise* when ``T_c`` is below the
``1 - level`` quantile of ``k F(k, BLOCKS - k)`` (``k`` the difference in parameter counts, at
least 1; the F rather than the chi-square because ``V_c`` is itself estimated from the blocks),
``level`` = :data:`LEVEL`.  Simplest means fewest parameters (a nonzero delay counts as one),
then the shorter delay.  We chose this over held-out prediction (which needs a fit per
candidate and fold: several times the cost) because every candidate is then scored by the very
fit that would be returned, once.

Doubt
-----
When the candidates within the noise give materially different ``a`` or ``b`` (outside the
chosen fit's own 95 % interval): the range of ``a`` and ``b`` over those candidates is kept
with the estimate (``model_range``), its intervals become the union of the chosen fit's own and
that range (so they cover every candidate the data cannot rule out; the covariance stays the
chosen fit's), and when they differ by more than :data:`MATERIAL` relative the choice is called
unclear and a note says which experiment would separate them.  A delay at the top of the
searched range is never returned without a note.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from motorsim.recording import Recording

from .data import Segment, prepare_segments
from .errors import NotIdentifiableError
from .model_structures import ModelStructure, structures
from .sums import sum_squares

__all__ = ["Candidate", "CandidateFit", "Selection", "STRUCTURES", "MAX_AUTO_DELAY", "LEVEL", "BLOCKS", "MATERIAL",
           "best_fit", "block_sums", "block_mean_p", "choose", "choose_delay", "largest_delay", "plausible", "refine",
           "far_worse", "scan_delays", "separating_experiment", "statistic", "threshold", "parameters_threshold"]

#: Largest input delay in samples the selection tries.
MAX_AUTO_DELAY = 10
#: Level of the test that calls a candidate worse than the best (see the module docstring).
LEVEL = 0.001
#: Blocks of the batch-means variance.
BLOCKS = 32
#: Relative difference in ``a`` or ``b`` from which candidates the data cannot separate make the choice
#: unclear (smaller differences outside the interval only widen it).
MATERIAL = 0.01
#: Candidates fitted coarsely whose statistic (an upper bound) is within this factor of the threshold are
#: fitted fully before the choice.
REFINE_FACTOR = 20.0
#: Relative excess of residual sum over the best's below which a coarse candidate is always fitted fully,
#: and a delay scan never stops: on long data the coarse steps' ``a`` (from a prefix) is less precise than
#: the full data's standard error, so their statistic alone can overstate how far a candidate is.
CLOSE = 0.01
#: A delay scan stops after this many delays in a row whose every candidate is worse than the best by
#: more than :data:`STOP_FACTOR` times the threshold.
STOP_AFTER = 2
STOP_FACTOR = 100.0


#: The candidate structures of the default, simplest first: the registered ones
#: (:func:`identify.structures`) it considers.
STRUCTURES: Mapping[str, ModelStructure] = structures(in_default=True)
#: Every registered structure: a candidate may be one the default fits only on evidence (a gain per direction).
_REGISTERED: Mapping[str, ModelStructure] = structures()


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One model the selection fitted (or left out), and how it scored.

    Attributes
    ----------
    structure : str
        A registered structure's name (:data:`STRUCTURES`).
    input_delay : int
        Samples.
    a, b : float
        The candidate's fit on the common rows (nan when it failed).
    residual_sum : float
        Its residual sum of squares on the common rows (nan when it failed).
    statistic : float
        ``T_c`` against the best candidate (0 for the best itself).
    within_noise : bool
        Whether the data cannot tell it from the best.
    note : str
        Why it failed, when it did.
    fitted_by : str
        The estimator that fitted it when not the structure's own (``pem-disturbance`` in a closed loop).
    fit_options : tuple of (str, value) pairs
        That estimator's options besides the delay.
    """

    structure: str
    input_delay: int
    a: float
    b: float
    residual_sum: float
    statistic: float = math.nan
    within_noise: bool = False
    note: str = ""
    fitted_by: str = ""
    fit_options: tuple[tuple[str, Any], ...] = ()

    @property
    def n_params(self) -> int:
        """Shared parameters, a nonzero delay counted as one more."""
        return _REGISTERED[self.structure].n_params + (self.input_delay > 0)

    @property
    def method(self) -> str:
        """The estimator that fits this candidate."""
        return self.fitted_by or _REGISTERED[self.structure].method

    def options(self) -> dict[str, Any]:
        """``fit(recordings, method, **options)`` reproduces the candidate on all rows (a structure the default
        fits only on evidence, outside :data:`STRUCTURES`, too)."""
        if self.fitted_by:
            return {"input_delay": self.input_delay, **dict(self.fit_options)}
        return {"input_delay": self.input_delay, **_REGISTERED[self.structure].options}

    @property
    def label(self) -> str:
        return f"{self.structure}, delay {self.input_delay}"


@dataclasses.dataclass(frozen=True)
class Selection:
    """What :func:`select_model` compared and chose (kept with the estimate as an
    :class:`identify.SelectionReport`).

    Attributes
    ----------
    candidates : tuple of Candidate
        Every candidate fitted, in the order tried.
    chosen : Candidate
        The simplest candidate within the noise of the best.
    best : Candidate
        The candidate with the least residual sum.
    runner_up : Candidate or None
        The next simplest candidate within the noise (else the best of the others).
    clear : bool
        False when candidates the data cannot separate give materially different ``a`` or ``b``
        (set by :func:`fit_selected`, which knows the chosen fit's interval).
    doubt : str
        One line saying what the data cannot separate, the range and what would separate it.
    notes : tuple of str
        What the data cannot answer, and what the selection left out and why.
    level : float
        Level of the test.
    criterion : str
        The test, in words.
    refuted : (float, str) or None
        Where a fit overruled the screen that left friction out: the score test's p-value and what the fit of
        friction moved, in words (:func:`identify.default.selection.select_model`); None otherwise.
    """

    candidates: tuple[Candidate, ...]
    chosen: Candidate
    best: Candidate
    runner_up: Candidate | None
    clear: bool = True
    doubt: str = ""
    notes: tuple[str, ...] = ()
    level: float = LEVEL
    criterion: str = "simplest candidate within the noise of the best (batch-means test)"
    refuted: tuple[float, str] | None = None

    def comparison(self) -> str:
        """The runner-up against the chosen model, in plain words."""
        other = self.runner_up
        if other is None:
            return "no other candidate fitted"
        if other.within_noise:
            return (f"the data cannot tell {other.label} from it (T = {other.statistic:.3g}, "
                    f"threshold {threshold(other, self.best, self.level):.3g}); the simpler one is kept")
        return (f"{other.label} fits worse by T = {other.statistic:.3g} noise units "
                f"(threshold {threshold(other, self.best, self.level):.3g})")


@dataclasses.dataclass(eq=False)
class CandidateFit:
    """A candidate's fit on the common rows: its residuals (None when it failed), the bias, and
    whether it is the full fit or only coarse steps (whose residual sum bounds the full one's)."""

    candidate: Candidate
    residuals: np.ndarray | None
    bias: float = 0.0
    refined: bool = True          # False: a coarse fit, whose residual sum bounds the candidate's from above
    start: tuple[float, ...] = ()  # its nonlinear parameters, a start for the same structure at a neighbouring delay


def threshold(c: Candidate, best: Candidate, level: float) -> float:
    return parameters_threshold(max(best.n_params - c.n_params, 1), level)


@functools.lru_cache(maxsize=64)
def parameters_threshold(k: int, level: float) -> float:
    """``k`` times the ``1 - level`` quantile of ``F(k, BLOCKS - k)`` (a few values, asked for every candidate)."""
    from scipy.special import fdtri  # the F quantile, lighter than scipy.stats
    return k * float(fdtri(k, BLOCKS - k, 1.0 - level))


def largest_delay(recs: list[Recording], max_delay: int) -> int:
    """``max_delay``, less on short data: at least 20 rows per delay tried in the shortest segment."""
    longest = max(len(seg) for rec in recs for seg in rec.segments())
    return max(0, min(max_delay, longest // 20))


def block_sums(x: np.ndarray) -> np.ndarray:
    """Sums of ``x`` along its first axis over :data:`BLOCKS` consecutive blocks of nearly equal length
    (one per row when there are fewer rows): the pieces of every batch-means variance here."""
    n = len(x)
    if n == 0:
        return np.zeros((0, *np.shape(x)[1:]))
    return np.add.reduceat(x, _block_starts(n), axis=0)


@functools.lru_cache(maxsize=16)
def _block_starts(n: int) -> np.ndarray:
    """First row of each block of :func:`block_sums` for ``n`` rows (the same few lengths, asked for often)."""
    starts = np.linspace(0, n, min(BLOCKS, n) + 1).astype(int)[:-1]
    starts.flags.writeable = False
    return starts


def block_mean_p(scores: np.ndarray) -> float:
    """p-value of Hotelling's T^2 test that the rows of ``scores`` (block sums, ``(m, k)`` or ``(m,)``)
    have mean zero: ``T^2 = m xbar^T S^-1 xbar`` with ``S`` their sample covariance, and
    ``T^2 (m - k) / (k (m - 1))`` an ``F(k, m - k)`` variate when the blocks are independent and normal.

    Centring matters under the alternative: a misfit that the blocks share inflates their raw second
    moment as much as their mean, which would hide it (that statistic cannot exceed ``m``).
    1.0 when there are too few blocks (``m <= k + 1``) or nothing to test; 0.0 when ``S`` is singular
    while the mean is not zero.
    """
    from scipy.special import fdtrc
    x = np.asarray(scores, dtype=float)
    x = x.reshape(len(x), -1)
    m, k = x.shape
    if k == 0 or m <= k + 1:
        return 1.0
    mean = x.mean(axis=0)
    if not np.any(mean):
        return 1.0
    spread = np.atleast_2d(np.cov(x, rowvar=False, ddof=1))
    try:
        t2 = m * float(mean @ np.linalg.solve(spread, mean))
    except np.linalg.LinAlgError:
        return 0.0
    if not math.isfinite(t2):
        return 0.0
    return float(fdtrc(k, m - k, max(t2, 0.0) * (m - k) / (k * (m - 1))))


def statistic(delta: np.ndarray, excess: float, reference: np.ndarray, rounding: np.ndarray | None = None) -> float:
    """``T = excess |delta|^2 / V`` with ``V`` the batch-means variance of ``delta . e`` (module docstring),
    plus the variance of ``delta . e`` over the encoder's rounding at other phases when given."""
    norm2 = sum_squares(delta)
    if excess <= 0 or norm2 == 0:
        return 0.0
    v = float(np.sum(block_sums(delta * reference) ** 2))
    if rounding is not None:
        v += float(np.var(delta @ rounding, ddof=1))
    return excess * norm2 / v if v > 0 else math.inf


#: Residual variance, in encoder rounding variances ``step^2/12``, above which the rounding realisations
#: are left out (the other noise dominates and the batch means account for it).
ROUNDING_DOMINATED = 2.0
#: Encoder phases of the rounding realisations (:func:`_rounding_realisations`).
PHASES = 16


def rounding_realisations(recs: list[Recording], segs: list[Segment], residuals: np.ndarray) -> np.ndarray | None:
    """The encoder's rounding error of the model ``segs' output - residuals`` at :data:`PHASES` phases.

    Columns ``-step frac(theta/step + phi)``, centred per segment like the residuals.  The phase of
    an encoder against the shaft is arbitrary, so these are realisations of the rounding noise the
    data could have had; on a periodic run they repeat every period, so their projection on a
    periodic difference between two models adds up coherently, which the batch means (blocks
    assumed independent) would miss.  None unless every segment is an encoder's angle and the
    residuals are mostly its rounding (variance at most :data:`ROUNDING_DOMINATED` rounding variances).
    """
    steps = []
    for seg in segs:
        cpr = recs[seg.recording].counts_per_rev
        if seg.kind != "angle" or not cpr or recs[seg.recording].counts is None:
            return None
        steps.append(2 * math.pi / cpr)
    if sum_squares(residuals) / len(residuals) > ROUNDING_DOMINATED * max(steps) ** 2 / 12:
        return None         # other noise dominates: the batch means see it
    phases = (np.arange(PHASES) + 0.5) / PHASES
    out = np.empty((PHASES, len(residuals)))        # a phase per row: each realisation one contiguous pass
    row = 0
    for seg, step in zip(segs, steps):
        n = len(seg.output)
        model = (seg.output - residuals[row:row + n]) / step
        for phase, realisation in zip(phases, out[:, row:row + n]):
            np.add(model, phase, out=realisation)
            realisation -= np.floor(realisation)
            realisation *= -step
            realisation -= realisation.mean()
        row += n
    return out.T


def best_fit(fitted: list[CandidateFit]) -> CandidateFit | None:
    ok = [f for f in fitted if f.residuals is not None]
    return min(ok, key=lambda f: f.candidate.residual_sum) if ok else None


def far_worse(here: Sequence[CandidateFit], fitted: Sequence[CandidateFit], level: float) -> bool:
    """Whether every candidate of ``here`` is far beyond the noise of the best of ``fitted`` (:data:`STOP_FACTOR`
    times the threshold of the test at ``level``; a failed fit counts as far beyond it)."""
    best = best_fit(list(fitted))
    if best is None or any(f is best for f in here):
        return False
    for f in here:
        if f.residuals is None:
            continue
        t = _against(f, best)
        if t <= STOP_FACTOR * threshold(f.candidate, best.candidate, level) or _close(f, best):
            return False
    return True


def _against(f: CandidateFit, best: CandidateFit, rounding: np.ndarray | None = None) -> float:
    """:func:`statistic` of fit ``f`` against the best fit (both with residuals)."""
    assert f.residuals is not None and best.residuals is not None
    return statistic(f.residuals - best.residuals, f.candidate.residual_sum - best.candidate.residual_sum,
                     best.residuals, rounding)


def _close(f: CandidateFit, best: CandidateFit) -> bool:
    """Whether ``f``'s residual sum is within :data:`CLOSE` of the best's, relative."""
    return f.candidate.residual_sum - best.candidate.residual_sum <= CLOSE * best.candidate.residual_sum


def plausible(fitted: list[CandidateFit], level: float, factor: float = 1.0) -> list[CandidateFit]:
    """The fits within ``factor`` times the noise of the best (the best among them): statistic at most
    ``factor`` times the threshold, or residual sum within :data:`CLOSE` of the best's."""
    best = best_fit(fitted)
    if best is None:
        return []
    scored = [f for f in fitted if f.residuals is not None]
    near = {id(f) for f in scored if f is best or _close(f, best)}
    tested = [f for f in scored if id(f) not in near]
    found = dict(zip(map(id, tested), _statistics(tested, best, None)))       # stacked, as the choice scores them
    return [f for f in scored
            if id(f) in near or found[id(f)] <= factor * threshold(f.candidate, best.candidate, level)]


def scan_delays(delays: Sequence[int], fit_at: Callable[[int], list[CandidateFit]], level: float,
                notes: list[str]) -> list[CandidateFit]:
    """Fit ``fit_at(d)`` for each delay in turn; stop when the fit has worsened far beyond the noise of the
    best for :data:`STOP_AFTER` delays in a row (the delays left out are said in ``notes``)."""
    fitted: list[CandidateFit] = []
    worse = 0
    for d in delays:
        here = fit_at(d)
        fitted += here
        worse = worse + 1 if far_worse(here, fitted, level) else 0
        if worse == STOP_AFTER and d < delays[-1]:
            skipped = f"delay {d + 1}" if d + 1 == delays[-1] else f"delays {d + 1}-{delays[-1]}"
            notes.append(f"{skipped} not fitted: the fit worsened far beyond the noise for "
                         f"{STOP_AFTER} delays in a row past the best")
            break
    return fitted


def choose_delay(recs: list[Recording], fit_at: Callable[[list[Segment], int, bool], CandidateFit],
                 max_delay: int, level: float, what: str) -> int:
    """The shortest input delay whose fit is within the noise of the best, one structure's.

    ``fit_at(segments, delay, refine)`` fits the candidate at ``delay`` on the common rows (only its
    coarse steps when ``refine`` is False, where it has such steps).  The delays ``0 ... max_delay``
    (fewer on short data) are scanned with :func:`scan_delays`, refined with :func:`refine` and
    chosen by :func:`choose`; a delay at the top of the range is said in a warning naming ``what``.
    """
    import warnings

    top = largest_delay(recs, max_delay)
    segments = {d: segs for d in range(top + 1) if (segs := prepare_segments(recs, d, skip=top))}
    if not segments:
        raise NotIdentifiableError(f"recording is too short for input delays up to {top} samples")
    notes: list[str] = []
    fitted = scan_delays(list(segments), lambda d: [fit_at(segments[d], d, False)], level, notes)
    refine(fitted, lambda f: fit_at(segments[f.candidate.input_delay], f.candidate.input_delay, True), level)
    selection = choose(fitted, level, notes, top, recs, segments)
    edge = [n for n in selection.notes if n.startswith("the chosen delay is the largest")]
    if edge:
        warnings.warn(f"{what} input_delay='auto': {edge[0]}", UserWarning, stacklevel=5)
    return selection.chosen.input_delay


def refine(fitted: list[CandidateFit], refit: Callable[[CandidateFit], CandidateFit],
           level: float) -> CandidateFit | None:
    """Fit fully, in place, the coarse candidates that could be the best or within its noise; the best.

    A coarse candidate's residual sum bounds its full fit's from above, so one far above the best's
    (statistic beyond :data:`REFINE_FACTOR` times the threshold, and residual sum more than
    :data:`CLOSE` above, relative) stays far above it once fitted.
    """
    while True:
        best = best_fit(fitted)
        if best is None:
            return None
        if not best.refined:
            pending = [best]
        else:
            pending = [f for f in plausible(fitted, level, REFINE_FACTOR) if not f.refined]
            if not pending:
                return best
        for f in pending:
            fitted[fitted.index(f)] = refit(f)


def _scored(fitted: list[CandidateFit], best: CandidateFit, level: float, recs: list[Recording],
            segments: dict[int, list[Segment]]) -> list[Candidate]:
    """Every candidate with its statistic against ``best`` and whether it is within the noise of it."""
    reference = best.residuals
    assert reference is not None
    rounding = rounding_realisations(recs, segments[best.candidate.input_delay], reference)
    others = [f for f in fitted if f is not best and f.residuals is not None and len(f.residuals) == len(reference)]
    found = dict(zip(map(id, others), _statistics(others, best, rounding)))
    scored: list[Candidate] = []
    for f in fitted:
        c = f.candidate
        if f.residuals is None or len(f.residuals) != len(reference):
            scored.append(c)
            continue
        t = 0.0 if f is best else found[id(f)]
        scored.append(dataclasses.replace(c, statistic=t, within_noise=t <= threshold(c, best.candidate, level)))
    return scored


#: Candidates whose statistics :func:`_statistics` computes in one array (bounds its memory on long data).
STATISTICS_AT_ONCE = 16


def _statistics(fits: list[CandidateFit], best: CandidateFit, rounding: np.ndarray | None) -> list[float]:
    """:func:`statistic` of every fit against the best, their differences stacked (one product with the
    rounding realisations for several of them, not one each); the same sums, to rounding."""
    reference = best.residuals
    assert reference is not None
    out: list[float] = []
    for first in range(0, len(fits), STATISTICS_AT_ONCE):
        group = fits[first:first + STATISTICS_AT_ONCE]
        deltas = np.array([f.residuals for f in group])
        deltas -= reference
        excess = np.array([f.candidate.residual_sum - best.candidate.residual_sum for f in group])
        norm2 = np.einsum("ij,ij->i", deltas, deltas)
        spread = np.var(deltas @ rounding, axis=1, ddof=1) if rounding is not None else 0.0
        deltas *= reference                          # in place: the products of the batch means
        v = np.sum(block_sums(deltas.T) ** 2, axis=0) + spread
        for e, n2, vi in zip(excess.tolist(), norm2.tolist(), v.tolist()):
            out.append(0.0 if e <= 0 or n2 == 0 else (e * n2 / vi if vi > 0 else math.inf))
    return out


def choose(fitted: list[CandidateFit], level: float, notes: list[str], top: int | None, recs: list[Recording],
            segments: dict[int, list[Segment]]) -> Selection:
    """The simplest candidate within the noise of the best (module docstring).

    Structures of a higher rank (a second pole) are judged after the first-order family: the family's
    choice is made against its own best fit, as if they were not there, and stands unless the best of
    the family is itself outside the noise of the best fit overall; then the simplest higher-rank
    candidate within the noise of that best is chosen.  Higher-rank candidates within the noise of the
    best overall are kept as candidates the data cannot rule out either way.
    """
    best = best_fit(fitted)
    if best is None:
        reasons = "; ".join(sorted({f.candidate.note for f in fitted if f.candidate.note}))
        raise NotIdentifiableError(f"no candidate model could be fitted: {reasons}")
    family = best_fit([f for f in fitted if _REGISTERED[f.candidate.structure].rank == 0]) or best
    scored = _scored(fitted, family, level, recs, segments)
    order = list(_REGISTERED)

    def simplicity(c: Candidate) -> tuple:
        return (_REGISTERED[c.structure].rank, c.n_params, c.input_delay, order.index(c.structure))
    if family is not best:
        overall = _scored(fitted, best, level, recs, segments)
        if overall[fitted.index(family)].within_noise:        # the family holds: higher ranks only widen
            scored = [o if _REGISTERED[c.structure].rank else c for c, o in zip(scored, overall)]
        else:
            scored = overall
    best_c = scored[fitted.index(best)]
    within = [c for c in scored if c.within_noise]
    first = [c for c in within if _REGISTERED[c.structure].rank == 0]
    chosen = min(first or within, key=simplicity)
    others = [c for c in within if c is not chosen]
    runner_up = min(others, key=simplicity) if others else min(
        (c for c in scored if c is not chosen and math.isfinite(c.statistic)), key=lambda c: c.statistic, default=None)
    if top is not None and top > 0:
        if chosen.input_delay == top:
            notes.append(f"the chosen delay is the largest tried ({top} samples): the true delay may be longer; "
                         "pass input_delay (--input-delay N) to fit a longer one")
        elif best_c.input_delay == top and best_c is not chosen:
            notes.append(f"the least residual is at the largest delay tried ({top} samples), but no better than "
                         f"{chosen.label} within the noise")
    return Selection(candidates=tuple(scored), chosen=chosen, best=best_c, runner_up=runner_up, notes=tuple(notes),
                     level=level)


def separating_experiment(chosen: Candidate, others: Sequence[Candidate]) -> str:
    kinds = []
    if any(c.input_delay != chosen.input_delay for c in others):
        kinds.append("a lag and an input delay look alike: a second frequency (a multisine) or a step "
                     "would separate them")
    structures = {c.structure for c in others} | {chosen.structure}
    if {"friction", "dead-zone"} <= structures:
        kinds.append("friction and a dead zone look alike: slow reversals with small inputs would separate them")
    elif len(structures) > 1:
        kinds.append("the structures look alike here: runs at several amplitudes, through zero speed, "
                      "would separate them")
    return "; ".join(kinds) or "a longer or richer run would separate them"


