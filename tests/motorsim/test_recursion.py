"""``first_order_filter`` against ``scipy.signal.lfilter`` and the plain loop.

Tolerance 1e-13 of the largest value: both are sums of the same terms in a different
order; the scan's error grows with its few levels of blocks (measured below 1e-15), far
below what any estimate reads.
"""
import numpy as np
import pytest
from scipy.signal import lfilter

from motorsim.recursion import BLOCK, SHORT_RECORD, first_order_filter

TOL = 1e-13


def _loop(e, x, initial):
    y = np.empty_like(x)
    state = np.broadcast_to(np.asarray(initial, dtype=float), x.shape[1:]).copy()
    for k in range(len(x)):
        state = e * state + x[k]
        y[k] = state
    return y


def _close(got, want):
    scale = max(float(np.max(np.abs(want))), 1e-300)
    return float(np.max(np.abs(got - want))) / scale


@pytest.mark.parametrize("n", [1, 2, BLOCK - 1, BLOCK, BLOCK + 1, BLOCK * BLOCK + 5, 3000,
                               SHORT_RECORD - 1, SHORT_RECORD, SHORT_RECORD + 7])
@pytest.mark.parametrize("e", [0.0, 1e-12, 0.5, 0.975, 0.999999, 1.0])
def test_matches_lfilter_across_block_boundaries(n, e):
    rng = np.random.default_rng(n)
    x = rng.standard_normal((n, 3)) * [1.0, 1e3, 1e-3]
    initial = np.array([0.7, -2.0, 5.0])
    want, _ = lfilter([1.0], [1.0, -e], x, axis=0, zi=(e * initial)[None, :])
    got = first_order_filter(e, x, initial)
    assert got.shape == x.shape
    for column in range(3):
        assert _close(got[:, column], want[:, column]) < TOL


@pytest.mark.parametrize("n", [5, 200, 2 * BLOCK * BLOCK + 3])
def test_one_dimensional_and_scalar_initial_state_match_the_loop(n):
    x = np.sin(np.arange(n) * 0.37) * 200.0
    got = first_order_filter(0.9, x, 1.5)
    assert got.shape == (n,)
    assert _close(got, _loop(0.9, x[:, None], 1.5)[:, 0]) < TOL


def test_a_factor_above_one_grows_as_the_loop_does():
    x = np.ones(5000)
    assert _close(first_order_filter(1.001, x), _loop(1.001, x[:, None], 0.0)[:, 0]) < 1e-12


@pytest.mark.parametrize("bad", [np.inf, np.nan])
def test_a_non_finite_forcing_spreads_only_forward(bad):
    x = np.ones(1000)
    x[400] = bad
    got = first_order_filter(0.9, x, 0.0)
    want = lfilter([1.0], [1.0, -0.9], x)
    assert np.all(np.isfinite(got[:400]))
    assert np.array_equal(np.isfinite(got), np.isfinite(want))
    assert _close(got[:400], want[:400]) < TOL


def test_overflow_gives_the_loops_infinities_without_warnings():
    with np.errstate(all="raise"):
        got = first_order_filter(1.5, np.ones(3000))
    assert np.isinf(got[-1]) and np.isfinite(got[10])


def test_empty_forcing_gives_an_empty_result():
    assert first_order_filter(0.5, np.empty((0, 2)), np.zeros(2)).shape == (0, 2)


@pytest.mark.parametrize("n", [20, 1000, SHORT_RECORD + 3])
def test_out_receives_the_result_contiguous_or_not(n):
    x = np.cos(np.arange(n) * 0.1)[:, None] * [1.0, 2.0]
    want = first_order_filter(0.95, x, [0.5, -0.5])
    contiguous = np.full((n, 2), np.nan)
    assert first_order_filter(0.95, x, [0.5, -0.5], out=contiguous) is contiguous
    assert np.array_equal(contiguous, want)
    wide = np.full((n, 3), np.nan)                       # a column of a wider array: strided
    first_order_filter(0.95, x[:, 0], 0.5, out=wide[:, 1])
    assert _close(wide[:, 1], want[:, 0]) < TOL and np.all(np.isnan(wide[:, [0, 2]]))
