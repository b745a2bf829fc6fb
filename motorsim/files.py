"""Writing files safely: never destroy, never follow a link, never leave half a file.

Every file motorid writes goes through here:

- a temporary or partial file is created exclusively (``O_CREAT | O_EXCL | O_NOFOLLOW``):
  an existing file or a symbolic link planted under its name is never opened, truncated
  or followed;
- a finished file replaces its target atomically (:func:`write_atomically`,
  :func:`atomic_writer`: a temporary file in the same folder, then ``os.replace``), so
  the old file survives any failure (a full disk, a read-only place, Ctrl-C);
- a target that exists but is not a regular file (a folder, a device node such as
  ``/dev/null``, a FIFO, a socket) is refused: ``os.replace`` would put a regular file in
  its place;
- files are created with mode ``0o666`` less the user's umask, as any program's files are;
- every failure is an :class:`OutputFileError` (an ``OSError``) whose message names the
  file, the reason, and what became of the old file.
"""
from __future__ import annotations

import contextlib
import os
import re
import secrets
import stat
from pathlib import Path
from typing import Iterator, TextIO

__all__ = ["OutputFileError", "open_exclusive", "atomic_writer", "write_atomically", "check_output_file",
           "make_output_dir", "safe_file_name"]

_EXCLUSIVE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


class OutputFileError(OSError):
    """A file could not be written (or was refused); the message says which, why, and what was kept."""

    def __init__(self, message: str, errno: int | None = None):
        super().__init__(errno, message) if errno is not None else super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def open_exclusive(path: str | os.PathLike) -> TextIO:
    """Create ``path`` for writing text (UTF-8), failing if anything, a link included, is there.

    Parameters
    ----------
    path : str or path-like
        The file to create; mode ``0o666`` less the umask.

    Returns
    -------
    text file
        Open for writing, newlines untranslated.

    Raises
    ------
    FileExistsError
        Something (a file, a link, a folder) already has that name.
    """
    fd = os.open(path, _EXCLUSIVE, 0o666)
    return os.fdopen(fd, "w", encoding="utf-8", newline="")


def _refuse_non_regular(path: Path) -> bool:
    """Raise unless ``path`` is absent, a regular file or a link (a link is replaced, never followed).

    Returns whether something exists at ``path``.
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise OutputFileError(f"cannot write {path}: {_reason(exc)}", exc.errno) from None
    if stat.S_ISDIR(mode):
        raise OutputFileError(f"cannot write {path}: it is a folder; give a file name")
    if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
        raise OutputFileError(f"cannot write {path}: it is not a regular file (a device, FIFO or socket), "
                              f"and it is never replaced")
    return True


def _temporary_beside(path: Path) -> tuple[Path, TextIO]:
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return tmp, open_exclusive(tmp)
        except FileExistsError:
            continue
    raise OutputFileError(f"cannot write {path}: no free temporary name beside it")  # pragma: no cover


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike) -> Iterator[TextIO]:
    """A text file that becomes ``path`` when the block ends normally, and vanishes otherwise.

    Parameters
    ----------
    path : str or path-like
        The file to (re)place; an existing regular file is replaced, a folder or a device refused.

    Yields
    ------
    text file
        A temporary file beside ``path``, created exclusively.

    Raises
    ------
    OutputFileError
        The folder is missing or not writable, the disk is full, ``path`` is not a regular
        file: the message names the file and says that the old one, if any, is unchanged.
    """
    path = Path(path)
    existed = _refuse_non_regular(path)
    kept = "the old file is unchanged" if existed else "nothing was written"
    try:
        tmp, f = _temporary_beside(path)
    except OSError as exc:
        if isinstance(exc, OutputFileError):
            raise
        raise OutputFileError(f"cannot write {path}: {_reason(exc)}; {kept}", exc.errno) from None
    try:
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OutputFileError):
            raise
        raise OutputFileError(f"cannot write {path}: {_reason(exc)}; {kept}", exc.errno) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_atomically(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_writer`; returns the path.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> write_atomically(folder / "a.txt", "one\\n").read_text()
    'one\\n'
    >>> write_atomically(folder, "two")
    Traceback (most recent call last):
    ...
    motorsim.files.OutputFileError: cannot write ...: it is a folder; give a file name
    """
    with atomic_writer(path) as f:
        f.write(text)
    return Path(path)


def check_output_file(path: str | os.PathLike, *, overwrite: bool = True, flag: str = "--out") -> Path:
    """Check, before any work, that ``path`` can be written: its folder exists and takes a new file.

    Parameters
    ----------
    path : str or path-like
        The file to be written.
    overwrite : bool
        Whether an existing regular file may be replaced (else it is refused).
    flag : str
        How the caller names ``path`` in messages.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    OutputFileError
        The folder is missing, not a folder or not writable (probed by creating and removing
        an exclusive temporary file there); ``path`` is a folder or a device; or it exists
        and ``overwrite`` is False.
    """
    path = Path(path)
    folder = path.parent
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise OutputFileError(f"{flag} {path}: the folder {folder} {what}")
    if _refuse_non_regular(path) and not overwrite:
        raise OutputFileError(f"{flag} {path} exists; pass --overwrite to replace it, or choose another name")
    try:
        tmp, f = _temporary_beside(path)
    except OSError as exc:
        raise OutputFileError(f"{flag} {path}: cannot create files in {folder}: {_reason(exc)}", exc.errno) from None
    f.close()
    os.unlink(tmp)
    return path


def make_output_dir(path: str | os.PathLike, flag: str = "--out") -> Path:
    """Create the folder ``path`` (and its parents) if needed, or say in one line why it cannot be.

    Raises
    ------
    OutputFileError
        ``path`` is a file, or the folder cannot be created or written.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputFileError(f"{flag} {path} is a file, not a folder") from None
    except OSError as exc:
        raise OutputFileError(f"{flag} {path}: cannot create the folder: {_reason(exc)}", exc.errno) from None
    check_output_file(path / "probe", flag=flag)
    return path


def safe_file_name(name: str, default: str = "unnamed") -> str:
    """``name`` as one file name: no folder separators, no leading dot, only ``A-Z a-z 0-9 . _ -``.

    Examples
    --------
    >>> safe_file_name("../../etc"), safe_file_name("/abs/path"), safe_file_name("ok-name_1.2")
    ('etc', 'abs_path', 'ok-name_1.2')
    >>> safe_file_name(".."), safe_file_name("a b")
    ('unnamed', 'a_b')
    """
    cleaned = re.sub(r"[^A-Za-z0-9._-]+", "_", str(name)).strip("._")
    cleaned = re.sub(r"_*\.\._*", "_", cleaned)
    return cleaned[:100] or default
