"""The parsers of ``motorid`` and of each ``motorid bench NAME``, for the generated command reference.

``motorid bench NAME`` hands its flags to the benchmark, which builds its own parser when it runs;
:func:`bench_parser` catches that parser when ``NAME --help`` is asked, without running anything.
"""
from __future__ import annotations

import argparse

from motorid.bench import BENCHMARKS
from motorid.cli import build_parser

__all__ = ["build_parser", "bench_parser", "BENCH_NAMES"]

BENCH_NAMES = list(BENCHMARKS)


class _Found(Exception):
    pass


def bench_parser(name: str) -> argparse.ArgumentParser:
    """The parser of ``motorid bench NAME``."""
    original = argparse.ArgumentParser.parse_args

    def catch(self, args=None, namespace=None):
        raise _Found(self)
    argparse.ArgumentParser.parse_args = catch  # type: ignore[method-assign]
    try:
        BENCHMARKS[name].run(["--help"])
    except _Found as found:
        return found.args[0]
    finally:
        argparse.ArgumentParser.parse_args = original  # type: ignore[method-assign]
    raise RuntimeError(f"motorid bench {name} parsed no arguments")


def _bench_function(name: str):
    def parser() -> argparse.ArgumentParser:
        return bench_parser(name)
    parser.__name__ = f"bench_{name}"
    return parser


for _name in BENCH_NAMES:
    globals()[f"bench_{_name}"] = _bench_function(_name)
