"""The gate's timing helpers on a made-up clock (no clock of the machine involved), and its memory probe."""
import os

import numpy as np
import pytest

from motorid.bench.selection import peak_memory
from motorid.bench.timing import interleaved_rounds, least_time, median_ratio


class FakeClock:
    """A clock that only the timed functions move: each call adds its own cost."""

    def __init__(self):
        self.now = 0.0
        self.calls = []

    def __call__(self):
        return self.now

    def work(self, name, costs):
        costs = iter(costs)

        def run():
            self.calls.append(name)
            self.now += next(costs)
        return run


def test_rounds_alternate_the_functions_and_time_each_call():
    clock = FakeClock()
    a = clock.work("a", [0.001] * 100)                      # batched: 20 calls fill the 0.02 s of a batch
    b = clock.work("b", [0.5, 0.4, 0.6, 0.5])              # slow: one call a round
    rounds = interleaved_rounds([a, b], repeats=3, clock=clock)
    assert rounds.shape == (3, 2)
    np.testing.assert_allclose(rounds[:, 0], 0.001, rtol=1e-9)
    np.testing.assert_allclose(rounds[:, 1], [0.4, 0.6, 0.5], rtol=1e-9)
    # warm-ups first, then each round times a (20 calls) and then b (one call)
    assert clock.calls == ["a", "b"] + (["a"] * 20 + ["b"]) * 3


def test_the_ratio_is_the_median_of_the_rounds_ratios():
    # a round where both were slowed (the machine got busy) keeps its ratio; a ratio of medians would not
    rounds = np.array([[1.0, 0.5], [4.0, 2.0], [1.1, 0.5], [1.0, 0.6]])
    assert median_ratio(rounds, 0, 1) == pytest.approx(np.median([2.0, 2.0, 2.2, 1.0 / 0.6]))
    assert median_ratio(rounds, 1, 0) == pytest.approx(np.median([0.5, 0.5, 0.5 / 1.1, 0.6]))


def test_least_time_is_the_least_after_a_warm_up():
    clock = FakeClock()
    f = clock.work("f", [9.0, 0.3, 0.2, 0.25])              # the warm-up's 9 s is left out
    assert least_time(f, repeats=3, clock=clock) == pytest.approx(0.2)
    assert len(clock.calls) == 4


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="the child's own peak comes from /proc")
def test_the_memory_probe_reports_the_childs_own_peak():
    # a child that touches 200 MB peaks at least 150 MB above one that does nothing; the parent's own size (this
    # test process, far larger than an idle child) does not show in either
    idle = peak_memory("-c", "pass")
    busy = peak_memory("-c", "import numpy; a = numpy.ones(25_000_000); print(a.sum())")
    assert busy - idle > 150 * 2**20
    assert idle < 60 * 2**20
    with pytest.raises(RuntimeError, match="failed"):
        peak_memory("-c", "raise SystemExit(3)")


def test_cpu_time_is_taken_with_blas_on_one_thread():
    # a BLAS helper thread waiting for a core spins on the process's CPU clock: the gate's CPU timings run the work
    # on one BLAS thread, and leave the setting as it was after; a timing on another clock changes nothing
    from threadpoolctl import threadpool_info

    from motorid.bench.timing import cpu_clock

    def blas_threads():
        return max((pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"), default=1)
    before = blas_threads()
    seen = []
    least_time(lambda: seen.append(blas_threads()), repeats=2, clock=cpu_clock)
    interleaved_rounds([lambda: seen.append(blas_threads())], repeats=2, batch_seconds=0.0, clock=cpu_clock)
    assert seen and set(seen) == {1}
    assert blas_threads() == before
    clock = FakeClock()
    least_time(lambda: seen.append(blas_threads()) or clock.work("f", [0.1])(), repeats=1, clock=clock)
    assert seen[-1] == before
