"""The ``motorid`` command line.

:data:`COMMANDS` maps each sub-command to a :class:`Command`: its one-line help and a
loader that imports the command's module when the parser is built and returns its
``add_arguments(parser)`` and ``run(args) -> int``.  Modules import their heavy
dependencies (matplotlib, python-control) inside ``run`` only.  Add a command by
writing its module and adding one entry.  Flags shared by several commands live in
:mod:`scenarios.arguments`.

Errors a user can fix (bad flags, bad files, data that cannot identify the
motor) print ``motorid: error: ...`` and exit with status 2, never a traceback.
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable, NamedTuple, Sequence

from motorsim.recording import RecordingFormatError

from .arguments import CommandError, print_to_stderr

__all__ = ["main", "build_parser", "COMMANDS", "Command"]

AddArguments = Callable[[argparse.ArgumentParser], None]
Run = Callable[[argparse.Namespace], int]


class Command(NamedTuple):
    """A sub-command: its help line and a loader returning ``(add_arguments, run)``."""

    help: str
    load: Callable[[], tuple[AddArguments, Run]]


def _simulate() -> tuple[AddArguments, Run]:
    from . import simulate
    return simulate.add_simulate_arguments, simulate.run_simulate


def _identify() -> tuple[AddArguments, Run]:
    from . import identification
    return identification.add_identify_arguments, identification.run_identify


def _demo() -> tuple[AddArguments, Run]:
    from . import demo
    return demo.add_demo_arguments, demo.run_demo


def _bench() -> tuple[AddArguments, Run]:
    from . import benchmarks
    return benchmarks.add_bench_arguments, benchmarks.run_bench


def _sweep() -> tuple[AddArguments, Run]:
    from . import sweep
    return sweep.add_sweep_arguments, sweep.run_sweep


def _design() -> tuple[AddArguments, Run]:
    from . import design
    return design.add_design_arguments, design.run_design


def _live() -> tuple[AddArguments, Run]:
    from . import live
    return live.add_live_arguments, live.run_live


def _control() -> tuple[AddArguments, Run]:
    from . import control
    return control.add_control_arguments, control.run_control


COMMANDS: dict[str, Command] = {
    "simulate": Command("simulate the bench and write a recording (format v1)", _simulate),
    "identify": Command("identify a and b from recordings", _identify),
    "demo": Command("the article's section 5 on the simulated bench", _demo),
    "bench": Command("speed and accuracy benchmarks", _bench),
    "sweep": Command("sweep scenarios: grid x estimators x Monte Carlo repetitions", _sweep),
    "design": Command("recommend the sine that minimises the Cramér-Rao bound of a and b", _design),
    "live": Command("run an experiment on the bench (or 'fake://'), record it live, identify", _live),
    "control": Command("design a controller from a model and predict its closed-loop response", _control),
}


def build_parser() -> argparse.ArgumentParser:
    """The ``motorid`` parser with every sub-command of :data:`COMMANDS`."""
    parser = argparse.ArgumentParser(prog="motorid", description="Identify a and b of a PWM-driven DC motor, "
                                     "dω/dt + aω = b·u, on a simulated or real bench.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, command in COMMANDS.items():
        p = sub.add_parser(name, help=command.help, description=command.help)
        add_arguments, run = command.load()
        add_arguments(p)
        p.set_defaults(run=run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``motorid`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except (CommandError, RecordingFormatError, ValueError, TypeError) as exc:
        print_to_stderr(f"motorid: error: {exc}")
        return 2
    except KeyboardInterrupt:
        print_to_stderr("motorid: interrupted")
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
