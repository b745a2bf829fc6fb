"""The order statistics of long columns are numpy's own, bit for bit, whatever the column holds."""
import numpy as np
import pytest

from motorsim import quantiles
from motorsim.quantiles import kth_smallest, median

N = 200_003     # above quantiles.DIRECT: the bracketed path


def _columns():
    rng = np.random.default_rng(7)
    normal = rng.normal(size=N)
    return {
        "normal": normal,
        "whole numbers (ties)": rng.integers(0, 20, N).astype(float),
        "one value": np.full(N, 2.5),
        "sorted": np.arange(N, dtype=float),
        "reversed": np.arange(N, dtype=float)[::-1].copy(),
        "int64": rng.integers(-5, 5, N),
        "a sine (periodic)": np.sin(np.arange(N) * 0.001),
        "nan and inf": np.where(rng.random(N) < 0.02, np.nan, np.where(rng.random(N) < 0.02, np.inf, normal)),
        "mostly nan": np.where(rng.random(N) < 0.9, np.nan, normal),
        "two clusters": np.where(rng.random(N) < 0.5, -1e9, 1e9) + normal,
        # a column built against the sample: the values the sample sees are not the column's
        "adversarial": _against_the_sample(normal),
    }


def _against_the_sample(x):
    x = np.abs(x).copy()
    seen = np.random.default_rng(0).integers(0, len(x), quantiles.SAMPLE)
    x[seen] = -1.0                                   # every sampled value below every other
    return x


@pytest.mark.parametrize("name", list(_columns()))
def test_kth_smallest_is_the_value_np_partition_places(name):
    x = _columns()[name]
    before = x.copy()
    for k in (0, 1, N // 3, N // 2, N - 1 - N // 100, N - 2, N - 1):
        ours, theirs = kth_smallest(x, k), np.partition(x, k)[k]
        assert ours.dtype == theirs.dtype
        assert np.array_equal(ours, theirs, equal_nan=True), (k, ours, theirs)
    np.testing.assert_array_equal(x, before)         # the column is not reordered


@pytest.mark.parametrize("name", [n for n in _columns() if "nan" not in n])
@pytest.mark.parametrize("drop", [0, 1])             # odd and even counts: numpy averages the two middle values
def test_median_is_np_median(name, drop):
    x = _columns()[name][drop:]
    assert median(x) == float(np.median(x))


def test_short_columns_and_bad_places():
    x = np.array([3.0, 1.0, 2.0])
    assert kth_smallest(x, 0) == 1.0 and median(x) == 2.0 and median(x[:2]) == 2.0
    with pytest.raises(IndexError, match="k must be in 0...2, got 3"):
        kth_smallest(x, 3)
    with pytest.raises(ValueError, match="the median of no values"):
        median(x[:0])
