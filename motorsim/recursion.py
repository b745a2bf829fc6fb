"""The first-order linear recursion ``y[k] = e y[k-1] + x[k]``, without a Python loop per sample.

Every model in motorid is first order, so every simulation, residual and sensitivity
comes down to this recursion with a constant factor ``e = exp(-a h)``.
:func:`first_order_filter` solves it with ``scipy.signal.lfilter`` on long records
and, below :data:`SHORT_RECORD` samples, with a blocked scan in numpy: importing
``scipy.signal`` takes about half a second (most of what ``import control`` costs),
several times what a command needs to read and fit a short recording, while the
scan costs a few tens of microseconds per pass there (1.5 to 3 times an ``lfilter``
pass).  Both agree with the sequential loop to rounding (a few units in 1e-16 of
the largest value, tested against ``lfilter`` and the plain loop).

The scan: the record is cut into blocks of :data:`BLOCK` samples; within every
block the solution from a zero state is one product with the lower-triangular
matrix ``P[i, j] = e^(i-j)`` (all blocks in one ``matmul``); the block ends then
obey the same recursion with factor ``e^BLOCK``, solved the same way, and each
block adds its incoming state times ``e^(i+1)``.  For ``|e| <= 1`` every power is
at most 1, so nothing is amplified.  A result that is not finite everywhere (a
non-finite forcing, or an unstable factor overflowing) is recomputed by ``lfilter``,
whose sequential order keeps what the loop would give.

Once numba is loaded in a process (a friction or prediction-error fit loads it), or once the process
has sent :data:`COMPILE_AFTER` values through the recursion, the plain loop compiled by numba
(:func:`compiled_recursion`) runs instead of ``lfilter`` (from :data:`SHORT_RECORD` samples): 4 to 13
times faster, and the same numbers bit for bit (the same products and sums in the same order).  Shorter
records keep the scan whatever the process has loaded: its rounding differs from the loop's, and an answer
must not depend on what ran before it in the process (a sweep's CSV is the same from one worker or two).  A short
command that never loads numba does not pay its import (about 0.3 s) for it; ``MOTORID_NUMBA=0``
turns it off, as every compiled loop (:func:`motorsim.compiled.numba_jit`).

For example:

>>> import numpy as np
>>> from motorsim.recursion import first_order_filter
>>> first_order_filter(0.5, np.array([1.0, 0.0, 0.0, 2.0]), initial=4.0)
array([3.   , 1.5  , 0.75 , 2.375])
"""
from __future__ import annotations

import functools
import math
import sys
from typing import Callable

import numpy as np

from .compiled import numba_jit

__all__ = ["first_order_filter", "compiled_recursion", "recursion_loop", "SHORT_RECORD", "BLOCK", "COMPILE_AFTER"]

#: Records shorter than this (samples along the recursion) use the numpy scan, longer
#: ones ``scipy.signal.lfilter``.
SHORT_RECORD = 8192
#: Block length of the numpy scan (32 was the fastest of 16, 32, 64 and 128 at every length measured).
BLOCK = 32

_OFFSET = np.arange(BLOCK)[:, None] - np.arange(BLOCK)[None, :]
#: ``P[i, j] = powers[_POWER_INDEX[i, j]]``: ``e^(i-j)`` on and below the diagonal, the
#: zero kept in ``powers[BLOCK + 1]`` above it.
_POWER_INDEX = np.where(_OFFSET >= 0, _OFFSET, BLOCK + 1)
_EXPONENTS = np.arange(BLOCK + 2, dtype=float)
#: Values (samples times columns) a process sends through the numpy scan and ``lfilter`` before it compiles
#: the loop although nothing else has loaded numba: about 0.3 s of scans, what importing numba costs, so a
#: process never pays more than twice the better choice made in hindsight.
COMPILE_AFTER = 50_000_000
#: Values this process has sent through the scan and ``lfilter`` so far.
usage = {"values": 0}


def recursion_loop(e: float, x: np.ndarray, start: np.ndarray, y: np.ndarray) -> None:
    """``y[k, j] = e y[k-1, j] + x[k, j]`` with ``y[-1] = start``: the plain loop that
    :func:`compiled_recursion` compiles (``x`` and ``y`` of shape (n, m), ``start`` (m,))."""
    n, m = x.shape
    if m == 1:
        s = start[0]
        for k in range(n):
            s = e * s + x[k, 0]
            y[k, 0] = s
        return
    state = start.copy()
    for k in range(n):
        for j in range(m):
            state[j] = e * state[j] + x[k, j]
            y[k, j] = state[j]


@functools.cache
def compiled_recursion() -> Callable[[float, np.ndarray, np.ndarray, np.ndarray], None] | None:
    """:func:`recursion_loop` compiled by numba (cached on disk); None without numba or with ``MOTORID_NUMBA=0``."""
    jit = numba_jit()
    return None if jit is None else jit(recursion_loop)


def _compiled_loop() -> Callable[[float, np.ndarray, np.ndarray, np.ndarray], None] | None:
    """The compiled loop when this process has loaded numba or used the recursion enough, else None."""
    if compiled_recursion.cache_info().currsize or "numba" in sys.modules or usage["values"] >= COMPILE_AFTER:
        return compiled_recursion()
    return None


def first_order_filter(e: float, x: np.ndarray, initial: float | np.ndarray = 0.0,
                       out: np.ndarray | None = None) -> np.ndarray:
    """``y[k] = e y[k-1] + x[k]`` along axis 0, with ``y[-1] = initial``.

    The same as ``scipy.signal.lfilter([1], [1, -e], x, axis=0, zi=e * initial)`` (its
    first output), to rounding.

    Parameters
    ----------
    e : float
        The constant factor (``exp(-a h)`` for a pole ``a`` in 1/s and a sample period
        ``h`` in s).
    x : ndarray, shape (n,) or (n, m)
        The forcing; a 2-D array is ``m`` independent recursions, one per column.
    initial : float or ndarray, shape (m,)
        The state before the first sample.
    out : ndarray, optional
        Where to write ``y`` (the shape of ``x``, not overlapping it), so that a caller
        iterating over the same record allocates nothing.

    Returns
    -------
    ndarray
        ``y``, of the shape of ``x`` (``out`` when given).
    """
    x = np.asarray(x, dtype=float)
    if len(x) == 0:
        return x.copy() if out is None else out
    columns = x.reshape(len(x), -1)
    # the scan writes through reshaped views, so only a contiguous ``out`` is written in place
    target = out.reshape(columns.shape) if out is not None and out.flags.c_contiguous else None
    start = np.zeros(columns.shape[1])
    start += initial                                 # a scalar or one value per column
    y = None
    # only in place of lfilter, whose numbers it repeats bit for bit: the scan's rounding differs, so a record the
    # scan takes keeps it whatever the process has loaded (the same answers in every process and worker)
    loop = _compiled_loop() if len(x) >= SHORT_RECORD else None
    if loop is not None:
        y = target if target is not None else np.empty(columns.shape)
        loop(float(e), columns, start, y)
        if out is None:
            return y.reshape(x.shape)
        if y is not target:
            out[...] = y.reshape(x.shape)
        return out
    usage["values"] += columns.size
    if len(x) < SHORT_RECORD:
        with np.errstate(all="ignore"):              # overflow is caught below, as a non-finite result
            y = _blocked_scan(float(e), columns, start, target)
            if not math.isfinite(float(y.sum())):    # a sum that overflows only sends finite data to lfilter
                # a non-finite forcing or factor: within a block it would spread to earlier samples
                # (0 * inf), so such records take lfilter, which keeps the loop's order
                y = None
    if y is None:
        from scipy.signal import lfilter  # imported when used: it costs most of `import control`
        y, _ = lfilter([1.0], [1.0, -e], columns, axis=0, zi=(e * start)[None, :])
    if out is None:
        return y.reshape(x.shape)
    if y is not target:                              # lfilter's, or the scan's beside a strided ``out``
        out[...] = y.reshape(x.shape)
    return out


@functools.lru_cache(maxsize=8)
def _scan_factors(e: float) -> tuple[np.ndarray, np.ndarray]:
    """``e^0 ... e^BLOCK`` and a zero (read-only), and the block's lower-triangular ``P[i, j] = e^(i-j)``: the same
    for every pass with the factor ``e`` (a fit's few factors recur pass after pass)."""
    powers = np.power(e, _EXPONENTS)
    powers[BLOCK + 1] = 0.0
    within = powers[_POWER_INDEX]
    powers.flags.writeable = within.flags.writeable = False
    return powers, within


def _blocked_scan(e: float, x: np.ndarray, start: np.ndarray, y: np.ndarray | None = None) -> np.ndarray:
    """The numpy scan of the module docstring; ``x`` (n, m) with n >= 1, ``start`` (m,), into ``y``."""
    n, m = x.shape
    powers, within = _scan_factors(e)
    if y is None:
        y = np.empty((n, m))
    if n <= BLOCK:                                               # one block
        np.matmul(within[:n, :n], x, out=y)
        y += powers[1:n + 1, None] * start
        return y
    blocks, tail = divmod(n, BLOCK)
    full = blocks * BLOCK
    body = y[:full].reshape(blocks, BLOCK, m)
    np.matmul(within, x[:full].reshape(blocks, BLOCK, m), out=body)   # each block from a zero state
    if tail:
        np.matmul(within[:tail, :tail], x[full:], out=y[full:])
    parts = blocks + (1 if tail else 0)
    incoming = np.empty((parts, m))                              # the state before each block
    incoming[0] = start
    _blocked_scan(float(powers[BLOCK]), y[BLOCK - 1:full:BLOCK][:parts - 1], start, incoming[1:])
    body += incoming[:blocks, None, :] * powers[1:BLOCK + 1, None]
    if tail:
        y[full:] += incoming[blocks] * powers[1:tail + 1, None]
    return y
