"""The files each command writes, checked against the one output rule before the command runs.

:data:`FILE_OUTPUTS` lists, per command, the flags that name a file it writes and whether the
extension names the format (figures); :data:`FOLDER_OUTPUTS` the flags that name a folder;
:data:`INPUT_ATTRIBUTES` the arguments that name its inputs.  :func:`check_outputs` applies
:func:`motorsim.files.check_output_path` to every file output given: a regular file or a new
name (never a link, a folder, a device or a FIFO), never one of the command's inputs, and for a
figure an extension that names the format written; no two outputs naming one file.  The files
a command writes into its folder (:data:`FOLDER_FILES`) pass the same rule.  ``motorid`` calls
it for every command before the command's own work, so a new command's outputs are one line
here; what a command writes is then moved into place only once it has succeeded
(:func:`motorsim.files.deferred_outputs`).
"""
from __future__ import annotations

import argparse
import os
from typing import Iterator

from motorsim.files import FIGURE_SUFFIXES, OutputFileError, check_output_path, same_file

__all__ = ["FILE_OUTPUTS", "FOLDER_OUTPUTS", "FOLDER_FILES", "INPUT_ATTRIBUTES", "check_outputs", "input_paths",
           "has_outputs"]

#: command -> {argument name: extensions that name the format written, or None}
FILE_OUTPUTS: dict[str, dict[str, tuple[str, ...] | None]] = {
    "simulate": {"out": None},
    "import": {"out": None},
    "live": {"out": None, "save": None},
    "identify": {"save": None, "report": FIGURE_SUFFIXES},
    "frequency": {"plot": FIGURE_SUFFIXES},
    "control": {"plot": FIGURE_SUFFIXES},
}

#: command -> arguments naming a folder the command writes into.
FOLDER_OUTPUTS: dict[str, tuple[str, ...]] = {"demo": ("out",), "design": ("out",), "sweep": ("out",)}

#: command -> the fixed names of the files it writes into its folder output.
FOLDER_FILES: dict[str, tuple[str, ...]] = {
    "demo": ("table.txt", "table.json", "closed_loop.txt", "overlay.png", "closed_loop.png"),
    "design": ("design.json",),
    "sweep": ("sweep.csv", "summary.json"),
}

#: Arguments that name input files, in any command that has them.
INPUT_ATTRIBUTES = ("files", "file", "validate", "model", "scenario")


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def has_outputs(args: argparse.Namespace) -> bool:
    """Whether ``args.command`` writes outputs (listed here), which then wait until it has succeeded.

    A command without (``bench``) may write scratch files that it reads back at once.
    """
    command = str(getattr(args, "command", ""))
    return command in FILE_OUTPUTS or command in FOLDER_OUTPUTS


def input_paths(args: argparse.Namespace) -> Iterator[str]:
    """The paths of ``args`` that name existing input files."""
    for name in INPUT_ATTRIBUTES:
        value = getattr(args, name, None)
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, str) and item and os.path.exists(item):
                yield item


def check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, an output of ``args.command`` that breaks the output rule.

    Raises
    ------
    motorsim.files.OutputFileError
        Naming the flag, the path and the rule.
    """
    command = str(getattr(args, "command", ""))
    inputs = list(input_paths(args))
    seen: dict[str, str] = {}
    for name, suffixes in FILE_OUTPUTS.get(command, {}).items():
        value = getattr(args, name, None)
        if isinstance(value, str):
            check_output_path(value, flag=_flag(name), inputs=inputs, suffixes=suffixes)
            _refuse_same(value, _flag(name), seen)
    for name in FOLDER_OUTPUTS.get(command, ()):
        value = getattr(args, name, None)
        if isinstance(value, str):
            if not value.strip():
                raise OutputFileError(f"{_flag(name)}: an empty path; give a folder")
            if os.path.exists(value) and not os.path.isdir(value):
                raise OutputFileError(f"{_flag(name)} {value} is a file, not a folder")
            for source in inputs:
                if same_file(value, source):
                    raise OutputFileError(f"{_flag(name)} {value} is an input of this command")
            if os.path.isdir(value):
                for file_name in FOLDER_FILES.get(command, ()):
                    check_output_path(os.path.join(value, file_name), flag=f"{_flag(name)} {value}: the file",
                                      inputs=inputs)


def _refuse_same(path: str, flag: str, seen: dict[str, str]) -> None:
    """Refuse ``path`` when an earlier output flag in ``seen`` (path -> flag) names the same file."""
    key = os.path.join(os.path.realpath(os.path.dirname(path) or "."), os.path.basename(path))
    for other, other_flag in seen.items():
        if other == key or same_file(other, path):
            raise OutputFileError(f"{flag} {path} and {other_flag} name the same file; give each output its own "
                                  "name")
    seen[key] = flag
