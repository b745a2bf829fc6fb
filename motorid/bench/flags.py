"""Argument types of the benchmarks' flags: every count, length and list checked where it is parsed.

Each factory returns an ``argparse`` type whose refusal names the rule and the value
(``argparse`` adds the flag): ``--repeats 0`` is refused as ``must be an integer >= 1, got
'0'`` before any work, instead of failing later with an error about something else.
"""
from __future__ import annotations

import argparse
import math
from typing import Callable

__all__ = ["integer", "real", "integers", "reals"]


def _int(text: str, lo: int) -> int:
    try:
        value = int(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {text!r}") from None
    if value < lo:
        raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {text!r}")
    return value


def _real(text: str, positive: bool) -> float:
    rule = "a finite number > 0" if positive else "a finite number >= 0"
    try:
        value = float(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}") from None
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
    return value


def integer(lo: int = 1) -> Callable[[str], int]:
    """An integer >= ``lo`` (a count: samples, rows, repeats)."""
    def parse(text: str) -> int:
        return _int(text, lo)
    parse.__name__ = "integer"
    return parse


def real(positive: bool = True) -> Callable[[str], float]:
    """A finite number > 0 (or >= 0 when not ``positive``: a length that 0 switches off)."""
    def parse(text: str) -> float:
        return _real(text, positive)
    parse.__name__ = "number"
    return parse


def _listing(item: Callable[[str], object], rule: str, name: str) -> Callable[[str], list]:
    """A comma-separated list of ``item``s, at least one, none empty; ``rule`` says what each must be."""
    def parse(text: str) -> list:
        items = text.split(",")
        if not text.strip() or any(not part.strip() for part in items):
            raise argparse.ArgumentTypeError(f"must be comma-separated {rule}, got {text!r}")
        return [item(part) for part in items]
    parse.__name__ = name
    return parse


def integers(lo: int = 1) -> Callable[[str], list[int]]:
    """A comma-separated list of integers >= ``lo``, at least one."""
    return _listing(lambda part: _int(part, lo), f"integers >= {lo}", "integer list")


def reals(positive: bool = True) -> Callable[[str], list[float]]:
    """A comma-separated list of finite numbers > 0 (>= 0 when not ``positive``), at least one."""
    return _listing(lambda part: _real(part, positive), f"numbers {'>' if positive else '>='} 0", "number list")
