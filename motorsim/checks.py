"""Argument checks shared by every package: one message format, one rule per check.

Each check returns the value converted to a plain Python type, or raises
:class:`ParameterTypeError` (wrong kind, a ``TypeError``) / :class:`ParameterError`
(wrong value, a ``ValueError``) with a message that
names the parameter, the rule and the value received, e.g.
``"sample_period must be > 0, got -1.0"``.  Booleans are never accepted as numbers.

Examples
--------
>>> check_int("order", 7, lo=2, hi=31)
7
>>> check_real("sample_period", 0.005, positive=True)
0.005
>>> check_real("sample_period", 0, positive=True)
Traceback (most recent call last):
...
motorsim.checks.ParameterError: sample_period must be > 0, got 0.0
"""
from __future__ import annotations

import math
from typing import Any, Collection

import numpy as np

__all__ = ["ParameterError", "ParameterTypeError", "check_int", "check_real", "check_bool", "check_choice",
           "real_array", "is_int", "is_real"]


class ParameterError(ValueError):
    """A parameter's value breaks its rule (the message names the parameter, the rule and the value)."""


class ParameterTypeError(ParameterError, TypeError):
    """A parameter is of the wrong kind; a ``TypeError`` (and a :class:`ParameterError`)."""


def is_int(value: Any) -> bool:
    """True for an int or numpy integer (not a bool)."""
    return not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, np.integer))


def is_real(value: Any) -> bool:
    """True for an int, float or numpy number (not a bool)."""
    return not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.integer, np.floating))


def check_int(name: str, value: Any, lo: int | None = None, hi: int | None = None, *,
              allow_integral_float: bool = True) -> int:
    """``value`` as an int in ``lo ... hi`` (either bound may be None).

    An integral float (``3.0``) is accepted unless ``allow_integral_float`` is False.
    """
    if not is_int(value):
        if allow_integral_float and isinstance(value, (float, np.floating)) and math.isfinite(value) \
                and float(value).is_integer():
            value = int(value)
        else:
            raise ParameterTypeError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if lo is not None and hi is not None and not lo <= value <= hi:
        raise ParameterError(f"{name} must be in {lo}...{hi}, got {value!r}")
    if lo is not None and value < lo:
        raise ParameterError(f"{name} must be >= {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {value!r}")
    return value


def check_real(name: str, value: Any, *, positive: bool = False, nonnegative: bool = False,
               finite: bool = True, below: float | None = None) -> float:
    """``value`` as a float; optionally > 0, >= 0, finite (default) and < ``below``."""
    if not is_real(value):
        raise ParameterTypeError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if finite and not math.isfinite(value):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    if positive and not value > 0:
        raise ParameterError(f"{name} must be > 0, got {value!r}")
    if nonnegative and not value >= 0:
        raise ParameterError(f"{name} must be >= 0, got {value!r}")
    if below is not None and not value < below:
        raise ParameterError(f"{name} must be < {below!r}, got {value!r}")
    return value


def real_array(name: str, value: Any) -> np.ndarray:
    """``value`` as a float array, or :class:`ParameterTypeError` naming ``name`` (not numpy's ``could not convert``).

    Examples
    --------
    >>> real_array("duty", [1, 2.5]).tolist()
    [1.0, 2.5]
    >>> real_array("duty", ["a", "b"])
    Traceback (most recent call last):
    ...
    motorsim.checks.ParameterTypeError: duty must be an array of real numbers, got ['a', 'b']
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        shown = repr(value)
        raise ParameterTypeError(f"{name} must be an array of real numbers, got "
                                 f"{shown if len(shown) <= 80 else shown[:77] + '...'}") from None
    return arr


def check_bool(name: str, value: Any) -> bool:
    """``value`` as a bool (only ``True``/``False`` and numpy bools are accepted)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterTypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_choice(name: str, value: Any, choices: Collection[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    if value not in choices:
        raise ParameterError(f"{name} must be one of {sorted(map(str, choices))}, got {value!r}")
    return value
