"""A tiny progress bar on stderr (quiet when stderr is not a terminal, or when asked)."""
from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["ProgressBar"]


class ProgressBar:
    """``label [#####.....] done/total unit, elapsed, ETA`` redrawn in place.

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
    """

    def __init__(self, total: int, label: str = "", *, unit: str = "points", stream: TextIO | None = None,
                 enabled: bool | None = None):
        self.total = max(int(total), 0)
        self.label = label
        self.unit = unit
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.done = 0
        self._start = time.monotonic()
        self._last = -1.0

    def __enter__(self) -> "ProgressBar":
        self._draw(force=True)
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, steps: int = 1) -> None:
        """Advance by ``steps`` and redraw (at most ten times a second)."""
        self.done += steps
        self._draw(force=self.done >= self.total)

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
        if not force and now - self._last < 0.1:
            return
        self._last = now
        elapsed = now - self._start
        frac = self.done / self.total if self.total else 1.0
        width = 30
        fill = int(round(frac * width))
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        eta_text = f", ETA {eta:.0f} s" if frac < 1 and frac > 0 else ""
        self.stream.write(f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
                          f"{self.unit}, {elapsed:.0f} s{eta_text}  ")
        self.stream.flush()
