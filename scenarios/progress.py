"""The progress bar of every long command (``sweep``, ``live``) on stderr.

Quiet when stderr is not a terminal, or when asked.
"""
from __future__ import annotations

import sys
import time
from typing import Callable, TextIO, Union

Note = Union[str, Callable[[], str]]

__all__ = ["ProgressBar"]


class ProgressBar:
    """``label [#####.....] done/total unit, elapsed, ETA  note`` redrawn in place.

    Parameters
    ----------
    total : int
        Number of steps.
    label : str
        Text before the bar.
    unit : str
        What a step is (``points``).
    stream : file, optional
        Where to draw (default ``sys.stderr``).
    enabled : bool, optional
        Force on or off; default: on only when ``stream`` is a terminal.
    interval : float
        Shortest time between two redraws in s (default 0.1).
    """

    def __init__(self, total: int, label: str = "", *, unit: str = "points", stream: TextIO | None = None,
                 enabled: bool | None = None, interval: float = 0.1):
        self.total = max(int(total), 0)
        self.label = label
        self.unit = unit
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.done = 0
        self.note: Note = ""
        self.interval = interval
        self._start = time.monotonic()
        self._last = -1.0

    def __enter__(self) -> "ProgressBar":
        self._draw(force=True)
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, steps: int = 1, note: Note | None = None) -> None:
        """Advance by ``steps`` and redraw (at most once per ``interval``).

        ``note`` follows the bar: a string, or a function called only when the bar is redrawn.
        """
        self.set(self.done + steps, note)

    def set(self, done: int, note: Note | None = None, *, force: bool = False) -> None:
        """Set the steps done (and the note) and redraw (at most once per ``interval`` unless ``force``)."""
        self.done = done
        if note is not None:
            self.note = note
        self._draw(force=force or self.done >= self.total)

    def close(self) -> None:
        """Finish the line."""
        if self.enabled:
            self._draw(force=True)
            self.stream.write("\n")
            self.stream.flush()
            self.enabled = False

    def _draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < self.interval:
            return
        self._last = now
        elapsed = now - self._start
        frac = self.done / self.total if self.total else 1.0
        width = 30
        fill = int(round(frac * width))
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        eta_text = f", ETA {eta:.0f} s" if frac < 1 and frac > 0 else ""
        note = self.note() if callable(self.note) else self.note
        self.stream.write(f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
                          f"{self.unit}, {elapsed:.0f} s{eta_text}  {note}")
        self.stream.flush()
