"""Recordings read for a fit, screened for corrupted samples and for the same file given twice.

``motorid identify`` reads its files through :func:`read_and_fit`: the screening itself is
:func:`identify.checks.screening.screened_fit`'s (what ``identify.fit`` does): a row no motor can
produce or an isolated residual outlier after the fit is refused, naming the file and the row's
``seq``; with ``--drop-outliers`` such rows are dropped as gaps, the fit is repeated, and every
dropped row is reported.  Pooling the same data twice would halve the
variance the standard errors claim, so a file given twice is refused.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import stat
from typing import Any, Callable, NamedTuple, Sequence

from motorid.arguments import CommandError
from motorsim.reading import read_recording
from motorsim.recording import Recording

__all__ = ["DroppedSamples", "read_and_fit", "refuse_duplicates", "with_speed_unit"]


class DroppedSamples(NamedTuple):
    """Rows dropped from one file before the fit, by ``seq``, and why."""

    file: str
    seq: list[int]
    reason: str

    def __str__(self) -> str:
        shown = ", ".join(map(str, self.seq[:10])) + (", ..." if len(self.seq) > 10 else "")
        return f"{self.file}: seq {shown} ({self.reason})"


def refuse_duplicates(files: Sequence[str]) -> None:
    """Refuse a file given twice, by path or by identical content.

    Only files of equal size can have the same content, so only those are read and hashed (one
    file, the usual call, is never read here).
    """
    seen: dict[Any, str] = {}
    sizes: dict[int, list[str]] = {}
    for name in files:
        try:
            st = os.stat(name)
        except OSError:
            continue  # the reader names the problem
        key: Any = (st.st_dev, st.st_ino)
        if key in seen:
            raise CommandError(f"{name} is the same file as {seen[key]}; pooling data twice would understate "
                               "the standard errors")
        seen[key] = name
        if stat.S_ISREG(st.st_mode) and st.st_size <= 1 << 28:
            sizes.setdefault(st.st_size, []).append(name)
    digests: dict[str, str] = {}
    for same_size in (names for names in sizes.values() if len(names) > 1):
        for name in same_size:
            try:
                with open(name, "rb") as f:
                    digest = hashlib.sha256(f.read()).hexdigest()
            except OSError:
                continue
            if digest in digests:
                raise CommandError(f"{name} has the same content as {digests[digest]}; pooling data twice would "
                                   "understate the standard errors")
            digests[digest] = name


def read_and_fit(files: Sequence[str], method: str, options: dict[str, Any], *, drop_outliers: bool = False,
                 read: Callable[[str, bool], Recording] | None = None,
                 ) -> tuple[Any, list[Recording], list[DroppedSamples]]:
    """Read ``files``, screen them, fit ``method``; returns the estimate, the recordings fitted, the drops.

    The screening is :func:`identify.checks.screening.screened_fit`'s, as ``identify.fit`` does it, so
    the command line and Python give the same answer or the same refusal.

    Parameters
    ----------
    files : sequence of str
        Recordings (format v1), pooled.
    method : str
        Estimator name.
    options : dict
        Estimator keyword options.
    drop_outliers : bool, optional
        Drop implausible rows and isolated residual outliers as gaps (and refit) instead of refusing.
    read : callable, optional
        ``read(path, check_samples) -> Recording``; default :func:`~motorsim.reading.read_recording`
        (a lab's own files come through the column mapping of ``motorid import``).

    Raises
    ------
    CommandError
        A file given twice, or an isolated residual outlier without ``drop_outliers``.
    """
    from identify.checks.screening import screened_fit
    from identify.errors import CorruptedSamplesError, NotIdentifiableError
    from identify.methods import method_function
    refuse_duplicates(files)
    if read is None:
        def read(path: str, check_samples: bool) -> Recording:
            return read_recording(path, check_samples=check_samples)
    recs = [read(f, not drop_outliers) for f in files]
    try:
        found = screened_fit(recs, method_function(method), options, outliers="drop" if drop_outliers else "refuse",
                             samples_checked=not drop_outliers, name=method)
    except CorruptedSamplesError as exc:
        shown = ", ".join(map(str, exc.seq[:10]))
        raise CommandError(f"{files[exc.recording]}: {exc.reason} at seq {shown}; a corrupted sample? fix the "
                           "file, or re-run with --drop-outliers to drop them as gaps") from None
    except NotIdentifiableError as exc:
        # every refusal of the data names the files they came from, whichever estimator found it
        if any(str(f) in str(exc) for f in files):
            raise
        raise NotIdentifiableError(f"{', '.join(map(str, files))}: {exc}") from None
    dropped = [DroppedSamples(files[d.recording], list(d.seq), d.reason) for d in found.dropped]
    return with_speed_unit(found.estimate, found.recordings), list(found.recordings), dropped


def with_speed_unit(estimate: Any, recordings: Sequence[Recording]) -> Any:
    """``estimate`` remembering the speed unit its recordings came in (rad/s when they differ)."""
    units = {r.speed_unit for r in recordings}
    unit = units.pop() if len(units) == 1 else "rad/s"
    return dataclasses.replace(estimate, speed_unit=unit) if unit != estimate.speed_unit else estimate
