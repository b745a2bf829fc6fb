"""What ``motorid`` prints reaches the terminal as text, whatever the files held and whatever the locale.

- Standard output passes through :func:`motorsim.text.printable` (newlines kept): a control
  character that came from a file (a unit, a column, a scenario's or a board's name) is printed
  as its escape, never sent raw to the terminal.  Lines on standard error are made printable
  where they are written (``motorid: error:``, notes, warnings), the progress bar's own
  control sequences untouched.
- Under a locale whose encoding cannot spell motorid's own characters (``LC_ALL=C`` with
  ``PYTHONUTF8=0``: ASCII), they are written in ASCII (``ω`` as ``w``, ``±`` as ``+-``,
  ``µ`` as ``u``, ``²`` as ``^2``); anything else as its ``\\u`` escape, never an encoding error.
"""
from __future__ import annotations

import codecs
import contextlib
import sys
from typing import Any, Iterator, TextIO

__all__ = ["printable_output", "ERRORS", "ASCII_SPELLINGS"]

#: The name of the codec error handler that writes :data:`ASCII_SPELLINGS`.
ERRORS = "motorid-ascii"

#: motorid's own non-ASCII characters, as they are written where the terminal's encoding lacks them.
ASCII_SPELLINGS = {"ω": "w", "Ω": "Ohm", "±": "+-", "µ": "u", "μ": "u", "°": "deg", "²": "^2", "³": "^3",
                   "×": "x", "·": "*", "—": "-", "–": "-", "…": "...", "≤": "<=", "≥": ">=", "≈": "~",
                   "≠": "!=", "→": "->", "←": "<-", "√": "sqrt", "∞": "inf", "Δ": "D", "τ": "tau",
                   "α": "alpha", "λ": "lambda", "σ": "sigma", "é": "e", "è": "e", "ü": "u", "ö": "o",
                   "✓": "ok", "✗": "x", "−": "-", "’": "'", "‘": "'", "“": '"', "”": '"'}


def _ascii_spelling(exc: UnicodeError) -> tuple[str, int]:
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    text = exc.object[exc.start:exc.end]
    return "".join(ASCII_SPELLINGS.get(c) or (f"\\x{ord(c):02x}" if ord(c) < 0x100 else f"\\u{ord(c):04x}")
                   for c in text), exc.end


codecs.register_error(ERRORS, _ascii_spelling)


def _lacks_own_characters(stream: Any) -> bool:
    encoding = getattr(stream, "encoding", None)
    if not encoding:
        return False
    try:
        "ω±µ°²×—é".encode(encoding)
    except (UnicodeEncodeError, LookupError):
        return True
    return False


class _PrintableStdout:
    """A text stream writing :func:`motorsim.text.printable` of what it is given (newlines kept)."""

    def __init__(self, stream: TextIO):
        from motorsim.text import printable
        self._stream = stream
        self._printable = printable

    def write(self, text: str) -> int:
        self._stream.write(self._printable(text, newlines=True))
        return len(text)

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextlib.contextmanager
def printable_output() -> Iterator[None]:
    """Within the block, standard output is printable and both streams write in any locale."""
    changed = []
    for stream in (sys.stdout, sys.stderr):
        if _lacks_own_characters(stream) and hasattr(stream, "reconfigure"):
            with contextlib.suppress(Exception):
                old = stream.errors
                stream.reconfigure(errors=ERRORS)
                changed.append((stream, old))
    original = sys.stdout
    if original is not None:
        sys.stdout = _PrintableStdout(original)
    try:
        yield
    finally:
        if sys.stdout is not original and isinstance(sys.stdout, _PrintableStdout):
            sys.stdout = original
        for stream, old in changed:
            with contextlib.suppress(Exception):
                stream.reconfigure(errors=old)
