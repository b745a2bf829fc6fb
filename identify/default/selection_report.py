"""``SelectionReport``: how the default estimator chose its model, as kept with the estimate.

:func:`identify.default.selection.fit_selected` compares candidate models (a structure at an input
delay, :mod:`identify.comparison`) and returns the chosen one's :class:`identify.Estimate`; its
``selection`` field is a :class:`SelectionReport`: every candidate with its fit and score
(:class:`CandidateReport`), the chosen one, the best, the runner-up, whether the choice was
clear and the doubt when it was not.  It is a record of what was compared, independent of the
structures registered now, so a saved estimate reads back unchanged (:meth:`SelectionReport.to_dict`
writes the ``selection`` object of the estimate's JSON document, :meth:`SelectionReport.from_dict`
reads it, each wrong field named).  The range of ``a`` and ``b`` over the candidates the data
cannot rule out is the estimate's own ``model_range``.
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, Mapping, Sequence, TypeVar

from motorsim.checks import ParameterError, ParameterTypeError

if TYPE_CHECKING:
    from ..comparison import Candidate, Selection

__all__ = ["CandidateReport", "SelectionReport", "PartCheck", "doubted", "BLIND", "blind_check", "widened_range"]


@dataclasses.dataclass(frozen=True)
class CandidateReport:
    """One candidate model the selection fitted (or failed to fit), and how it scored.

    Attributes
    ----------
    structure : str
        The structure's name (:func:`identify.structures`).
    input_delay : int
        Samples.
    method : str
        The estimator that fits it (``fit(recordings, method, input_delay=...)`` reproduces it).
    a, b : float
        Its fit on the rows all candidates share (nan when it failed).
    residual_sum : float
        Its residual sum of squares on those rows (nan when it failed).
    statistic : float
        The test statistic against the best candidate (0 for the best itself, nan when not scored).
    within_noise : bool
        Whether the data cannot tell it from the best.
    note : str
        Why it failed, when it did ("" otherwise).
    """

    structure: str
    input_delay: int
    method: str
    a: float
    b: float
    residual_sum: float
    statistic: float
    within_noise: bool
    note: str = ""

    @property
    def label(self) -> str:
        """``"STRUCTURE, delay N"``."""
        return f"{self.structure}, delay {self.input_delay}"

    @classmethod
    def from_candidate(cls, c: Candidate) -> CandidateReport:
        """The report of a scored :class:`identify.comparison.Candidate`."""
        return cls(structure=c.structure, input_delay=c.input_delay, method=c.method, a=c.a, b=c.b,
                   residual_sum=c.residual_sum, statistic=c.statistic, within_noise=c.within_noise, note=c.note)

    def to_dict(self) -> dict:
        """JSON-ready, non-finite numbers kept as they are (the estimate's document writes them as null)."""
        return {"structure": self.structure, "input_delay": self.input_delay, "method": self.method,
                "a": self.a, "b": self.b, "residual_sum": self.residual_sum, "statistic": self.statistic,
                "within_noise": self.within_noise, **({"note": self.note} if self.note else {})}

    @classmethod
    def from_dict(cls, d: Any, where: str = "selection.candidate") -> CandidateReport:
        """The candidate of a document's ``selection`` (``where`` names it in errors)."""
        f = _Checked(d, where)
        return cls(structure=f.text("structure"), input_delay=f.integer("input_delay"), method=f.text("method"),
                   a=f.real("a"), b=f.real("b"), residual_sum=f.real("residual_sum"), statistic=f.real("statistic"),
                   within_noise=f.flag("within_noise"), note=f.text("note", ""))


@dataclasses.dataclass(frozen=True)
class SelectionReport:
    """What the default estimator compared and chose (:func:`identify.default.selection.fit_selected`).

    Attributes
    ----------
    chosen : CandidateReport
        The simplest candidate within the noise of the best: the estimate's model.
    best : CandidateReport
        The candidate with the least residual sum.
    runner_up : CandidateReport or None
        The next simplest candidate within the noise (else the best of the others).
    clear : bool
        False when candidates the data cannot separate give materially different ``a`` or ``b``,
        or the choice is otherwise in doubt (``doubt`` says why).
    doubt : str
        One line saying what the data cannot separate, the range and what would separate it ("" when clear).
    notes : tuple of str
        What the data cannot answer, and what the selection left out and why.
    candidates : tuple of CandidateReport
        Every candidate fitted, in the order tried.
    level : float
        Level of the test that calls a candidate worse than the best.
    criterion : str
        The rule of the choice, in words.
    checks : tuple of PartCheck
        The chosen model's ``a`` and ``b`` on parts of the recording (early and late, forward and reverse, low
        and high drive, slow and fast: :mod:`identify.default.consistency`); a material disagreement makes the choice
        unclear.

    Examples
    --------
    >>> from identify import fit
    >>> from motorsim import Experiment, Motor, Multisine, SimRig
    >>> rec = SimRig(Motor(25.0, 3.0)).run(
    ...     Experiment(Multisine((5.0, 17.0, 41.0), (60, 60, 50), (0, 1, 2)), 0.005, 4.0))
    >>> report = fit(rec).selection
    >>> report.chosen.label, report.clear, report.chosen in report.candidates
    ('linear, delay 0', True, True)
    """

    chosen: CandidateReport
    best: CandidateReport
    runner_up: CandidateReport | None
    clear: bool
    doubt: str
    notes: tuple[str, ...]
    candidates: tuple[CandidateReport, ...]
    level: float
    criterion: str = "simplest candidate within the noise of the best (batch-means test)"
    checks: tuple[PartCheck, ...] = ()

    @classmethod
    def from_selection(cls, selection: Selection) -> SelectionReport:
        """The report of an :class:`identify.comparison.Selection`."""
        runner_up = selection.runner_up
        return cls(chosen=CandidateReport.from_candidate(selection.chosen),
                   best=CandidateReport.from_candidate(selection.best),
                   runner_up=None if runner_up is None else CandidateReport.from_candidate(runner_up),
                   clear=selection.clear, doubt=selection.doubt, notes=tuple(selection.notes),
                   candidates=tuple(CandidateReport.from_candidate(c) for c in selection.candidates),
                   level=selection.level, criterion=selection.criterion)

    def to_dict(self) -> dict:
        """The ``selection`` object of the estimate's JSON document (non-finite numbers kept as they are)."""
        return {"criterion": self.criterion, "level": self.level, "chosen": self.chosen.to_dict(),
                "best": self.best.to_dict(),
                "runner_up": None if self.runner_up is None else self.runner_up.to_dict(),
                "clear": self.clear, "doubt": self.doubt, "notes": list(self.notes),
                "candidates": [c.to_dict() for c in self.candidates],
                **({"checks": [c.to_dict() for c in self.checks]} if self.checks else {})}

    @classmethod
    def from_dict(cls, d: Any) -> SelectionReport:
        """The report of a document's ``selection`` object (null numbers read as nan).

        Raises
        ------
        motorsim.checks.ParameterError
            (a ``ValueError``; ``ParameterTypeError`` for the wrong kind) naming the field that is
            missing or wrong, e.g. ``selection.chosen.input_delay``.
        """
        f = _Checked(d, "selection")
        raw = f.get("candidates", list)
        runner_up = f.get("runner_up", (dict, type(None)))
        return cls(chosen=CandidateReport.from_dict(f.get("chosen", dict), "selection.chosen"),
                   best=CandidateReport.from_dict(f.get("best", dict), "selection.best"),
                   runner_up=None if runner_up is None else CandidateReport.from_dict(runner_up, "selection.runner_up"),
                   clear=f.flag("clear"), doubt=f.text("doubt"), notes=tuple(f.texts("notes")),
                   candidates=tuple(CandidateReport.from_dict(c, f"selection.candidates[{i}]")
                                    for i, c in enumerate(raw)),
                   level=f.real("level"), criterion=f.text("criterion"),
                   checks=tuple(PartCheck.from_dict(c, f"selection.checks[{i}]")
                                for i, c in enumerate(f.get("checks", list, []))))


@dataclasses.dataclass(frozen=True)
class PartCheck:
    """One split of the rows into two parts, and whether the chosen model's ``a`` and ``b`` agree on them.

    Attributes
    ----------
    split : str
        Its name (a key of :data:`identify.default.consistency.SPLITS`).
    parts : tuple of str
        The two parts' names.
    a, b : tuple of float
        ``a`` (1/s) and ``b`` on each part (one Gauss--Newton step of per-part parameters from the full fit).
    a_interval, b_interval : tuple of (float, float)
        Their 95 % intervals, part by part.
    p_value : float
        Of the test that the parts share ``a``, ``b`` and the constant acceleration.
    agree : bool
        ``p_value`` at or above the level.
    material : bool
        A part's ``a`` or ``b`` differs from the full fit's by more than :data:`~identify.comparison.MATERIAL`
        (relative): disagreement that makes the choice unclear.
    hint : str
        What the difference suggests, in words ("" when the parts agree).
    """

    split: str
    parts: tuple[str, str]
    a: tuple[float, float]
    b: tuple[float, float]
    a_interval: tuple[tuple[float, float], tuple[float, float]]
    b_interval: tuple[tuple[float, float], tuple[float, float]]
    p_value: float
    agree: bool
    material: bool
    hint: str = ""

    def describe(self) -> str:
        """One line: the split, each part's ``a`` and ``b``, the p-value and the verdict."""
        (p, q) = self.parts
        if not math.isfinite(self.p_value):
            # no covariance: a part's information sits in one block of rows (a single step), so no test
            return f"{self.split}: not testable on this run (a part's information sits in one stretch of rows)"
        verdict = "agree" if self.agree else "DIFFER" + (f": {self.hint}" if self.hint else "")
        return (f"{self.split}: a {_g(self.a[0])} {p}, {_g(self.a[1])} {q}; b {_g(self.b[0])} {p}, "
                f"{_g(self.b[1])} {q} (p = {self.p_value:.2g}) {verdict}")

    def to_dict(self) -> dict:
        """The check's object in ``selection.checks`` of the estimate's JSON document."""
        return {"split": self.split, "parts": list(self.parts), "a": list(self.a), "b": list(self.b),
                "a_interval": [list(x) for x in self.a_interval], "b_interval": [list(x) for x in self.b_interval],
                "p_value": self.p_value, "agree": self.agree, "material": self.material, "hint": self.hint}

    @classmethod
    def from_dict(cls, d: Any, where: str = "selection.checks") -> PartCheck:
        """The check of a document's object (``where`` names it in errors)."""
        f = _Checked(d, where)

        def pair(name: str) -> tuple[float, float]:
            values = f.get(name, list)
            if len(values) != 2 or not all(v is None or isinstance(v, (int, float)) and not isinstance(v, bool)
                                           for v in values):
                raise _bad(where, name, "a list of two numbers", values)
            return tuple(math.nan if v is None else float(v) for v in values)  # type: ignore[return-value]

        def intervals(name: str) -> tuple[tuple[float, float], tuple[float, float]]:
            values = f.get(name, list)
            if len(values) != 2:
                raise _bad(where, name, "a list of two intervals", values)
            out = []
            for v in values:
                if not (isinstance(v, list) and len(v) == 2 and all(
                        x is None or isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
                    raise _bad(where, name, "a list of two intervals", values)
                out.append(tuple(math.nan if x is None else float(x) for x in v))
            return out[0], out[1]  # type: ignore[return-value]

        parts = f.texts("parts")
        if len(parts) != 2:
            raise _bad(where, "parts", "a list of two names", parts)
        return cls(split=f.text("split"), parts=(parts[0], parts[1]), a=pair("a"), b=pair("b"),
                   a_interval=intervals("a_interval"), b_interval=intervals("b_interval"),
                   p_value=f.real("p_value"), agree=f.flag("agree"), material=f.flag("material"),
                   hint=f.text("hint", ""))


_Doubted = TypeVar("_Doubted", "Selection", "SelectionReport")


def doubted(selection: _Doubted, doubt: str, otherwise: str = "") -> _Doubted:
    """``selection`` (a :class:`SelectionReport` or the selection it is made from) not clear, ``doubt`` said before
    the doubt it had (or, where it had none, before ``otherwise``), the two joined by ``"; "``."""
    rest = selection.doubt or otherwise
    return dataclasses.replace(selection, clear=False, doubt=f"{doubt}; {rest}" if rest else doubt)


def _bad(where: str, name: str, rule: str, value: Any) -> Exception:
    return ParameterError(f"estimate field '{where}.{name}' must be {rule}, got {value!r:.80}")


def _g(x: float) -> str:
    return f"{x:.4g}"


class _Checked:
    """The fields of one JSON object, each read with its kind checked and named in the error."""

    def __init__(self, d: Any, where: str):
        if not isinstance(d, Mapping):
            raise ParameterTypeError(f"estimate field {where!r} must be an object, got {d!r:.80}")
        self.d, self.where = d, where

    def get(self, name: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        if name not in self.d:
            if default is ...:
                raise ParameterError(f"estimate field {self.where!r} must have {name!r}")
            return default
        value = self.d[name]
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise ParameterTypeError(f"estimate field '{self.where}.{name}' must be {_kind(kind)}, got {value!r:.80}")
        return value

    def real(self, name: str) -> float:
        value = self.get(name, (int, float, type(None)))
        return math.nan if value is None else float(value)

    def integer(self, name: str) -> int:
        value = self.get(name, int)
        if value < 0:
            raise ParameterError(f"estimate field '{self.where}.{name}' must be >= 0, got {value}")
        return value

    def flag(self, name: str) -> bool:
        return self.get(name, bool)

    def text(self, name: str, default: Any = ...) -> str:
        return self.get(name, str, default)

    def texts(self, name: str) -> list[str]:
        values = self.get(name, list)
        if not all(isinstance(v, str) for v in values):
            raise ParameterTypeError(f"estimate field '{self.where}.{name}' must be a list of strings, "
                                     f"got {values!r:.80}")
        return values


def _kind(kind: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "an object",
             bool: "true or false", type(None): "null"}
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if float in kinds:
        kinds = tuple(k for k in kinds if k is not int)
    return " or ".join(names.get(k, k.__name__) for k in kinds)


#: Smallest difference between a check's two parts, relative to the answer's value, that the check must be able to
#: find (its 95 % half-width) for it to vouch for the answer.  A check blind to a larger one passes a model that
#: misfits by that much as readily as a right one: on the random rigs past our structures whose answers were clear
#: and wrong on a 12-48 count encoder or under Stribeck's friction, the blindest check could not tell its parts
#: apart by 68-380 % of the value; on the right-model classes of ``motorid bench coverage`` it always could by 2 %.
BLIND = 0.5


def blind_check(checks: Sequence[PartCheck], a: float, b: float) -> tuple[PartCheck, str, float] | None:
    """The check least able to tell its parts apart, if it cannot by :data:`BLIND` of ``a`` or ``b``: the check,
    the parameter and the 95 % half-width of its parts' difference relative to the value (the parts' own
    half-widths in quadrature; infinite where a part has no finite interval).  ``None`` where every check can.  A
    check whose test could not be formed (its p-value not a number: a split whose part columns repeat the model's
    own, as by direction under a binary input) is no check and is not counted."""
    worst: tuple[PartCheck, str, float] | None = None
    for check in checks:
        if not math.isfinite(check.p_value):
            continue
        for name, intervals, value in (("a", check.a_interval, a), ("b", check.b_interval, b)):
            halves = [(x1 - x0) / 2 for x0, x1 in intervals]
            if not value:
                continue
            width = (math.hypot(*halves) / abs(value) if all(math.isfinite(h) for h in halves) else math.inf)
            if width > BLIND and (worst is None or width > worst[2]):
                worst = (check, name, width)
    return worst


def widened_range(ranges: Mapping[str, tuple[float, float]],
                  checks: Sequence[PartCheck]) -> dict[str, tuple[float, float]]:
    """``ranges`` (``a`` and ``b`` intervals) widened to hold every disagreeing part's own 95 % interval."""
    out = dict(ranges)
    for check in checks:
        if check.agree:
            continue
        for name, intervals in (("a", check.a_interval), ("b", check.b_interval)):
            lo, hi = out[name]
            for x0, x1 in intervals:
                if math.isfinite(x0) and math.isfinite(x1):
                    lo, hi = min(lo, x0), max(hi, x1)
            out[name] = (lo, hi)
    return out
