"""Editing a recording file's column as text, for tests that hand the reader a file a user might write."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

__all__ = ["rewrite_column"]


def rewrite_column(path: Path, out: Path, column: str, change: Callable[[list[str]], list[str]]) -> Path:
    """``path`` with ``change(cells)`` applied to ``column`` (its cells as text), written to ``out``."""
    lines = path.read_text().splitlines()
    header = [k for k, line in enumerate(lines) if line.startswith("seq")][0]
    k = lines[header].split(",").index(column)
    rows = [line.split(",") for line in lines[header + 1:]]
    for row, value in zip(rows, change([row[k] for row in rows])):
        row[k] = value
    out.write_text("\n".join(lines[:header + 1] + [",".join(row) for row in rows]) + "\n")
    return out
