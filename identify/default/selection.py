"""The default estimator: input delay and model structure chosen by the evidence in the data.

``identify.fit(recordings)`` and ``motorid identify FILE`` (no ``method``) call
:func:`fit_selected`.  It fits every candidate model

* input delay ``0 ... N`` samples (``N`` = :data:`MAX_AUTO_DELAY`, fewer on short data; from the
  device's own delay when the recording declares one, ``input_delay_samples``), times
* structure ``linear`` (``oe``), ``bias`` (``oe`` with a constant acceleration ``d``),
  ``friction`` (``oe-friction``: Coulomb friction ``c`` and ``d``) and ``dead-zone``
  (``oe-friction``: ``c``, ``d`` and a duty dead zone), and, judged after them, ``stiction``
  (``oe-friction``: ``c``, ``d`` and a static friction above ``c``, where a test on the first rows
  finds one) and ``second-order``,

each by the estimator that would return it, on the same rows (every segment from row ``N``; on
long data the first :data:`SELECTION_ROWS` of them), and returns the **simplest candidate whose fit
is within the noise of the best**, fitted on all rows.

The choice is :func:`identify.default.comparison.choose`'s (its docstring gives the criterion).

Friction and dead zone are fitted only when a score (Lagrange multiplier) test on the best
linear candidate finds their directions in its residuals (same batch-means variance, level
:data:`SCREEN_LEVEL`) or those directions explain a material share of them
(:data:`SCREEN_SHARE`), and only when the speed reverses or rests (otherwise friction is a
constant acceleration, the bias).  The screen is what keeps the default within a few ``oe``
fits on a linear motor; the report says when it left them out and why.

"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Callable, Sequence

import numpy as np

from motorsim.recording import Recording

from ..comparison import (
    CLOSE,
    LEVEL,
    MATERIAL,
    MAX_AUTO_DELAY,
    STOP_AFTER,
    STRUCTURES,
    Candidate,
    CandidateFit,
    Selection,
    best_fit,
    block_mean_p,
    block_sums,
    choose,
    far_worse,
    largest_delay,
    plausible,
    refine,
    scan_delays,
    separating_experiment,
)
from ..data import (
    DEFAULT_INPUT_DELAY,
    Segment,
    as_recordings,
    check_excitation,
    check_input_delay,
    declared_input_delay,
    delayed_segments,
    first_rows,
    saturation_note,
)
from ..errors import NotIdentifiableError
from ..estimate import Estimate
from ..fits.friction import FrictionScan, friction_candidate, segments_reverse
from ..fits.variable_projection import shared_work
from ..sums import sum_squares
from .consistency import PartCheck, consistency
from .disturbance import disturbance_follows_input
from .evidence import on_evidence
from .feedback import ClosedLoopFit, feedback_evidence, fit_changing_torque, fit_closed_loop
from .selection_report import SelectionReport, blind_check, doubted, widened_range

__all__ = ["fit_selected", "select_model", "residual_checks", "sign_correlation_p", "SCREEN_LEVEL", "SCREEN_SHARE"]

#: p-value of a part check below which the model is refuted beyond doubt: the answer is then not clear even where
#: the check's own columns move ``a`` and ``b`` by less than :data:`MATERIAL` (its columns need not be the misfit's:
#: a quadratic drag under a PRBS, fitted with a bias, was refuted by three checks at p = 1e-9 to 4e-15 with every
#: shift under 1 %, and ``b`` was 7 % off, clear).  A refutation near the checks' own level moves nothing (a model
#: the data barely refute, on a clock whose jitter the simulator holds differently, p = 8e-4).
REFUTED_LEVEL = 1e-6
#: What the doubt of an answer that lacks an interval suggests where it had no doubt of its own.
RICHER_INPUT = "a richer input (several frequencies, a step) would pin them down"

#: Rows of the score test that screens friction and a dead zone (the first of every segment).
SCREEN_SAMPLES = 2000
#: Rows (the first of every segment) of the fit that checks a screen that left friction and a dead zone out.
REFUTE_SAMPLES = 1000
#: Level of the score test that decides whether friction and a dead zone are fitted at all.
SCREEN_LEVEL = 0.05
#: Share of the linear model's residual sum of squares that friction and a dead zone, linearised,
#: must explain to be fitted even when the score test does not reject (a large misfit that varies
#: along the run, a chirp's, can hide from a test whose variance it inflates).  Measured: at most
#: 0.4 % on linear motors (sines on 44-16667 counts, chirps, PRBS, steps), 96-99 % with friction
#: or a dead zone of 8-25 duty.
SCREEN_SHARE = 0.02
#: Level of the test of the chosen model's residuals against the sign of its speed below which friction,
#: left out by the screen, is fitted after all: no screen overrules what the fit's own residuals say.
SIGN_LEVEL = 0.001
#: How the note of a screen that left friction out begins.
SCREENED_OUT = "friction and dead zone not fitted"
#: How the note begins where a fit on the screen's rows overruled it (:func:`_screen_refuted`).
REFUTED = "friction and dead zone fitted although the score test found no sign of them"
#: Share of the non-zero input samples at one magnitude from which the input counts as one amplitude (a
#: binary PRBS, a square wave): a dead zone is then a gain change the data cannot see.
SINGLE_AMPLITUDE_SHARE = 0.95
#: Encoder counts the whole run must sweep for ``a`` and ``b`` to rest on more than a few steps.
MIN_COUNTS_SWEPT = 50
#: Share of the input's power at or above ``a / 5`` below which ``a`` rests on the static gain alone.
MIN_FAST_POWER = 0.01


def _screen_nonlinear(segs: list[Segment], base: Candidate, bias: float) -> tuple[float, float]:
    """The score test for friction and a dead zone at the linear candidate ``base``: its p-value,
    and the share of the residual sum of squares their directions explain.

    Their sensitivities at ``c = 0`` and ``z = 0`` are the linear model's responses to the
    accelerations ``-sign(omega)`` (the model's speed over each interval) and ``-b sign(u)``;
    with each segment's initial speed and offset, and ``a``, ``b``, ``d``, projected out, their
    correlation with the residuals is tested with the batch-means variance: Hotelling's T^2 of
    the block scores (centred, so a large, uneven misfit does not hide in its own variance).
    The share is what one Gauss--Newton step into them would remove from the residual: near
    ``k/n`` when they are absent, most of it when the model misses friction or a dead zone.
    """
    from ..fits.output_error import OutputErrorProblem
    from ..fits.sensitivity import project_out_initial_state, zoh_response
    segs = first_rows(segs, SCREEN_SAMPLES)
    problem = OutputErrorProblem(segs, with_bias=True)
    x = np.array([base.a, base.b, bias])
    with np.errstate(over="ignore", invalid="ignore"):
        r, J, starts = problem.evaluate(x, jacobian=True)
    columns = []
    for seg, w0 in zip(segs, starts):
        # the speed and the initial-speed column alone; with a bias the response takes the same path (the same
        # numbers) without its other sensitivities, which nothing here reads
        resp = zoh_response(base.a, base.b, seg.drive, seg.time, float(w0), bias=bias, uniform=seg.uniform,
                            sensitivities=bias == 0)
        moving = np.append(-np.sign(resp.speed[:-1] + resp.speed[1:]), 0.0)
        outputs = []
        for drive, gain in ((moving, 1.0), (-np.sign(seg.drive), base.b)):
            g = zoh_response(base.a, gain, drive, seg.time, 0.0, uniform=seg.uniform, sensitivities=False)
            outputs.append(g.angle if seg.kind == "angle" else g.speed)
        s0 = resp.angle_initial_speed if seg.kind == "angle" else resp.speed_initial_speed
        columns.append(np.column_stack(project_out_initial_state(s0, seg.kind == "angle", *outputs)))
    G = np.vstack(columns)
    if J is None or not (np.all(np.isfinite(G)) and np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return 0.0, 1.0              # cannot screen: fit them
    G -= J @ np.linalg.lstsq(J, G, rcond=None)[0]
    keep = np.sqrt(np.einsum("ij,ij->j", G, G)) > 1e-9 * np.sqrt(np.einsum("ij,ij->j", J, J)).max(initial=1.0)
    G = G[:, keep]
    k = G.shape[1]
    rss = sum_squares(r)
    if k == 0 or rss == 0:
        return 1.0, 0.0
    step = G @ np.linalg.lstsq(G, r, rcond=None)[0]
    share = float(step @ step) / rss
    return block_mean_p(block_sums(G * r[:, None])), share


def _linear_on(segs: list[Segment], base: Candidate, bias: float) -> tuple[float, float]:
    """The linear model's ``a`` and ``b`` (with its constant acceleration) on ``segs``: one Gauss--Newton step
    from ``base``'s fit on more rows (nan where its residuals cannot be formed)."""
    from ..fits.output_error import OutputErrorProblem
    x = np.array([base.a, base.b, bias])
    with np.errstate(over="ignore", invalid="ignore"):
        r, J, _ = OutputErrorProblem(segs, with_bias=True).evaluate(x, jacobian=True)
    if J is None or not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        return math.nan, math.nan
    step = x - np.linalg.lstsq(J, r, rcond=None)[0]
    return float(step[0]), float(step[1])


def _screen_refuted(recs: list[Recording], segs: list[Segment], base: Candidate, bias: float,
                    nonlinear: list[str], fix_bias: bool) -> str:
    """What a fit of the most general nonlinear structure on the screen's own rows says against the screen:
    "" where it leaves ``a`` and ``b`` within :data:`MATERIAL` of the linear model's, else the shift in words.

    The score test is linear in friction at zero friction; a motor that sticks at its reversals, or a single
    sine whose fundamental hides friction in ``a``, can pass it while a fit finds friction that moves ``a``.
    No screen overrules a fit: this one costs a fit on :data:`REFUTE_SAMPLES` rows."""
    general = max(nonlinear, key=list(STRUCTURES).index)
    rows = first_rows(segs, REFUTE_SAMPLES)
    from ..fits.friction_kernel import without_loading
    with without_loading():             # a linear recording's check: no numba imported for it
        c = friction_candidate(recs, rows, base.input_delay, general, fix_bias).candidate
    own = _linear_on(rows, base, bias)
    if not all(math.isfinite(v) and v != 0 for v in (c.a, c.b, *own)):
        return ""
    da, db = c.a / own[0] - 1, c.b / own[1] - 1
    if abs(da) <= MATERIAL and abs(db) <= MATERIAL:
        return ""
    return f"the {general} model moves a by {100 * da:+.2g} % and b by {100 * db:+.2g} %"


def _checked_arguments(structures: Sequence[str] | None, input_delay: int | str, max_delay: int, fix_bias: bool,
                       level: float) -> tuple[int | str, int, bool, float, tuple[str, ...]]:
    """:func:`select_model`'s arguments checked, and the structures it fits (the bias left out where it is held)."""
    from motorsim.checks import ParameterError, check_bool, check_int, check_real

    input_delay = check_input_delay(input_delay)
    max_delay = check_int("max_delay", max_delay, lo=0, allow_integral_float=False)
    fix_bias = check_bool("fix_bias", fix_bias)
    level = check_real("level", level)
    if not 0 < level < 0.5:
        raise ParameterError(f"level must be in (0, 0.5), got {level!r}")
    wanted = tuple(structures) if structures is not None else tuple(STRUCTURES)
    for s in wanted:
        if s not in STRUCTURES:
            raise ParameterError(f"structures must be among {list(STRUCTURES)}, got {s!r}")
    wanted = tuple(s for s in wanted if not (fix_bias and s == "bias"))     # the bias held at 0 everywhere
    return input_delay, max_delay, fix_bias, level, wanted


def _delays(recs: list[Recording], input_delay: int | str, max_delay: int, notes: list[str]) -> tuple[int, list[int]]:
    """The largest delay tried and the delays: ``"auto"`` from the one the recording declares (a note says so) to
    what the data allow; an integer alone."""
    if input_delay != "auto":
        return int(input_delay), [int(input_delay)]
    known = declared_input_delay(recs)
    top = max(largest_delay(recs, max_delay), known)
    if known:
        notes.append(f"delays below {known} sample(s) not tried: the recording says its device applies each "
                     f"duty {known} sample(s) late (input_delay_samples)")
    return top, list(range(known, top + 1))


def _screened_out(recs: list[Recording], segments: dict, base: CandidateFit | None, nonlinear: list[str],
                  fix_bias: bool, screen: bool, notes: list[str]) -> tuple[bool, tuple[float, str] | None]:
    """Whether the score test leaves friction and the dead zone out (the linear model's residuals show no sign of
    them, and a friction fit on the best linear candidate's rows does not refute it); the note says either way.
    Also, where a fit overruled the screen, its p and what it moved."""
    if base is None:
        p, share = 0.0, 1.0
    else:
        p, share = _screen_nonlinear(segments[base.candidate.input_delay], base.candidate, base.bias)
    moved = ""
    if screen and p >= SCREEN_LEVEL and share < SCREEN_SHARE and base is not None:
        moved = _screen_refuted(recs, segments[base.candidate.input_delay], base.candidate, base.bias,
                                nonlinear, fix_bias)
    if screen and p >= SCREEN_LEVEL and share < SCREEN_SHARE and not moved:
        notes.append(f"{SCREENED_OUT}: the linear model's residuals show no sign of "
                     f"them (score test p = {p:.2g}; their directions explain {100 * share:.2g} % of the "
                     "residual)")
        return True, None
    if moved:
        notes.append(f"{REFUTED} (p = {p:.2g}): fitted on its rows, {moved}")
        return False, (p, moved)
    return False, None


@shared_work()      # candidates on the same rows share what they compute alike (the same numbers)
def select_model(recordings: Recording | Sequence[Recording], *, structures: Sequence[str] | None = None,
                 input_delay: int | str = DEFAULT_INPUT_DELAY, max_delay: int = MAX_AUTO_DELAY, fix_bias: bool = False,
                 level: float = LEVEL, screen: bool = True, widening: bool = False) -> Selection:
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
    screen : bool
        Screen friction and the dead zone by the score test first (module docstring); False fits them
        whenever the speed reverses (what :func:`fit_selected` does when the chosen model's residuals
        then correlate with the sign of the speed).
    widening : bool
        The caller searches a wider delay range when the best fit is at the top of this one (as
        :func:`fit_selected` does): when the first-order family's best fit is at the top, the structures
        of a higher rank are not fitted (whatever they scored, the range is widened, and they are fitted
        on the wider one).

    Returns
    -------
    Selection
    """
    recs = as_recordings(recordings)
    input_delay, max_delay, fix_bias, level, wanted = _checked_arguments(structures, input_delay, max_delay,
                                                                         fix_bias, level)
    notes: list[str] = []
    refuted: tuple[float, str] | None = None       # a fit that overruled the screen: its p and what it moved
    top, delays = _delays(recs, input_delay, max_delay, notes)
    segments = delayed_segments(recs, delays, top, SELECTION_ROWS)
    delays = [d for d in delays if segments[d]]
    if not delays:
        raise NotIdentifiableError(f"recording is too short for an input delay of {top} samples: no gap-free "
                                   "stretch is left; record longer or fix the dropped samples")
    fitted: list[CandidateFit] = []
    higher = [s for s in wanted if STRUCTURES[s].rank > 0 and STRUCTURES[s].linear]
    sticking = [s for s in wanted if STRUCTURES[s].rank > 0 and not STRUCTURES[s].linear]
    wanted = tuple(s for s in wanted if STRUCTURES[s].rank == 0)
    linear = [s for s in wanted if STRUCTURES[s].linear]
    nonlinear = [s for s in wanted if not STRUCTURES[s].linear]
    if nonlinear and not segments_reverse(segments[delays[0]]):     # on the rows the candidates are fitted on
        notes.append("friction and dead zone not fitted: the speed never reverses or rests, so they act as a "
                     "constant acceleration (the bias d); a run through zero speed would separate them")
        linear = sorted(set(linear) | ({"linear"} if fix_bias else {"bias"}), key=list(STRUCTURES).index)
        nonlinear = []
    fitted += scan_delays(delays, lambda d: [_candidate(recs, segments[d], d, s, refine=False) for s in linear],
                          level, notes)

    def refit(f: CandidateFit) -> CandidateFit:
        d = f.candidate.input_delay
        return _candidate(recs, segments[d], d, f.candidate.structure)
    if nonlinear and linear:
        out, refuted = _screened_out(recs, segments, _refined_best(fitted, refit), nonlinear, fix_bias, screen, notes)
        if out:
            nonlinear = []
    if nonlinear:
        fitted += _fit_nonlinear(recs, segments, delays, nonlinear, fix_bias, best_fit(fitted), level)
    refine(fitted, refit, level)
    fitted += _fit_higher_ranks(recs, segments, delays, fitted, sticking if nonlinear else [], higher, fix_bias,
                                level, notes, top if widening and input_delay == "auto" else None)
    selection = choose(fitted, level, notes, top if input_delay == "auto" else None, recs, segments)
    return dataclasses.replace(selection, refuted=refuted) if refuted else selection


def _fit_higher_ranks(recs: list[Recording], segments: dict[int, list[Segment]], delays: list[int],
                      fitted: list[CandidateFit], sticking: list[str], higher: list[str], fix_bias: bool, level: float,
                      notes: list[str], widened_at: int | None) -> list[CandidateFit]:
    """The structures of a higher rank, static levels first (:func:`_fit_sticking`), then second poles
    (:func:`_fit_higher`); none when the first-order family's best fit is at ``widened_at``, the top of a
    range the caller widens then (:func:`_select_widening`): whatever they scored here, they are fitted
    once, on the wider range."""
    if not (sticking or higher):
        return []
    best = best_fit(fitted)
    if widened_at is not None and best is not None and best.candidate.input_delay == widened_at:
        return []
    out = _fit_sticking(recs, segments, fitted, sticking, fix_bias, level, notes) if sticking else []
    if higher:
        out += _fit_higher(recs, segments, delays, higher, fitted + out, level, notes)
    return out


def _candidate(recs: list[Recording], segs: list[Segment], delay: int, name: str, *, refine: bool = True,
               fix_bias: bool = False, **start: object) -> CandidateFit:
    """The registered structure ``name`` fitted at ``delay`` by its estimator's candidate fit (``start``:
    that fit's start values, where it takes them)."""
    from ..methods import candidate_function
    found = STRUCTURES[name]
    return candidate_function(found)(recs, segs, delay, found, refine=refine, fix_bias=fix_bias, **start)


#: Delays, counted down from the first-order model's best, at which a structure with a second pole is fitted:
#: the pole's lag looks like part of a delay, so its own delay is at most the first-order one.
HIGHER_DELAYS = 8
#: Rows (the first of every segment) of the first fit of a structure with a second pole at each delay.
HIGHER_FIRST_ROWS = 500
#: Shortest electrical time constant, in sample periods, that the first fit must find for the full fit to
#: follow: a faster pole is a fraction of a sample's delay, which the first-order model with its delay holds.
MIN_TAU_SAMPLES = 0.25


def _fit_higher(recs: list[Recording], segments: dict[int, list[Segment]], delays: list[int], names: list[str],
                fitted: list[CandidateFit], level: float, notes: list[str]) -> list[CandidateFit]:
    """The structures of a higher rank (a second pole) at the delays up to the best first-order delay.

    A lag between the duty and the torque is what a first-order model absorbs as a longer input
    delay, so the second pole's own delay is the first-order best delay or shorter: those (at most
    :data:`HIGHER_DELAYS`, from the best down, each started from its neighbour's poles, and further down
    while the best of them is at the shortest fitted: :func:`_lower_delay`) are fitted,
    first on the first :data:`HIGHER_FIRST_ROWS` rows; where that fit finds the pole slower than
    :data:`MIN_TAU_SAMPLES` samples it is fitted on all rows and becomes a candidate, else its own
    fit has shown the pole too fast for this sample period to tell from a delay, which is said.  The
    scan down stops, as a delay scan does (:func:`identify.default.comparison.scan_delays`), once the full fits
    at :data:`~identify.default.comparison.STOP_AFTER` delays in a row are far beyond the noise of the best of all
    fitted so far (a friction model's, say, which no linear second pole comes near).
    """
    h = recs[0].sample_period
    best = best_fit(fitted)
    top = best.candidate.input_delay if best is not None else delays[0]
    near = sorted((d for d in delays if top - HIGHER_DELAYS < d <= top), reverse=True) or [delays[0]]
    out: list[CandidateFit] = []
    for name in names:
        previous: tuple[float, ...] = ()
        fastest = 0.0
        worse = 0
        i = 0
        scan = list(near)
        while i < len(scan):
            d = scan[i]
            first = _candidate(recs, first_rows(segments[d], HIGHER_FIRST_ROWS), d, name, refine=False,
                               starts=[previous] if previous else [])
            if first.residuals is not None and first.start:
                previous = first.start
                tau = 1.0 / first.start[1]
                fastest = max(fastest, tau)
                if tau >= MIN_TAU_SAMPLES * h:
                    out.append(_candidate(recs, segments[d], d, name, starts=[first.start]))
                    worse = worse + 1 if far_worse(out[-1:], [*fitted, *out], level) else 0
                    if worse == STOP_AFTER and i + 1 < len(scan):
                        notes.append(_stopped_note(name, scan[i + 1:], ""))
                        break
            if i + 1 == len(scan):
                scan += _lower_delay(out, name, d, delays)
            i += 1
        if not out and fastest:
            notes.append(f"{name} not a candidate: its fit finds the second pole faster than {MIN_TAU_SAMPLES:g} "
                         f"sample (tau_e {fastest:.2g} s at most): a lag that short is part of a sample's delay "
                         "at this sample period; a faster sample rate would show it")
    return out


def _lower_delay(fitted: list[CandidateFit], name: str, lowest: int, delays: list[int]) -> list[int]:
    """The delay below ``lowest`` (the shortest fitted) when the best fit of ``name`` so far is at it: a lag
    of many samples stands in for as many samples of delay, more than :data:`HIGHER_DELAYS`; else none."""
    best = best_fit([f for f in fitted if f.candidate.structure == name])
    below = [d for d in delays if d < lowest]
    return [max(below)] if best is not None and below and best.candidate.input_delay == lowest else []


def _fit_sticking(recs: list[Recording], segments: dict[int, list[Segment]], fitted: list[CandidateFit],
                  names: list[str], fix_bias: bool, level: float, notes: list[str]) -> list[CandidateFit]:
    """The nonlinear structures of a higher rank (static friction) at the best friction fit's delay and the
    shorter ones (at most :data:`HIGHER_DELAYS`: sticking longer at each start looks like a later input), each
    started from the friction fit there; judged after the family, like a second pole
    (:func:`identify.default.comparison.choose`).

    The delays are fitted from the best friction fit's down, and the scan stops, as a delay scan does
    (:func:`identify.default.comparison.scan_delays`), once the fits at :data:`~identify.default.comparison.STOP_AFTER`
    delays in a row are far beyond the noise of the best of all fitted so far: each delay further from
    the one the data fit best fits worse.  Where the static level is left out by its gate (its fit would
    be the friction fit's), the friction fit at that delay stands for it.
    """
    family = best_fit([f for f in fitted if not STRUCTURES[f.candidate.structure].linear])
    if family is None:
        return []
    top = family.candidate.input_delay
    out: list[CandidateFit] = []
    worse = 0
    delays = sorted((d for d in segments if top - HIGHER_DELAYS < d <= top), reverse=True)
    for i, d in enumerate(delays):
        friction = [f for f in fitted if f.candidate.structure == "friction" and f.candidate.input_delay == d]
        starts = [f.start for f in friction if f.refined and f.start]
        here = [_candidate(recs, segments[d], d, name, fix_bias=fix_bias, starts=starts) for name in names]
        out += here
        judged = [f for f in here if f.residuals is not None] or friction
        worse = worse + 1 if judged and far_worse(judged, [*fitted, *out], level) else 0
        if worse == STOP_AFTER and i + 1 < len(delays):
            notes.append(_stopped_note(", ".join(names), delays[i + 1:], " below the best friction fit's"))
            break
    return out


def _stopped_note(what: str, skipped: Sequence[int], where: str) -> str:
    """The note of a scan down the delays that stopped before ``skipped``: they were not fitted, and why."""
    low, high = min(skipped), max(skipped)
    delays = f"delay {low}" if low == high else f"delays {low}-{high}"
    return (f"{what} not fitted at {delays}: the fit worsened far beyond the noise of the best for {STOP_AFTER} "
            f"delays in a row{where}")


def _refined_best(fitted: list[CandidateFit], refit: Callable[[CandidateFit], CandidateFit]) -> CandidateFit | None:
    """The best fit, refitted in full in place until the best is a full fit (the first steps of
    :func:`identify.default.comparison.refine`): what the friction screen needs.  The other coarse candidates
    are refined at the end, against the best of all; with friction they are far above it and left be."""
    while (best := best_fit(fitted)) is not None and not best.refined:
        fitted[fitted.index(best)] = refit(best)
    return best


#: Rows on which the candidates are compared: on longer data, the first rows of every segment (in
#: proportion); the chosen candidate is then fitted on all rows.  25 times the 2000 rows on which every
#: class of the tests is told apart; half the selection's time on a 10^6-row file at 10^5 rows.
SELECTION_ROWS = 50_000


def _fit_nonlinear(recs: list[Recording], segments: dict[int, list[Segment]], delays: list[int],
                   structures: list[str], fix_bias: bool, linear_best: CandidateFit | None,
                   level: float) -> list[CandidateFit]:
    """The most general nonlinear structure at every delay, the other near every delay where the general
    one could be within the noise (and near the linear model's best delay)."""
    general, *rest = sorted(structures, key=list(STRUCTURES).index, reverse=True)
    # neighbouring delays share starts; a candidate that cannot come near the best stops early (refined later)
    scan = FrictionScan(linear_best.candidate.residual_sum if linear_best is not None else math.inf, level)
    out = scan_delays(delays, lambda d: [friction_candidate(recs, segments[d], d, general, fix_bias, scan=scan)],
                      level, [])
    near: set[int] = set()
    for anchor in plausible(out, level) + ([linear_best] if linear_best is not None else []):
        d = anchor.candidate.input_delay
        near |= {x for x in (d - 1, d, d + 1) if x in segments}
    for s in rest:
        out += [friction_candidate(recs, segments[d], d, s, fix_bias, scan=scan) for d in sorted(near)]
    return out


def fit_selected(recordings: Recording | Sequence[Recording], *, input_delay: int | str = DEFAULT_INPUT_DELAY,
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
        separate disagree, their range of ``a`` and ``b`` is the estimate's ``model_range`` and
        every interval (:meth:`Estimate.confidence_interval`) is the union of the chosen fit's
        own and that range.

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
    >>> est.selection.chosen.structure, est.selection.clear
    ('linear', True)
    """
    recs = as_recordings(recordings)
    check_excitation(recs, 2)
    closed = _closed_loop(recs, structures, input_delay, fix_bias)
    if closed.estimate is not None:
        return closed.estimate
    changing = structures is None and not fix_bias and not closed.note
    try:
        est = _fit_open_loop(recs, structures, input_delay, fix_bias, closed.note)
    except NotIdentifiableError as refusal:
        # no output-error model could be fitted on all rows: a torque that changes over the run may be why
        fallback = _changing_torque(recs, f"no output-error model could be fitted ({refusal})",
                                    input_delay) if changing else None
        if fallback is None:
            raise
        return fallback
    if changing and _no_answer(est):
        fallback = _changing_torque(recs, f"the output-error models give no answer ({_no_answer(est)})",
                                    input_delay)
        if fallback is not None:
            return fallback
    return est


def _changing_torque(recs: list[Recording], why: str, input_delay: int | str) -> Estimate | None:
    """:func:`~identify.default.feedback.fit_changing_torque`, None where it cannot be made either."""
    try:
        est = fit_changing_torque(recs, why, input_delay=input_delay)
    except (NotIdentifiableError, ArithmeticError, LookupError, np.linalg.LinAlgError, ValueError):
        return None          # a second opinion that cannot be formed leaves the first answer, never a crash
    if est is None or est.selection is None:
        return None
    ci = est.confidence_interval(0.95)
    if any(not (math.isfinite(ci[n][0]) and math.isfinite(ci[n][1]) and ci[n][0] < ci[n][1])
           or ci[n][0] <= 0 <= ci[n][1] for n in ("a", "b")):
        return None          # no answer either (or one pinned at a bound): the output-error answer stands
    est = _load_or_drive(recs, est)
    top = _one_magnitude(recs)
    if top is None or est.selection is None:
        return est
    # b u + d(t) at u = +-U is a gain of b + d(t)/U forward and b - d(t)/U in reverse: with one magnitude a torque
    # that changes cannot be told from gains that differ by direction (_one_magnitude_bias, for a constant d)
    doubt = (f"the input takes one magnitude, |u| = {top:g}, both ways, so a torque that changes over the run cannot "
             "be told from forward and reverse gains that differ: this is not a clear choice; runs at two or more "
             "amplitudes would separate them")
    return dataclasses.replace(est, selection=doubted(est.selection, doubt), notes=(doubt, *est.notes))


def _load_or_drive(recs: list[Recording], est: Estimate) -> Estimate:
    """``est`` (a ``pem-disturbance`` answer on an open-loop run) not clear where its disturbance follows the input
    (:func:`~identify.default.disturbance.disturbance_follows_input`: a drive that clips or limits, not a load), ``b``'s
    interval holding the gains at a small and the full input."""
    found = disturbance_follows_input(recs, est)
    if found is None or not found.follows or est.selection is None:
        return est
    ranges = dict(est.model_range) if est.model_range else {n: est.confidence_interval(0.95)[n] for n in ("a", "b")}
    lo, hi = ranges["b"]
    ranges["b"] = (min(lo, found.small_gain, found.full_gain), max(hi, found.small_gain, found.full_gain))
    doubt = (f"the torque the disturbance model calls a load follows the input (p = {found.p_value:.2g}): the gain is "
             f"{found.small_gain:.4g} at a small input and {found.full_gain:.4g} at the full one, so the drive clips "
             "or limits (or curves) rather than a load changing; this is not a clear choice, and b's interval holds "
             "both gains")
    return dataclasses.replace(est, model_range=ranges, selection=doubted(est.selection, doubt),
                               notes=(doubt, *est.notes))


def _one_magnitude(recs: list[Recording]) -> float | None:
    """The input's one magnitude where it takes one both ways (a binary PRBS, a square wave), else None."""
    pooled = recs[0].duty if len(recs) == 1 else np.concatenate([np.asarray(r.duty, dtype=float) for r in recs])
    moving = pooled[pooled != 0]
    if not len(moving) or not (np.any(moving > 0) and np.any(moving < 0)):
        return None
    top = float(np.max(np.abs(moving)))
    return top if float(np.mean(np.abs(moving) == top)) >= SINGLE_AMPLITUDE_SHARE else None


def _no_answer(est: Estimate) -> str:
    """Why the default's output-error answer is none (``""`` if it is one): not clear, and the 95 % interval of ``a``
    or ``b`` unbounded or holding zero (the data do not tell the motor's pole or gain from none)."""
    if est.selection is None or est.selection.clear:
        return ""
    ci = est.confidence_interval(0.95)
    for name in ("a", "b"):
        low, high = ci[name]
        if not (math.isfinite(low) and math.isfinite(high)) or low <= 0 <= high:
            return f"{name} in [{low:.4g}, {high:.4g}]"
    return ""


def _fit_open_loop(recs: list[Recording], structures: Sequence[str] | None, input_delay: int | str, fix_bias: bool,
                   loop_note: str) -> Estimate:
    """:func:`fit_selected` on a recording the closed-loop fit leaves to output error (``loop_note`` says why where
    it was made in a loop after all)."""
    swept = _counts_swept(recs)
    structures, few_note = _few_counts(structures, swept)
    selection, edge = _select_widening(recs, structures, input_delay, fix_bias)
    est, selection = _refit_chosen(recs, selection, fix_bias)
    est, selection, edge, checks = _friction_after_all(recs, est, selection, edge, structures, input_delay, fix_bias)
    if few_note:
        selection = dataclasses.replace(selection, notes=(*selection.notes, few_note))
    chosen = selection.chosen
    notes = list(selection.notes) + _data_notes(recs, est, swept) + ([loop_note] if loop_note else [])
    est, selection = _within_noise(recs, est, selection, swept, fix_bias)
    selection = _split_evidence(selection)
    averaged = _speed_as_average(recs, est, chosen, structures, input_delay, fix_bias)
    if averaged is not None:
        est, doubt = averaged
        selection = doubted(selection, doubt)
    est, selection = _unsure_intervals(est, selection)
    selection = _doubts(est, selection, edge, notes, checks, loop_note)
    before = (est, selection)
    est, selection, parts = _check_parts(recs, est, selection, open_loop=not loop_note)
    # a structure a split's differing parts point to (nothing is fitted where they agree), when every structure is
    # asked for
    if structures is None:
        est, selection, parts = on_evidence(recs, before, (est, selection, parts), _check_parts)
    est, selection = _one_magnitude_bias(recs, est, selection)
    report = dataclasses.replace(SelectionReport.from_selection(selection), checks=parts)
    return dataclasses.replace(est, selection=report, notes=tuple(
        ([selection.doubt] if selection.doubt else []) + list(selection.notes)))


def _few_counts(structures: Sequence[str] | None, swept: float) -> tuple[Sequence[str] | None, str]:
    """On a handful of encoder counts no test tells a richer structure from their rounding: the structures of a
    higher rank left out, and the note saying so."""
    if swept >= MIN_COUNTS_SWEPT:
        return structures, ""
    wanted = tuple(structures) if structures is not None else tuple(STRUCTURES)
    higher = [s for s in wanted if s in STRUCTURES and STRUCTURES[s].rank > 0]
    if not higher:
        return structures, ""
    return [s for s in wanted if s not in higher], (
        f"{', '.join(higher)} not fitted: the encoder sweeps only {swept:.0f} counts, whose rounding "
        f"{'they' if len(higher) > 1 else 'it'} would fit as well as any motor")


def _friction_after_all(recs: list[Recording], est: Estimate, selection: Selection, edge: str,
                        structures: Sequence[str] | None, input_delay: int | str, fix_bias: bool
                        ) -> tuple[Estimate, Selection, str, dict[str, float]]:
    """No screen overrules a fit: friction left out by the screen is fitted after all when the chosen model's own
    residuals correlate with the sign of its speed.  Also the correlation's p-value (``checks``)."""
    checks: dict[str, float] = {}
    if any(n.startswith(SCREENED_OUT + ":") for n in selection.notes) and STRUCTURES[est.structure].linear:
        checks = {"sign_p": _own_sign_p(est, recs)}
        if checks["sign_p"] < SIGN_LEVEL:
            label = selection.chosen.label
            selection, edge = _select_widening(recs, structures, input_delay, fix_bias, screen=False)
            selection = dataclasses.replace(selection, notes=(*selection.notes, (
                f"friction and dead zone fitted after all: the screen found no sign of them, but the {label} "
                f"model's residuals correlate with the sign of its speed (p = {checks['sign_p']:.2g})")))
            est, selection = _refit_chosen(recs, selection, fix_bias)
            checks = {"sign_p": _own_sign_p(est, recs)} if STRUCTURES[est.structure].linear else {}
    return est, selection, edge, checks


def _within_noise(recs: list[Recording], est: Estimate, selection: Selection, swept: float, fix_bias: bool
                  ) -> tuple[Estimate, Selection]:
    """The intervals widened over the candidates the data cannot rule out that fall outside them (and over the
    encoder's resolution on a handful of counts); not clear where those differ materially."""
    chosen = selection.chosen
    # on a handful of encoder counts the residual is the rounding of those counts, not noise: the
    # test's variance means little there, so every candidate whose residual sum is as small (within
    # CLOSE of the best's) is one the data cannot rule out
    few = swept < MIN_COUNTS_SWEPT
    # and the amplitude itself is known to one count of those swept: a floor under every interval
    resolution = 1.0 / swept if few and swept > 0 else 0.0
    least = min((c.residual_sum for c in selection.candidates if math.isfinite(c.residual_sum)
                 and STRUCTURES[c.structure].rank == 0), default=math.nan)
    within = [c for c in selection.candidates if c is not chosen and math.isfinite(c.a) and (
        c.within_noise or (few and c.residual_sum <= (1 + CLOSE) * least))]
    within += _linear_kept(selection, within)
    ci = est.confidence_interval(0.95)
    material = [c for c in within if not (ci["a"][0] <= c.a <= ci["a"][1] and ci["b"][0] <= c.b <= ci["b"][1])]
    if material or resolution:
        est, doubt = _widen(est, chosen, material, resolution)
        est = _cover_richer(recs, est, chosen, material, fix_bias)
        if material and any(abs(c.a - est.a) > MATERIAL * abs(est.a) or abs(c.b - est.b) > MATERIAL * abs(est.b)
               for c in material):
            selection = dataclasses.replace(selection, clear=False, doubt=doubt)
    return est, selection


def _doubts(est: Estimate, selection: Selection, edge: str, notes: list[str], checks: dict[str, float],
            loop_note: str) -> Selection:
    """The selection with its notes and the doubts that make a choice not clear: no finite interval, a delay at
    the edge, residuals that correlate with the sign of the speed, a feedback loop."""
    se = est.stderr()
    if not (math.isfinite(se["a"]) and math.isfinite(se["b"])):
        # a choice whose own fit cannot say how well it knows a and b is no clear choice
        selection = doubted(selection, f"the chosen fit has no finite interval for a and b ({est.missing_intervals()})",
                            RICHER_INPUT)
    if edge:
        selection = doubted(selection, edge)
    selection = dataclasses.replace(selection, notes=tuple(notes))
    if checks and checks.get("sign_p", 1.0) < SIGN_LEVEL and STRUCTURES[selection.chosen.structure].linear:
        selection = doubted(selection, f"the chosen model's residuals correlate with the sign of its speed (p = "
                                       f"{checks['sign_p']:.2g}): it misses something friction-like",
                            "its intervals may not cover the motor")
    if loop_note:
        # no disturbance to feed back, but the encoder's rounding and noise still reach the duty
        selection = doubted(selection, LOOP_DOUBT)
    return selection


def _check_parts(recs: list[Recording], est: Estimate, selection: Selection,
                 open_loop: bool) -> tuple[Estimate, Selection, tuple[PartCheck, ...]]:
    """The chosen answer against the data's own parts (:mod:`identify.default.consistency`): where parts disagree the
    intervals widen to hold each part's, and where a part's ``a`` or ``b`` is materially off the answer is not
    clear, the doubt saying which part differs and what it suggests.  Where the residuals are correlated at the
    blocks' scale and the blocks' jackknife knows ``a`` or ``b`` less well than the chosen fit's own covariance,
    the interval widens to the jackknife's.  Not made on a recording made in a loop (its output-error residual
    holds the fed-back noise, which the input answers)."""
    if not open_loop:
        return est, selection, ()
    found = consistency(est, recs)
    parts = found.checks
    differ = [c for c in parts if not c.agree]
    ci = est.confidence_interval(0.95)
    ranges = {"a": ci["a"], "b": ci["b"]}
    se = est.stderr()
    wider = {n: x for n, x in found.block_stderr.items() if not x <= se[n]}
    for name, x in wider.items():
        value, half = float(est.value(name)), 1.959963984540054 * x
        ranges[name] = (min(ranges[name][0], value - half), max(ranges[name][1], value + half))
    blind = blind_check(parts, float(est.a), float(est.b)) if selection.clear else None
    if blind is not None:
        check, name, width = blind
        selection = doubted(selection, f"the part checks cannot vouch for the model: {check.split} could not tell its "
                                       f"parts' {name} apart by less than {100 * width:.3g} % of its value (95 %), so "
                                       "a structure that misfits this recording would pass them as this one does; "
                                       "this is not a clear choice", "a finer encoder or a longer, richer run would "
                                       "let them check it")
    if not (differ or wider):
        return est, selection, parts
    est = dataclasses.replace(est, model_range=widened_range(ranges, differ))
    material = [c for c in differ if c.material]
    if material:
        first = min(material, key=lambda c: c.p_value)
        others = f" (and {len(material) - 1} more split{'s' if len(material) > 2 else ''}: see the part checks)" \
            if len(material) > 1 else ""
        selection = doubted(selection, f"the model's a and b differ between parts of the recording, {first.split} "
                                       f"(p = {first.p_value:.2g}): {first.hint}{others}; no single a and b fits it "
                                       "all, so this is not a clear choice; the intervals hold every part's")
    elif selection.clear and any(c.p_value < REFUTED_LEVEL for c in differ):
        first = min(differ, key=lambda c: c.p_value)
        selection = doubted(selection, f"a part check refutes the model beyond doubt, {first.split} (p = "
                                       f"{first.p_value:.2g}), though its a and b move little when that check's "
                                       f"columns are added: {first.hint}; the structure does not fit this recording, "
                                       "and what it misses may move a and b in a way no check here measures, so this "
                                       "is not a clear choice")
    return est, selection, parts


def _one_magnitude_bias(recs: list[Recording], est: Estimate, selection: Selection) -> tuple[Estimate, Selection]:
    """``b``'s interval where the input takes one magnitude ``U`` both ways (a binary PRBS, a square wave) and the
    chosen model has a constant acceleration ``d``: there ``b u + d`` is exactly a gain of ``b + d/U`` forward and
    ``b - d/U`` in reverse, so the data cannot tell a constant torque from forward and reverse gains that differ.
    The interval holds both gains; the answer is not clear where they differ from ``b`` by over
    :data:`MATERIAL`."""
    values = est.values()
    d = float(values.get("bias", 0.0) or 0.0)
    top = _one_magnitude(recs)
    if d == 0 or not math.isfinite(d) or top is None:
        return est, selection
    b, shift = float(est.b), abs(d) / top
    own = est.confidence_interval(0.95)["b"]
    ranges = dict(est.model_range) if est.model_range else {n: est.confidence_interval(0.95)[n] for n in ("a", "b")}
    lo, hi = ranges["b"]
    # each gain as well known as b itself
    ranges["b"] = (min(lo, own[0] - shift), max(hi, own[1] + shift))
    est = dataclasses.replace(est, model_range=ranges)
    if shift > MATERIAL * abs(b):
        forward, reverse = b + math.copysign(shift, d), b - math.copysign(shift, d)
        selection = doubted(selection, f"the input takes one magnitude, |u| = {top:g}, both ways, so the constant "
                                       f"acceleration d = {d:.4g} is also a forward gain {forward:.4g} and a reverse "
                                       f"one {reverse:.4g}: the data cannot tell them apart, so b's interval holds "
                                       "both and this is not a clear choice; runs at two or more amplitudes would "
                                       "separate them")
    return est, selection


def _slower_than_run(est: Estimate) -> str:
    """The model's time constant (``1/a``, or the electrical one) that is longer than the whole run, in words
    ("" where none is): over less than one time constant a fit sees a ramp, not the pole."""
    span = est.n_samples * est.sample_period
    values = est.values()
    slow = []
    if math.isfinite(est.a) and span > 0 and abs(est.a) * span < 1:
        slow.append(f"1/a = {1 / abs(est.a):.3g} s" if est.a else "1/a unbounded")
    tau = float(values.get("electrical_time_constant", 0.0) or 0.0)
    if span > 0 and tau > span:
        slow.append(f"the electrical time constant {tau:.3g} s")
    if not slow:
        return ""
    return f"{' and '.join(slow)} {'is' if len(slow) == 1 else 'are'} longer than the run ({span:.3g} s)"


def _unsure_intervals(est: Estimate, selection: Selection) -> tuple[Estimate, Selection]:
    """An answer whose intervals say nothing is no clear choice: a zero standard error from data with a residual
    (a degenerate covariance: the interval made infinite) or the chosen fit's own 95 % interval wider than the
    value itself (a ramp, a few steps: the run does not determine it)."""
    se = est.stderr()
    exact = [n for n in ("a", "b") if se[n] == 0 and est.residual_rms > 0]
    if exact:
        # a covariance that knows a parameter exactly from data with a residual is degenerate: it is no interval
        ranges = est.model_range or {n: est.confidence_interval(0.95)[n] for n in ("a", "b")}
        est = dataclasses.replace(est, model_range={**ranges, **{n: (-math.inf, math.inf) for n in exact}})
        selection = doubted(selection, f"the chosen fit's covariance is degenerate (a zero standard error for "
                                       f"{' and '.join(exact)} from data with a residual), so it gives no interval",
                            RICHER_INPUT)
    # the chosen fit's own interval (not the range of candidates the data cannot rule out, which may be a richer
    # structure's wide one around a well-determined answer)
    wide = [n for n in ("a", "b") if math.isfinite(se[n]) and 1.959963984540054 * se[n] > abs(est.value(n))]
    slow = _slower_than_run(est)
    if slow and not (exact or wide):
        selection = doubted(selection, f"{slow}: the run does not determine the pole, so this is not a clear choice",
                            "a run several time constants long would")
    if wide and not exact:
        # an interval wider than the value itself (a ramp, a few steps): the run does not determine it
        ci = est.confidence_interval(0.95)
        said = ", ".join(f"{n} in [{ci[n][0]:.4g}, {ci[n][1]:.4g}]" for n in wide)
        selection = doubted(selection, f"the run does not determine {' and '.join(wide)} ({said}, 95 %): this is not "
                                       "a clear choice", RICHER_INPUT)
    return est, selection


#: The doubt of a closed-loop recording the default fits as any other (no disturbance found to feed back).
LOOP_DOUBT = ("recorded in a closed loop: the measurement's rounding and noise reach the duty through the loop, "
              "which the intervals do not model; they may not cover")


def _closed_loop(recs: list[Recording], structures: Sequence[str] | None, input_delay: int | str,
                 fix_bias: bool) -> ClosedLoopFit:
    """The closed-loop fit (:func:`identify.default.feedback.fit_closed_loop`) of recordings made in a feedback loop
    when every structure is asked for; no estimate (and no note) otherwise."""
    evidence = feedback_evidence(recs) if structures is None else ""
    if not evidence:
        return ClosedLoopFit(None)
    return fit_closed_loop(recs, evidence, input_delay=input_delay, fix_bias=fix_bias)


#: The longest input delay, in samples, the default searches when the best delay is at the top of the range
#: (fewer on short data: at least 20 rows per delay).
LARGEST_DELAY = 250


def _select_widening(recs: list[Recording], structures: Sequence[str] | None, input_delay: int | str,
                     fix_bias: bool, screen: bool = True) -> tuple[Selection, str]:
    """:func:`select_model`, its delay range doubled while the best or the chosen delay is at its top (as far
    as :data:`LARGEST_DELAY` and the data allow); and the doubt when the choice is still at the top ("" if not).
    """
    max_delay = MAX_AUTO_DELAY
    widened = False
    limit = largest_delay(recs, LARGEST_DELAY)
    while True:
        top = max(largest_delay(recs, max_delay), declared_input_delay(recs))
        selection = select_model(recs, structures=structures, input_delay=input_delay, max_delay=max_delay,
                                 fix_bias=fix_bias, screen=screen, widening=top < limit)
        if input_delay != "auto":
            return selection, ""
        first_order = [c for c in selection.candidates if STRUCTURES[c.structure].rank == 0 and
                       math.isfinite(c.residual_sum)]
        best_first = min(first_order, key=lambda c: c.residual_sum, default=selection.best)
        # the chosen delay at the top, or the best fit at the top: a misfit whose residual still falls at the
        # top may fall much further past it, and a choice below the top "within the noise" of a best that is
        # itself not the best is no answer (a long delay with friction: its misfit inflates the noise)
        at_top = top in (selection.chosen.input_delay, selection.best.input_delay, best_first.input_delay)
        if not at_top or top >= limit:
            break
        max_delay = min(2 * max_delay, limit)
        widened = True
    notes = list(selection.notes)
    if widened:
        notes.append(f"input delays searched up to {top} samples ({top * recs[0].sample_period:.6g} s): the best "
                     f"delay was at the top of the usual range (0-{MAX_AUTO_DELAY})")
    selection = dataclasses.replace(selection, notes=tuple(notes))
    if selection.chosen.input_delay == top and top > 0:
        return selection, (f"the chosen delay, {top} samples, is the longest searched"
                           f"{' (the data allow no longer one)' if top >= limit else ''}: the true delay may be "
                           "longer, so this is not a clear choice; record longer, or pass --input-delay N")
    return selection, ""


def _own_sign_p(est: Estimate, recs: list[Recording]) -> float:
    """The chosen fit's sign test on the first recording, from its kept residuals where it has them."""
    kept = est.speed_residuals[0] if est.speed_residuals else None
    return sign_correlation_p(est, recs[0], kept)


def _linear_kept(selection: Selection, within: list[Candidate]) -> list[Candidate]:
    """Where a fit overruled the screen (:data:`REFUTED`) and a nonlinear structure was chosen, the best linear
    candidate (when not already ``within``): the score test found no friction and a fit of it moved ``a`` and ``b``,
    so the data back the linear model by the one and friction by the other, and neither answer is ruled out."""
    if selection.refuted is None or STRUCTURES[selection.chosen.structure].linear:
        return []
    linear = [c for c in selection.candidates if STRUCTURES[c.structure].linear and STRUCTURES[c.structure].rank == 0
              and math.isfinite(c.residual_sum) and math.isfinite(c.a)]
    best = min(linear, key=lambda c: c.residual_sum, default=None)
    return [best] if best is not None and best not in within else []


def _split_evidence(selection: Selection) -> Selection:
    """Not clear where a fit overruled the screen and a nonlinear structure was chosen: which structure the answer
    rests on, the data do not settle (a quasi-static ramp, one sine, friction that is not Coulomb's)."""
    if selection.refuted is None or STRUCTURES[selection.chosen.structure].linear or not selection.clear:
        return selection
    p, moved = selection.refuted
    return dataclasses.replace(selection, clear=False, doubt=(
        f"the evidence for friction is split: the score test (p = {p:.2g}) finds none, while {moved} on the first "
        "rows; the answer rests on "
        "a structure the data do not settle, so this is not a clear choice; runs through zero speed at several "
        "amplitudes would settle it"))


def _refit_chosen(recs: list[Recording], selection: Selection, fix_bias: bool) -> tuple[Estimate, Selection]:
    """The chosen candidate fitted on all rows; where that fit fails (it was chosen on the comparison's rows),
    the next candidate that fits, tried in order of their residual sums, with the choice no longer clear."""
    try:
        return _chosen_fit(recs, selection.chosen, fix_bias), selection
    except (NotIdentifiableError, FloatingPointError, np.linalg.LinAlgError) as exc:
        failure = exc
    others = sorted((c for c in selection.candidates if c is not selection.chosen and math.isfinite(c.residual_sum)),
                    key=lambda c: (not c.within_noise, c.residual_sum))
    for other in others:
        try:
            est = _chosen_fit(recs, other, fix_bias)
        except (NotIdentifiableError, FloatingPointError, np.linalg.LinAlgError):
            continue
        doubt = (f"the {selection.chosen.label} model, chosen on the comparison's rows, could not be fitted on all "
                 f"rows ({str(failure).split(';')[0]}); the {other.label} model is given instead, so this is not "
                 "a clear choice")
        return est, dataclasses.replace(selection, chosen=other, clear=False,
                                        doubt=doubt + (f"; {selection.doubt}" if selection.doubt else ""))
    raise failure


def _chosen_fit(recs: list[Recording], chosen: Candidate, fix_bias: bool) -> Estimate:
    """The chosen candidate fitted on all rows by its own method."""
    from ..methods import method_function
    options = chosen.options()
    if chosen.method == "oe-friction" and fix_bias:
        options["fix_bias"] = True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # the selection says it once, in its notes
        return method_function(chosen.method)(recs, **options)


#: Electrical time constants, in sample periods, that a speed column averaged over each interval (a difference
#: of positions, not an instantaneous speed) also shows as: that average lags the speed by half a sample.
AVERAGING_LAG = (0.3, 0.7)


def _speed_as_average(recs: list[Recording], est: Estimate, chosen: Candidate, structures: Sequence[str] | None,
                      input_delay: int | str, fix_bias: bool) -> tuple[Estimate, str] | None:
    """When a second pole chosen on a speed column lags by about half a sample (:data:`AVERAGING_LAG`), the
    estimate widened to cover the first-order model of that column read as the average speed over each
    interval (its integral fitted as an angle), and the doubt line; None otherwise.

    A speed column that is a difference of positions is the average speed over the interval before each
    sample; fitted as the instantaneous speed it looks like a lag of half a sample, which a second pole
    fits. Which one the column is, the file does not say: both answers are kept.
    """
    tau = float(est.extra.get("electrical_time_constant", 0.0))
    h = est.sample_period
    if STRUCTURES[est.structure].rank == 0 or not AVERAGING_LAG[0] * h <= tau <= AVERAGING_LAG[1] * h:
        return None
    if not all(r.speed is not None and r.counts is None and r.angle is None and not r.has_gaps for r in recs):
        return None
    integrated = [dataclasses.replace(r, speed=None, angle=np.concatenate(
        [[0.0], np.cumsum(np.asarray(r.speed)[1:] * np.diff(r.time))])) for r in recs]
    first = [s for s in (structures if structures is not None else STRUCTURES) if STRUCTURES[s].rank == 0]
    try:
        alt = _chosen_fit(integrated, select_model(integrated, structures=first, input_delay=input_delay,
                                                   fix_bias=fix_bias).chosen, fix_bias)
    except NotIdentifiableError:
        return None
    other = Candidate(alt.structure, alt.input_delay, alt.a, alt.b, math.nan)
    widened, _ = _widen(est, chosen, [other])
    doubt = (f"the speed column may be the average speed over each interval (a difference of positions) rather "
             f"than the speed at each sample: read so, the {alt.structure} model with delay {alt.input_delay} "
             f"gives a = {alt.a:.4g} 1/s, b = {alt.b:.4g}, where the second pole (tau_e {tau:.2g} s, about half a "
             "sample) gives the one above; the intervals cover both; a column of positions (angle or counts) "
             "would tell them apart")
    return widened, doubt


def _widen(est: Estimate, chosen: Candidate, material: list[Candidate],
           resolution: float = 0.0) -> tuple[Estimate, str]:
    """The estimate whose intervals cover ``material`` too (``model_range``); the doubt line.

    Each candidate the data cannot rule out is as uncertain as the chosen fit (the same data and
    noise), so ``model_range`` is the union of the 95 % intervals of all of them, each candidate's
    taken as the chosen fit's, relative to its value, carried to the candidate's value, and at least
    ``resolution`` of it on either side (one encoder count of the few a run sweeps).  The doubt
    line gives the span of the candidates' own values ("" without candidates).
    """
    ci = est.confidence_interval(0.95)
    ranges, spans = {}, {}
    for name in ("a", "b"):
        value = float(est.value(name))
        values = [value] + [getattr(c, name) for c in material]
        spans[name] = (min(values), max(values))
        below, above = ((value - ci[name][0]) / abs(value), (ci[name][1] - value) / abs(value)) if value else (0, 0)
        below, above = (max(x, resolution) if math.isfinite(x) else resolution for x in (below, above))
        ranges[name] = (min(v - abs(v) * below for v in values), max(v + abs(v) * above for v in values))
    if not material:
        return dataclasses.replace(est, model_range=ranges), ""
    top = max(c.a for c in material)
    a_text = (f"a from {spans['a'][0]:.4g} 1/s to unbounded (a static gain fits as well)"
              if top >= 1e6 * max(est.a, 1.0) else f"a in [{spans['a'][0]:.4g}, {spans['a'][1]:.4g}] 1/s")
    doubt = (f"the data cannot tell {chosen.label} from {', '.join(c.label for c in material[:4])}"
             f"{' and others' if len(material) > 4 else ''}: {a_text}, "
             f"b in [{spans['b'][0]:.4g}, {spans['b'][1]:.4g}]; the intervals cover them all; "
             + separating_experiment(chosen, material))
    if top >= 1e6 * max(est.a, 1.0):
        ranges["a"] = (ranges["a"][0], math.inf)
    return dataclasses.replace(est, model_range=ranges), doubt


#: Candidates of a higher rank than the chosen one at most whose own intervals :func:`_cover_richer` fits.
RICHER_FITS = 3


def _cover_richer(recs: list[Recording], est: Estimate, chosen: Candidate, material: list[Candidate],
                  fix_bias: bool) -> Estimate:
    """The estimate whose intervals also hold the own 95 % intervals of the candidates of a higher rank than the
    chosen one among ``material`` (the :data:`RICHER_FITS` of least residual, each fitted on all rows): a second
    pole that fits as well knows ``a`` and ``b`` less precisely than the chosen first-order fit, whose relative
    width :func:`_widen` carries to it (one sine through a lag: a 30 times narrower interval, around the
    first-order model's value), and at each delay it sits elsewhere."""
    rank = STRUCTURES[chosen.structure].rank
    richer = sorted((c for c in material if STRUCTURES[c.structure].rank > rank), key=lambda c: c.residual_sum)
    if not richer or "a" not in est.model_range:
        return est
    ranges = dict(est.model_range)
    for candidate in richer[:RICHER_FITS]:
        try:
            own = _chosen_fit(recs, candidate, fix_bias).confidence_interval(0.95)
        except (NotIdentifiableError, ValueError):
            continue
        for name in ("a", "b"):
            low, high = own[name]
            if math.isfinite(low) and math.isfinite(high):
                ranges[name] = (min(ranges[name][0], low), max(ranges[name][1], high))
    return dataclasses.replace(est, model_range=ranges)


def _counts_swept(recs: list[Recording]) -> float:
    """The most encoder counts any recording sweeps (max minus min); ``inf`` without counts."""
    counts = [r.counts for r in recs if r.counts is not None and len(r.counts)]
    return max(float(np.max(c) - np.min(c)) for c in counts) if counts else math.inf


def _data_notes(recs: list[Recording], est: Estimate, swept: float) -> list[str]:
    """What the recordings cannot answer, said plainly (saturation, one amplitude, few counts, a too slow input)."""
    notes = []
    found = sorted({r.metadata["speed_from_counts"] for r in recs if "speed_from_counts" in r.metadata})
    if found:
        notes.append(f"the speed column is a backward difference of encoder counts ({'; '.join(found)}): "
                     "fitted as the counts it differences (identify.data.counts_behind_speed)")
    saturated = saturation_note(recs)      # counted, and kept in the fit: its docstring says why
    if saturated:
        notes.append(saturated)
    moving = np.abs(np.concatenate([r.duty[:SELECTION_ROWS] for r in recs])[:SELECTION_ROWS])
    moving = moving[moving > 0]
    if est.method == "oe" and len(moving):
        top = float(moving.max())
        share = float(np.mean(moving == top))
        if share >= SINGLE_AMPLITUDE_SHARE:
            notes.append(f"the input takes one magnitude, |u| = {top:g}, in {100 * share:.0f} % of its non-zero "
                         "samples: b is the gain at that amplitude, and a dead zone would be absorbed in it "
                         "unseen; runs at two or more amplitudes would separate them")
    if swept < MIN_COUNTS_SWEPT:           # swept: _counts_swept(recs), as the caller has it
        notes.append(f"the encoder sweeps only {swept:.0f} counts in the whole run: a and b rest on a few "
                     f"steps (their intervals allow one count in {swept:.0f}, +-{100 / max(swept, 1):.2g} %); "
                     "run longer or faster, or use a finer encoder")
    if est.a > 0 and math.isfinite(est.a):
        fast = 0.0
        total = 0.0
        for r in recs:
            u = np.array(r.duty[:SELECTION_ROWS], dtype=float)
            u -= float(np.mean(u))
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
    unmodelled Coulomb friction leaves), its variance by batch means over :data:`BLOCKS` blocks (:func:`block_mean_p`).
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
    from ..checks.validation import validate
    report = validate(estimate, recording)
    return {"whiteness_p": float(report.whiteness_p), "input_p": float(report.independence_p),
            "sign_p": _sign_p(report.measured_speed, report.simulated_speed)}


def _sign_p(measured: np.ndarray, simulated: np.ndarray) -> float:
    """p-value of the speed residual's correlation with the sign of the model's speed (batch means)."""
    from ..checks.outliers import finite_rows
    ok = finite_rows(measured, simulated)   # a slice past the first rows where only they are undefined: no copies
    residual = measured[ok] - simulated[ok]
    sign = np.sign(simulated[ok])          # the model's: a coarse encoder's speed is often 0
    sign -= sign.mean()
    spread = float(sign @ sign)
    scores = block_sums(np.multiply(sign, residual, out=residual))     # in place: 8 MB a row of 10^6 not allocated
    return block_mean_p(scores) if len(scores) > 2 and spread > 0 and np.any(scores) else math.nan


def sign_correlation_p(estimate: Estimate, recording: Recording, residual: np.ndarray | None = None) -> float:
    """:func:`residual_checks`' ``sign_p`` alone: from the fit's own speed residual when given (the entry of
    :attr:`Estimate.speed_residuals`), else from one simulation (:func:`identify.checks.validation.model_output`)."""
    from ..checks.validation import model_output
    if residual is not None:
        measured = recording.measured_speed()
        return _sign_p(measured, measured - residual)
    return _sign_p(*model_output(estimate, recording))
