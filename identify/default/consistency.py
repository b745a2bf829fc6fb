"""Part checks: does the chosen model give the same ``a`` and ``b`` on every fair part of the recording?

A model that is right for the plant gives the same ``a`` and ``b`` — within their intervals — on any
part of the data: early and late, forward and reverse motion, low and high drive, slow and fast.  A
model that is wrong (a motor that warms over the run, a load switched on partway, a driver whose forward
gain differs from its reverse one, that clips the duty or limits its current, friction that weakens with
speed) fits some parts with other values than others, *whatever structure was chosen*: this check needs
no structure that describes the misfit, only the chosen one's answer.  It is the default's last word on
whether a choice is clear (:func:`identify.default.selection.fit_selected`).

The test, for each split of the rows into two parts ``S`` and its complement, is a Chow test in its
output-error form.  Letting ``a``, ``b`` and a constant acceleration ``d`` take other values on ``S``,
``dω/dt = -(a + δa 1_S) ω + (b + δb 1_S) v + δd 1_S``, the model output moves, to first order, along
the responses of the chosen model's pole to the inputs ``-1_S ω``, ``1_S v`` and ``1_S`` (``ω`` the
model's speed over each interval, ``v`` the drive the structure's gain multiplies: the duty past its dead
zone, the current behind its lag).  These columns and the model's own (the same without ``1_S``, the
Coulomb friction's ``-sign ω`` when the structure has it, each segment's initial state) are fitted to the
chosen model's residual by least squares, starting from the full fit: one Gauss--Newton step of the
model with per-part parameters.  Its ``(δa, δb, δd)`` are tested against zero with the batch-means
sandwich covariance (:data:`~identify.default.comparison.BLOCKS` blocks of consecutive rows, so correlated
residuals — a misfit's, an encoder's rounding — are allowed for) as Hotelling's ``T^2``, an
``F(k, m - k)`` variate (the blocks' scores each taken as the fit without that block would leave them,
a cluster jackknife, so a block that holds a step is not judged by its own fit); the parts' values are the
step's ``a``, ``b`` on each side, with their intervals from the same covariance.

The parts (:data:`SPLITS`):

* ``early / late``: ``a`` and ``b`` along the run, a linear trend from its start to its end (a motor warming,
  a setting drifting: a trend finds a steady drift at p = 1e-42 where a step between the halves found it at 3e-4),
  and the constant acceleration (and friction) between the first and the second half (a load switched on); its
  parts ``a`` and ``b`` at the start and at the end of the run;
* ``forward / reverse``: ``ω > 0`` against ``ω < 0`` for ``a`` and ``d``, ``v > 0`` against ``v < 0`` for
  ``b`` (an asymmetric driver or gearbox);
* ``low / high drive``: ``|v|`` at or below its median against above (a duty clipped, a current limit);
* ``slow / fast``: ``|ω|`` at or below its median against above (friction or drag that varies with speed);
* ``short / long interval``, on an uneven clock only (intervals spread over :data:`UNEVEN_CLOCK` of their
  median): the sample interval at or below its median against above (a column that steps with the row, not
  with the clock: a per-row sum, a rate over another interval, a log's time that is not the sample's).

Four checks are no split: the same step with columns beside the model's own instead of per-part ones,

* ``gain by duty``: ``v |v| / V`` and ``v^3 / V^2`` (a gain that curves with the duty: a supply that sags, a
  current limit, a driver's curved map), its parts the gain at a small duty and at the full one;
* ``angle torque``: ``θ`` (a spring, a cable, gravity near its balance) and, over :data:`MIN_TURN_RANGE`,
  ``sin θ`` and ``cos θ`` (gravity on an arm, an unbalanced load), which act alike in every part and so pass
  every split; its parts the model as fitted and with the torque;
* ``friction by speed``: ``sign(ω) exp(-(ω/s)²)`` at knees ``s`` of :data:`KNEES` times the top speed (a friction
  that weakens from rest, Stribeck's, where the model has Coulomb's or none), and ``ω |ω|`` (a drag that grows with
  speed): the slow / fast split halves the speeds at their median, far above such a knee, and misses it; its parts
  the model as fitted and with the curve;
* ``torque curve``: the model's own torque ``T = b v - a ω`` through ``T |T|`` and ``T^3`` (Ramsey's RESET: the
  fitted values' powers beside the model), a torque that bends where the model asks for the most (a current limit
  reached at steps and reversals only, on one row in a hundred, where no split holds enough of those rows); its
  parts the model as fitted and with the curve.

A split is left out where either part holds less than :data:`MIN_PART_SHARE` of the rows (a run in one
direction only), or where the drive takes one magnitude (a binary PRBS has no low and high drive).  The
level of each test is :data:`PART_LEVEL` divided by the number of checks made (Bonferroni): on a right model
the whole check finds a difference in about one run in a hundred, and then only widens the intervals to hold
each part's.  The answer becomes unclear where a check finds a difference and a part's ``a`` or ``b`` is off
the full fit's by more than :data:`~identify.default.comparison.MATERIAL`: the model is refuted, and by an amount that
matters.  A shift still inside its own 95 % interval counts too: the test has found the parts apart beyond the
noise, and an imprecise model that the data refute (a cogging motor at one sample per time constant: ``a`` 226
[122, 331] for 102) is no clear choice.  On a right model the check finds a difference in about one run in a
hundred, so at most that share of right answers loses its "clear".
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from motorsim.recording import Recording

from ..comparison import MATERIAL
from ..data import Segment
from .check_columns import (
    KNEES,
    MIN_TURN_RANGE,
    _angle_inputs,
    _curve_inputs,
    _drag_inputs,
    _friction_curve_inputs,
    _push_curve_inputs,
    _Rows,
    _three_magnitudes,
)
from .selection_report import PartCheck, _g

__all__ = ["PartCheck", "part_checks", "Consistency", "consistency", "COLOURED", "SPLITS", "PART_LEVEL",
           "MIN_PART_SHARE", "MAX_ROWS", "KNEES", "MIN_TURN_RANGE"]

#: The splits, in the order they are made and reported: name and the two parts' names.
SPLITS: dict[str, tuple[str, str]] = {
    "early / late": ("start", "end"),
    "forward / reverse": ("forward", "reverse"),
    "low / high drive": ("low drive", "high drive"),
    "slow / fast": ("slow", "fast"),
    "short / long interval": ("short intervals", "long intervals"),
    "gain by duty": ("small duty", "full duty"),
    "angle torque": ("as fitted", "with an angle torque"),
    "friction by speed": ("as fitted", "with a friction curve"),
    "torque curve": ("as fitted", "with a torque curve"),
}
#: The check that is no split: the gain as a curve of the duty (:func:`_curve_check`).
CURVE = "gain by duty"
#: The check that is no split: the chosen model with a torque of the angle beside it (:func:`_beside_check`).
ANGLE = "angle torque"
#: The check that is no split: the chosen model with a friction that changes with speed beside it
#: (:func:`_friction_curve_inputs`).
SPEED_CURVE = "friction by speed"
#: The split by the sample interval, made on an uneven clock only: a model of the motor's own time gives the same ``a``
#: and ``b`` over short and long intervals; a column that steps per row whatever the clock (a per-row sum, a rate
#: over another interval, a log's time that is not the sample's) does not.
CLOCK = "short / long interval"
#: Spread of the sample intervals, relative to their median, from which the clock is uneven enough to split by it.
UNEVEN_CLOCK = 0.2
#: The split along the run: ``a`` and ``b`` take a linear trend over it, the constant a step at its middle.
DRIFT = "early / late"
#: The splits whose parts may also differ in a constant acceleration: a load switched on, a torque or friction on
#: one side.  By drive and by speed a constant that differs is friction or a dead zone, the structures' own.
CONSTANT_PARTS = ("early / late", "forward / reverse")
#: The splits whose parts may also differ in the Coulomb friction, where the structure has one: friction that
#: changes over the run, or with speed (Stribeck's, weakening from rest: what the slow / fast split finds).  By
#: direction friction's part is the constant's.
FRICTION_PARTS = ("early / late", "slow / fast")
#: Level of the whole check (all its splits): a difference found only widens the intervals, so it may be found
#: by chance more often than the selection's own test (:data:`~identify.default.comparison.LEVEL`); the 0.001 of that
#: test missed a 5 % drift over the run (warming) in one run of two.
PART_LEVEL = 0.01
#: Share of the rows each part must hold for its split to be made.
MIN_PART_SHARE = 0.1
#: Share of the drive's (and the speed's) energy each part must hold for its split to be made: the half of the
#: rows at the lower drive of a multisine holds about 8 % of its energy.
MIN_ENERGY_SHARE = 0.02
#: Rows the check uses at most (windows spread over every segment, in proportion: :func:`_windows`): its cost
#: stays a few model responses however long the recording.
MAX_ROWS = 6_000
#: Windows of a long segment the check takes (:func:`_windows`), and the fewest rows of one.
WINDOWS = 4
MIN_WINDOW = 250


def part_checks(estimate: Any, recordings: Sequence[Recording], *,
                level: float = PART_LEVEL) -> tuple[PartCheck, ...]:
    """The chosen model's ``a`` and ``b`` on each split of the recordings' rows (module docstring).

    Parameters
    ----------
    estimate : Estimate
        A fit of ``recordings`` by a first-order or second-order structure.
    recordings : sequence of Recording
        The data it was fitted on.
    level : float
        Level of the whole check; each split's test is at ``level`` over the number of splits made.

    Returns
    -------
    tuple of PartCheck
        One per split made (none where the model's output cannot be formed).
    """
    return consistency(estimate, recordings, level=level).checks


@dataclasses.dataclass(frozen=True)
class Consistency:
    """The part checks of an answer and the block-resampled standard errors of its ``a`` and ``b``.

    Attributes
    ----------
    checks : tuple of PartCheck
    block_stderr : dict of str to float
        ``a`` and ``b``'s standard errors from the cluster jackknife over blocks of consecutive rows, where the
        blocks show the residuals correlated well beyond white noise (the jackknife over
        :data:`COLOURED` times the classical error); empty otherwise.
    """

    checks: tuple[PartCheck, ...] = ()
    block_stderr: Mapping[str, float] = dataclasses.field(default_factory=dict)


#: Ratio of the blocks' jackknife standard error to the classical (white-residual) one of the same linearised
#: fit from which the residuals count as correlated at the blocks' scale: on the right models of ``motorid bench
#: coverage`` the ratio is 0.7-1.3; a model that fits but not exactly (a dead zone fitted to a quasi-static ramp)
#: gives 11, its own interval 280 times too narrow.
COLOURED = 2.0


def consistency(estimate: Any, recordings: Sequence[Recording], *, level: float = PART_LEVEL) -> Consistency:
    """:func:`part_checks` and the block-resampled standard errors of ``a`` and ``b`` (:class:`Consistency`)."""
    rows = _rows(estimate, recordings)
    if rows is None or _exact(rows):
        return Consistency(tuple(_exact_checks(estimate, rows)) if rows is not None else ())
    splits = _split_labels(rows)
    own = _own_inputs(rows)
    inputs, where = list(own), {}
    for name, masks in splits.items():
        parted = _parted_inputs(rows, name, masks)
        where[name] = list(range(len(inputs), len(inputs) + len(parted)))
        inputs += parted
    curve = _curve_inputs(rows)
    if curve:
        where[CURVE] = list(range(len(inputs), len(inputs) + len(curve)))
        inputs += curve
    turning = _angle_inputs(rows)
    if turning:
        where[ANGLE] = list(range(len(inputs), len(inputs) + len(turning)))
        inputs += turning
    weakening = _friction_curve_inputs(rows)
    weakening += _drag_inputs(rows) if weakening else []
    if weakening:
        where[SPEED_CURVE] = list(range(len(inputs), len(inputs) + len(weakening)))
        inputs += weakening
    pushing = _push_curve_inputs(rows)
    if pushing:
        where[PUSH_CURVE] = list(range(len(inputs), len(inputs) + len(pushing)))
        inputs += pushing
    moments = _moments(rows, inputs)
    base = list(range(len(own)))
    alone = _fit_on(moments, base)
    _, jack, _, classical, _ = alone
    block = {}
    for i, name in enumerate(("a", "b")):
        if math.isfinite(jack[i, i]) and jack[i, i] > COLOURED ** 2 * classical[i, i]:
            block[name] = math.sqrt(jack[i, i])
    made = len(splits) + bool(curve) + bool(turning) + bool(weakening) + bool(pushing)
    if not made:
        return Consistency((), block)
    each = level / made
    checks = [_check(estimate, _fit_on(moments, base + where[name]), len(own), name, each) for name in splits]
    if curve:
        checks.append(_curve_check(estimate, _fit_on(moments, base + where[CURVE]), len(own), each))
    if turning:
        checks.append(_beside_check(ANGLE, estimate, alone, _fit_on(moments, base + where[ANGLE]), len(own), each))
    if weakening:
        checks.append(_beside_check(SPEED_CURVE, estimate, alone, _fit_on(moments, base + where[SPEED_CURVE]),
                                    len(own), each))
    if pushing:
        checks.append(_beside_check(PUSH_CURVE, estimate, alone, _fit_on(moments, base + where[PUSH_CURVE]),
                                    len(own), each))
    return Consistency(tuple(checks), block)


#: The check that is no split: the model's own torque, ``b v - a ω``, through a curve beside it
#: (:func:`_push_curve_inputs`).
PUSH_CURVE = "torque curve"


def _curve_check(estimate: Any, fitted: tuple[np.ndarray, np.ndarray, int, np.ndarray, int], p_own: int,
                 level: float) -> PartCheck:
    """The gain as a curve of the duty beside the chosen model (:func:`_curve_inputs`): the curve's test, and
    the gain at a small duty (the slope at zero) against the gain at the full duty (the torque there over the duty),
    with ``a`` alongside.  Material where either gain is over :data:`~identify.default.comparison.MATERIAL` off the
    model's ``b``."""
    from scipy import special
    z = float(-special.ndtri(0.025))
    beta, cov, m, classical, _ = fitted
    p = max(_joint_p(beta[p_own:], cov[p_own:, p_own:], m), _joint_p(beta[p_own:], classical[p_own:, p_own:], 0))
    agree = not (math.isfinite(p) and p < level)
    k = len(beta)
    unit = np.eye(k)
    maps = {"a": (unit[0], unit[0]), "b": (unit[1], unit[1] + unit[p_own] + unit[p_own + 1])}
    values: dict[str, tuple[float, float]] = {}
    intervals: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {}
    off = False
    for key, full in (("a", float(estimate.a)), ("b", float(estimate.b))):
        pair, span = [], []
        for vec in maps[key]:
            shift = float(vec @ beta)
            se = _stderr(vec, fitted)
            off |= abs(shift) > MATERIAL * abs(full)
            pair.append(full + shift)
            span.append((full + shift - z * se, full + shift + z * se))
        values[key], intervals[key] = (pair[0], pair[1]), (span[0], span[1])
    hint = ""
    if not agree:
        small, large = values["b"]
        hint = (f"the gain is {'lower' if large < small else 'higher'} at full duty than at a small one (b {_g(small)} "
                f"at a small duty, {_g(large)} at the full duty): "
                + ("a supply that sags, a current limit or a driver that clips?" if large < small
                   else "a driver whose gain rises with the duty, or a dead zone the model misses?"))
    return PartCheck(CURVE, SPLITS[CURVE], values["a"], values["b"], intervals["a"], intervals["b"], p, agree,
                     bool(off and not agree), hint)


#: What a check of columns beside the model suggests when it finds them (:func:`_beside_check`).
BESIDE_HINTS = {
    ANGLE: "a torque that depends on the angle (gravity on an arm, a spring, a cable, an unbalanced load)",
    SPEED_CURVE: "a friction that changes with speed (Stribeck's, weakening from rest; a drag that grows)",
    PUSH_CURVE: "a torque that bends where the model asks for the most (a current limit, a driver that saturates)",
}


def _beside_check(name: str, estimate: Any, alone: tuple[np.ndarray, np.ndarray, int, np.ndarray, int],
                  fitted: tuple[np.ndarray, np.ndarray, int, np.ndarray, int], p_own: int, level: float) -> PartCheck:
    """The model as fitted against the model with check ``name``'s columns beside it (:func:`_angle_inputs`,
    :func:`_friction_curve_inputs`): their test, and ``a`` and ``b`` with them.  Material where they are found and
    move ``a`` or ``b`` by over :data:`~identify.default.comparison.MATERIAL`."""
    from scipy import special
    z = float(-special.ndtri(0.025))
    beta, cov, m, classical, _ = fitted
    p = max(_joint_p(beta[p_own:], cov[p_own:, p_own:], m), _joint_p(beta[p_own:], classical[p_own:, p_own:], 0))
    agree = not (math.isfinite(p) and p < level)
    pairs, intervals, off = {}, {}, False
    for i, key, full in ((0, "a", float(estimate.a)), (1, "b", float(estimate.b))):
        values = []
        for fit in (alone, fitted):
            bt = fit[0]
            se = _stderr(np.eye(len(bt))[i], fit)
            values.append((full + float(bt[i]), (full + float(bt[i]) - z * se, full + float(bt[i]) + z * se), se))
        shift = values[1][0] - values[0][0]
        off |= abs(shift) > MATERIAL * abs(full)
        pairs[key] = (values[0][0], values[1][0])
        intervals[key] = (values[0][1], values[1][1])
    hint = ""
    if not agree:
        moved = " and ".join(f"{k} to {_g(pairs[k][1])}" for k in ("a", "b")
                             if abs(pairs[k][1] - pairs[k][0]) > MATERIAL * abs(pairs[k][0]))
        hint = BESIDE_HINTS[name] + (f" moves {moved}" if moved else "") + "?"
    return PartCheck(name, SPLITS[name], pairs["a"], pairs["b"], intervals["a"], intervals["b"], p, agree,
                     bool(off and not agree), hint)


def _exact_checks(estimate: Any, rows: _Rows) -> list[PartCheck]:
    """Every split's check of a model that reproduces the data to its rounding: nothing to test."""
    a0, b0 = float(estimate.a), float(estimate.b)
    return [PartCheck(name, SPLITS[name], (a0, a0), (b0, b0), ((a0, a0), (a0, a0)), ((b0, b0), (b0, b0)), 1.0,
                      True, False) for name in _split_labels(rows)]


def _own_inputs(rows: _Rows) -> list[np.ndarray]:
    """The inputs whose responses are the chosen model's own directions: ``a``, ``b``, ``d`` (and friction)."""
    w = rows.speed
    return [-w, rows.drive, np.ones(len(w))] + ([-np.sign(w)] if rows.friction else [])


def _rows(estimate: Any, recordings: Sequence[Recording]) -> _Rows | None:
    """The chosen model on the recordings' segments (the first :data:`MAX_ROWS` rows, in proportion)."""
    from ..checks.validation import _models
    values = estimate.values()
    a = float(values["a"])
    if not (math.isfinite(a) and math.isfinite(float(values["b"]))):
        return None
    pairs: list[tuple[Segment, np.ndarray]] = []
    for rec in recordings:
        try:
            pairs += _models(estimate, rec)
        except Exception:          # a recording the model cannot be formed on: no check (said by the caller)
            return None
    if not pairs:
        return None
    total = sum(len(seg.time) for seg, _ in pairs)
    residual, speed, drive, order, bounds, outputs, angles, intervals = [], [], [], [], [], [], [], []
    respond: list[Callable[..., np.ndarray]] = []
    start = 0
    tau = float(values.get("electrical_time_constant", 0.0) or 0.0)
    zone = float(values.get("dead_zone", 0.0) or 0.0)
    limit = float(values.get("drive_limit", 0.0) or 0.0)      # a driver's clip (the drive-limit structure)
    for seg, model, place in _windows(pairs, total):
        n = len(seg.time)
        t = seg.time
        angle = seg.kind == "angle"
        if not np.all(np.isfinite(model)):
            return None
        w = np.diff(model) / np.diff(t) if angle else 0.5 * (model[:-1] + model[1:])
        v = np.asarray(seg.drive, dtype=float)
        if zone > 0:
            v = np.sign(v) * np.maximum(np.abs(v) - zone, 0.0)
        if limit > 0:
            v = np.clip(v, -limit, limit)
        if tau > 0:
            v = _lagged(v, t, tau)
        residual.append(seg.output - model)
        if angle:
            angles.append(np.asarray(seg.output, dtype=float))
        else:
            angles.append(np.concatenate([[0.0], np.cumsum(0.5 * (seg.output[1:] + seg.output[:-1]) * np.diff(t))]))
        outputs.append(seg.output - seg.output[0])
        speed.append(np.append(w, 0.0))
        drive.append(np.append(v[:-1], 0.0))
        order.append((place + np.arange(n)) / max(total - 1, 1))
        intervals.append(np.append(np.diff(t), 0.0))
        respond.append(functools.partial(_respond, a, t, seg.uniform, angle))
        bounds.append((start, start + n))
        start += n
    every = np.concatenate(intervals)
    uneven = every[:-1][every[:-1] > 0]
    interval = every if len(uneven) and float(np.ptp(uneven)) > UNEVEN_CLOCK * float(np.median(uneven)) else None
    w_all, v_all = np.concatenate(speed), np.concatenate(drive)
    push = float(values["b"]) * v_all - a * w_all
    return _Rows(np.concatenate(residual), w_all, v_all, np.concatenate(order),
                 respond, np.concatenate(angles), bounds, float(values.get("friction", 0.0) or 0.0) > 0,
                 float(np.sqrt(np.mean(np.concatenate(outputs) ** 2))), interval, push)


def _windows(pairs: list[tuple[Segment, np.ndarray]], total: int) -> list[tuple[Segment, np.ndarray, int]]:
    """The segments with the model on them, and each one's first row's place among all ``total`` rows; on more
    than :data:`MAX_ROWS` rows, :data:`WINDOWS` windows of every segment spread evenly over it, in proportion
    (each window a segment of its own, its initial state a nuisance), so that every part of a long run is
    compared within the same cost."""
    out, place = [], 0
    for seg, model in pairs:
        n = len(seg.time)
        keep = n if total <= MAX_ROWS else max(MIN_WINDOW, n * MAX_ROWS // total)
        if keep >= n:
            out.append((seg, model, place))
        else:
            width = max(MIN_WINDOW, keep // WINDOWS)
            for lo in np.linspace(0, n - width, max(1, keep // width)).astype(int):
                hi = lo + width
                out.append((seg.rows(lo, hi), model[lo:hi], place + int(lo)))
        place += n
    return out


def _respond(a: float, t: np.ndarray, uniform: bool, angle: bool, x: np.ndarray,
             out: np.ndarray | None = None) -> np.ndarray:
    """The responses of the pole ``a`` from rest to the held inputs ``x`` (columns) on one segment, each less its
    least-squares fit on the segment's initial state (speed, and for an angle the offset); into ``out`` (row-major,
    the shape of ``x``) when given.

    On a uniform clock by one pass of :func:`motorsim.recursion.first_order_filter` over every column (the exact
    ZOH step, as :func:`identify.fits.sensitivity.zoh_response` takes it), else column by column through it."""
    from motorsim.plant import first_order_coefficients
    from motorsim.recursion import first_order_filter

    from ..fits.sensitivity import zoh_response
    n, k = x.shape
    if out is None:
        out = np.empty((n, k))
    if uniform and n > 1:
        h = float(t[1] - t[0])
        if a * h > 1e-4:
            # the step's speed gain of a held unit input and its angle over the interval
            e, c1, c2 = first_order_coefficients(a, h)
        else:                       # their series, where (h - c1)/a cancels (and a may be 0)
            e = math.exp(-a * h)
            c1 = -math.expm1(-a * h) / a if a * h > 1e-8 else h
            c2 = h * h / 2 - a * h ** 3 / 6
        # row-major, as the filter's scan takes it; one work array, the rest written in ``out``
        forcing = np.empty((n, k))
        forcing[0] = 0.0
        np.multiply(x[:-1], c1, out=forcing[1:])
        first_order_filter(e, forcing, out=out)                             # the speeds
        s0 = np.power(e, np.arange(n, dtype=float))                        # the free response to a unit speed
        if angle:                  # the angle's steps, c1 (speed before) + c2 (input), summed
            np.multiply(out[:-1], c1, out=forcing[1:])
            forcing[1:] += np.multiply(x[:-1], c2, out=out[1:])
            np.cumsum(forcing, axis=0, out=out)
            s0 = np.concatenate([[0.0], np.cumsum(c1 * s0[:-1])])
    else:
        s0 = getattr(zoh_response(a, 0.0, np.zeros(n), t, 1.0, uniform=uniform, sensitivities=False),
                     "angle" if angle else "speed")
        for j in range(k):
            out[:, j] = getattr(zoh_response(a, 1.0, x[:, j], t, 0.0, uniform=uniform, sensitivities=False),
                                "angle" if angle else "speed")
    # less the least-squares fit on the initial state (project_out_initial_state, for every column at once)
    if angle:
        s0 = s0 - s0.mean()
        out -= out.mean(axis=0)
    ss = float(s0 @ s0)
    if ss > 0:
        out -= np.multiply.outer(s0, (s0 @ out) / ss)
    return out


def _lagged(v: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """The drive behind a first-order lag ``tau`` from rest, averaged over each interval (the gain multiplies
    that): ``i[k+1] = e i[k] + (1 - e) v[k]``, ``e = exp(-h/tau)``."""
    from motorsim.recursion import first_order_filter
    h = np.diff(t)
    e = np.exp(-h / tau)
    i = np.zeros(len(v))
    if len(h) and np.all(h == h[0]):
        forcing = np.zeros(len(v))
        forcing[1:] = (1 - e[0]) * v[:-1]
        i = first_order_filter(float(e[0]), forcing)
    else:
        for k in range(len(v) - 1):          # an irregular clock: its own factor per interval
            i[k + 1] = e[k] * i[k] + (1 - e[k]) * v[k]
    mean = v[:-1] + (i[:-1] - v[:-1]) * tau / h * (1 - e)
    return np.append(mean, 0.0)


def _split_labels(rows: _Rows) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each split's part ``S`` as masks for the ``a``, ``b`` and ``d`` columns (module docstring); splits whose
    parts are too small left out."""
    w, v = rows.speed, rows.drive
    moving_v = np.abs(v[v != 0])
    out = {}

    def enough(mask: np.ndarray, weight: np.ndarray) -> bool:
        rows_share = float(np.mean(mask))
        total = float(np.sum(weight))
        share = float(np.sum(weight[mask])) / total if total > 0 else 0.0
        return (MIN_PART_SHARE <= rows_share <= 1 - MIN_PART_SHARE
                and MIN_ENERGY_SHARE <= share <= 1 - MIN_ENERGY_SHARE)
    late = rows.order >= 0.5
    out["early / late"] = (late, late, late)
    fwd_w, fwd_v = w > 0, v > 0
    if enough(fwd_w, w * w) and enough(fwd_v, v * v):
        out["forward / reverse"] = (fwd_w, fwd_v, fwd_w)
    if _three_magnitudes(moving_v):
        high = np.abs(v) > np.median(moving_v)
        if enough(high, v * v):
            out["low / high drive"] = (high, high, high)
    fast = np.abs(w) > np.median(np.abs(w))
    if enough(fast, w * w):
        out["slow / fast"] = (fast, fast, fast)
    if rows.interval is not None:
        long = rows.interval > np.median(rows.interval[rows.interval > 0])
        if enough(long, v * v):
            out[CLOCK] = (long, long, long)
    return out


#: Residual, relative to the output's RMS, at or below which a fit is exact (rounding, not noise): no test.
EXACT = 1e-9


def _exact(rows: _Rows) -> bool:
    """Whether the model reproduces the data to rounding (:data:`EXACT`)."""
    r = rows.residual
    return bool(np.sqrt(np.mean(r * r)) <= EXACT * rows.output_rms)


def _parted_inputs(rows: _Rows, name: str, masks: tuple[np.ndarray, np.ndarray, np.ndarray]) -> list[np.ndarray]:
    """The inputs of a split's part columns: ``a``, ``b``, the constant (and friction) on part ``S`` only."""
    w, v = rows.speed, rows.drive
    s_a, s_b, s_d = masks
    if name == DRIFT:
        along = rows.order - 0.5                     # the run from -1/2 to 1/2: a and b's trend over it
        s_a = s_b = along
    parted = [-w * s_a, v * s_b]
    if name in CONSTANT_PARTS:
        parted.append(np.ones(len(w)) * s_d)
    if rows.friction and name in FRICTION_PARTS:
        parted.append(-np.sign(w) * s_d)
    return parted


def _check(estimate: Any, fitted: tuple[np.ndarray, np.ndarray, int, np.ndarray, int], p_own: int, name: str,
           level: float) -> PartCheck:
    """One split's test and its parts' values (module docstring) from its fit (:func:`_fit_on`: the model's own
    ``p_own`` columns, then the part's)."""
    from scipy import special
    beta, cov, m, classical, _ = fitted
    a0, b0 = float(estimate.a), float(estimate.b)
    # both must find the difference: the jackknife allows correlated residuals, the classical one a column
    # whose information sits in a few blocks; each standard error below is the larger of the two
    p = max(_joint_p(beta[p_own:], cov[p_own:, p_own:], m), _joint_p(beta[p_own:], classical[p_own:, p_own:], 0))
    # the complement of S takes the base values (the full fit's plus the step's), S those plus its shifts:
    # the shifts of a and b from the full fit, each part's, as one linear map of the step
    ia, ib = p_own, p_own + 1
    unit = np.eye(len(beta))
    if name == DRIFT:          # the trend's values at the run's start and end
        maps = {"a": (unit[0] - 0.5 * unit[ia], unit[0] + 0.5 * unit[ia]),
                "b": (unit[1] - 0.5 * unit[ib], unit[1] + 0.5 * unit[ib])}
    else:
        maps = {"a": (unit[0], unit[0] + unit[ia]), "b": (unit[1], unit[1] + unit[ib])}
    z = float(-special.ndtri(0.025))
    values, intervals, off = {}, {}, False
    for key, full in (("a", a0), ("b", b0)):
        rest, part = maps[key]
        pair = []
        for vec in (rest, part, part - rest):
            shift = float(vec @ beta)
            se = _stderr(vec, fitted)
            # materially off: a part's shift from the full fit, or the parts' difference, is over MATERIAL of the
            # value (the test has found it beyond the noise: within its own interval it is still a model refuted)
            off |= abs(shift) > MATERIAL * abs(full)
            pair.append((full + shift, (full + shift - z * se, full + shift + z * se)))
        values[key], intervals[key] = pair[:2], pair[:2]
    agree = not (math.isfinite(p) and p < level)
    order = (1, 0) if name == "forward / reverse" else (0, 1)     # S is the first part by direction, else the second
    a_pair = (values["a"][order[0]][0], values["a"][order[1]][0])
    b_pair = (values["b"][order[0]][0], values["b"][order[1]][0])
    ai = (intervals["a"][order[0]][1], intervals["a"][order[1]][1])
    bi = (intervals["b"][order[0]][1], intervals["b"][order[1]][1])
    first, second = SPLITS[name]
    hint = "" if agree else _hint(name, a_pair, b_pair, (first, second))
    return PartCheck(name, (first, second), a_pair, b_pair, ai, bi, p, agree, bool(off and not agree), hint)


@dataclasses.dataclass(frozen=True)
class _Moments:
    """Cross-products of every column (scaled to unit norm) and the residual, in all and block by block: what
    each split's fit and its covariances need (:func:`_fit_on`), made in one pass over the rows."""

    scale: np.ndarray           # (K,) the columns' norms
    gram: np.ndarray            # (K, K)
    xr: np.ndarray              # (K,)
    rr: float
    block_gram: np.ndarray      # (m, K, K)
    block_xr: np.ndarray        # (m, K)
    n: int


def _moments(rows: _Rows, xs: Sequence[np.ndarray]) -> _Moments:
    """:class:`_Moments` of the projected responses to the inputs ``xs`` (full length, :func:`_respond` segment by
    segment) and the residual, over the blocks of :func:`identify.default.comparison.block_sums`.

    Made segment by segment in one work array of a segment's rows, each segment's cross-products taken while its
    responses are fresh: the columns are never held for all rows at once (a 6000 x 18 array made, filtered and
    scaled in memory cost more than the arithmetic).  The columns' norms are the square roots of the cross-products'
    diagonal, and the cross-products are scaled by them at the end (:class:`_Moments` holds the unit-norm columns')."""
    from ..comparison import _block_starts
    r = rows.residual
    n, k = len(r), len(xs)
    bounds = np.append(_block_starts(n), n)
    grams = np.zeros((len(bounds) - 1, k, k))
    xr = np.zeros((len(bounds) - 1, k))
    longest = max(hi - lo for lo, hi in rows.bounds)
    inputs = np.empty((k, longest))               # a segment's inputs, one contiguous row each
    out = np.empty((longest, k))                  # its responses, row-major as the filter takes them
    for (lo, hi), respond in zip(rows.bounds, rows.respond):
        for j, x in enumerate(xs):
            inputs[j, :hi - lo] = x[lo:hi]
        X = respond(inputs[:, :hi - lo].T, out=out[:hi - lo])
        # the blocks (or their parts) within this segment
        first = int(np.searchsorted(bounds, lo, side="right")) - 1
        for b in range(first, len(bounds) - 1):
            b_lo, b_hi = max(int(bounds[b]), lo), min(int(bounds[b + 1]), hi)
            if b_lo >= b_hi:
                break
            part = X[b_lo - lo:b_hi - lo]
            grams[b] += part.T @ part
            xr[b] += r[b_lo:b_hi] @ part
    gram = grams.sum(axis=0)
    scale = np.sqrt(np.diagonal(gram).copy())
    scale[scale == 0] = 1.0
    grams /= np.multiply.outer(scale, scale)
    xr /= scale
    return _Moments(scale, grams.sum(axis=0), xr.sum(axis=0), float(r @ r), grams, xr, n)


def _fit_on(mom: _Moments, idx: list[int]) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, int]:
    """Least squares of the residual on the columns ``idx``; the coefficients' cluster-jackknife covariance over
    the ``m`` blocks of consecutive rows (``m`` returned) and their classical covariance (white residuals) with
    its degrees of freedom.

    The blocks are clusters: their scores allow correlated residuals within each.  Each block's score is
    taken with its residual as the fit without that block would leave it (CR3, MacKinnon and Webb 2018:
    ``X_j' (I - H_jj)^-1 r_j``, by Woodbury in the block's ``p x p`` cross-products), so a block that holds
    most of a column's information (a step, a reversal) is not judged by the residual it was fitted to:
    the plain sandwich, fed those residuals, put the variance four times too low on a slow ramp with a
    step.  A block without which a column cannot be fitted at all gives no covariance (infinite).  Where a
    column's information sits in a few blocks the jackknife's own estimate rests on those few and can still
    fall short of the classical one (half of it on a ramp up and down through friction), so the tests use both
    (:func:`_check`).
    """
    rows = np.asarray(idx)
    gram, xr, scale = mom.gram[rows[:, None], rows], mom.xr[rows], mom.scale[rows]     # np.ix_, without its cost
    p = len(idx)
    bread = np.linalg.pinv(gram)
    beta = bread @ xr
    dof = max(mom.n - p, 1)
    rss = max(mom.rr - 2.0 * float(beta @ xr) + float(beta @ gram @ beta), 0.0)
    classical = bread * (rss / dof) / np.outer(scale, scale)
    blocks = mom.block_gram[:, rows][:, :, rows]
    m = len(blocks)
    own = mom.block_xr[:, rows] - np.einsum("mij,j->mi", blocks, beta)
    rest = gram[None] - blocks
    eig = np.linalg.eigvalsh(rest)              # symmetric: the condition from the eigenvalues, no SVD
    if not np.all(eig[:, 0] > 1e-12 * eig[:, -1]):
        return beta / scale, np.full((p, p), math.inf), m, classical, dof
    scores = own + np.einsum("mij,mj->mi", blocks, np.linalg.solve(rest, own[..., None])[..., 0])
    meat = np.einsum("mi,mj->ij", scores, scores) * ((m - 1) / m)
    return beta / scale, bread @ meat @ bread / np.outer(scale, scale), m, classical, dof


def _joint_p(delta: np.ndarray, cov: np.ndarray, m: int) -> float:
    """p-value of Hotelling's ``T^2 = delta' cov^+ delta`` with ``m`` blocks (``m = 0``: a chi-squared test, the
    classical covariance), on the directions ``cov`` resolves (a part column that repeats another's adds no
    degree of freedom)."""
    from scipy import special
    if not (np.all(np.isfinite(delta)) and np.all(np.isfinite(cov))):
        return math.nan
    vals, vecs = np.linalg.eigh(cov)
    keep = vals > 1e-12 * max(float(vals.max(initial=0.0)), 1e-300)
    k = int(np.sum(keep))
    if k == 0 or (m and m <= k):
        return math.nan
    proj = vecs[:, keep].T @ delta
    t2 = float(np.sum(proj * proj / vals[keep]))
    if not m:
        return float(special.chdtrc(k, t2))
    return float(special.fdtrc(k, m - k, t2 * (m - k) / (k * (m - 1))))


def _stderr(vec: np.ndarray, fitted: tuple[np.ndarray, np.ndarray, int, np.ndarray, int]) -> float:
    """Standard error of ``vec @ beta``, a linear map of a check's step (:func:`_fit_on`'s ``beta``): from the larger
    of its jackknife and its classical variance, the jackknife's infinite where its covariance could not be formed
    (any entry not finite).  A variance below zero (rounding) counts as 0; one that is not a number gives a standard
    error that is not one (no interval, never a material shift)."""
    _, cov, _, classical, _ = fitted
    var = float(vec @ classical @ vec)
    jack = float(vec @ cov @ vec) if np.isfinite(cov).all() else math.inf
    if not jack <= var:                 # the larger; a classical variance that is not a number gives way to it
        var = jack
    return math.sqrt(var) if not var < 0 else 0.0


def _hint(name: str, a: tuple[float, float], b: tuple[float, float], parts: tuple[str, str]) -> str:
    """What a disagreement of the parts suggests, in the user's words: the parameter that moved materially
    between them (``b`` first, then ``a``), else the constant acceleration (the only other one tested)."""
    def moved(x: tuple[float, float]) -> float:
        return (x[1] - x[0]) / max(abs(x[0]), abs(x[1]), 1e-300)
    da, db = moved(a), moved(b)
    p, q = parts
    big_a, big_b = abs(da) >= MATERIAL, abs(db) >= MATERIAL
    if name == "early / late":
        if not (big_a or big_b):
            return "a constant torque changes over the run: a load switched on or off?"
        which = [f"{n} {'rises' if d > 0 else 'falls'} from {_g(x[0])} to {_g(x[1])}" for n, d, x, big in
                 (("a", da, a, big_a), ("b", db, b, big_b)) if big]
        return f"{' and '.join(which)} over the run: warming, a load or a setting that changed?"
    if name == CLOCK:
        return ("the data step with the row, not with the clock (a speed or a time column that is not the sample's: "
                "a per-row sum, a rate over another interval, a log's own time?)")
    if name == "forward / reverse":
        if big_b:
            return f"b {p} {_g(b[0])}, {q} {_g(b[1])}: an asymmetric driver or gearbox?"
        if big_a:
            return f"a {p} {_g(a[0])}, {q} {_g(a[1])}: drag or friction that differs by direction?"
        return "a constant torque differs by direction: friction or a load on one side?"
    if name == "low / high drive":
        if big_b:
            why = "the driver clips or limits current?" if db < 0 else "a dead zone or friction the model misses?"
            where = f"b {_g(b[0])} {p}, {_g(b[1])} {q}"
            return f"the gain is {'lower' if db < 0 else 'higher'} at high duty ({where}): {why}"
        if big_a:
            return f"a {_g(a[0])} {p}, {_g(a[1])} {q}: a driver whose response changes with the duty?"
        return "a constant torque that changes with the duty: a nonlinearity in the driver?"
    if big_a:
        return (f"a {_g(a[0])} {p}, {_g(a[1])} {q}: "
                + ("drag that grows with speed?" if da > 0 else "friction that weakens with speed?"))
    if big_b:
        return f"the gain changes with speed (b {_g(b[0])} {p}, {_g(b[1])} {q}): a current limit the model misses?"
    return "friction that changes with speed?"
