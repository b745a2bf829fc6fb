"""Order statistics of long columns: :func:`kth_smallest` and :func:`median`, exactly numpy's, in fewer passes.

``np.partition`` reorders a whole copy of the column to find one value: on 10^6 rows about 7-10 ms,
several times one pass over the data, and the checks of every file read ask for three of them (the
time base's median interval, the 99th-percentile speed and duty step of the plausibility rules).
Here the value is bracketed first, from a fixed pseudo-random sample of :data:`SAMPLE` values, between
two sample quantiles a few standard errors either side of it; one pass counts the values below the
bracket and keeps those within it, and only those (a few per cent of the column) are partitioned.
When the bracket misses (it cannot on a sample drawn fairly, but a column may be adversarial) the
whole column is partitioned as before.  Either way the value returned is the one ``np.partition``
gives, bit for bit: only the work to find it differs.

>>> import numpy as np
>>> x = np.random.default_rng(1).normal(size=200_001)
>>> float(kth_smallest(x, 198_000)) == float(np.partition(x, 198_000)[198_000])
True
>>> float(median(x)) == float(np.median(x))
True
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["kth_smallest", "median", "SAMPLE", "DIRECT"]

#: Values sampled to bracket the order statistic.
SAMPLE = 8192
#: Columns shorter than this are partitioned directly (the bracket does not pay below it).
DIRECT = 65_536
#: Standard errors of the sample quantile the bracket spans on either side.
_MARGIN = 6.0


def kth_smallest(values: np.ndarray, k: int) -> np.generic:
    """``np.partition(values, k)[k]``: the ``k``-th smallest of a 1-D array (0-based), exactly.

    Parameters
    ----------
    values : ndarray, shape (n,)
        The column; not changed.  NaN sorts last, as in ``np.partition``.
    k : int
        ``0 <= k < n``.

    Returns
    -------
    numpy scalar
        The value, of the array's dtype.
    """
    values = np.asarray(values)
    if not 0 <= k < len(values):
        raise IndexError(f"k must be in 0...{len(values) - 1}, got {k}")
    return _smallest(values, k, k)[-1]


def median(values: np.ndarray) -> float:
    """``float(np.median(values))`` of a 1-D array without NaN, exactly (the mean of the two middle values of an
    even count, as numpy takes it)."""
    values = np.asarray(values)
    n = len(values)
    if n == 0:
        raise ValueError("the median of no values")
    if n < DIRECT:
        return float(np.median(values))
    if n % 2:
        return float(_smallest(values, n // 2, n // 2)[0])
    return float(np.mean(np.array(_smallest(values, n // 2 - 1, n // 2))))


def _smallest(values: np.ndarray, first: int, last: int) -> list:
    """The ``first``-th and ``last``-th smallest values (``first <= last``, close together), as ``np.partition``
    places them."""
    n = len(values)
    if n < DIRECT:
        part = np.partition(values, [first, last])
        return [part[first], part[last]]
    sample = np.sort(values[np.random.default_rng(0).integers(0, n, SAMPLE)])
    q_lo, q_hi = first / (n - 1), last / (n - 1)
    lo = sample[max(0, math.floor((q_lo - _spread(q_lo)) * (SAMPLE - 1)))]
    hi = sample[min(SAMPLE - 1, math.ceil((q_hi + _spread(q_hi)) * (SAMPLE - 1)))]
    if lo == lo and hi == hi:                        # no NaN in the bracket (comparisons could not place it)
        below = int(np.count_nonzero(values < lo))
        if below <= first:
            if lo == hi:                             # one value spans the bracket (ties): it is the answer if it
                if last < below + int(np.count_nonzero(values == lo)):     # holds both places
                    return [lo, lo]
            else:
                within = values[(values >= lo) & (values <= hi)]
                if last < below + len(within):
                    within.partition([first - below, last - below])     # a copy of a few per cent, in place
                    return [within[first - below], within[last - below]]
    part = np.partition(values, [first, last])       # the bracket missed: the whole column, as numpy does it
    return [part[first], part[last]]


def _spread(q: float) -> float:
    """Half the bracket around the sample quantile ``q``: :data:`_MARGIN` standard errors and two samples."""
    return _MARGIN * math.sqrt(q * (1 - q) / SAMPLE) + 2 / SAMPLE
