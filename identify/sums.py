"""Sums of products over long vectors, by numpy's own loop (``einsum``) rather than a BLAS dot product.

OpenBLAS runs a dot product of more than about 10^4 numbers on threads, and on a busy machine each
call waits for a free core: on 15 000 rows under a load average of 10, 26 ms for the 20 lags of an
autocorrelation against 0.7 ms by ``einsum``; 13 ms against 6 us for one residual sum of squares on
a loaded 2-core machine.  Every long sum of products in :mod:`identify` goes through here.

The products numpy sends to BLAS all the same (a matrix times a long vector, ``x @ y`` in code
that is not :mod:`identify`'s own) run single-threaded inside a fit: :func:`single_threaded_blas`,
which every fit of :func:`identify.checks.screening.screened_fit` (``identify.fit``, ``motorid identify``)
runs in.  A fit is a sequence of passes over its rows, each too short for threads to pay: on a
10^6-row ``motorid identify FILE`` the threads' waiting cost 0.11 s of CPU time of 0.55 s.
"""
from __future__ import annotations

import contextlib
from typing import Any, Iterator

import numpy as np

__all__ = ["dot", "sum_squares", "single_threaded_blas"]


def dot(x: np.ndarray, y: np.ndarray) -> float:
    """``x . y`` of two 1-D arrays of one length, by numpy's own loop."""
    return float(np.einsum("i,i->", x, y))


def sum_squares(r: np.ndarray) -> float:
    """``r . r`` of a 1-D array (a residual sum of squares), by numpy's own loop."""
    return float(np.einsum("i,i->", r, r))


#: The BLAS libraries loaded in this process, found once (threadpoolctl's controller), or False without threadpoolctl.
_controller: Any = None


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with every loaded BLAS library on one thread (their settings restored after).

    By threadpoolctl (a dependency); where it is missing the block runs as it is.  The libraries
    are listed on first use, numpy's and scipy's loaded before.
    """
    global _controller
    if _controller is None:
        try:
            import scipy.linalg  # noqa: F401  (its own BLAS loaded before the libraries are listed)
            from threadpoolctl import ThreadpoolController
            _controller = ThreadpoolController()
        except ImportError:
            _controller = False
    if _controller is False:
        yield
        return
    with _controller.limit(limits=1, user_api="blas"):
        yield
