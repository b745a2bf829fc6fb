"""The default estimator: input delay and model structure chosen by the evidence in the data.

``identify.fit(recordings)`` and ``motorid identify FILE`` (no ``method``) call
:func:`fit_selected`.  It fits every candidate model

* input delay ``0 ... N`` samples (``N`` = :data:`MAX_AUTO_DELAY`, fewer on short data), times
* structure ``linear`` (``oe``), ``bias`` (``oe`` with a constant acceleration ``d``),
  ``friction`` (``oe-friction``: Coulomb friction ``c`` and ``d``) and ``dead-zone``
  (``oe-friction``: ``c``, ``d`` and a duty dead zone),

each by the estimator that would return it, on the same rows (every segment from row ``N``), and
returns the **simplest candidate whose fit is within the noise of the best**.

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

Friction and dead zone are fitted only when a score (Lagrange multiplier) test on the best
linear candidate finds their directions in its residuals (same batch-means variance, level
:data:`SCREEN_LEVEL`), and only when the speed reverses or rests (otherwise friction is a
constant acceleration, the bias).  The screen is what keeps the default within a few ``oe``
fits on a linear motor; the report says when it left them out and why.

Doubt
-----
When the candidates within the noise give materially different ``a`` or ``b`` (outside the
chosen fit's own 95 % interval), the choice is not clear: the estimate's covariance gains
``(spread/z)^2`` on ``a`` and ``b`` (``spread`` the largest distance from the chosen value to
another such candidate's, ``z`` the 95 % normal quantile), so its 95 % interval covers every
candidate the data cannot rule out, and a note says which experiment would separate them.  A
delay at the top of the searched range is never returned without a note.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import statistics
import warnings
from typing import Any, Mapping, Sequence

import numpy as np

from motorsim.recording import Recording

from .data import Segment, as_recordings, check_excitation, check_input_delay, prepare_segments
from .errors import NotIdentifiableError
from .estimate import Estimate

__all__ = ["fit_selected", "select_model", "residual_checks", "Selection", "Candidate", "STRUCTURES",
           "MAX_AUTO_DELAY", "LEVEL", "SCREEN_LEVEL", "BLOCKS"]

#: Largest input delay in samples the selection tries.
MAX_AUTO_DELAY = 10
#: Level of the test that calls a candidate worse than the best (see the module docstring).
LEVEL = 0.001
#: Level of the score test that decides whether friction and a dead zone are fitted at all.
SCREEN_LEVEL = 0.01
#: Blocks of the batch-means variance.
BLOCKS = 32
#: Relative difference in ``a`` or ``b`` from which candidates the data cannot separate make the choice
#: unclear (smaller differences outside the interval only widen it).
MATERIAL = 0.01
#: Rows on which a candidate's first Gauss--Newton steps run on long data (its last run on all rows).
COARSE_SAMPLES = 1000
#: Rows of the score test that screens friction and a dead zone (the first of every segment).
SCREEN_SAMPLES = 2000
#: Share of samples at the duty limit above which the data are called saturated.
SATURATED_SHARE = 0.10
#: Encoder counts the whole run must sweep for ``a`` and ``b`` to rest on more than a few steps.
MIN_COUNTS_SWEPT = 50
#: Share of the input's power at or above ``a / 5`` below which ``a`` rests on the static gain alone.
MIN_FAST_POWER = 0.01


@dataclasses.dataclass(frozen=True)
class _Structure:
    name: str
    method: str
    options: Mapping[str, Any]
    n_params: int
    text: str


#: The candidate structures, simplest first.
STRUCTURES: dict[str, _Structure] = {s.name: s for s in (
    _Structure("linear", "oe", {}, 2, "linear (oe)"),
    _Structure("bias", "oe", {"fit_bias": True}, 3, "linear with a constant acceleration d (oe, fit_bias)"),
    _Structure("friction", "oe-friction", {"dead_zone": False}, 4, "Coulomb friction c and bias d (oe-friction)"),
    _Structure("dead-zone", "oe-friction", {}, 5, "friction c, bias d and a duty dead zone (oe-friction)"),
)}


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One model the selection fitted (or left out), and how it scored.

    Attributes
    ----------
    structure : str
        A key of :data:`STRUCTURES`.
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
    """

    structure: str
    input_delay: int
    a: float
    b: float
    residual_sum: float
    statistic: float = math.nan
    within_noise: bool = False
    note: str = ""

    @property
    def n_params(self) -> int:
        """Shared parameters, a nonzero delay counted as one more."""
        return STRUCTURES[self.structure].n_params + (self.input_delay > 0)

    @property
    def method(self) -> str:
        """The estimator that fits this candidate."""
        return STRUCTURES[self.structure].method

    def options(self) -> dict[str, Any]:
        """``fit(recordings, method, **options)`` reproduces the candidate on all rows."""
        return {"input_delay": self.input_delay, **STRUCTURES[self.structure].options}

    @property
    def label(self) -> str:
        return f"{self.structure}, delay {self.input_delay}"

    def to_dict(self) -> dict:
        return {"structure": self.structure, "input_delay": self.input_delay, "method": self.method,
                "a": self.a, "b": self.b, "residual_sum": self.residual_sum, "statistic": self.statistic,
                "within_noise": self.within_noise, **({"note": self.note} if self.note else {})}


@dataclasses.dataclass(frozen=True)
class Selection:
    """What :func:`select_model` compared and chose.

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
    """

    candidates: tuple[Candidate, ...]
    chosen: Candidate
    best: Candidate
    runner_up: Candidate | None
    clear: bool = True
    doubt: str = ""
    notes: tuple[str, ...] = ()
    level: float = LEVEL

    def comparison(self) -> str:
        """The runner-up against the chosen model, in plain words."""
        other = self.runner_up
        if other is None:
            return "no other candidate fitted"
        if other.within_noise:
            return (f"the data cannot tell {other.label} from it (T = {other.statistic:.3g}, "
                    f"threshold {_threshold(other, self.best, self.level):.3g}); the simpler one is kept")
        return (f"{other.label} fits worse by T = {other.statistic:.3g} noise units "
                f"(threshold {_threshold(other, self.best, self.level):.3g})")

    def to_dict(self) -> dict:
        """JSON-ready: every candidate with its score, the chosen one, whether the choice was clear."""
        return {"criterion": "simplest candidate within the noise of the best (batch-means test)",
                "level": self.level, "chosen": self.chosen.to_dict(), "best": self.best.to_dict(),
                "runner_up": None if self.runner_up is None else self.runner_up.to_dict(),
                "clear": self.clear, "doubt": self.doubt, "notes": list(self.notes),
                "candidates": [c.to_dict() for c in self.candidates]}


@dataclasses.dataclass(eq=False)
class _Fitted:
    candidate: Candidate
    residuals: np.ndarray | None
    bias: float = 0.0
    refined: bool = True          # False: a coarse fit, whose residual sum bounds the candidate's from above


def _threshold(c: Candidate, best: Candidate, level: float) -> float:
    from scipy.special import fdtri  # the F quantile, lighter than scipy.stats
    k = max(best.n_params - c.n_params, 1)
    return k * float(fdtri(k, BLOCKS - k, 1.0 - level))


def _largest_delay(recs: list[Recording], max_delay: int) -> int:
    """``max_delay``, less on short data: at least 20 rows per delay tried in the shortest segment."""
    longest = max(len(seg) for rec in recs for seg in rec.segments())
    return max(0, min(max_delay, longest // 20))


def _blocks(n: int) -> list[slice]:
    edges = np.linspace(0, n, min(BLOCKS, n) + 1).astype(int)
    return [slice(i, j) for i, j in zip(edges[:-1], edges[1:]) if j > i]


def _statistic(delta: np.ndarray, excess: float, reference: np.ndarray) -> float:
    """``T = excess |delta|^2 / V`` with ``V`` the batch-means variance of ``delta . e`` (module docstring)."""
    norm2 = float(delta @ delta)
    if excess <= 0 or norm2 == 0:
        return 0.0
    v = sum(float(delta[s] @ reference[s]) ** 2 for s in _blocks(len(delta)))
    return excess * norm2 / v if v > 0 else math.inf


def _fit_linear(recs: list[Recording], segs: list[Segment], delay: int, with_bias: bool,
                refine: bool = True) -> _Fitted:
    """The ``oe`` fit (with or without a bias) on ``segs``: what ``fit_output_error`` computes
    (with ``refine=False`` on long data, only its first steps: see :func:`_choose`)."""
    from .output_error import _separable_start, solve_output_error
    from .variable_projection import is_separable, separable_candidate, static_gain_ceiling
    name = "bias" if with_bias else "linear"
    if is_separable(segs, False):
        found = separable_candidate(segs, _separable_start(recs, segs), with_bias=with_bias,
                                    ceiling=static_gain_ceiling(segs), coarse_samples=COARSE_SAMPLES, refine=refine)
        if found is not None:
            a, b, bias, r, refined = found
            return _Fitted(Candidate(name, delay, a, b, float(r @ r)), r, bias, refined)
    try:
        solution = solve_output_error(recs, segs, delay, with_bias=with_bias)
    except NotIdentifiableError as exc:
        return _Fitted(Candidate(name, delay, math.nan, math.nan, math.nan, note=str(exc)), None)
    r = np.asarray(solution.result.fun, float)
    x = solution.result.x
    return _Fitted(Candidate(name, delay, float(x[0]), float(x[1]), float(r @ r)), r,
                   float(x[2]) if with_bias else 0.0)


def _fit_friction(recs: list[Recording], segs: list[Segment], delay: int, structure: str,
                  fix_bias: bool) -> _Fitted:
    from .friction import friction_parameter_names, solve_friction
    names = friction_parameter_names(fix_bias=fix_bias, dead_zone=structure == "dead-zone")
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            _, res = solve_friction(recs, segs, names, delay)
    except (NotIdentifiableError, np.linalg.LinAlgError) as exc:
        return _Fitted(Candidate(structure, delay, math.nan, math.nan, math.nan, note=str(exc)), None)
    r = np.asarray(res.fun, float)
    return _Fitted(Candidate(structure, delay, float(res.x[0]), float(res.x[1]), float(r @ r)), r)


def _screen_nonlinear(segs: list[Segment], base: Candidate, bias: float) -> float:
    """p-value of the score test for friction and a dead zone at the linear candidate ``base``.

    Their sensitivities at ``c = 0`` and ``z = 0`` are the linear model's responses to the
    accelerations ``-sign(omega)`` (the model's speed over each interval) and ``-b sign(u)``;
    with each segment's initial speed and offset, and ``a``, ``b``, ``d``, projected out, their
    correlation with the residuals is tested with the batch-means variance (Hotelling's T^2).
    """
    from scipy.special import fdtrc

    from .output_error import OutputErrorProblem
    from .sensitivity import zoh_response
    from .variable_projection import _prefixes
    if sum(len(s.time) for s in segs) > SCREEN_SAMPLES:
        segs = _prefixes(segs, SCREEN_SAMPLES)
    problem = OutputErrorProblem(segs, with_bias=True)
    x = np.array([base.a, base.b, bias])
    with np.errstate(over="ignore", invalid="ignore"):
        r, J, starts = problem.evaluate(x, jacobian=True)
    columns = []
    for seg, w0 in zip(segs, starts):
        resp = zoh_response(base.a, base.b, seg.drive, seg.time, float(w0), bias=bias, uniform=seg.uniform)
        moving = np.append(-np.sign(resp.speed[:-1] + resp.speed[1:]), 0.0)
        outputs = []
        for drive, gain in ((moving, 1.0), (-np.sign(seg.drive), base.b)):
            g = zoh_response(base.a, gain, drive, seg.time, 0.0, uniform=seg.uniform, sensitivities=False)
            outputs.append(g.angle if seg.kind == "angle" else g.speed)
        G = np.column_stack(outputs)
        s0 = (resp.angle_sensitivity if seg.kind == "angle" else resp.speed_sensitivity)[:, 2].copy()
        if seg.kind == "angle":
            G -= G.mean(axis=0)
            s0 -= s0.mean()
        ss = float(s0 @ s0)
        if ss > 0:
            G -= np.outer(s0, (s0 @ G) / ss)
        columns.append(G)
    G = np.vstack(columns)
    if J is None or not (np.all(np.isfinite(G)) and np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return 0.0                   # cannot screen: fit them
    G -= J @ np.linalg.lstsq(J, G, rcond=None)[0]
    keep = np.sqrt(np.einsum("ij,ij->j", G, G)) > 1e-9 * np.sqrt(np.einsum("ij,ij->j", J, J)).max(initial=1.0)
    G = G[:, keep]
    k = G.shape[1]
    blocks = _blocks(len(r))
    if k == 0 or len(blocks) <= k + 1:
        return 1.0
    scores = np.array([G[s].T @ r[s] for s in blocks])
    total = scores.sum(axis=0)
    V = scores.T @ scores
    try:
        t2 = float(total @ np.linalg.solve(V, total))
    except np.linalg.LinAlgError:
        return 0.0
    m = len(blocks)
    return float(fdtrc(k, m - k, max(t2, 0.0) * (m - k) / (k * (m - 1))))


def select_model(recordings: Recording | Sequence[Recording], *, structures: Sequence[str] | None = None,
                 input_delay: int | str = "auto", max_delay: int = MAX_AUTO_DELAY, fix_bias: bool = False,
                 level: float = LEVEL) -> Selection:
    """Fit the candidate models and choose the simplest one within the noise of the best.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for every estimator.
    structures : sequence of str, optional
        Keys of :data:`STRUCTURES` to consider (default all).  Friction and dead zone are
        screened first (module docstring) only when a linear structure is among them.
    input_delay : int or "auto"
        ``"auto"`` (default) tries ``0 ... max_delay``; an integer fixes the delay.
    max_delay : int
        Largest delay tried, samples.
    fix_bias : bool
        Hold the bias at 0 in the friction structures.
    level : float
        Level of the test, in (0, 0.5).

    Returns
    -------
    Selection
    """
    from motorsim.checks import check_bool, check_int, check_real

    from .friction import speed_reverses
    recs = as_recordings(recordings)
    input_delay = check_input_delay(input_delay)
    max_delay = check_int("max_delay", max_delay, lo=0, allow_integral_float=False)
    fix_bias = check_bool("fix_bias", fix_bias)
    level = check_real("level", level)
    if not 0 < level < 0.5:
        raise ValueError(f"level must be in (0, 0.5), got {level!r}")
    wanted = tuple(structures) if structures is not None else tuple(STRUCTURES)
    for s in wanted:
        if s not in STRUCTURES:
            raise ValueError(f"structures must be among {list(STRUCTURES)}, got {s!r}")
    notes: list[str] = []
    if input_delay == "auto":
        top = _largest_delay(recs, max_delay)
        delays = list(range(top + 1))
    else:
        top = int(input_delay)
        delays = [top]
    segments = {d: prepare_segments(recs, d, skip=top) for d in delays}
    delays = [d for d in delays if segments[d]]
    if not delays:
        raise NotIdentifiableError(f"recording is too short for an input delay of {top} samples: no gap-free "
                                   "stretch is left; record longer or fix the dropped samples")
    fitted: list[_Fitted] = []
    linear = [s for s in wanted if s in ("linear", "bias")]
    nonlinear = [s for s in wanted if s in ("friction", "dead-zone")]
    if nonlinear and not speed_reverses(recs):
        notes.append("friction and dead zone not fitted: the speed never reverses or rests, so they act as a "
                     "constant acceleration (the bias d); a run through zero speed would separate them")
        linear = sorted(set(linear) | {"bias"}, key=list(STRUCTURES).index)
        nonlinear = []
    worse = 0
    for d in delays:
        here = [_fit_linear(recs, segments[d], d, s == "bias", refine=False) for s in linear]
        fitted += here
        worse = worse + 1 if _far_worse(here, fitted, level) else 0
        if worse == STOP_AFTER and d < delays[-1]:
            skipped = f"delay {d + 1}" if d + 1 == delays[-1] else f"delays {d + 1}-{delays[-1]}"
            notes.append(f"{skipped} not fitted: the fit worsened far beyond the noise for "
                         f"{STOP_AFTER} delays in a row past the best")
            break
    refine = functools.partial(_refine, recs, segments, level)
    if nonlinear and linear:
        base = refine(fitted)
        if base is None:
            p = 0.0
        else:
            p = _screen_nonlinear(segments[base.candidate.input_delay], base.candidate, base.bias)
        if p >= SCREEN_LEVEL:
            notes.append(f"friction and dead zone not fitted: the linear model's residuals show no sign of "
                         f"them (score test p = {p:.2g})")
            nonlinear = []
    if nonlinear:
        fitted += _fit_nonlinear(recs, segments, delays, nonlinear, fix_bias, _best(fitted))
    refine(fitted)
    return _choose(fitted, level, notes, top if input_delay == "auto" else None)


#: Candidates fitted coarsely whose statistic (an upper bound) is within this factor of the threshold are
#: fitted fully before the choice.
REFINE_FACTOR = 20.0


def _refine(recs: list[Recording], segments: dict[int, list[Segment]], level: float,
            fitted: list[_Fitted]) -> _Fitted | None:
    """Fit fully, in place, the coarse candidates that could be the best or within its noise; the best.

    A coarse candidate's residual sum bounds its full fit's from above, so one far above the best's
    (statistic beyond :data:`REFINE_FACTOR` times the threshold) stays far above it once fitted.
    """
    while True:
        best = _best(fitted)
        if best is None:
            return None
        reference = best.residuals
        assert reference is not None
        if not best.refined:
            pending = [best]
        else:
            pending = [f for f in fitted if not f.refined and f.residuals is not None and _statistic(
                f.residuals - reference, f.candidate.residual_sum - best.candidate.residual_sum,
                reference) <= REFINE_FACTOR * _threshold(f.candidate, best.candidate, level)]
            if not pending:
                return best
        for f in pending:
            c = f.candidate
            fitted[fitted.index(f)] = _fit_linear(recs, segments[c.input_delay], c.input_delay, c.structure == "bias")


#: The delay scan stops after this many delays in a row whose every candidate is worse than the best by
#: more than :data:`STOP_FACTOR` times the threshold.
STOP_AFTER = 2
STOP_FACTOR = 100.0


def _far_worse(here: list[_Fitted], fitted: list[_Fitted], level: float) -> bool:
    """Whether every candidate of ``here`` is far beyond the noise of the best so far."""
    best = _best(fitted)
    if best is None or any(f is best for f in here):
        return False
    assert best.residuals is not None
    for f in here:
        if f.residuals is None:
            continue
        t = _statistic(f.residuals - best.residuals, f.candidate.residual_sum - best.candidate.residual_sum,
                       best.residuals)
        if t <= STOP_FACTOR * _threshold(f.candidate, best.candidate, level):
            return False
    return True


def _best(fitted: list[_Fitted]) -> _Fitted | None:
    ok = [f for f in fitted if f.residuals is not None]
    return min(ok, key=lambda f: f.candidate.residual_sum) if ok else None


def _fit_nonlinear(recs: list[Recording], segments: dict[int, list[Segment]], delays: list[int],
                   structures: list[str], fix_bias: bool, linear_best: _Fitted | None) -> list[_Fitted]:
    """The most general nonlinear structure at every delay, the other near the delays it prefers."""
    general, *rest = sorted(structures, key=list(STRUCTURES).index, reverse=True)
    out: list[_Fitted] = []
    worse = 0
    for d in delays:
        here = [_fit_friction(recs, segments[d], d, general, fix_bias)]
        out += here
        worse = worse + 1 if _far_worse(here, out, LEVEL) else 0
        if worse == STOP_AFTER:
            break
    best = _best(out)
    near: set[int] = set()
    for anchor in (best, linear_best):
        if anchor is not None:
            d = anchor.candidate.input_delay
            near |= {x for x in (d - 1, d, d + 1) if x in segments}
    for s in rest:
        out += [_fit_friction(recs, segments[d], d, s, fix_bias) for d in sorted(near)]
    return out


def _choose(fitted: list[_Fitted], level: float, notes: list[str], top: int | None) -> Selection:
    best = _best(fitted)
    if best is None:
        reasons = "; ".join(sorted({f.candidate.note for f in fitted if f.candidate.note}))
        raise NotIdentifiableError(f"no candidate model could be fitted: {reasons}")
    reference = best.residuals
    assert reference is not None
    scored: list[Candidate] = []
    for f in fitted:
        c = f.candidate
        if f.residuals is None or len(f.residuals) != len(reference):
            scored.append(c)
            continue
        t = 0.0 if f is best else _statistic(f.residuals - reference, c.residual_sum - best.candidate.residual_sum,
                                             reference)
        scored.append(dataclasses.replace(c, statistic=t, within_noise=t <= _threshold(c, best.candidate, level)))
    best_c = scored[fitted.index(best)]
    within = [c for c in scored if c.within_noise]
    order = list(STRUCTURES)

    def simplicity(c: Candidate) -> tuple:
        return (c.n_params, c.input_delay, order.index(c.structure))
    chosen = min(within, key=simplicity)
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


def _separating_experiment(chosen: Candidate, others: Sequence[Candidate]) -> str:
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


def fit_selected(recordings: Recording | Sequence[Recording], *, input_delay: int | str = "auto",
                 structures: Sequence[str] | None = None, fix_bias: bool = False) -> Estimate:
    """The default estimator: delay and structure chosen by evidence, fitted on all rows.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Pooled, as for every estimator.
    input_delay : int or "auto"
        ``"auto"`` (default) chooses it in ``0 ... MAX_AUTO_DELAY``; an integer fixes it.
    structures : sequence of str, optional
        Keys of :data:`STRUCTURES` to choose among (default all).
    fix_bias : bool
        Hold the bias at 0 in the friction structures.

    Returns
    -------
    Estimate
        The chosen candidate's estimate, made by its own method on all rows (``method`` is
        ``"oe"`` or ``"oe-friction"``, so ``fit(recordings, est.method, **options)`` with the
        candidate's options reproduces it), with ``selection`` holding every candidate and its
        score and ``notes`` what the data cannot answer.  When candidates the data cannot
        separate disagree, the covariance of ``a`` and ``b`` is widened so that the 95 %
        interval covers them (``covariance_method`` ends in ``+model-spread``).

    Examples
    --------
    A multisine through a motor with a 2-sample input delay:

    >>> from identify import fit
    >>> from motorsim import Experiment, Motor, Multisine, SimRig
    >>> rec = SimRig(Motor(25.0, 3.0, input_delay=2)).run(
    ...     Experiment(Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3)), 0.005, 10.0))
    >>> est = fit(rec)
    >>> print(f"{est.method}, delay {est.input_delay}, a = {est.a:.3f}, b = {est.b:.4f}")
    oe, delay 2, a = 25.000, b = 3.0000
    >>> est.selection["chosen"]["structure"], est.selection["clear"]
    ('linear', True)
    """
    from .methods import method_function
    recs = as_recordings(recordings)
    check_excitation(recs, 2)
    selection = select_model(recs, structures=structures, input_delay=input_delay, fix_bias=fix_bias)
    chosen = selection.chosen
    options = chosen.options()
    if chosen.method == "oe-friction" and fix_bias:
        options["fix_bias"] = True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # the selection says it once, in its notes
        est = method_function(chosen.method)(recs, **options)
    within = [c for c in selection.candidates if c.within_noise and c is not chosen and math.isfinite(c.a)]
    ci = est.confidence_interval(0.95)
    material = [c for c in within if not (ci["a"][0] <= c.a <= ci["a"][1] and ci["b"][0] <= c.b <= ci["b"][1])]
    notes = list(selection.notes) + _data_notes(recs, est)
    if material:
        est, doubt = _widen(est, chosen, material)
        if any(abs(c.a - est.a) > MATERIAL * abs(est.a) or abs(c.b - est.b) > MATERIAL * abs(est.b)
               for c in material):
            selection = dataclasses.replace(selection, clear=False, doubt=doubt)
    selection = dataclasses.replace(selection, notes=tuple(notes))
    return dataclasses.replace(est, selection=selection.to_dict(), notes=tuple(
        ([selection.doubt] if selection.doubt else []) + notes))


def _widen(est: Estimate, chosen: Candidate, material: list[Candidate]) -> tuple[Estimate, str]:
    """The estimate with ``a`` and ``b``'s variances grown to cover ``material``; the doubt line."""
    z = statistics.NormalDist().inv_cdf(0.975)
    a_values = [est.a] + [c.a for c in material]
    b_values = [est.b] + [c.b for c in material]
    cov = np.array(est.covariance if est.covariance is not None else np.full((len(est.param_names),) * 2, np.nan))
    cov = np.where(np.isfinite(cov), cov, 0.0) if np.all(np.isfinite(np.diag(cov))) else cov
    for i, values in ((0, a_values), (1, b_values)):
        spread = max(abs(v - values[0]) for v in values)
        if not math.isfinite(cov[i, i]):
            cov[i, i] = 0.0
        cov[i, i] += (spread / z) ** 2
    doubt = (f"the data cannot tell {chosen.label} from {', '.join(c.label for c in material[:4])}"
             f"{' and others' if len(material) > 4 else ''}: a in [{min(a_values):.4g}, {max(a_values):.4g}] 1/s, "
             f"b in [{min(b_values):.4g}, {max(b_values):.4g}]; the intervals cover them all; "
             + _separating_experiment(chosen, material))
    method = (est.covariance_method + "+model-spread") if est.covariance_method else "model-spread"
    return dataclasses.replace(est, covariance=cov, covariance_method=method), doubt


def _data_notes(recs: list[Recording], est: Estimate) -> list[str]:
    """What the recordings cannot answer, said plainly (saturation, few counts, a too slow input)."""
    notes = []
    duty = np.concatenate([r.duty for r in recs])
    if recs[0].input_unit == "duty":
        limit = float(recs[0].metadata.get("duty_limit", 255))
        share = float(np.mean(np.abs(duty) >= limit)) if limit > 0 else 0.0
        if share > SATURATED_SHARE:
            notes.append(f"the duty sits at its limit +-{limit:g} for {100 * share:.0f} % of the samples: the "
                         "model only sees what the driver delivered; lower the amplitude if the driver clips")
    counts = [r.counts for r in recs if r.counts is not None]
    if counts:
        swept = max(float(np.max(c) - np.min(c)) for c in counts)
        if swept < MIN_COUNTS_SWEPT:
            notes.append(f"the encoder sweeps only {swept:.0f} counts in the whole run: a and b rest on a few "
                         "steps; run longer or faster, or use a finer encoder")
    if est.a > 0 and math.isfinite(est.a):
        fast = 0.0
        total = 0.0
        for r in recs:
            u = np.asarray(r.duty, float) - float(np.mean(r.duty))
            if len(u) < 8:
                continue
            power = np.abs(np.fft.rfft(u)) ** 2
            omega = 2 * math.pi * np.fft.rfftfreq(len(u), r.sample_period)
            total += float(power[1:].sum())
            fast += float(power[1:][omega[1:] >= est.a / 5].sum())
        if total > 0 and fast / total < MIN_FAST_POWER:
            notes.append(f"the input has {100 * fast / total:.2g} % of its power at or above a/5 = {est.a / 5:.3g} "
                         "rad/s: a rests on the slow response alone; add a faster component (or a step)")
    return notes


def residual_checks(estimate: Estimate, recording: Recording) -> dict[str, float]:
    """The fitted model's residuals on its own data, tested: whiteness, the input, the sign of the model's speed.

    ``whiteness_p`` and ``input_p`` are :func:`identify.validate`'s Ljung--Box and cross-correlation
    tests; ``sign_p`` tests the correlation of the speed residual with ``sign(omega)`` (what an
    unmodelled Coulomb friction leaves), its variance by batch means over :data:`BLOCKS` blocks.
    Small p-values say the model misses something; large ones that nothing was found.

    Parameters
    ----------
    estimate : Estimate
        A fit of ``recording`` (or of recordings pooled with it).
    recording : Recording
        The data.

    Returns
    -------
    dict
        ``whiteness_p``, ``input_p``, ``sign_p`` (nan when a test cannot be made).
    """
    from scipy.special import fdtrc

    from .validation import model_output, validate
    report = validate(estimate, recording)
    measured, simulated = model_output(estimate, recording)
    ok = np.isfinite(measured) & np.isfinite(simulated)
    residual = (measured - simulated)[ok]
    sign = np.sign(simulated[ok])          # the model's: a coarse encoder's speed is often 0
    sign = sign - sign.mean()
    sign_p = math.nan
    blocks = _blocks(len(residual))
    if len(blocks) > 2 and float(sign @ sign) > 0:
        scores = np.array([float(sign[s] @ residual[s]) for s in blocks])
        v = float(scores @ scores)
        if v > 0:
            m = len(blocks)
            sign_p = float(fdtrc(1, m - 1, float(scores.sum()) ** 2 / v * (m - 1) / m))
    return {"whiteness_p": float(report.whiteness_p), "input_p": float(report.independence_p), "sign_p": sign_p}
