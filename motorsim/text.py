"""Text that came from a file or a device, made safe to print and to write back.

A unit, a column name, a scenario's name or a board name is data: printed raw, an escape
sequence in it can retitle or clear a terminal, a carriage return can overwrite what was
printed, a newline can forge a line of output, a lone surrogate stops the printing with an
encoding error.  :func:`printable` spells every such character as a Python escape
(``\\x1b``, ``\\r``, ``\\udc80``), so what reaches a terminal or a file is exactly what was
read, made visible.  :func:`control_characters` lists them, for the checks that refuse them.
"""
from __future__ import annotations

import re

__all__ = ["printable", "control_characters", "UNSAFE"]

#: Characters never printed raw: C0 controls but tab and newline, DEL, C1 controls, the line and
#: paragraph separators, the bidirectional overrides and isolates, lone surrogates.
UNSAFE = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069\ud800-\udfff]")
_UNSAFE_KEEPING_NEWLINES = re.compile(UNSAFE.pattern.replace("\x0a-\x1f", "\x0b-\x1f"))


def _escape(match: re.Match) -> str:
    code = ord(match.group())
    if code in (0x0a, 0x0d):
        return "\\n" if code == 0x0a else "\\r"
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def printable(text: str, *, newlines: bool = False) -> str:
    """``text`` with every character of :data:`UNSAFE` spelled as its escape; tabs kept.

    Parameters
    ----------
    text : str
    newlines : bool
        Keep ``\\n`` (text motorid itself laid out in lines); else a newline is escaped too.

    Examples
    --------
    >>> printable("rad/s\\x1b[2J\\r\\nforged")
    'rad/s\\\\x1b[2J\\\\r\\\\nforged'
    >>> printable("two\\nlines\\ud800", newlines=True)
    'two\\nlines\\\\ud800'
    """
    return (_UNSAFE_KEEPING_NEWLINES if newlines else UNSAFE).sub(_escape, text)


def control_characters(text: str) -> str:
    """The characters of ``text`` that :func:`printable` escapes (none: ``""``), each spelled as its escape."""
    return "".join(printable(c) for c in dict.fromkeys(UNSAFE.findall(text)))
