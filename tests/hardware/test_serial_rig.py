"""SerialRig against the emulated device: the contract with SimRig, and every fault with a clear outcome."""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
import serial

from hardware import protocol as P
from hardware.errors import (
    DeviceFaultError,
    DeviceRefusedError,
    ProtocolVersionError,
    RigCheckError,
    RigDisconnectedError,
    RigTimeoutError,
)
from hardware.fake_device import FakeDevice, FaultPlan, parse_fake_url
from hardware.ports import open_port, url_keys
from hardware.serial_rig import SerialRig
from motorsim import PRBS, Chirp, Encoder, Experiment, Motor, Multisine, OddMultisine, Rig, SimRig, Sine, Step
from motorsim.rig import bench_knobs

MOTOR = Motor(25.0, 3.0)


def _as_seen_through_the_device(motor: Motor) -> Motor:
    """The motor SimRig must simulate to record what the device records: it applies each duty one tick later."""
    return dataclasses.replace(motor, input_delay=motor.input_delay + P.DEVICE_INPUT_DELAY)
EXPERIMENT = Experiment(Sine(10.0), 0.005, 2.0)      # 400 samples


def _fake(faults=None, *, speed=0.0, motor=MOTOR, seed=1, **kw):
    return FakeDevice(motor, Encoder(), faults, speed=speed, rng=np.random.default_rng(seed), **kw)


def _wait_for(predicate, what, limit=3.0):
    deadline = time.monotonic() + limit
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


# ------------------------------------------------------------------ the contract: SimRig == SerialRig
_CONTRACT = [Experiment(Sine(10.0), 0.005, 2.0),
             Experiment(Multisine((10.0, 20.0, 30.0, 40.0), (80, 60, 40, 30), (0.0, 1.0, 2.0, 3.0)), 0.002, 1.0, 200),
             Experiment(Chirp(2.0, 200.0, 220), 0.001, 1.0),
             Experiment(PRBS(180, -180, 9, 4, 3), 0.005, 2.0),
             Experiment(Step(150, 0.4, -30), 0.0025, 1.0),
             Experiment(OddMultisine(256, 63, 20, 3), 0.005, 2.56)]


@pytest.mark.parametrize("motor", [MOTOR, Motor(8.0, 0.9, friction=4.0, bias=-1.0, dead_zone=12.0, input_delay=2)],
                         ids=["linear", "friction-deadzone-delay"])
@pytest.mark.parametrize("experiment", _CONTRACT, ids=[e.excitation.describe() for e in _CONTRACT])
def test_contract_serial_rig_on_the_emulated_device_records_what_simrig_simulates(experiment, motor):
    sim = SimRig(_as_seen_through_the_device(motor)).run(experiment)
    with _fake(motor=motor) as dev, SerialRig(dev.port_name) as rig:
        assert isinstance(rig, Rig)
        rec = rig.run(experiment)
    assert dev.error is None
    # the same duty sequence, exactly; no sample lost; the device's clock gives k dt to 1 µs
    assert np.array_equal(rec.seq, sim.seq) and np.array_equal(rec.duty, sim.duty)
    assert np.allclose(rec.time, sim.time, rtol=0, atol=1e-9)
    # Counts within one count: both integrate the same exact ZOH model, SimRig over the whole run
    # (lfilter + cumsum), the device interval by interval, so the angles differ by float rounding
    # (~1e-12 rad), which moves floor() only for an angle that close to a count boundary.
    assert np.max(np.abs(rec.counts - sim.counts)) <= 1
    assert rec.counts_per_rev == sim.counts_per_rev
    assert rec.metadata["complete"] == "true" and rec.metadata["device_samples_sent"] == str(len(sim))


def test_contract_holds_in_real_time_with_heartbeats():
    # Real time for 1 s with a 200 ms watchdog: only the heartbeats can keep the run alive.
    exp = Experiment(Sine(20.0), 0.002, 1.0)
    sim = SimRig(_as_seen_through_the_device(MOTOR)).run(exp)
    with _fake(speed=1.0) as dev, SerialRig(dev.port_name, watchdog_ms=200) as rig:
        rec = rig.run(exp)
    assert np.array_equal(rec.duty, sim.duty) and np.max(np.abs(rec.counts - sim.counts)) <= 1
    assert rec.metadata["device_end_reason"] == "0"


# ------------------------------------------------------------------ faults on the link: nothing corrupted passes
def _clean():
    return SimRig(_as_seen_through_the_device(MOTOR)).run(EXPERIMENT)


def _assert_rows_are_true(rec, clean):
    """Every row that arrived is exactly the clean row of the same index (nothing corrupted got through)."""
    idx = rec.seq
    assert np.array_equal(rec.duty, clean.duty[idx])
    assert np.max(np.abs(rec.counts - clean.counts[idx])) <= 1       # tolerance: see the contract test


def test_garbage_before_and_between_frames_loses_nothing():
    with _fake(FaultPlan(garbage_rate=0.3)) as dev, SerialRig(dev.port_name) as rig:
        rec = rig.run(EXPERIMENT)
    assert not rec.has_gaps and len(rec) == EXPERIMENT.n_samples
    assert int(rec.metadata["host_rx_errors"]) > 50     # ~120 garbage runs expected, each one error
    _assert_rows_are_true(rec, _clean())


def test_flipped_bits_are_all_detected_counted_and_shown_as_gaps():
    with _fake(FaultPlan(flip_rate=0.15), seed=3) as dev, SerialRig(dev.port_name) as rig:
        rec = rig.run(EXPERIMENT)
    missing = EXPERIMENT.n_samples - len(rec)
    assert missing > 20                                 # ~60 flips expected at this rate
    assert int(rec.metadata["host_rx_errors"]) >= missing
    assert int(rec.metadata["host_link_frames_lost"]) == missing
    assert rec.metadata["device_samples_sent"] == str(EXPERIMENT.n_samples)
    _assert_rows_are_true(rec, _clean())


def test_dropped_frames_are_counted_as_seq_gaps_matching_end_totals():
    with _fake(FaultPlan(drop_rate=0.1, queue_drop_rate=0.05), seed=4) as dev, SerialRig(dev.port_name) as rig:
        rec = rig.run(EXPERIMENT)
    m = rec.metadata
    lost_on_link, dropped_on_device = int(m["host_link_frames_lost"]), int(m["device_samples_dropped"])
    assert lost_on_link > 10 and dropped_on_device > 5
    # received + lost on the link + dropped by the device = ticks elapsed (PROTOCOL.md, END check)
    assert len(rec) + lost_on_link + dropped_on_device == EXPERIMENT.n_samples
    assert int(m["device_samples_sent"]) == len(rec) + lost_on_link
    assert np.sum(np.diff(rec.seq) - 1) + rec.seq[0] + (EXPERIMENT.n_samples - 1 - rec.seq[-1]) \
        == lost_on_link + dropped_on_device
    assert m["device_fault_code"] == str(int(P.FaultCode.QUEUE_OVERFLOW))
    _assert_rows_are_true(rec, _clean())


class _OneByteAtATime:
    """A port whose every read returns at most one byte (a frame split across many reads)."""

    def __init__(self, port):
        self._port = port
        self.name = port.name
        self.reads = 0

    in_waiting = 0

    def read(self, size=1):
        self.reads += 1
        return self._port.read(1)

    def write(self, data):
        return self._port.write(data)


def test_a_frame_split_across_reads_one_byte_at_a_time():
    exp = Experiment(Sine(10.0), 0.005, 0.5)
    with _fake() as dev, serial.Serial(dev.port_name, timeout=0.02) as port:
        slow = _OneByteAtATime(port)
        rec = SerialRig(slow).run(exp)
    assert len(rec) == exp.n_samples and not rec.has_gaps
    assert slow.reads >= 21 * exp.n_samples
    assert np.array_equal(rec.duty, exp.duty())


# ------------------------------------------------------------------ the device fails: error, motor stopped, data kept
def test_device_going_silent_times_out_stops_the_motor_and_keeps_the_partial_recording():
    with _fake(FaultPlan(stall_at=120), speed=1.0) as dev:     # the run would end 1.4 s after the stall
        with SerialRig(dev.port_name, timeout=0.3) as rig, pytest.raises(RigTimeoutError, match="silent") as err:
            rig.run(EXPERIMENT)
        _wait_for(lambda: dev.stops_received >= 1, "the STOP from the host")
        assert dev.duty == 0 and dev.last_end.reason == P.EndReason.STOPPED_BY_HOST
    rec = err.value.recording
    assert rec.metadata["complete"] == "false" and "silent" in rec.metadata["incomplete_reason"]
    assert np.array_equal(rec.seq, np.arange(120))
    _assert_rows_are_true(rec, _clean())


def test_disconnect_mid_run_raises_and_keeps_what_arrived():
    with _fake(FaultPlan(disconnect_at=150), speed=5.0) as dev:
        with SerialRig(dev.port_name) as rig, pytest.raises(RigDisconnectedError) as err:
            rig.run(EXPERIMENT)
    rec = err.value.recording
    assert rec.metadata["complete"] == "false" and np.array_equal(rec.seq, np.arange(150))
    _assert_rows_are_true(rec, _clean())


def test_injected_watchdog_trip_is_a_device_fault_with_the_partial_recording():
    with _fake(FaultPlan(watchdog_trip_at=200)) as dev, SerialRig(dev.port_name) as rig:
        with pytest.raises(DeviceFaultError, match="HOST_SILENCE at sample 200") as err:
            rig.run(EXPERIMENT)
        assert dev.duty == 0
    rec = err.value.recording
    assert len(rec) == 200 and rec.metadata["device_end_reason"] == str(int(P.EndReason.HOST_SILENCE))


def test_the_device_watchdog_stops_a_host_that_goes_silent():
    # Speak the protocol by hand and never send a HEARTBEAT: the device must stop on its own.
    reader = P.FrameReader()
    with _fake(speed=1.0) as dev, serial.Serial(dev.port_name, timeout=0.05) as port:
        for frame_seq, msg in enumerate([P.Config(5000, 100_000, 255, 4, 100), P.WaveConstant(120), P.Start()]):
            port.write(P.encode_message(msg, frame_seq))
        got = []
        deadline = time.monotonic() + 3.0
        while not any(isinstance(m, P.End) for m in got) and time.monotonic() < deadline:
            got += [m for _, m in reader.feed(port.read(256))]
        assert P.Fault(P.FaultCode.HOST_SILENCE, got[-2].seq) in got
        assert got[-1].reason == P.EndReason.HOST_SILENCE and dev.duty == 0
        # stopped by the watchdog (after ~20 samples), long before the 100 000 of the run
        assert 0 < got[-1].samples_sent < 100_000


def test_ctrl_c_during_a_run_sends_stop_and_propagates():
    def interrupt(sample):
        if sample.seq == 50:
            raise KeyboardInterrupt
    with _fake(speed=2.0) as dev:
        with SerialRig(dev.port_name) as rig, pytest.raises(KeyboardInterrupt):
            rig.run(EXPERIMENT, on_sample=interrupt)
        _wait_for(lambda: dev.last_end is not None, "END after the STOP")
        assert dev.stops_received == 1 and dev.duty == 0
        assert dev.last_end.reason == P.EndReason.STOPPED_BY_HOST and dev.last_end.samples_sent < 400


# ------------------------------------------------------------------ handshake
def test_wrong_protocol_version_is_refused_naming_both_versions():
    with _fake(FaultPlan(version=1)) as dev, pytest.raises(ProtocolVersionError, match=r"version 1.*version 6"):
        SerialRig(dev.port_name).open()


def test_a_device_that_never_answers_hello_times_out_after_retries():
    with _fake(FaultPlan(mute=True)) as dev, pytest.raises(RigTimeoutError, match=r"never answered HELLO \([2-9] sent"):
        SerialRig(dev.port_name, hello_timeout=0.7).open()


def test_hello_is_retried_while_the_board_sits_in_its_bootloader():
    with _fake(FaultPlan(boot_delay=0.5)) as dev, SerialRig(dev.port_name) as rig:
        assert rig.device.board == "fake" and rig.device.version == P.PROTOCOL_VERSION
        assert len(rig.run(Experiment(Sine(10.0), 0.005, 0.2))) == 40


def test_nak_is_raised_with_its_reason():
    with _fake() as dev, SerialRig(dev.port_name) as rig:
        with pytest.raises(DeviceRefusedError, match="BAD_VALUE"):
            rig._command(P.Config(50, 10, 255, 4, 0))          # sample period below 100 µs
        with pytest.raises(DeviceRefusedError, match="NOT_CONFIGURED"):
            rig._command(P.Start())


def test_a_duty_other_than_the_waves_is_caught(monkeypatch):
    real = P.expand
    monkeypatch.setattr(P, "expand", lambda wave, n, lim: real(wave, n, lim) + (np.arange(n) == 77))
    with _fake() as dev, SerialRig(dev.port_name) as rig, pytest.raises(RigCheckError, match="sample 77"):
        rig.run(EXPERIMENT)


def test_the_fake_device_counts_an_overlong_frame_once_and_resynchronises():
    reader = P.FrameReader()
    with _fake() as dev, serial.Serial(dev.port_name, timeout=0.05) as port:
        port.write(b"\x01" * 70)
        time.sleep(0.05)
        port.write(b"\x01" * 70 + b"\x00" + P.encode_message(P.Hello(), 0))
        got = []
        deadline = time.monotonic() + 2.0
        while not any(isinstance(m, P.HelloAck) for m in got) and time.monotonic() < deadline:
            got += [m for _, m in reader.feed(port.read(256))]
        assert any(isinstance(m, P.HelloAck) for m in got) and dev.rx_errors == 1


def test_the_fake_device_answers_busy_and_unknown_types():
    reader = P.FrameReader()
    with _fake(speed=1.0) as dev, serial.Serial(dev.port_name, timeout=0.05) as port:
        for frame_seq, msg in enumerate([P.Config(5000, 1000, 255, 4, 0), P.WaveConstant(10), P.Start(), P.Hello()]):
            port.write(P.encode_message(msg, frame_seq))
        port.write(P.encode_frame(0x30, 4))
        port.write(P.encode_frame(P.MsgType.WAVE, 5, b"\x07\x00"))
        port.write(P.encode_frame(P.MsgType.STOP, 6, b"\x00"))
        port.write(P.encode_message(P.Stop(), 7))
        got = []
        deadline = time.monotonic() + 2.0
        while not any(isinstance(m, P.End) for m in got) and time.monotonic() < deadline:
            got += [m for _, m in reader.feed(port.read(256))]
    assert P.Nak(P.MsgType.HELLO, 3, P.NakReason.BUSY) in got
    assert P.Nak(0x30, 4, P.NakReason.UNKNOWN_TYPE) in got
    assert P.Nak(P.MsgType.WAVE, 5, P.NakReason.BAD_VALUE) in got
    assert P.Nak(P.MsgType.STOP, 6, P.NakReason.BAD_LENGTH) in got
    assert got[-1].reason == P.EndReason.STOPPED_BY_HOST


# ------------------------------------------------------------------ ports
def test_pyserial_urls_work_and_a_loopback_never_answers_hello():
    with pytest.raises(RigTimeoutError, match="never answered HELLO"):
        SerialRig("loop://", hello_timeout=0.3).open()


def test_unknown_and_unavailable_schemes_are_clear_errors(monkeypatch):
    with pytest.raises(ValueError, match="nosuch"):
        with open_port("nosuch://x", 250000, 0.1):
            pass
    import hardware.ports as ports
    monkeypatch.setitem(ports._SCHEMES, "avr-sim", "hardware.no_such_module:open_it")
    with pytest.raises(ValueError, match="avr-sim:// is not available"):
        with open_port("avr-sim://x", 250000, 0.1):
            pass
    with pytest.raises(RigDisconnectedError, match="cannot open port"):
        with open_port("/dev/motorid-no-such-port", 250000, 0.1):
            pass


def test_fake_url_opens_a_running_device():
    with open_port("fake://?a=10&b=2&counts_per_rev=1000&speed=0", 250000, 0.02) as port:
        dev = port.fake_device
        assert dev.motor == Motor(10.0, 2.0) and dev.encoder.counts_per_rev == 1000
        rec = SerialRig(port, counts_per_rev=1000).run(Experiment(Sine(10.0), 0.005, 0.5))
    assert len(rec) == 100
    with pytest.raises(ValueError, match="unknown keys"):
        with open_port("fake://?a=1&colour=red", 250000, 0.02):
            pass


@pytest.mark.parametrize("kwargs, name", [({"baudrate": 0}, "baudrate"), ({"decoding": 3}, "decoding"),
                                          ({"watchdog_ms": 10}, "watchdog_ms"), ({"timeout": -1.0}, "timeout"),
                                          ({"counts_per_rev": 0}, "counts_per_rev")],
                         ids=["baudrate", "decoding", "watchdog", "timeout", "cpr"])
def test_serial_rig_rejects_bad_settings_naming_them(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SerialRig("loop://", **kwargs)


def test_a_run_left_over_from_an_earlier_session_is_stopped_at_hello():
    # An earlier host started a long run without a watchdog and vanished; the new host's HELLO is
    # NAKed BUSY, so it sends STOP and shakes hands.
    with _fake(speed=1.0) as dev:
        with serial.Serial(dev.port_name, timeout=0.05) as port:
            for frame_seq, msg in enumerate([P.Config(5000, 1_000_000, 255, 4, 0), P.WaveConstant(50), P.Start()]):
                port.write(P.encode_message(msg, frame_seq))
            _wait_for(lambda: dev.runs_started == 1, "the first session's run")
        with SerialRig(dev.port_name) as rig:
            assert rig.device is not None
            assert dev.stops_received == 1 and dev.last_end.reason == P.EndReason.STOPPED_BY_HOST
            assert len(rig.run(Experiment(Sine(10.0), 0.005, 0.1))) == 20


class _Meddler:
    """A port that corrupts chosen host writes and deletes chosen device frames (by decoded message)."""

    def __init__(self, port, corrupt_writes=(), drop=lambda msg: False):
        self._port, self.name, self.in_waiting = port, port.name, 0
        self._corrupt, self._drop, self._writes, self._pending = set(corrupt_writes), drop, 0, b""
        self.dropped = []

    def write(self, data):
        self._writes += 1
        if self._writes in self._corrupt:
            data = bytes([data[0], data[1] ^ 0x04]) + data[2:]
        return self._port.write(data)

    def read(self, size=1):
        parts = (self._pending + self._port.read(max(size, self._port.in_waiting))).split(b"\x00")
        self._pending = parts.pop()
        out = []
        for part in parts:
            got = P.FrameReader().feed(part + b"\x00")
            if got and self._drop(got[0][1]):
                self.dropped.append(got[0][1])
                continue
            out.append(part + b"\x00")
        return b"".join(out)


def test_a_corrupted_command_is_retried_and_counted_by_the_device():
    with _fake() as dev, serial.Serial(dev.port_name, timeout=0.02) as port:
        meddler = _Meddler(port, corrupt_writes={2})       # write 1 is HELLO, write 2 the first CONFIG
        rec = SerialRig(meddler, command_timeout=0.1).run(EXPERIMENT)
    assert len(rec) == EXPERIMENT.n_samples and rec.metadata["device_rx_errors"] == "1"


@pytest.mark.parametrize("experiment, speed", [(EXPERIMENT, 0.0), (Experiment(Sine(1.0), 0.25, 0.75), 1.0)],
                         ids=["samples-arrive-first", "retry-nak-busy"])
def test_a_lost_start_ack_still_starts_the_run_once(experiment, speed):
    # Fast samples show the run started; with 0.25 s samples the retried START is NAKed BUSY instead.
    with _fake(speed=speed) as dev, serial.Serial(dev.port_name, timeout=0.02) as port:
        meddler = _Meddler(port, drop=lambda m: type(m) is P.Ack and m.acked_type == P.MsgType.START)
        rec = SerialRig(meddler, command_timeout=0.1).run(experiment)
    assert len(meddler.dropped) == 1 and dev.runs_started == 1
    assert len(rec) == experiment.n_samples and not rec.has_gaps
    # the lost ACK is one frame lost on the link, so the host's count shows it
    assert rec.metadata["host_link_frames_lost"] == "1"


def test_a_sample_rate_the_line_cannot_carry_is_refused_before_anything_is_sent():
    # 1 kHz of 21-byte frames is 210 000 baud: more than 115 200 can carry, so drops would be certain.
    with pytest.raises(ValueError, match=r"210000 baud.*baudrate 115200"):
        SerialRig("loop://", 115_200).run(Experiment(Sine(10.0), 0.001, 1.0))
    assert SerialRig("loop://", 250_000).line_load(0.002) == pytest.approx(0.42)   # the README's 42 %


@pytest.mark.parametrize("old, new", [("cpr", "counts_per_rev"), ("noise", "angle_noise"), ("offset", "count_offset")])
def test_fake_url_refuses_old_key_names_naming_the_new_one(old, new):
    with pytest.raises(ValueError, match=f"'{old}' is now called '{new}'"):
        parse_fake_url(f"fake://?a=1&{old}=2")


def test_url_keys_are_the_bench_knobs_under_their_own_names():
    bench = {k.name for k in bench_knobs() if k.owner in (Motor, Encoder)}
    assert bench <= set(url_keys("fake"))
    assert {"a", "b", "friction", "counts_per_rev"} <= set(url_keys("avr-sim"))
    device = parse_fake_url("fake://?a=30&b=2&friction=1&bias=0.5&dead_zone=3&input_delay=2"
                            "&counts_per_rev=2000&count_offset=-7&angle_noise=0.001")
    assert device.motor == Motor(30.0, 2.0, friction=1.0, bias=0.5, dead_zone=3.0, input_delay=2)
    assert device.encoder == Encoder(2000, -7, 0.001)


def test_a_device_repeating_one_sample_forever_times_out_and_is_stopped():
    # Frames keep arriving, so silence alone never trips: seq must advance.
    with _fake(FaultPlan(repeat_at=50), speed=1.0) as dev:
        with SerialRig(dev.port_name, timeout=0.3) as rig, \
                pytest.raises(RigTimeoutError, match=r"frames but no new sample .* after sample 50") as err:
            rig.run(EXPERIMENT)
        _wait_for(lambda: dev.stops_received >= 1, "the STOP from the host")
        assert dev.last_end.reason == P.EndReason.STOPPED_BY_HOST
    rec = err.value.recording
    assert rec.metadata["complete"] == "false" and np.array_equal(rec.seq, np.arange(51))
    assert rec.metadata["device_end_reason"] == "1"


@pytest.mark.slow
def test_a_device_slower_than_its_clock_passes_the_run_deadline():
    # Every sample arrives and seq advances, but at half the pace that would end the run by its
    # deadline (duration + run_margin): the run ends there, not when the device finally does.
    from hardware.serial_rig import run_margin
    experiment = dataclasses.replace(EXPERIMENT, duration=0.2)
    allowed = experiment.duration + run_margin(experiment.duration, 0.3)
    with _fake(speed=experiment.duration / allowed / 2) as dev:     # samples 57 ms apart: never "silent"
        with SerialRig(dev.port_name, timeout=0.3) as rig, pytest.raises(RigTimeoutError, match="deadline") as err:
            rig.run(experiment)
        _wait_for(lambda: dev.stops_received >= 1, "the STOP from the host")
        assert dev.last_end.reason == P.EndReason.STOPPED_BY_HOST
    rec = err.value.recording
    assert rec.metadata["complete"] == "false" and rec.metadata["device_end_reason"] == "1"
    assert 0 < len(rec) < experiment.n_samples


def test_an_unpaced_device_drops_nothing_when_the_pty_takes_frames_in_pieces(monkeypatch):
    # Under load a pty accepts a few bytes of a frame at a time, or none: the device's queue then holds
    # a partly written frame, and the byte count it waited on read one frame short of full. At speed=0
    # it dropped 316 of these 400 samples; it must wait for the host instead and drop none.
    import os
    import types

    import hardware.fake_device as fake_device
    calls = {"n": 0}

    def write_in_pieces(fd: int, data) -> int:
        calls["n"] += 1
        if calls["n"] % 3 == 0:
            raise BlockingIOError
        return os.write(fd, bytes(data[:13]))
    slow_os = types.SimpleNamespace(**{k: getattr(os, k) for k in dir(os) if not k.startswith("__")})
    slow_os.write = write_in_pieces
    monkeypatch.setattr(fake_device, "os", slow_os)
    with SerialRig("fake://?a=25&b=3&speed=0") as rig:
        rec = rig.run(Experiment(Sine(10.0, 100), 0.005, 2.0))
    assert rec.metadata["device_samples_dropped"] == "0" and rec.metadata["samples_lost"] == "0"
    assert len(rec) == 400
