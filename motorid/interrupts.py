"""SIGTERM and SIGHUP handled as Ctrl-C is: the command unwinds, stops the motor and keeps its data.

Python turns Ctrl-C (SIGINT) into :class:`KeyboardInterrupt`, so every ``finally`` and
``with`` block of a command runs: ``motorid live`` sends STOP, records the device's END
counters and writes its recording; the emulator process is reaped; ``motorid sweep``
removes its unfinished CSV and its worker processes.  By default SIGTERM (``kill``,
systemd, a batch scheduler) and SIGHUP (the terminal closed) end the process at once
and none of that happens.  :func:`signals_as_interrupts` makes them raise
:class:`Terminated`, a ``KeyboardInterrupt``, instead.  The command then exits with
status 128 + the signal number (143 for SIGTERM, 129 for SIGHUP), as the shell reports
a process killed by that signal.  Further SIGTERM/SIGHUPs during the clean-up are
ignored (SIGKILL still ends the process at once).
"""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator

__all__ = ["Terminated", "HANDLED_SIGNALS", "signals_as_interrupts", "exit_status",
           "describe_interrupt"]

#: The signals handled like Ctrl-C (those this platform has).
HANDLED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM or SIGHUP; ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


def describe_interrupt(exc: BaseException) -> str:
    """How an interruption is named in messages and recordings: ``interrupted (Ctrl-C)`` or ``(SIGTERM)``."""
    if isinstance(exc, Terminated):
        return f"interrupted ({signal.Signals(exc.signum).name})"
    return "interrupted (Ctrl-C)"


def exit_status(exc: KeyboardInterrupt) -> int:
    """The exit status after ``exc``: 128 + the signal number (130 for Ctrl-C, 143 for SIGTERM)."""
    return 128 + (exc.signum if isinstance(exc, Terminated) else int(signal.SIGINT))


@contextlib.contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated` in the main thread.

    The first such signal raises; later ones are ignored while the block unwinds.  The
    previous handlers are restored on exit.  Outside the main thread this does nothing
    (Python delivers signals to the main thread only).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def handler(signum, frame):
        if received:
            return
        received.append(signum)
        raise Terminated(signum)

    previous = {s: signal.signal(s, handler) for s in HANDLED_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
