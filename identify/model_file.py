"""The estimate's JSON document: one schema for ``motorid identify --json`` and ``--save``.

:func:`estimate_document` writes it, :func:`read_estimate_document` reads it back (checking
every field, naming the one that is wrong) and :func:`estimate_fields` turns it into the
arguments of :class:`identify.Estimate`.  The document of format ``motorid estimate v2``::

    format, structure, method                 the model structure (identify.structures) and its estimator
    a, b, friction, bias, dead_zone, ...      every parameter of the estimate, at the top level
    input_delay, input_delay_seconds          samples (an integer) and the same in s
    sample_period, input_unit, input_limit    s; the unit of the input; its largest magnitude (or null)
    param_names, covariance                   the covariance's order and rows (null where not finite)
    NAME_stderr, NAME_ci95                    per fitted parameter (the 95 % interval covers model_range)
    static_gain, fit_percent, n_samples, residual_rms, residual_unit, covariance_method
    units (``speed``: the unit of the data, for showing results in it), notes, selection, model_range,
    data_files, feedforward (derived: kS, kV, kA, k0)

Files of the first format (``motorid estimate v1``: further parameters and the delay nested
under ``extra``) are read and migrated; the command line's ``--json`` output of either version
carries the same fields at the same paths as the saved file.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from typing import Any, Mapping

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int, check_real
from motorsim.text import control_characters, printable
from motorsim.units import SPEED_UNITS

__all__ = ["ESTIMATE_FORMAT", "READABLE_FORMATS", "MAX_ESTIMATE_BYTES", "estimate_document",
           "read_estimate_document", "estimate_fields", "json_ready", "file_sha256"]

#: The ``format`` field of the document written.
ESTIMATE_FORMAT = "motorid estimate v2"
#: Every format :func:`read_estimate_document` reads (older ones migrated).
READABLE_FORMATS = ("motorid estimate v1", ESTIMATE_FORMAT)
#: The largest saved estimate read, in bytes (one is about 3 kB).
MAX_ESTIMATE_BYTES = 1 << 20
#: Prefix of the note the document adds for parameters without an interval (derived, not read back).
_MISSING_NOTE = "no interval for "


def estimate_document(est: Any) -> dict:
    """The JSON-ready document of ``est`` (module docstring), non-finite numbers as None."""
    se = est.stderr()
    ci = est.confidence_interval(0.95)
    missing = est.missing_intervals()
    doc: dict[str, Any] = {
        "format": ESTIMATE_FORMAT, "structure": est.structure, "method": est.method, "a": est.a, "b": est.b,
        **est.extra, "input_delay": est.input_delay, "input_delay_seconds": est.input_delay * est.sample_period,
        "static_gain": est.static_gain, "fit_percent": est.fit_percent, "n_samples": est.n_samples,
        "sample_period": est.sample_period, "residual_rms": est.residual_rms, "residual_unit": est.residual_unit,
        "input_unit": est.input_unit, "input_limit": est.input_limit, "counts_per_rev": est.counts_per_rev}
    if est.covariance_method:
        doc["covariance_method"] = est.covariance_method
    doc["param_names"] = list(est.param_names)
    doc["covariance"] = None if est.covariance is None else est.covariance.tolist()
    for name in est.param_names:
        doc[f"{name}_stderr"] = se[name]
        doc[f"{name}_ci95"] = list(ci[name])
    doc["units"] = {**est.model_structure().units(est.input_unit), "input": est.input_unit,
                    "input_delay": "samples", "input_delay_seconds": "s", "sample_period": "s",
                    "residual_rms": est.residual_unit, "speed": getattr(est, "speed_unit", "rad/s")}
    doc["notes"] = list(est.notes) + ([f"{_MISSING_NOTE}{missing}"] if missing else [])
    if est.selection is not None:
        doc["selection"] = est.selection.to_dict()
    if est.model_range:
        doc["model_range"] = {k: list(v) for k, v in est.model_range.items()}
    doc["data_files"] = [{"path": p, "sha256": h} for p, h in est.data_files]
    if est.b != 0 and math.isfinite(est.b):
        from .feedforward import feedforward_constants
        doc["feedforward"] = feedforward_constants(est).to_dict()     # kS, kV, kA: derived, not read back
    return json_ready(doc)


def read_estimate_document(text: str | bytes) -> dict:
    """The document in ``text`` (JSON text, UTF-8 bytes, or the path of a file holding it), its format checked.

    Raises
    ------
    motorsim.checks.ParameterError
        (a ``ValueError``) When the document is not a motorid estimate (``format`` missing or
        another, invalid or binary JSON, nested too deep, over :data:`MAX_ESTIMATE_BYTES`, a
        number that is not finite).
    """
    if not isinstance(text, (str, bytes)):
        raise ParameterTypeError(f"text must be JSON text or the path of a JSON file, got {type(text).__name__}")
    if isinstance(text, bytes):
        text = _decoded(text, "text")
    if not text.lstrip().startswith("{") and os.path.exists(text):
        from motorsim.files import read_input_bytes
        text = _decoded(read_input_bytes(text, what="model", max_bytes=MAX_ESTIMATE_BYTES), text)
    if len(text) > MAX_ESTIMATE_BYTES:
        raise ParameterError(f"an estimate must be at most {MAX_ESTIMATE_BYTES} characters of JSON, "
                             f"got {len(text)}")
    try:
        doc = json.loads(text, parse_constant=_no_constant, parse_float=_finite_float, parse_int=_bounded_int,
                         object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as exc:
        raise ParameterError(f"an estimate must be a JSON document, got invalid JSON ({exc})") from None
    except RecursionError:
        raise ParameterError("an estimate must be a JSON document of a few levels, got one nested "
                             "too deep to read") from None
    if not isinstance(doc, dict) or doc.get("format") not in READABLE_FORMATS:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise ParameterError(f"an estimate must have format {ESTIMATE_FORMAT!r} (or an older "
                             f"{READABLE_FORMATS[:-1]!r}), got {found!r}")
    return doc


def _decoded(data: bytes, name: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterError(f"an estimate must be UTF-8 JSON text; {name} is binary ({exc.reason} at byte "
                             f"{exc.start})") from None


def _no_constant(name: str) -> float:
    raise ParameterError(f"an estimate must hold finite numbers or null, got {name}")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ParameterError(f"an estimate must hold finite numbers, got {text:.40} (beyond a float's range)")
    return value


def _bounded_int(text: str) -> int | float:
    if len(text.lstrip("-")) > 18:      # past int64: a count or delay no estimate holds; a float's range at most
        return _finite_float(text)
    return int(text)


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for key, value in pairs:
        for text in (key, value, *(value if isinstance(value, list) else ())):
            if isinstance(text, str) and control_characters(text):
                raise ParameterError(f"an estimate's text must be printable: field {key!r} holds "
                                     f"{control_characters(text)} (a control character, line break or lone "
                                     f"surrogate), in '{printable(text)[:80]}'")
        if key in doc:
            raise ParameterError(f"an estimate must name each field once, got {key!r} twice")
        doc[key] = value
    return doc


def _units(units: dict) -> dict:
    for key in ("residual_rms", "input", "speed"):
        if not isinstance(units.get(key, ""), str):
            raise ParameterTypeError(f"estimate field 'units.{key}' must be a string, got {units[key]!r:.80}")
        if key in units and not units[key].strip():
            raise ParameterError(f"estimate field 'units.{key}' must name a unit, got {units[key]!r}")
    return units


class _Fields:
    """Typed access to a document's fields, each error naming the field."""

    def __init__(self, doc: Mapping[str, Any]):
        self.doc = doc

    def get(self, name: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        if name not in self.doc:
            if default is ...:
                raise ParameterError(f"an estimate must have the field {name!r}")
            return default
        value = self.doc[name]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if not isinstance(value, kind) or isinstance(value, bool) and bool not in kinds:
            raise ParameterTypeError(f"estimate field {name!r} must be {_kind_name(kind)}, got {value!r:.80}")
        return value

    @staticmethod
    def real(name: str, value: Any, *, finite: bool = True) -> float:
        if value is None and not finite:
            return math.nan
        return check_real(f"estimate field {name!r}", value, finite=finite)


def estimate_fields(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :class:`identify.Estimate` from a document of any readable format."""
    f = _Fields(doc)
    names = f.get("param_names", list, ["a", "b"])
    if not all(isinstance(n, str) for n in names):
        raise ParameterTypeError(f"estimate field 'param_names' must be a list of names, got {names!r:.80}")
    cov = f.get("covariance", (list, type(None)), None)
    if cov is not None:
        if len(cov) != len(names) or not all(isinstance(row, list) and len(row) == len(names) for row in cov):
            raise ParameterError(f"estimate field 'covariance' must be {len(names)} rows of {len(names)} numbers, "
                                 f"got {cov!r:.80}")
        cov = np.array([[f.real("covariance", x, finite=False) for x in row] for row in cov])
    method = f.get("method", str)
    if doc.get("format") == ESTIMATE_FORMAT:
        structure, extra, delay = _parameters_v2(f, method, tuple(names))
    else:
        structure, extra, delay = "", *_parameters_v1(f)
    units = _units(f.get("units", dict, {}))
    files = f.get("data_files", list, [])
    if not all(isinstance(x, dict) and isinstance(x.get("path"), str) and isinstance(x.get("sha256"), str)
               for x in files):
        raise ParameterTypeError(f"estimate field 'data_files' must be a list of {{path, sha256}}, got {files!r:.80}")
    notes = _strings("notes", f.get("notes", list, []))
    return dict(method=method, structure=structure, a=f.real("a", f.get("a", (int, float))),
                b=f.real("b", f.get("b", (int, float))),
                n_samples=check_int("estimate field 'n_samples'", f.get("n_samples", int), lo=0),
                sample_period=check_real("estimate field 'sample_period'", f.get("sample_period", (int, float)),
                                         positive=True),
                residual_rms=f.real("residual_rms", f.get("residual_rms", (int, float, type(None)), None),
                                    finite=False),
                fit_percent=f.real("fit_percent", f.get("fit_percent", (int, float, type(None)), None), finite=False),
                covariance=cov, param_names=tuple(names), extra=extra, input_delay=delay,
                residual_unit=units.get("residual_rms", "rad/s"), input_unit=units.get("input", "duty"),
                data_files=tuple((x["path"], x["sha256"]) for x in files),
                covariance_method=f.get("covariance_method", str, ""),
                selection=_selection(f.get("selection", (dict, type(None)), None)),
                notes=tuple(n for n in notes if not n.startswith(_MISSING_NOTE)),
                model_range=_model_range(f.get("model_range", (dict, type(None)), None) or {}),
                input_limit=_input_limit(f.get("input_limit", (int, float, type(None)), None)),
                speed_unit=_speed_unit(units.get("speed", "rad/s")),
                counts_per_rev=_counts_per_rev(f.get("counts_per_rev", (int, type(None)), None)))


def _parameters_v1(f: _Fields) -> tuple[dict[str, float], int]:
    """``extra`` and the delay of a first-format document (the delay nested in ``extra``)."""
    extra: dict[str, float] = {}
    delay = 0
    for key, value in f.get("extra", dict, {}).items():
        if key == "input_delay":
            delay = check_int("estimate field 'extra.input_delay'", value, lo=0, allow_integral_float=False)
        else:
            extra[key] = f.real(f"extra.{key}", value, finite=False)
    return extra, delay


def _parameters_v2(f: _Fields, method: str, names: tuple[str, ...]) -> tuple[str, dict[str, float], int]:
    """The structure's name, its further parameters (top-level fields) and the delay."""
    from .model_structures import structure, structure_of
    name = f.get("structure", str, "")
    found = structure(name) if name else structure_of(method, names)
    extra = {}
    for key in (*found.param_names[2:], *found.fixed):
        if key in f.doc:
            extra[key] = f.real(key, f.get(key, (int, float, type(None))), finite=False)
    delay = check_int("estimate field 'input_delay'", f.get("input_delay", int, 0), lo=0, allow_integral_float=False)
    return found.name, extra, delay


def _selection(value: dict | None) -> Any:
    """The :class:`identify.SelectionReport` of a document's ``selection`` object (None when absent)."""
    if value is None:
        return None
    from .default.selection_report import SelectionReport
    return SelectionReport.from_dict(value)


def _counts_per_rev(value: int | None) -> int | None:
    return None if value is None else check_int("estimate field 'counts_per_rev'", value, lo=1, hi=2**31 - 1)


def _speed_unit(unit: str) -> str:
    if unit not in SPEED_UNITS:
        raise ParameterError(f"estimate field 'units.speed' must be one of {list(SPEED_UNITS)}, got {unit!r:.40}")
    return unit


def _input_limit(value: Any) -> float | None:
    if value is None:
        return None
    return check_real("estimate field 'input_limit'", value, positive=True)


def _strings(name: str, values: list) -> list[str]:
    if not all(isinstance(v, str) for v in values):
        raise ParameterTypeError(f"estimate field {name!r} must be a list of strings, got {values!r:.80}")
    return values


def _model_range(ranges: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    out = {}
    for key, pair in ranges.items():
        if not (isinstance(pair, list) and len(pair) == 2):
            raise ParameterTypeError(f"estimate field 'model_range.{key}' must be [low, high], got {pair!r:.80}")
        low, high = (math.nan if x is None else check_real(f"estimate field 'model_range.{key}'", x, finite=False)
                     for x in pair)
        out[key] = (low, high)
    return out


def _kind_name(kind: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "an object",
             type(None): "null"}
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if float in kinds:
        kinds = tuple(k for k in kinds if k is not int)
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 hex digest of a file's bytes (the ``data_files`` of an estimate); of a folder (a ROS 2 bag),
    of its regular files' names (relative, sorted) and bytes in turn."""
    digest = hashlib.sha256()
    if os.path.isdir(path):
        root = os.fspath(path)
        found = sorted(os.path.relpath(os.path.join(d, f), root) for d, _, files in os.walk(root) for f in files)
        for name in found:
            full = os.path.join(root, name)
            if os.path.isfile(full) and not os.path.islink(full):
                digest.update(name.encode("utf-8", "surrogateescape") + b"\0" + file_sha256(full).encode() + b"\0")
        return digest.hexdigest()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def json_ready(value):
    """``value`` with every non-finite float (nan, inf) replaced by None, recursively.

    JSON has no nan; ``json.dumps`` would write the invalid token ``NaN``.

    >>> json_ready({"a": float("nan"), "b": [1.0, float("inf")]})
    {'a': None, 'b': [1.0, None]}
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    return value
