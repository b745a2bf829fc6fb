"""The ``motorid`` command line.

:data:`COMMANDS` maps each sub-command to a :class:`Command`: its one-line help and a
loader that imports the command's module when the parser is built and returns its
``add_arguments(parser)`` and ``run(args) -> int``.  Modules import their heavy
dependencies (matplotlib, python-control) inside ``run`` only.  Add a command by
writing its module and adding one entry.  Flags shared by several commands live in
:mod:`motorid.arguments`.

Error contract.  Errors a user can fix (:func:`user_error_types`: bad flags, bad
files, a scenario that breaks a rule, data that cannot identify the motor, a device
that misbehaves, a path that cannot be read or written) print one line
``motorid: error: ...`` naming the file, line or flag and the rule, and exit with
status 2.  Any other exception is a bug, never disguised as a user error: one line
``motorid: internal error: ...`` asks to re-run with ``--traceback`` (which prints the
traceback), and the status is 1.  Ctrl-C, SIGTERM and SIGHUP unwind the command (STOP
sent, data kept) and exit with 128 + the signal number (:mod:`motorid.interrupts`).
"""
from __future__ import annotations

import sys

TYPE_CHECKING = False      # typing.TYPE_CHECKING without importing typing, which would cost 2.5 ms at start-up
if TYPE_CHECKING:
    import argparse
    from typing import Callable, Sequence

    AddArguments = Callable[[argparse.ArgumentParser], None]
    Run = Callable[[argparse.Namespace], int]

# Nothing else at import: main() installs the signal handlers before anything heavier loads.

__all__ = ["main", "build_parser", "COMMANDS", "Command", "user_error_types"]


class Command:
    """A sub-command: its help line and a loader returning ``(add_arguments, run)``."""

    __slots__ = ("help", "load")

    def __init__(self, help: str, load: Callable[[], tuple[AddArguments, Run]]):
        self.help = help
        self.load = load

    def __repr__(self) -> str:
        return f"Command({self.help!r}, {self.load.__name__})"


def _simulate() -> tuple[AddArguments, Run]:
    from motorid.commands import simulate
    return simulate.add_simulate_arguments, simulate.run_simulate


def _identify() -> tuple[AddArguments, Run]:
    from motorid.commands import identify
    return identify.add_identify_arguments, identify.run_identify


def _import() -> tuple[AddArguments, Run]:
    from motorid.commands import importing
    return importing.add_import_arguments, importing.run_import


def _demo() -> tuple[AddArguments, Run]:
    from motorid.commands import demo
    return demo.add_demo_arguments, demo.run_demo


def _bench() -> tuple[AddArguments, Run]:
    from motorid.commands import bench
    return bench.add_bench_arguments, bench.run_bench


def _sweep() -> tuple[AddArguments, Run]:
    from motorid.commands import sweep
    return sweep.add_sweep_arguments, sweep.run_sweep


def _design() -> tuple[AddArguments, Run]:
    from motorid.commands import design
    return design.add_design_arguments, design.run_design


def _live() -> tuple[AddArguments, Run]:
    from motorid.commands import live
    return live.add_live_arguments, live.run_live


def _frequency() -> tuple[AddArguments, Run]:
    from motorid.commands import frequency
    return frequency.add_frequency_arguments, frequency.run_frequency


def _control() -> tuple[AddArguments, Run]:
    from motorid.commands import control
    return control.add_control_arguments, control.run_control


COMMANDS: dict[str, Command] = {
    "simulate": Command("simulate the bench and write a recording (format v1)", _simulate),
    "identify": Command("identify a and b from recordings", _identify),
    "import": Command("a lab's own file (CSV, TSV, whitespace, MATLAB .mat) to a recording (format v1)", _import),
    "demo": Command("the article's section 5 on the simulated bench", _demo),
    "bench": Command("speed and accuracy benchmarks", _bench),
    "sweep": Command("sweep scenarios: grid x estimators x Monte Carlo repetitions", _sweep),
    "design": Command("recommend the sine that minimises the Cramér-Rao bound of a and b", _design),
    "live": Command("run an experiment on the bench (or 'fake://'), record it live, identify", _live),
    "control": Command("design a controller from a model and predict its closed-loop response", _control),
    "frequency": Command("frequency response of recordings (Bode with bounds, models, distortion)", _frequency),
}


def build_parser() -> argparse.ArgumentParser:
    """The ``motorid`` parser with every sub-command of :data:`COMMANDS`."""
    import argparse

    import motorid
    parser = argparse.ArgumentParser(prog="motorid", description="Identify a and b of a PWM-driven DC motor, "
                                     "dω/dt + aω = b·u, on a simulated or real bench.")
    parser.add_argument("--traceback", action="store_true",
                        help="on an error, print the Python traceback (for bug reports)")
    parser.add_argument("--version", action="version", version=f"motorid {motorid.__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, command in COMMANDS.items():
        p = sub.add_parser(name, help=command.help, description=command.help)
        add_arguments, run = command.load()
        add_arguments(p)
        p.set_defaults(run=run)
    return parser


def user_error_types() -> tuple[type[BaseException], ...]:
    """The exceptions that report a user's mistake (exit status 2); anything else is a bug (status 1).

    ``OSError`` (a path that cannot be read or written, a full disk, a port that cannot
    be opened) is one too.
    """
    from hardware.errors import ProtocolError, RigError
    from identify.errors import NotIdentifiableError
    from motorid.arguments import CommandError
    from motorsim.checks import ParameterError
    from motorsim.recording import RecordingFormatError
    from scenarios.scenario import ScenarioError
    return (CommandError, RecordingFormatError, ScenarioError, NotIdentifiableError, ParameterError,
            ProtocolError, RigError, OSError)


def _one_line(exc: BaseException) -> str:
    from motorsim.files import OutputFileError
    text = " ".join(str(exc).split())
    if isinstance(exc, OSError) and not isinstance(exc, OutputFileError) and exc.filename is not None \
            and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    return text or type(exc).__name__


def _quiet_broken_pipe() -> int:
    """The reader of stdout went away (``motorid ... | head``): end quietly, as ``SIGPIPE`` would."""
    import os
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())    # the interpreter's final flush must not fail again
    except (OSError, ValueError, AttributeError):
        pass                                     # stdout is not a file descriptor (captured, embedded)
    return 141                                   # 128 + SIGPIPE, the shell's status for the same case


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the command line shows it: ``motorid: warning: ...`` on stderr."""
    from motorid.arguments import print_to_stderr
    print_to_stderr(f"motorid: warning: {' '.join(str(message).split())}")


def _traceback_flag(argv: Sequence[str]) -> tuple[list[str], bool]:
    """``argv`` without ``--traceback`` and whether it was there: the flag works wherever it is put (the
    error's hint says 're-run with --traceback', and users add it at the end), not only before the command."""
    argv = list(argv)
    end = argv.index("--") if "--" in argv else len(argv)
    found = "--traceback" in argv[:end]
    return [a for a in argv[:end] if a != "--traceback"] + argv[end:], found


def _parse_and_run(argv: Sequence[str] | None, checkpoint: Callable[[], None]) -> int:
    import contextlib
    import warnings

    from motorid.outputs import check_outputs, has_outputs, input_paths
    from motorsim.files import deferred_outputs
    argv, traceback_anywhere = _traceback_flag(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.traceback = args.traceback or traceback_anywhere
    checkpoint()                  # an interrupt the imports swallowed is raised here, before the command runs
    try:
        _check_numbers(args)
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning    # one line, not the source line that warned
            check_outputs(args)
            # every output is moved into place only once the command has succeeded
            with deferred_outputs(input_paths(args)) if has_outputs(args) else contextlib.nullcontext() as outputs:
                status = args.run(args)
                if status != 0 and outputs is not None:
                    outputs.discard()
            return status
    except (KeyboardInterrupt, BrokenPipeError):
        raise
    except Exception as exc:
        checkpoint()              # an interrupt that C code turned into this error is raised instead
        return _report_error(exc, args.traceback)


#: The largest magnitude of any number flag: past it no quantity of a motor, a run or a design makes sense, and
#: the arithmetic that follows (squares, products, counts) leaves a float's range or rounds to nothing.
FLAG_MAGNITUDE = 1e15


def _check_numbers(args: argparse.Namespace) -> None:
    """Refuse a number flag that is not finite or past :data:`FLAG_MAGNITUDE` (each command bounds its own
    flags more narrowly where it knows better); ``--max-memory`` is bytes, and exempt."""
    import math

    from motorid.arguments import CommandError
    for name, value in vars(args).items():
        if isinstance(value, float) and not (math.isfinite(value) and abs(value) <= FLAG_MAGNITUDE):
            raise CommandError(f"--{name.replace('_', '-')} must be a finite number within +-{FLAG_MAGNITUDE:g}, "
                               f"got {value!r}")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``motorid`` console script (see the module docstring for the exit statuses).

    The signal handlers are the first thing installed (this module imports nothing but
    ``sys``), before the parser is built (which imports every command), so
    a signal at any moment after the interpreter's own start-up gives 128 + its number and no
    traceback (:mod:`motorid.interrupts` says what the start-up leaves uncovered).
    """
    try:
        from motorid.interrupts import signals_as_interrupts
        from motorid.terminal import printable_output
        with signals_as_interrupts() as checkpoint, printable_output():
            return _parse_and_run(argv, checkpoint)
    except KeyboardInterrupt as exc:
        from motorid.interrupts import describe_interrupt, exit_status
        _say(f"motorid: {describe_interrupt(exc)}")
        return exit_status(exc)
    except BrokenPipeError:
        return _quiet_broken_pipe()


def _say(line: str) -> None:
    try:
        from motorsim.text import printable
        print(printable(line), file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _report_error(exc: Exception, show_traceback: bool) -> int:
    """One line for ``exc``: a user error (status 2) or a bug (status 1)."""
    if show_traceback:
        import traceback
        traceback.print_exc()
    if isinstance(exc, user_error_types()):
        _say(f"motorid: error: {_one_line(exc)}")
        return 2
    _say(f"motorid: internal error: {type(exc).__name__}: {_one_line(exc)[:300]} "
         "(a bug: re-run with --traceback to see where, and report it)")
    return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
