"""identify.sums: long sums of products by numpy's own loop, and BLAS on one thread inside a fit."""
import sys

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (its BLAS loaded, as inside every fit)
import threadpoolctl

from identify import sums
from identify.checks.screening import screened_fit
from identify.methods import method_function
from motorsim import Experiment, Motor, Multisine, SimRig


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]


@pytest.fixture(scope="module")
def recording():
    return SimRig(Motor(25.0, 3.0), rng=np.random.default_rng(0)).run(
        Experiment(Multisine((5.0, 17.0, 41.0), (60, 60, 50), (0, 1, 2)), 0.005, 4.0))


def test_dot_and_sum_squares_are_the_sums_of_products():
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=50_001), rng.normal(size=50_001)
    # the same sum in another order: a few ulps of the terms' magnitude apart
    assert sums.dot(x, y) == pytest.approx(float(np.sum(x * y)), abs=1e-10)
    assert sums.sum_squares(x) == pytest.approx(float(np.sum(x * x)), rel=1e-12)


def test_every_blas_runs_on_one_thread_inside_a_fit_and_as_before_after_it(recording):
    before = _blas_threads()
    assert before, "no BLAS library found by threadpoolctl: nothing to limit"
    seen = []

    def estimator(recs, **options):
        seen.append(_blas_threads())
        return method_function("oe")(recs, **options)

    est = screened_fit(recording, estimator, {"input_delay": 0}).estimate
    assert seen and all(threads == [1] * len(before) for threads in seen)
    assert _blas_threads() == before
    assert est.a == pytest.approx(25.0, rel=1e-3)


def test_the_limit_is_undone_when_the_fit_raises(recording):
    before = _blas_threads()

    def failing(recs, **options):
        raise ValueError("refused")

    with pytest.raises(ValueError, match="refused"):
        screened_fit(recording, failing, {})
    assert _blas_threads() == before


def test_without_threadpoolctl_the_fit_runs_as_it_is(recording, monkeypatch):
    monkeypatch.setattr(sums, "_controller", None)
    monkeypatch.setitem(sys.modules, "threadpoolctl", None)     # its import fails, as where it is not installed
    before = _blas_threads()
    seen = []

    def estimator(recs, **options):
        seen.append(_blas_threads())
        return method_function("oe")(recs, **options)

    limited = screened_fit(recording, method_function("oe"), {"input_delay": 0}).estimate
    est = screened_fit(recording, estimator, {"input_delay": 0}).estimate
    assert seen == [before] and sums._controller is False
    # the same fit on as many threads: the same answer to the solver's tolerance (sums in another order)
    assert est.a == pytest.approx(limited.a, rel=1e-9) and est.b == pytest.approx(limited.b, rel=1e-9)
