"""The speed and accuracy benchmarks of ``motorid bench NAME``, one module each.

============= ================================================================
``simulate``  :mod:`~motorid.bench.simulate`: ``motorsim.simulate`` against python-control
``sweep``     :mod:`~motorid.bench.sweep`: the sweeps' batch engine against a per-run loop
``oe``        :mod:`~motorid.bench.output_error`: the ``oe`` fit against ``lfilter`` and ``least_squares``
``accuracy``  :mod:`~motorid.bench.accuracy`: the estimators against the truth and the CRB
``serial``    :mod:`~motorid.bench.serial`: the host's frame reader and a pty run
``firmware``  :mod:`~motorid.bench.firmware`: the Arduino firmware under simavr
``parse``     :mod:`~motorid.bench.parse`: reading a large recording against pandas.read_csv
``startup``   :mod:`~motorid.bench.startup`: ``motorid --help`` and ``identify`` against ``import control``
``control``   :mod:`~motorid.bench.control`: closed-loop simulated runs against the open loop
``frequency`` :mod:`~motorid.bench.frequency`: the frequency response against scipy.signal csd/welch
``selection`` :mod:`~motorid.bench.selection`: the default (model chosen) against one ``oe`` fit and a CSV read
``coverage``  :mod:`~motorid.bench.coverage`: how often the default's intervals hold plants known exactly
``until``     :mod:`~motorid.bench.until`: motor time to a target precision, adaptive against fixed experiments
============= ================================================================

Benchmarks print their figures and ratios against a baseline measured in the
same run; tests never assert wall-clock times.  The goals among them are declared
once, next to the benchmark that measures them (:mod:`motorid.bench.goals`), and
``motorid bench --check`` runs them all and exits with status 1 on a missed goal.  Each benchmark is a function
``(argv: list[str]) -> int`` that parses its own flags; :data:`BENCHMARKS` maps
its name to it and a one-line description.  Add a benchmark by adding a module
and one entry.
"""
from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

__all__ = ["BENCHMARKS", "Benchmark"]


class Benchmark(NamedTuple):
    """A benchmark: its entry point and what it measures."""

    run: Callable[[Sequence[str]], int]
    description: str


# Each entry point imports its module when called, so ``motorid --help`` stays light.
def _simulate(argv: Sequence[str]) -> int:
    from motorid.bench.simulate import bench_simulate
    return bench_simulate(argv)


def _sweep(argv: Sequence[str]) -> int:
    from motorid.bench.sweep import bench_sweep
    return bench_sweep(argv)


def _output_error(argv: Sequence[str]) -> int:
    from motorid.bench.output_error import bench_output_error
    return bench_output_error(argv)


def _accuracy(argv: Sequence[str]) -> int:
    from motorid.bench.accuracy import bench_accuracy
    return bench_accuracy(argv)


def _serial(argv: Sequence[str]) -> int:
    from motorid.bench.serial import bench_serial
    return bench_serial(argv)


def _parse(argv: Sequence[str]) -> int:
    from motorid.bench.parse import bench_parse
    return bench_parse(argv)


def _firmware(argv: Sequence[str]) -> int:
    from motorid.bench.firmware import bench_firmware
    return bench_firmware(argv)


def _startup(argv: Sequence[str]) -> int:
    from motorid.bench.startup import bench_startup
    return bench_startup(argv)


def _control(argv: Sequence[str]) -> int:
    from motorid.bench.control import bench_control
    return bench_control(argv)


def _frequency(argv: Sequence[str]) -> int:
    from motorid.bench.frequency import bench_frequency
    return bench_frequency(argv)


def _selection(argv: Sequence[str]) -> int:
    from motorid.bench.selection import bench_selection
    return bench_selection(argv)


def _coverage(argv: Sequence[str]) -> int:
    from motorid.bench.coverage import bench_coverage
    return bench_coverage(argv)


def _until(argv: Sequence[str]) -> int:
    from motorid.bench.until import bench_until
    return bench_until(argv)


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
    "frequency": Benchmark(_frequency, "frequency_response of 10^6 samples (bounds, coherence) against "
                                       "scipy.signal.csd + welch of the same data"),
    "selection": Benchmark(_selection, "the default fit (delay and structure chosen) and one oe-friction fit against "
                                       "one oe fit on 10^4 samples, with and without friction; identify FILE on a "
                                       "position-loop recording, and on 10^6 rows against pandas.read_csv"),
    "coverage": Benchmark(_coverage, "the default's 95 per cent intervals on plants known exactly (electrical lags, "
                                     "long delays, differenced speeds, friction, a position loop with a fed-back "
                                     "torque): coverage over 100 seeds; --until: the adaptive runs' "
                                     "coverage under their stopping rule"),
    "until": Benchmark(_until, "motor time until the 95 per cent intervals of a and b are within 1 per cent: "
                               "motorid live --until's adaptive run against the oracle (the loop's own two-line "
                               "blocks designed for the true motor), the best fixed sine, the article's four sines "
                               "and a PRBS, on 100 seeded rigs; its coverage"),
}

