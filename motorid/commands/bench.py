"""``motorid bench NAME``: runs one of the benchmarks of :data:`motorid.bench.BENCHMARKS` with its own flags."""
from __future__ import annotations

import argparse

from motorid.bench import BENCHMARKS

__all__ = ["add_bench_arguments", "run_bench"]


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid bench``: the benchmark's name, then its own flags."""
    names = ", ".join(f"{name} ({b.description})" for name, b in BENCHMARKS.items())
    parser.add_argument("name", choices=list(BENCHMARKS), metavar="NAME", help=f"one of: {names}")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="the benchmark's own flags (see NAME --help)")


def run_bench(args: argparse.Namespace) -> int:
    """Run the named benchmark with its flags."""
    return BENCHMARKS[args.name].run(list(args.options))
