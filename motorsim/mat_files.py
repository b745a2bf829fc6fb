"""MATLAB ``.mat`` files read as data: only the file named, in a bounded memory, in a process of its own.

:func:`read_mat_variables` gives the numeric variables of a ``.mat`` file's bytes (v5 through
scipy, v7.3/HDF5 through h5py) or refuses the file in one line:

- **only the file named is read**: a v7.3 variable that is an HDF5 external link, keeps its data
  in another file (external storage) or is a virtual dataset over other files is refused, never
  followed (a crafted file would otherwise copy any file of the machine into the output);
- **memory bounded by what the file can honestly hold**: what the variables claim (their
  dimensions, their unpacked size) is checked before anything is allocated or unpacked past
  the bound; a recording saved with compression unpacks to 7-11 times its size (measured on
  10^6-sample runs: time, a step input, an encoder or a noisy speed), so a file may unpack to
  :data:`UNPACK_RATIO` times its size, at least :data:`UNPACK_FLOOR` bytes, never more than
  :data:`UNPACK_CAP` (a decompression bomb of 2 MB claiming 2.4 GB is refused at once);
- **a crash or a hang ends only the reader**: scipy's compiled reader can crash on a damaged
  file (a bus error in scipy 1.17 on one changed byte), so the reading runs in a child
  process whose address space is limited too, given :data:`MAT_READ_SECONDS`.
"""
from __future__ import annotations

import io
import struct
import zlib
from typing import Any

import numpy as np

__all__ = ["read_mat_variables", "MatFileRefused", "unpack_limit", "UNPACK_RATIO", "UNPACK_FLOOR", "UNPACK_CAP",
           "MAT_READ_SECONDS"]

#: How many times its size a .mat file may unpack to (honest recordings: 7-11 times).
UNPACK_RATIO = 32
#: What any .mat file may unpack to, whatever its size, in bytes.
UNPACK_FLOOR = 64 << 20
#: What no .mat file may unpack to, in bytes: more numbers than the largest text table motorid reads holds.
UNPACK_CAP = 1 << 30
#: Seconds the reader of a MATLAB file may take in its own process before the file is refused.
MAT_READ_SECONDS = 120.0

_MI_MATRIX, _MI_COMPRESSED, _MI_INT32, _MI_UINT32 = 14, 15, 5, 6
_CELL_OR_STRUCT = {1, 2, 3}        # mxCELL_CLASS, mxSTRUCT_CLASS, mxOBJECT_CLASS: one pointer per element


class MatFileRefused(ValueError):
    """A .mat file refused: the message says which variable and which rule (no file name: the caller adds it)."""


def unpack_limit(file_bytes: int) -> int:
    """The most bytes a .mat file of ``file_bytes`` may unpack to (:data:`UNPACK_RATIO` x its size, within
    :data:`UNPACK_FLOOR`...:data:`UNPACK_CAP`)."""
    return int(min(UNPACK_CAP, max(UNPACK_FLOOR, UNPACK_RATIO * file_bytes)))


def _over(name: str, claimed: str, limit: int, size: int) -> MatFileRefused:
    return MatFileRefused(f"the variable {name!r} {claimed}, more than the {limit} bytes a {size}-byte .mat file "
                          f"may unpack to ({UNPACK_RATIO} x its size, at least {UNPACK_FLOOR}, at most {UNPACK_CAP}: "
                          "saved recordings unpack to about 10 x): a decompression bomb or a damaged file, refused "
                          "before unpacking")


def _v5_name_and_dims(head: bytes) -> tuple[str, int, list[int]] | None:
    """The name, class and dimensions at the start of a miMATRIX element's content (None: unreadable)."""
    try:
        pos = 0
        kind, n = struct.unpack_from("<II", head, pos)
        if kind != _MI_UINT32 or n != 8:
            return None
        mx_class = head[pos + 8] & 0xFF
        pos += 16
        first, = struct.unpack_from("<I", head, pos)
        if first >> 16:                                   # small data element
            kind, n, pos = first & 0xFFFF, first >> 16, pos + 4
            dims_bytes = head[pos:pos + n]
            pos += 4
        else:
            kind, n = struct.unpack_from("<II", head, pos)
            pos += 8
            dims_bytes = head[pos:pos + n]
            pos += (n + 7) // 8 * 8
        if kind != _MI_INT32 or len(dims_bytes) < n:
            return None
        dims = list(struct.unpack(f"<{n // 4}i", dims_bytes[:n // 4 * 4]))
        first, = struct.unpack_from("<I", head, pos)
        if first >> 16:
            name = head[pos + 4:pos + 4 + (first >> 16)]
        else:
            n = struct.unpack_from("<I", head, pos + 4)[0]
            name = head[pos + 8:pos + 8 + min(n, 64)]
        return name.decode("latin-1"), mx_class, dims
    except (struct.error, IndexError):
        return None


def _check_v5(raw: bytes) -> None:
    """Refuse a v5 file whose variables claim, or unpack to, more than :func:`unpack_limit` allows.

    Walks the top-level elements; a compressed one is inflated in pieces, counted and thrown
    away, up to the limit (never past it).
    """
    limit = unpack_limit(len(raw))
    total, pos, k = 0, 128, 0
    little = raw[126:128] == b"IM"
    if not little:
        return                                             # big-endian files: scipy's own checks
    while pos + 8 <= len(raw):
        kind, n = struct.unpack_from("<II", raw, pos)
        body = raw[pos + 8:pos + 8 + n]
        pos += 8 + n + (0 if kind == _MI_COMPRESSED else (-n) % 8)
        k += 1
        if kind == _MI_COMPRESSED:
            inflate = zlib.decompressobj()
            head = inflate.decompress(body, 4096)
            size = len(head)
            rest = inflate.unconsumed_tail
            while rest and size <= limit - total:
                size += len(inflate.decompress(rest, 1 << 20))
                rest = inflate.unconsumed_tail
            if not rest and size <= limit - total:
                try:
                    size += len(inflate.flush())
                except zlib.error:
                    pass                                   # a damaged stream: scipy says so
            content = head[8:] if len(head) >= 8 and struct.unpack_from("<I", head)[0] == _MI_MATRIX else b""
        elif kind == _MI_MATRIX:
            size, content = n, body[:4096]
        else:
            size, content = n, b""
        found = _v5_name_and_dims(content) if content else None
        name = found[0] if found else f"#{k}"
        if found is not None:
            _, mx_class, dims = found
            elements = int(np.prod([max(d, 0) for d in dims], dtype=object)) if dims else 0
            item = 8 if mx_class in _CELL_OR_STRUCT else 1
            if elements * item > limit:
                shape = "x".join(map(str, dims))
                raise _over(name, f"claims {shape} elements", limit, len(raw))
        total += size
        if total > limit:
            raise _over(name, f"unpacks to more than {limit - (total - size)} bytes" if kind == _MI_COMPRESSED
                        else f"holds {size} bytes", limit, len(raw))


def _hdf5_variables(raw: bytes) -> dict[str, Any]:
    """The numeric datasets at the top of a v7.3 file, each checked before it is read (links, storage, size)."""
    import h5py
    limit = unpack_limit(len(raw))
    total = 0
    variables: dict[str, Any] = {}
    with h5py.File(io.BytesIO(raw), "r") as f:
        for name in f.keys():
            link = f.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise MatFileRefused(f"the variable {name!r} is a link to another file ({link.filename!r}, "
                                     f"{link.path!r}); motorid reads only the file it is given: save the "
                                     "variable's values in the file itself")
            if isinstance(link, h5py.SoftLink):
                continue                                   # a name for another variable of this file
            obj = f.get(name)
            if not isinstance(obj, h5py.Dataset):
                continue
            if obj.external:
                files = ", ".join(repr(e[0].decode("utf-8", "replace") if isinstance(e[0], bytes) else str(e[0]))
                                  for e in obj.external)
                raise MatFileRefused(f"the variable {name!r} keeps its values in another file ({files}: HDF5 "
                                     "external storage); motorid reads only the file it is given: save the "
                                     "values in the file itself")
            if obj.is_virtual:
                raise MatFileRefused(f"the variable {name!r} is an HDF5 virtual dataset, its values in other "
                                     "files; motorid reads only the file it is given: save the values in the "
                                     "file itself")
            if obj.dtype.kind not in "biuf":
                variables[name] = None
                continue
            claimed = int(np.prod(obj.shape, dtype=object)) * obj.dtype.itemsize
            total += claimed
            if total > limit:
                shape = "x".join(map(str, obj.shape))
                raise _over(name, f"claims {shape} values of {obj.dtype.itemsize} bytes ({claimed} bytes)", limit,
                            len(raw))
            # MATLAB writes column-major arrays: h5py sees them transposed
            variables[name] = np.asarray(obj).T
    return variables


def _limit_address_space(extra: int) -> None:
    """Let this process map at most ``extra`` bytes more than it has now (Linux; elsewhere nothing)."""
    try:
        import resource
        with open("/proc/self/statm") as f:
            now = int(f.read().split()[0]) * resource.getpagesize()
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        wanted = now + extra
        if hard != resource.RLIM_INFINITY:
            wanted = min(wanted, hard)
        if soft == resource.RLIM_INFINITY or soft > wanted:
            resource.setrlimit(resource.RLIMIT_AS, (wanted, hard))
    except (ImportError, OSError, ValueError):
        pass


def _child(raw: bytes, send: Any) -> None:
    """The reader's process: sends ``("ok", variables)`` or ``("refused"|"error"|"v7.3-missing", text)``.
    A crash says nothing here (no fault handler's dump): the parent says it in one line."""
    import faulthandler
    faulthandler.disable()
    # the file's own bound, then room for scipy or h5py themselves and a copy of the values
    _limit_address_space(3 * unpack_limit(len(raw)) + (1 << 30))
    try:
        if _is_hdf5(raw):
            variables = _hdf5_child(raw, send)
            if variables is None:
                return
        else:
            _check_v5(raw)
            from scipy import io as sio
            try:
                data = sio.loadmat(io.BytesIO(raw), squeeze_me=False)
            except NotImplementedError:                    # scipy's word for v7.3 (HDF5)
                variables = _hdf5_child(raw, send)
                if variables is None:
                    return
            else:
                variables = {k: v if isinstance(v, np.ndarray) and v.dtype.kind in "biuf" else None
                             for k, v in data.items() if not k.startswith("__")}
    except MatFileRefused as exc:
        send.send(("refused", str(exc)))
        return
    except MemoryError:
        send.send(("refused", f"reading it needs more memory than a {len(raw)}-byte .mat file may unpack to "
                              f"({unpack_limit(len(raw))} bytes): a decompression bomb or a damaged file"))
        return
    except Exception as exc:   # noqa: BLE001 -- the readers raise a zoo on a damaged file (MatReadError,
        # OSError "could not read bytes", IndexError, UnboundLocalError, NotImplementedError...)
        send.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    send.send(("ok", variables))


_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _is_hdf5(raw: bytes) -> bool:
    """A MATLAB v7.3 file (version 0x0200 at bytes 124-127) or any HDF5 file (its signature at 0 or 512)."""
    return raw[124:128] in (b"\x00\x02IM", b"\x02\x00MI") or _HDF5_SIGNATURE in (raw[:8], raw[512:520])


def _hdf5_child(raw: bytes, send: Any) -> dict[str, Any] | None:
    try:
        import h5py  # noqa: F401 -- optional: MATLAB v7.3 files only
    except ImportError:
        send.send(("v7.3-missing", ""))
        return None
    try:
        return _hdf5_variables(raw)
    except MatFileRefused:
        raise
    except Exception as exc:   # noqa: BLE001 -- h5py's errors on a damaged file (OSError, KeyError, ValueError)
        send.send(("error-hdf5", f"{type(exc).__name__}: {exc}"))
        return None


def _reader(raw: bytes) -> str:
    return "h5py's reader" if _is_hdf5(raw) else "scipy's reader"


def read_mat_variables(raw: bytes) -> dict[str, Any]:
    """The variables of a ``.mat`` file's bytes: numeric arrays, the others None.

    Raises
    ------
    MatFileRefused
        A variable outside the file, a size over :func:`unpack_limit`, a damaged file (the
        reader's error, its crash or its silence for :data:`MAT_READ_SECONDS`), or a v7.3
        file without h5py; the message names the variable and the rule, not the file.
    """
    import multiprocessing

    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    ctx = multiprocessing.get_context(method)
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_child, args=(raw, send), daemon=True)  # type: ignore[attr-defined]
    child.start()
    send.close()
    try:
        message = receive.recv() if receive.poll(MAT_READ_SECONDS) else None
    except EOFError:                    # the child ended without a word: it crashed
        message = None
    finally:
        receive.close()
    child.join(1.0)
    if child.is_alive():
        child.kill()
        child.join()
        raise MatFileRefused(f"a damaged MATLAB .mat file: {_reader(raw)} crashed on it (no answer in "
                             f"{MAT_READ_SECONDS:g} s); save it again from MATLAB, or export the columns as CSV")
    if message is None:
        code = child.exitcode
        how = f"signal {-code}" if code is not None and code < 0 else f"exit status {code}"
        raise MatFileRefused(f"a damaged MATLAB .mat file: {_reader(raw)} crashed on it ({how}); save it again "
                             "from MATLAB, or export the columns as CSV")
    kind, payload = message
    if kind == "ok":
        return payload
    if kind == "v7.3-missing":
        raise MatFileRefused("a MATLAB v7.3 (HDF5) file: reading it needs h5py (pip install h5py), or save it "
                             "from MATLAB with save(FILE, '-v7')")
    if kind == "error":
        raise MatFileRefused(f"a damaged or truncated MATLAB .mat file scipy cannot read ({payload})")
    if kind == "error-hdf5":
        raise MatFileRefused(f"a damaged MATLAB v7.3 (HDF5) file h5py cannot read ({payload})")
    raise MatFileRefused(payload)
