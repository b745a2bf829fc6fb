"""``first_order_filter`` against ``scipy.signal.lfilter`` and the plain loop, by each of its paths: the
numpy scan and ``lfilter`` (no numba loaded), and the loop compiled by numba.

Tolerance 1e-13 of the largest value: both are sums of the same terms in a different
order; the scan's error grows with its few levels of blocks (measured below 1e-15), far
below what any estimate reads.  The compiled loop is ``lfilter``'s order exactly: equal bit for bit.
"""
import numpy as np
import pytest
from scipy.signal import lfilter

from motorsim import recursion
from motorsim.recursion import BLOCK, SHORT_RECORD, compiled_recursion, first_order_filter

TOL = 1e-13


@pytest.fixture(autouse=True, params=["numpy", "numba"])
def path(request, monkeypatch):
    """Every test by the numpy scan / ``lfilter`` and by the compiled loop."""
    if request.param == "numba":
        if compiled_recursion() is None:
            pytest.skip("numba is not installed or MOTORID_NUMBA=0")
        monkeypatch.setattr(recursion, "_compiled_loop", compiled_recursion)
    else:
        monkeypatch.setattr(recursion, "_compiled_loop", lambda: None)
    return request.param


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


@pytest.mark.parametrize("n", [1, 7, 3000, SHORT_RECORD + 7])
@pytest.mark.parametrize("columns", [1, 3])
def test_the_compiled_loop_is_lfilter_bit_for_bit(path, n, columns):
    if path != "numba":
        pytest.skip("the compiled loop's own test")
    rng = np.random.default_rng(n)
    x = rng.standard_normal((n, columns))
    initial = rng.standard_normal(columns)
    want, _ = lfilter([1.0], [1.0, -0.987], x, axis=0, zi=(0.987 * initial)[None, :])
    loop = recursion.compiled_recursion()
    got = np.empty_like(x)
    loop(0.987, x, initial.copy(), got)
    assert np.array_equal(got, want)
    if n >= SHORT_RECORD:           # where first_order_filter takes it: in place of lfilter, whatever was loaded
        assert np.array_equal(first_order_filter(0.987, x, initial), want)
        assert np.array_equal(first_order_filter(0.987, x[::-1], initial),          # a strided forcing
                              lfilter([1.0], [1.0, -0.987], x[::-1], axis=0, zi=(0.987 * initial)[None, :])[0])
    else:                           # a short record keeps the scan in every process: no answer depends on history
        assert np.array_equal(first_order_filter(0.987, x, initial),
                              recursion._blocked_scan(0.987, x, initial.copy()))


def test_the_loop_compiles_once_numba_is_loaded_or_the_scans_have_cost_enough(path, monkeypatch):
    if path != "numpy":
        pytest.skip("the switch's own test")
    monkeypatch.undo()                                   # the real switch
    import sys
    compiled = compiled_recursion()
    monkeypatch.setitem(recursion.usage, "values", 0)
    monkeypatch.setattr(recursion.compiled_recursion, "cache_info", lambda: type("Info", (), {"currsize": 0})())
    if "numba" in sys.modules:
        monkeypatch.delitem(sys.modules, "numba")
    assert recursion._compiled_loop() is None           # a short command never imports numba for the recursion
    first_order_filter(0.5, np.ones((1000, 2)))
    assert recursion.usage["values"] == 2000             # the scan counts what it filtered
    monkeypatch.setitem(recursion.usage, "values", recursion.COMPILE_AFTER)
    assert recursion._compiled_loop() is compiled        # enough scans: the loop (None without numba)


def test_motorid_numba_0_keeps_the_numpy_paths(path, monkeypatch):
    if path != "numpy":
        pytest.skip("the switch's own test")
    monkeypatch.undo()
    monkeypatch.setenv("MOTORID_NUMBA", "0")
    compiled_recursion.cache_clear()
    try:
        assert compiled_recursion() is None
        monkeypatch.setitem(recursion.usage, "values", recursion.COMPILE_AFTER)
        assert recursion._compiled_loop() is None
        x = np.random.default_rng(0).standard_normal(500)
        assert _close(first_order_filter(0.9, x), lfilter([1.0], [1.0, -0.9], x)) < TOL
    finally:
        compiled_recursion.cache_clear()
