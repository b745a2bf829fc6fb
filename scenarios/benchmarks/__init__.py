"""``motorid bench NAME``: speed and accuracy benchmarks, one module each.

=========== ================================================================
``simulate`` :mod:`~scenarios.benchmarks.simulate`: ``motorsim.simulate`` against python-control
``sweep``    :mod:`~scenarios.benchmarks.sweep`: the sweeps' batch engine against a per-run loop
``oe``       :mod:`~scenarios.benchmarks.output_error`: the ``oe`` fit against ``lfilter`` and ``least_squares``
``accuracy`` :mod:`~scenarios.benchmarks.accuracy`: the estimators against the truth and the CRB
``serial``   :mod:`~scenarios.benchmarks.serial`: the host's frame reader and a pty run
``firmware`` :mod:`~scenarios.benchmarks.firmware`: the Arduino firmware under simavr
``parse``    :mod:`~scenarios.benchmarks.parse`: reading a large recording against pandas.read_csv
``startup``  :mod:`~scenarios.benchmarks.startup`: ``motorid --help`` and ``identify`` against ``import control``
``control``  :mod:`~scenarios.benchmarks.control`: closed-loop simulated runs against the open loop
=========== ================================================================

Benchmarks print their figures and ratios against a baseline measured in the
same run; tests never assert wall-clock times.  Each benchmark is a function
``(argv: list[str]) -> int`` that parses its own flags; :data:`BENCHMARKS` maps
its name to it and a one-line description.  Add a benchmark by adding a module
and one entry.
"""
from __future__ import annotations

import argparse
from typing import Callable, NamedTuple, Sequence

__all__ = ["BENCHMARKS", "Benchmark", "add_bench_arguments", "run_bench"]


class Benchmark(NamedTuple):
    """A benchmark: its entry point and what it measures."""

    run: Callable[[Sequence[str]], int]
    description: str


# Each entry point imports its module when called, so ``motorid --help`` stays light.
def _simulate(argv: Sequence[str]) -> int:
    from .simulate import bench_simulate
    return bench_simulate(argv)


def _sweep(argv: Sequence[str]) -> int:
    from .sweep import bench_sweep
    return bench_sweep(argv)


def _output_error(argv: Sequence[str]) -> int:
    from .output_error import bench_output_error
    return bench_output_error(argv)


def _accuracy(argv: Sequence[str]) -> int:
    from .accuracy import bench_accuracy
    return bench_accuracy(argv)


def _serial(argv: Sequence[str]) -> int:
    from .serial import bench_serial
    return bench_serial(argv)


def _parse(argv: Sequence[str]) -> int:
    from .parse import bench_parse
    return bench_parse(argv)


def _firmware(argv: Sequence[str]) -> int:
    from .firmware import bench_firmware
    return bench_firmware(argv)


def _startup(argv: Sequence[str]) -> int:
    from .startup import bench_startup
    return bench_startup(argv)


def _control(argv: Sequence[str]) -> int:
    from .control import bench_control
    return bench_control(argv)


BENCHMARKS: dict[str, Benchmark] = {
    "simulate": Benchmark(_simulate, "motorsim.simulate against control.forced_response of the same ZOH model"),
    "sweep": Benchmark(_sweep, "the sweeps' batch engine against a per-run control.forced_response + lstsq loop"),
    "oe": Benchmark(_output_error, "the oe fit against bare lfilter passes and a plain least_squares output-error "
                                   "fit, same recording; peak memory per sample"),
    "accuracy": Benchmark(_accuracy, "oe/oe-friction against the truth on an independent integrator, Monte "
                                     "Carlo vs the Cramér–Rao bound, oe fit time vs a finite-difference Jacobian"),
    "serial": Benchmark(_serial, "frames decoded/s by the host reader vs the 200 000/s goal; 60 s at 1 kHz "
                                 "through the pty"),
    "firmware": Benchmark(_firmware, "the Arduino firmware under simavr: size, sample rates per baud, encoder "
                                     "ceiling, speed"),
    "parse": Benchmark(_parse, "read_recording of a 2-million-row recording vs pandas.read_csv: time, peak memory"),
    "startup": Benchmark(_startup, "motorid --help and motorid identify small.csv against python -c 'import control' "
                                   "(subprocesses, medians)"),
    "control": Benchmark(_control, "SimRig closed-loop runs (each controller) against the open-loop run"),
}


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid bench``: the benchmark's name, then its own flags."""
    names = ", ".join(f"{name} ({b.description})" for name, b in BENCHMARKS.items())
    parser.add_argument("name", choices=list(BENCHMARKS), metavar="NAME", help=f"one of: {names}")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="the benchmark's own flags (see NAME --help)")


def run_bench(args: argparse.Namespace) -> int:
    """Run the named benchmark with its flags."""
    return BENCHMARKS[args.name].run(list(args.options))
