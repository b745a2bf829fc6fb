"""Ctrl-C, SIGTERM and SIGHUP: the command unwinds, stops the motor and keeps its data.

Python turns Ctrl-C (SIGINT) into :class:`KeyboardInterrupt`, so every ``finally`` and
``with`` block of a command runs: ``motorid live`` sends STOP, records the device's END
counters and writes its recording; the emulator process is reaped; ``motorid sweep``
removes its unfinished CSV and its worker processes.  By default SIGTERM (``kill``,
systemd, a batch scheduler) and SIGHUP (the terminal closed) end the process at once
and none of that happens.  :func:`signals_as_interrupts` makes all three raise
:class:`Interrupted` (SIGTERM and SIGHUP its subclass :class:`Terminated`), a
``KeyboardInterrupt``, instead.  The command then exits with status 128 + the signal
number (130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP), as the shell reports a process
killed by that signal.  Further SIGTERM/SIGHUPs during the clean-up are ignored (SIGKILL
still ends the process at once); a further Ctrl-C interrupts the clean-up, as it always does.

Two ways the interpreter itself would lose that status are closed here:

* Ctrl-C raises :class:`Interrupted`, a *subclass* of ``KeyboardInterrupt``: a bare
  ``KeyboardInterrupt`` that passes through the interpreter's own code runner (C code that
  runs Python source, met on a rare path at start-up) marks the process as killed by
  Ctrl-C, and the interpreter then ends with the signal (status -2) whatever the command
  returned; it marks only the exact type.
* An interrupt raised inside a weakref callback or a ``__del__`` method (the import system
  runs such callbacks on every import) is swallowed by the interpreter, which prints
  "Exception ignored" with a traceback and carries on.  Within the block such an interrupt
  prints nothing and stays pending: the ``checkpoint`` the block yields raises it, the
  block raises it when it ends, and a further SIGTERM/SIGHUP is not ignored.

What no handler covers is the interpreter's own start-up, before the entry point's first
line runs (``motorid.cli.main`` installs these handlers first of all): a SIGTERM then ends
the process at once (status -15) and a Ctrl-C either does too (-2, before the interpreter
has its own handler) or raises ``KeyboardInterrupt`` with the interpreter's traceback.
"""
from __future__ import annotations

import contextlib
import signal
import sys

TYPE_CHECKING = False      # typing.TYPE_CHECKING without importing typing: this module loads before the command
if TYPE_CHECKING:
    from typing import Any, Callable, Iterator

__all__ = ["Interrupted", "Terminated", "HANDLED_SIGNALS", "signals_as_interrupts", "exit_status",
           "describe_interrupt"]

#: The signals handled like Ctrl-C (those this platform has).
HANDLED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """The process received a signal (SIGINT: Ctrl-C); ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


class Terminated(Interrupted):
    """The process received SIGTERM or SIGHUP; ``signum`` says which."""


def describe_interrupt(exc: BaseException) -> str:
    """How an interruption is named in messages and recordings: ``interrupted (Ctrl-C)`` or ``(SIGTERM)``."""
    if isinstance(exc, Terminated):
        return f"interrupted ({signal.Signals(exc.signum).name})"
    return "interrupted (Ctrl-C)"


def exit_status(exc: KeyboardInterrupt) -> int:
    """The exit status after ``exc``: 128 + the signal number (130 for Ctrl-C, 143 for SIGTERM)."""
    return 128 + (exc.signum if isinstance(exc, Interrupted) else int(signal.SIGINT))


@contextlib.contextmanager
def signals_as_interrupts() -> Iterator[Callable[[], None]]:
    """Within the block, SIGINT raises :class:`Interrupted`, SIGTERM and SIGHUP :class:`Terminated`.

    The first SIGTERM or SIGHUP raises; later ones are ignored while the block unwinds,
    unless the interpreter swallowed the first (module docstring).  An interrupt that does
    not reach the block's end as a ``KeyboardInterrupt`` was lost on the way -- swallowed by
    the interpreter, or turned into another error by an extension's C code (numpy reports
    one that hits its start-up as an ``ImportError``) -- and is raised again: in place of any
    other exception that leaves the block, when the block ends, and by the ``checkpoint()``
    the block gets (call it where an error is reported rather than raised, and wherever
    the work had better stop early).  The previous handlers are restored on exit.  Outside
    the main thread this does nothing (Python delivers signals to the main thread only).
    """
    raised: list[Interrupted] = []          # every interrupt raised in the block, in order
    swallowed: list[Interrupted] = []       # those the interpreter swallowed

    def on_sigint(signum, frame):
        raised.append(Interrupted(signum))
        raise raised[-1]

    def on_termination(signum, frame):
        if any(isinstance(e, Terminated) and e not in swallowed for e in raised):
            return                          # the clean-up of the first one is under way
        raised.append(Terminated(signum))
        raise raised[-1]

    def checkpoint() -> None:
        if raised:
            raise raised[-1]

    previous_hook = sys.unraisablehook

    def unraisable(info) -> None:
        if isinstance(info.exc_value, Interrupted):
            swallowed.append(info.exc_value)    # raised again later; no "Exception ignored" traceback
        else:
            previous_hook(info)

    previous: dict[int, Any] = {}
    try:
        if _install(previous, on_sigint, on_termination):
            sys.unraisablehook = unraisable
        try:
            yield checkpoint
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            if raised:
                raise raised[-1] from exc
            raise
        checkpoint()
    finally:
        if previous:
            sys.unraisablehook = previous_hook
        for signum, handler in previous.items():
            if handler is not None:          # None: a handler not set from Python, which cannot be restored
                signal.signal(signum, handler)


def _install(previous: dict[int, Any], on_sigint: Callable, on_termination: Callable) -> bool:
    """Set the handlers, recording the ones they replace in ``previous``; False outside the main thread."""
    try:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, on_sigint)
    except ValueError:           # not the main thread: Python delivers signals to the main thread only
        return False
    for signum in HANDLED_SIGNALS:
        previous[signum] = signal.signal(signum, on_termination)
    return True
