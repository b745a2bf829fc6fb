"""Finding the processes a test started, by a marker in their environment (for tests that kill a parent and
check that no child outlives it)."""
from __future__ import annotations

from pathlib import Path

__all__ = ["MARKER_VARIABLE", "processes_with"]

#: The environment variable a test sets on the processes it starts.
MARKER_VARIABLE = "MOTORID_TEST_MARKER"


def processes_with(marker: str) -> list[int]:
    """Pids of the live processes whose environment carries ``MOTORID_TEST_MARKER=marker``."""
    needle = f"{MARKER_VARIABLE}={marker}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if needle in (entry / "environ").read_bytes().split(b"\0"):
                    found.append(int(entry.name))
            except OSError:
                continue
    return found
