"""Memory budgets: absurd sizes are refused before any work starts, with the estimate that refused them.

``motorid simulate`` and ``motorid sweep`` estimate the memory a run needs from its size
(samples, repetitions, grid points) and refuse a run over ``--max-memory`` (default
:data:`DEFAULT_MEMORY_FRACTION` of the machine's RAM).  The per-sample figures were measured
on this code (peak resident set size of ``motorid simulate`` over 200 000 and 800 000
samples: about 210 bytes per sample, formatting the CSV included) and are rounded up.
"""
from __future__ import annotations

import os
import re

from motorid.arguments import CommandError

__all__ = ["DEFAULT_MEMORY_FRACTION", "SIMULATE_BYTES_PER_SAMPLE", "SWEEP_BYTES_PER_SAMPLE",
           "physical_memory", "default_max_memory", "parse_memory", "format_bytes", "add_max_memory_flag",
           "check_memory", "check_sweep"]

#: Share of the machine's RAM a run may need by default.
DEFAULT_MEMORY_FRACTION = 0.5
#: Bytes ``motorid simulate`` holds per sample (recording, model, CSV text).
SIMULATE_BYTES_PER_SAMPLE = 250
#: Bytes the sweep's batch engine holds per sample of one grid point, per repetition.
SWEEP_BYTES_PER_SAMPLE = 100

_UNITS = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def physical_memory() -> int | None:
    """The machine's RAM in bytes, or None where it cannot be asked."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def default_max_memory() -> int:
    """:data:`DEFAULT_MEMORY_FRACTION` of the RAM (4 GiB where the RAM is unknown), in bytes."""
    ram = physical_memory()
    return int(DEFAULT_MEMORY_FRACTION * ram) if ram else 4 << 30


def parse_memory(text: str) -> int:
    """``--max-memory``: bytes, or a number with K, M, G or T (powers of 1024), e.g. ``8G``."""
    import argparse
    match = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]+)?)\s*([kmgtKMGT]?)i?[bB]?\s*", text)
    if not match or float(match.group(1)) <= 0:
        raise argparse.ArgumentTypeError(f"--max-memory must be a size such as 512M or 8G, got {text!r}")
    return int(float(match.group(1)) * _UNITS[match.group(2).lower()])


def format_bytes(n: float) -> str:
    """``n`` bytes with a binary unit, e.g. ``7.3 TiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.3g} EiB"  # pragma: no cover


def add_max_memory_flag(parser) -> None:
    """Add ``--max-memory SIZE`` (default :func:`default_max_memory`) to ``parser``."""
    parser.add_argument("--max-memory", type=parse_memory, default=default_max_memory(), metavar="SIZE",
                        help=f"refuse a run estimated to need more memory, e.g. 512M or 8G (default "
                             f"{100 * DEFAULT_MEMORY_FRACTION:.0f} %% of RAM, {format_bytes(default_max_memory())})")


def check_memory(what: str, estimate: float, budget: int) -> None:
    """Refuse ``what`` when its ``estimate`` in bytes is over ``budget``, naming both.

    Raises
    ------
    CommandError
        Naming the estimate, the budget and how to change either.
    """
    if estimate > budget:
        raise CommandError(f"{what} would need about {format_bytes(estimate)} of memory, over the --max-memory "
                           f"budget of {format_bytes(budget)} (default {DEFAULT_MEMORY_FRACTION:.0%} of RAM); "
                           "make it smaller, or raise --max-memory if the machine has the memory")


def check_sweep(scenario, budget: int) -> None:
    """Refuse a sweep whose largest grid point's batch is over ``budget`` bytes.

    The batch of one grid point holds every repetition's samples at once
    (:data:`SWEEP_BYTES_PER_SAMPLE` per sample and repetition); the grid itself is bounded
    by ``scenarios.scenario.MAX_GRID_POINTS`` when the scenario is loaded.
    """
    samples = scenario.max_samples()          # from the timing axes alone: a large grid is not walked
    check_memory(f"a sweep of {scenario.repetitions:,} repetitions of {samples:,} samples per grid point",
                 float(scenario.repetitions) * samples * SWEEP_BYTES_PER_SAMPLE, budget)
