"""``motorid bench NAME``: runs one of the benchmarks of :data:`motorid.bench.BENCHMARKS` with its own flags;
``motorid bench --check``: the goals of every gated benchmark (:mod:`motorid.bench.goals`)."""
from __future__ import annotations

import argparse

from motorid.arguments import CommandError
from motorid.bench import BENCHMARKS

__all__ = ["add_bench_arguments", "run_bench"]


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid bench``: ``--check``, or the benchmark's name, then its own flags."""
    names = ", ".join(f"{name} ({b.description})" for name, b in BENCHMARKS.items())
    parser.add_argument("--check", action="store_true",
                        help="run the benchmarks that carry speed goals (simulate, oe, selection, frequency; or the "
                             "NAME given), print each figure with its goal, exit 1 when a goal is missed")
    parser.add_argument("name", nargs="?", choices=list(BENCHMARKS), metavar="NAME", help=f"one of: {names}")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="the benchmark's own flags (see NAME --help)")


def run_bench(args: argparse.Namespace) -> int:
    """Run the named benchmark with its flags, or the gate."""
    if args.check:
        from motorid.bench.goals import GATED, run_check
        if args.options:
            raise CommandError(f"--check takes no benchmark flags, got {' '.join(args.options)!r}")
        if args.name is not None and args.name not in GATED:
            raise CommandError(f"--check runs {', '.join(GATED)}; {args.name!r} carries no goal")
        return run_check([args.name] if args.name else [])
    if args.name is None:
        raise CommandError("NAME is required (or --check): one of " + ", ".join(BENCHMARKS))
    return BENCHMARKS[args.name].run(list(args.options))
