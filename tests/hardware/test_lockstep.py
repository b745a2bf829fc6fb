"""``fake://`` in lock-step with the host: simulated time, the same recording however slow the host.

The device's clock moves only while the host reads (``hardware/lockstep.py``), and ``SerialRig``
counts its timeouts, HEARTBEATs and deadline in that clock.  What the host does between reads,
and how long the machine takes to do it, cannot change a sample.  The emulated firmware's own
tests of the same (``avr-sim://``) are in ``test_firmware_lockstep.py``.
"""
from __future__ import annotations

import time

import numpy as np
import pytest

from hardware import protocol as P
from hardware.errors import RigTimeoutError
from hardware.fake_device import FakeLockstepPort, parse_fake_url
from hardware.lockstep import POLL_QUANTUM
from hardware.ports import open_port
from hardware.serial_rig import SerialRig
from hardware.sim.device_link import DeviceLink
from motorsim import PRBS, Experiment, Sine

# Angle noise, a bias (the motor creeps while the device idles between runs) and faults on the
# link all draw on the device's seeded generator or its clock: any dependence on the wall clock
# or the order of host and device would show in the counts, the gaps or the counters.
NOISY = "fake://?a=25&b=3&speed=0&seed=7&angle_noise=0.002&bias=2&flip_rate=0.01&drop_rate=0.01&garbage_rate=0.01"
EXPERIMENTS = [Experiment(Sine(20.0, 100), sample_period=0.002, duration=0.4),
               Experiment(PRBS(80, -80, order=6, hold=4), sample_period=0.005, duration=0.5)]


def _record(url: str, on_sample=None, **rig) -> list:
    """Both experiments, one after the other on one device, as recordings (what a run returns)."""
    out = []
    with SerialRig(url, watchdog_ms=200, **rig) as rig_:
        assert rig_.simulated_time
        for experiment in EXPERIMENTS:
            out.append(rig_.run(experiment, on_sample=on_sample))
    return out


def _assert_same(first: list, second: list) -> None:
    for a, b in zip(first, second, strict=True):
        for column in ("seq", "time", "duty", "counts"):
            np.testing.assert_array_equal(getattr(a, column), getattr(b, column), err_msg=column)
        assert a.metadata == b.metadata


def test_the_same_seeded_run_gives_the_same_recording_twice():
    first, second = _record(NOISY), _record(NOISY)
    _assert_same(first, second)
    lost = int(first[0].metadata["samples_lost"]) + int(first[1].metadata["samples_lost"])
    assert lost > 0, "the faults were injected (the comparison covers the link's losses too)"
    assert np.ptp(first[1].counts) > 100, "the motor really turned"


def test_a_host_that_stalls_longer_than_the_watchdog_and_the_silence_timeout_changes_nothing():
    # A host stalled for 1.2 s of wall time (a loaded machine, a slow plot) in the middle of a run:
    # more than the device's 200 ms watchdog and the rig's 1 s silence timeout, and, on the wall
    # clock, 600 samples at 2 ms: a device ticking meanwhile would have dropped most of them.
    stalled = []

    def stall(sample):
        if sample.seq == 50 and len(stalled) < 2:
            stalled.append(sample.seq)
            time.sleep(0.6)

    slow = _record(NOISY, on_sample=stall)
    assert stalled == [50, 50]
    _assert_same(slow, _record(NOISY))


def test_a_slow_device_clock_paces_the_run_and_the_deadline_counts_simulated_time():
    # speed=0.08: 0.2 s of device time take 2.5 s of wall time, more than the wall-clock deadline
    # (0.2 s + 10 % + 2 s + timeout 0.2 s = 2.42 s) that refused such a device before.
    url = "fake://?a=25&b=3&speed=0.08"
    experiment = Experiment(Sine(20.0, 100), sample_period=0.005, duration=0.2)
    with SerialRig(url, timeout=0.2) as rig:
        paced = rig.run(experiment)
    with SerialRig("fake://?a=25&b=3&speed=0", timeout=0.2) as rig:
        free = rig.run(experiment)
    assert paced.metadata["complete"] == "true"
    np.testing.assert_array_equal(paced.counts, free.counts)


def test_a_read_lets_exactly_its_timeout_pass_when_the_device_is_silent():
    with open_port("fake://?mute=true&speed=0", 250000, 0.02) as port:
        assert isinstance(port, FakeLockstepPort)
        port.write(P.encode_message(P.Hello(), 0))
        assert port.read(1) == b""
        assert port.clock() == pytest.approx(0.02, abs=1e-12)
        port.timeout = 0
        assert port.read(1) == b""          # a zero timeout still moves time, by the poll quantum
        assert port.clock() == pytest.approx(0.02 + POLL_QUANTUM, abs=1e-12)


def test_a_mute_device_times_out_after_hello_timeout_simulated_seconds():
    with pytest.raises(RigTimeoutError, match="never answered HELLO"):
        with SerialRig("fake://?mute=true&speed=0", hello_timeout=5.0) as rig:
            pass
    with open_port("fake://?mute=true&speed=0", 250000, 0.02) as port:
        rig = SerialRig(port, hello_timeout=5.0)
        with pytest.raises(RigTimeoutError):
            rig.open()
        # HELLO every 0.2 s of device time until 5 s of it have passed, whatever the wall clock did
        assert 5.0 < port.clock() <= 5.0 + 0.02 + 1e-9


def test_wait_keeps_the_device_output_and_the_watchdog_counts_simulated_time():
    with open_port("fake://?a=25&b=3&speed=0", 250000, 0.02) as port:
        link = DeviceLink(port)
        link.hello()
        for msg in (P.Config(2000, 1000, 255, 4, 200), P.WaveConstant(100), P.Start()):
            assert isinstance(link.command(msg), P.Ack)
        started = port.clock()
        port.wait(0.5)                                 # the host says nothing for 0.5 s
        assert port.clock() == pytest.approx(started + 0.5, abs=1e-9)
        frames = link.poll() + link.poll() + link.poll()
    samples = [m for _, m in link.received if isinstance(m, P.Sample)]
    faults = [m for _, m in frames if isinstance(m, P.Fault)]
    ends = [m for _, m in frames if isinstance(m, P.End)]
    # the device ticks at 0, 2, 4 ... ms and trips at the first tick more than 200 ms after START
    assert [f.code for f in faults] == [P.FaultCode.HOST_SILENCE] and faults[0].seq in (100, 101)
    assert ends and ends[0].reason == P.EndReason.HOST_SILENCE
    assert [s.seq for s in samples] == list(range(faults[0].seq)), "nothing was dropped while the host waited"


def test_the_realtime_key_keeps_the_threaded_device_on_a_pty():
    device = parse_fake_url("fake://?realtime=true&speed=0")
    assert device.speed == 0
    with open_port("fake://?realtime=1&speed=0", 250000, 0.02) as port:
        assert not hasattr(port, "clock") and port.fake_device.port_name.startswith("/dev/")
    with pytest.raises(ValueError, match="realtime"):
        with open_port("fake://?realtime=maybe", 250000, 0.02):
            pass
