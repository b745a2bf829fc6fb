"""Progress on stderr: the bar of every long command (``sweep``, ``live``, ``demo``) and the
elapsed-time line of one long call (an ``oe-friction`` fit, a benchmark section).

Quiet when stderr is not a terminal, or when asked.
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Callable, TextIO, Union

Note = Union[str, Callable[[], str]]

__all__ = ["ProgressBar", "Ticker"]


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


def _on_terminal(stream: TextIO) -> bool:
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


class _ClearingStdout:
    """Standard output that first wipes the ticker's line, so a table printed meanwhile stays whole."""

    def __init__(self, ticker: "Ticker", real: TextIO):
        self._ticker = ticker
        self._real = real

    def write(self, text: str) -> int:
        with self._ticker.lock:
            self._ticker.clear_line()
            self._ticker.line_open = not text.endswith("\n")
            return self._real.write(text)

    def __getattr__(self, name):
        return getattr(self._real, name)


class Ticker:
    """``label, 12 s  note`` redrawn in place while one long call runs, which reports no steps.

    Used as a context manager around the call.  Draws first after ``delay`` s (short calls
    stay silent), then every ``interval`` s from a background thread; the line is wiped on
    exit.  While it runs, standard output is wrapped so that whatever is printed first wipes
    the line (tables stay intact on a terminal).

    Parameters
    ----------
    label : str
        What runs (``"identify: oe-friction fit"``).
    stream : file, optional
        Where to draw (default ``sys.stderr``).
    enabled : bool, optional
        Force on or off; default: on only when ``stream`` is a terminal.
    delay : float
        Seconds before the first line (0 draws on entry).
    interval : float
        Seconds between redraws.
    """

    def __init__(self, label: str, *, stream: TextIO | None = None, enabled: bool | None = None,
                 delay: float = 1.0, interval: float = 0.5):
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.enabled = _on_terminal(self.stream) if enabled is None else enabled
        self.delay = float(delay)
        self.interval = float(interval)
        self.note = ""
        self.lock = threading.Lock()
        self.line_open = False        # standard output left a line unfinished: do not draw over it
        self._drawn = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._stdout: TextIO | None = None
        self._start = time.monotonic()

    def __enter__(self) -> "Ticker":
        self._start = time.monotonic()
        if not self.enabled:
            return self
        if sys.stdout is not self.stream:
            self._stdout = sys.stdout
            sys.stdout = _ClearingStdout(self, sys.stdout)
        if self.delay <= 0:
            self.draw()
        self._thread = threading.Thread(target=self._run, name="motorid-ticker", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        with self.lock:
            self.clear_line()
        if self._stdout is not None:
            sys.stdout = self._stdout
            self._stdout = None

    def set_note(self, note: str) -> None:
        """Text after the elapsed time, shown at the next redraw (``"section 3 of 5"``)."""
        self.note = note

    def draw(self) -> None:
        """Redraw the line now (unless standard output left a line unfinished)."""
        with self.lock:
            if self.line_open:
                return
            elapsed = time.monotonic() - self._start
            self.stream.write(f"\r\033[K{self.label}, {elapsed:.0f} s  {self.note}".rstrip())
            self.stream.flush()
            self._drawn = True

    def clear_line(self) -> None:
        """Wipe the drawn line (call with :attr:`lock` held)."""
        if self._drawn:
            self.stream.write("\r\033[K")
            self.stream.flush()
            self._drawn = False

    def _run(self) -> None:
        if self._stop.wait(self.delay if self.delay > 0 else self.interval):
            return
        while True:
            self.draw()
            if self._stop.wait(self.interval):
                return
