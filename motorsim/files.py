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
  its place; so is a read-only file (no write permission for its owner, or for this user),
  which ``os.replace`` would replace as it replaces any other;
- files are created with mode ``0o666`` less the user's umask, as any program's files are;
- every failure is an :class:`OutputFileError` (an ``OSError``) whose message names the
  file, the reason, and what became of the old file.

The one rule for a command's outputs (:func:`check_output_path`, applied before any work):
a regular file or nothing (a symbolic link, a folder, a device, a FIFO refused), never one
of the command's own inputs, and, where the format follows the name (figures), an extension
that names the format written, so the path reported is the path written.  A refusal names
the flag.

Within :func:`deferred_outputs` (``motorid`` runs every command in one) a finished file is
not moved into place at once: it waits, written in full beside its target, until the whole
command has succeeded, and is removed if anything fails, so a command that fails half-way
(a validation file that cannot be read after ``--save``) replaces nothing.  Two outputs of
one command naming the same file, or an output naming one of its inputs, are refused there.
A replaced file keeps its permission bits (a ``0600`` model stays ``0600``).

Inputs are opened by :func:`open_input`: the kind is checked before the file is opened (a
FIFO would block ``open`` until a writer comes), then the size, so no read waits forever or
fills the memory.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import re
import secrets
import stat
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator, Sequence, TextIO

__all__ = ["OutputFileError", "InputFileError", "open_exclusive", "atomic_writer", "write_atomically",
           "write_bytes_atomically", "check_output_file", "check_output_path", "make_output_dir", "safe_file_name",
           "open_input", "read_input_bytes", "same_file", "FIGURE_SUFFIXES", "deferred_outputs", "StagedOutputs",
           "staged_path"]

_EXCLUSIVE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


class OutputFileError(OSError):
    """A file could not be written (or was refused); the message says which, why, and what was kept."""

    def __init__(self, message: str, errno: int | None = None):
        super().__init__(errno, message) if errno is not None else super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


class InputFileError(OSError, ValueError):
    """A file given as input cannot be read as one: missing, not a regular file, or too large.

    An ``OSError`` (a path that cannot be read) and a ``ValueError`` (a wrong argument), so
    callers that catch either see it.
    """

    def __init__(self, message: str, errno: int | None = None):
        super().__init__(errno, message) if errno is not None else super().__init__(message)
        self.message = message

    def __str__(self) -> str:
        return self.message


#: Extensions of the figure formats motorid writes (matplotlib's, by the extension).
FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


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
    if stat.S_ISREG(mode) and (not mode & stat.S_IWUSR or not os.access(path, os.W_OK)):
        # os.replace needs only the folder's permission: a read-only file would be replaced without a word
        raise OutputFileError(f"cannot write {path}: it is read-only (mode {stat.S_IMODE(mode):04o}) and a "
                              "read-only file is never replaced; make it writable (chmod u+w) or give another name")
    return True


def _existing_mode(path: Path) -> int | None:
    """The permission bits of the regular file at ``path`` (a link not followed), or None."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return stat.S_IMODE(st.st_mode) if stat.S_ISREG(st.st_mode) else None


def _identity(path: str | os.PathLike) -> str:
    """``path`` with its folder resolved: two names of one file (not yet written) compare equal."""
    p = Path(path)
    return os.path.join(os.path.realpath(p.parent), p.name)


class StagedOutputs:
    """The finished outputs of one command, waiting beside their targets until it has succeeded.

    Made by :func:`deferred_outputs`; :func:`atomic_writer` hands it each finished temporary
    file instead of moving it into place.

    Parameters
    ----------
    inputs : iterable of path-like
        The command's input files: no output may name one of them.
    """

    def __init__(self, inputs: Iterable[str | os.PathLike] = ()):
        self.inputs = [os.fspath(p) for p in inputs]
        self._files: dict[str, tuple[Path, Path]] = {}

    def add(self, path: Path, tmp: Path) -> None:
        """Keep ``tmp`` until :meth:`commit` moves it to ``path``; refuse a name already taken.

        Raises
        ------
        OutputFileError
            ``path`` is one of the inputs, or another output of the same command.
        """
        for source in self.inputs:
            if same_file(path, source) or _identity(path) == _identity(source):
                raise OutputFileError(f"cannot write {path}: it is an input of this command ({source}); "
                                      "give another name, the input is never overwritten")
        key = _identity(path)
        for other, (_, target) in self._files.items():
            if other == key or same_file(path, target):
                raise OutputFileError(f"cannot write {path}: another output of this command ({target}) is "
                                      "the same file; give each output its own name")
        self._files[key] = (tmp, path)

    def staged(self, path: str | os.PathLike) -> Path | None:
        """The temporary file waiting to become ``path``, or None."""
        entry = self._files.get(_identity(path))
        return entry[0] if entry else None

    def commit(self) -> list[Path]:
        """Move every waiting file into place (each atomically); return the targets."""
        done = []
        try:
            while self._files:
                key = next(iter(self._files))
                tmp, path = self._files[key]
                try:
                    os.replace(tmp, path)
                except OSError as exc:
                    raise OutputFileError(f"cannot write {path}: {_reason(exc)}; the old file, if any, is "
                                          "unchanged", exc.errno) from None
                del self._files[key]
                done.append(path)
        finally:
            self.discard()
        return done

    def discard(self) -> None:
        """Remove every waiting file: the targets stay as they were."""
        for tmp, _ in self._files.values():
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self._files.clear()


_STAGING: contextvars.ContextVar[StagedOutputs | None] = contextvars.ContextVar("motorid_staged_outputs",
                                                                                default=None)


@contextlib.contextmanager
def deferred_outputs(inputs: Iterable[str | os.PathLike] = ()) -> Iterator[StagedOutputs]:
    """Every file :func:`atomic_writer` finishes in this block is moved into place only when it ends normally.

    An exception (or :meth:`StagedOutputs.discard`) leaves every target as it was.

    Parameters
    ----------
    inputs : iterable of path-like
        Files no output may replace.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> try:
    ...     with deferred_outputs():
    ...         _ = write_atomically(folder / "model.json", "{}")
    ...         raise ValueError("the validation file is not a recording")
    ... except ValueError:
    ...     pass
    >>> (folder / "model.json").exists()
    False
    """
    staging = StagedOutputs(inputs)
    token = _STAGING.set(staging)
    try:
        yield staging
    except BaseException:
        _STAGING.reset(token)
        staging.discard()
        raise
    _STAGING.reset(token)
    staging.commit()


def staged_path(path: str | os.PathLike) -> Path:
    """Where the content of output ``path`` is now: its waiting temporary file, or ``path`` itself."""
    staging = _STAGING.get()
    tmp = staging.staged(path) if staging is not None else None
    return tmp if tmp is not None else Path(path)


def _temporary_beside(path: Path) -> tuple[Path, TextIO]:
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return tmp, open_exclusive(tmp)
        except FileExistsError:
            continue
    raise OutputFileError(f"cannot write {path}: no free temporary name beside it")  # pragma: no cover


def _kind(mode: int, folder: str = "a folder") -> str:
    if stat.S_ISDIR(mode):
        return folder
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    return "not a regular file"


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike, *, at_once: bool = False) -> Iterator[TextIO]:
    """A text file that becomes ``path`` when the block ends normally, and vanishes otherwise.

    Within :func:`deferred_outputs` it becomes ``path`` only when that block ends normally,
    unless ``at_once``.  An existing file's permission bits are kept.

    Parameters
    ----------
    path : str or path-like
        The file to (re)place; an existing regular file (or a link, replaced and never
        followed) is replaced, a folder or a device refused.
    at_once : bool
        Move the file into place now even within :func:`deferred_outputs`: for data that
        must survive a later failure (a recording of a bench run).

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
    mode = _existing_mode(path)
    try:
        tmp, f = _temporary_beside(path)
    except OSError as exc:
        if isinstance(exc, OutputFileError):
            raise
        raise OutputFileError(f"cannot write {path}: {_reason(exc)}; {kept}", exc.errno) from None
    staging = None if at_once else _STAGING.get()
    try:
        with f:
            if mode is not None:
                os.fchmod(f.fileno(), mode)
            yield f
            f.flush()
            os.fsync(f.fileno())
        if staging is not None:
            staging.add(path, tmp)
        else:
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


def write_atomically(path: str | os.PathLike, text: str, *, at_once: bool = False) -> Path:
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
    with atomic_writer(path, at_once=at_once) as f:
        f.write(text)
    return Path(path)


def write_bytes_atomically(path: str | os.PathLike, data: bytes, *, at_once: bool = False) -> Path:
    """Write ``data`` to ``path`` as :func:`write_atomically` writes text (temporary file, then rename)."""
    with atomic_writer(path, at_once=at_once) as f:
        f.flush()
        f.buffer.write(data)
    return Path(path)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether the paths ``a`` and ``b`` name one file (a link followed, the same inode)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return os.path.abspath(a) == os.path.abspath(b)


def check_output_path(path: str | os.PathLike, *, flag: str, inputs: Iterable[str | os.PathLike] = (),
                      suffixes: Sequence[str] | None = None) -> Path:
    """The one rule for a file a command writes, checked before any work.

    Parameters
    ----------
    path : str or path-like
        The file to be written.
    flag : str
        The flag that gave ``path`` (every message names it).
    inputs : iterable of path-like
        The command's input files: ``path`` must be none of them.
    suffixes : sequence of str, optional
        The extensions that name a format written (figures); ``path`` must end with one.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    OutputFileError
        ``path`` is a symbolic link, a folder, a device, a FIFO or a socket; it is one of
        ``inputs``; its extension is not one of ``suffixes``; or its folder cannot take it.

    Examples
    --------
    >>> check_output_path("fit.png", flag="--report", suffixes=FIGURE_SUFFIXES)
    PosixPath('fit.png')
    >>> check_output_path("fit", flag="--report", suffixes=FIGURE_SUFFIXES)
    Traceback (most recent call last):
    ...
    motorsim.files.OutputFileError: --report fit: the extension names the format written; give one of .png, .pdf, .svg
    """
    text = os.fspath(path)
    if isinstance(text, str) and text.strip() and text.endswith(("/", os.sep)):
        # Path() drops the separator: "m.json/" would otherwise be written as the file m.json
        raise OutputFileError(f"{flag} {text}: a name ending in a path separator names a folder; give a file name")
    path = Path(path)
    if not str(path).strip():
        raise OutputFileError(f"{flag}: an empty path; give a file name")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        got = f" (got {path.suffix!r})" if path.suffix else ""
        raise OutputFileError(f"{flag} {path}: the extension names the format written; give one of "
                              f"{', '.join(suffixes)}{got}")
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise OutputFileError(f"{flag} {path}: {_reason(exc)}", exc.errno) from None
    if mode is not None and not stat.S_ISREG(mode):
        raise OutputFileError(f"{flag} {path} is {_kind(mode)}, not a regular file: an output must be a regular "
                              "file or a new name (never replaced, never followed)")
    for source in inputs:
        if mode is not None and same_file(path, source):
            raise OutputFileError(f"{flag} {path} is an input of this command ({source}); "
                                  "give another name, the input is never overwritten")
    return check_output_file(path, flag=flag)

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
    try:
        existed = _refuse_non_regular(path)
    except OutputFileError as exc:
        raise OutputFileError(f"{flag} {exc.message.removeprefix('cannot write ')}") from None
    if existed and not overwrite:
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



def open_input(path: str | os.PathLike, *, what: str, max_bytes: int) -> BinaryIO:
    """``path`` opened for reading bytes, once it is known to be a regular file of at most ``max_bytes``.

    The kind is checked before opening: opening a FIFO waits for a writer, reading a device
    such as ``/dev/zero`` never ends.  The file is opened without blocking and checked again
    (it may have been swapped meanwhile).

    Parameters
    ----------
    path : str or path-like
        The file.
    what : str
        What the file is to the caller (``"--model"``, ``"recording"``), for messages.
    max_bytes : int
        The largest size accepted.

    Raises
    ------
    InputFileError
        Missing, unreadable, not a regular file (saying what it is), or over ``max_bytes``.
    """
    name = os.fspath(path)
    if not str(name).strip():
        raise InputFileError(f"{what}: an empty path; give a file")
    try:
        mode = os.stat(name).st_mode
    except FileNotFoundError:
        raise InputFileError(f"{what} {name}: cannot read: No such file or directory") from None
    except OSError as exc:
        raise InputFileError(f"{what} {name}: cannot read: {_reason(exc)}", exc.errno) from None
    if not stat.S_ISREG(mode):
        raise InputFileError(f"{what} {name}: not a regular file ({_kind(mode, 'a directory')}); give a file")
    try:
        fd = os.open(name, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputFileError(f"{what} {name}: cannot read: {_reason(exc)}", exc.errno) from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise InputFileError(f"{what} {name}: not a regular file ({_kind(st.st_mode, 'a directory')}); give a file")
    if st.st_size > max_bytes:
        os.close(fd)
        raise InputFileError(f"{what} {name}: {st.st_size} bytes is over the {max_bytes} bytes it may have")
    if hasattr(os, "set_blocking"):
        os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def read_input_bytes(path: str | os.PathLike, *, what: str, max_bytes: int) -> bytes:
    """The bytes of ``path`` through :func:`open_input`; a file that grew past ``max_bytes`` is refused too."""
    with open_input(path, what=what, max_bytes=max_bytes) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputFileError(f"{what} {os.fspath(path)}: over the {max_bytes} bytes it may have")
    return data
