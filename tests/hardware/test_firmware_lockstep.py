"""The emulated firmware (``avr-sim://``) in lock-step with the host: the same recording however slow the host.

The harness runs the AVR only as far as the host grants (``hardware/sim/motorid_avr_sim.c``,
the lock-step exchange), and the host's bytes reach the firmware at the cycle the grant starts:
two runs of the same experiment are the same run, cycle for cycle, whatever the machine's load.
A slow host (here: exchanges slowed, and a callback that stalls longer than the firmware's
watchdog) only takes longer.  One test runs the firmware against the wall clock
(``realtime=1``), the mode that shows a host keeping up with a board's real deadlines; it is
marked ``realtime`` and runs only with ``pytest --realtime`` (``make test-realtime``), because a
loaded machine fails it.
"""
from __future__ import annotations

import time
from urllib.parse import urlencode

import numpy as np
import pytest

import identify
from hardware import protocol as P
from hardware.serial_rig import SerialRig
from hardware.sim import launcher
from hardware.sim.launcher import open_avr_sim
from motorsim import PRBS, Experiment, Sine

pytestmark = pytest.mark.firmware

A, B, COUNTS_PER_REV = 25.0, 3.0, 16667
EXPERIMENTS = [Experiment(Sine(20.0, 100), sample_period=0.002, duration=0.4),
               Experiment(PRBS(120, -120, order=6, hold=5), sample_period=0.001, duration=0.3)]


def _record(on_sample=None, **query) -> tuple[list, dict]:
    """Both experiments on one fresh harness; the recordings and the harness's final statistics."""
    url = "avr-sim://?" + urlencode({"a": A, "b": B, "friction": 20, "speed": 0, **query})
    out = []
    with open_avr_sim(url, 250000, 0.02) as port:
        with SerialRig(port, 250000, counts_per_rev=COUNTS_PER_REV, watchdog_ms=200) as rig:
            assert rig.simulated_time
            for experiment in EXPERIMENTS:
                out.append(rig.run(experiment, on_sample=on_sample))
    return out, port.avr_simulation.stats


def _assert_same(first: list, second: list) -> None:
    for a, b in zip(first, second, strict=True):
        for column in ("seq", "time", "duty", "counts"):
            np.testing.assert_array_equal(getattr(a, column), getattr(b, column), err_msg=column)
        assert a.metadata == b.metadata


@pytest.fixture(scope="module")
def reference(built):
    return _record()


def test_two_runs_of_the_same_experiment_are_the_same_run(reference):
    first, stats = reference
    second, again = _record()
    _assert_same(first, second)
    # the emulations themselves agree to the cycle: the same edges, the same final count
    assert (stats["emulated_s"], stats["edges"], stats["counts"]) == (again["emulated_s"], again["edges"],
                                                                      again["counts"])
    assert np.ptp(first[0].counts) > 1000, "the motor really turned"


def test_a_slow_host_gives_the_same_recording(reference, monkeypatch):
    # Every exchange with the harness 1 ms later on the wall clock, and the host stalled for
    # 0.6 s in the middle of the first run: 3 times the firmware's host-silence watchdog, 300
    # samples of a board's wall time.  Simulated time stands still meanwhile.
    grant = launcher.AvrLockstepPort._grant

    def slow_grant(self, *args):
        time.sleep(0.001)
        return grant(self, *args)

    stalled = []

    def stall(sample):
        if sample.seq == 100 and not stalled:
            stalled.append(sample.seq)
            time.sleep(0.6)

    monkeypatch.setattr(launcher.AvrLockstepPort, "_grant", slow_grant)
    slow, _ = _record(on_sample=stall)
    assert stalled == [100]
    _assert_same(slow, reference[0])
    assert slow[0].metadata["device_end_reason"] == str(int(P.EndReason.COMPLETE))


@pytest.mark.realtime
def test_in_real_time_the_host_keeps_up_with_the_firmware(built):
    # The firmware against the wall clock, as on a board: 500 samples/s for 3 s, read, checked
    # and heartbeaten by the host in real time; nothing dropped, no tick late, and the motor's
    # a and b within 1 % (the count quantisation leaves less).
    experiment = Experiment(Sine(20.0, 100), sample_period=0.002, duration=3.0)
    url = "avr-sim://?" + urlencode({"a": A, "b": B, "realtime": 1})
    with open_avr_sim(url, 250000, 0.02) as port:
        with SerialRig(port, 250000, counts_per_rev=COUNTS_PER_REV, watchdog_ms=200) as rig:
            assert not rig.simulated_time
            recording = rig.run(experiment)
    meta = recording.metadata
    assert meta["samples_lost"] == "0" and meta["device_tick_overruns"] == "0"
    estimate = identify.fit(recording, method="oe", input_delay=P.DEVICE_INPUT_DELAY)
    assert estimate.a == pytest.approx(A, rel=0.01) and estimate.b == pytest.approx(B, rel=0.01)
