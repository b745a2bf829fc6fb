"""The bench firmware, compiled for the Uno and run byte for byte under simavr (``avr-sim://``).

Each test starts the harness (``hardware/sim/motorid_avr_sim.c``) with a motor, opens its
pseudo-terminal and talks protocol v2 to the real firmware: through the real ``SerialRig``
where a host would, frame by frame (``DeviceLink``) where the test needs exact bytes.
The emulated AVR runs in lock-step with the host (``hardware/lockstep.py``), as fast as the
machine goes (``speed=0``): every timeout and heartbeat of the host counts emulated seconds,
so a loaded machine makes the tests slower, never different.
"""
from __future__ import annotations

import contextlib
import math
import threading
from urllib.parse import urlencode

import numpy as np
import pytest
from scipy.optimize import least_squares

import identify
from hardware import protocol as P
from hardware.errors import DeviceFaultError
from hardware.serial_rig import SerialRig
from hardware.sim.device_link import DeviceLink
from hardware.sim.launcher import open_avr_sim
from motorsim import PRBS, Chirp, Constant, Experiment, Multisine, OddMultisine, Sine, Step

A, B, COUNTS_PER_REV = 25.0, 3.0, 16667
# 20 rad/s, amplitude 100: the speed swings +-9.4 rad/s (25 k counts/s, well under the
# encoder ceiling) and one frequency with the start-up transient identifies both a and b.
SINE = Experiment(Sine(20.0, 100), sample_period=0.002, duration=3.0)


def _open(baudrate: int = 250000, **query):
    query = {"a": A, "b": B, "counts_per_rev": COUNTS_PER_REV, "speed": 0, **query}
    return open_avr_sim("avr-sim://?" + urlencode(query), baudrate, 0.02)


pytestmark = pytest.mark.firmware


@contextlib.contextmanager
def _rig(**query):
    """A SerialRig on the emulated firmware, and the port (whose harness reports the motor)."""
    with _open(**query) as port:
        with SerialRig(port, 250000, counts_per_rev=COUNTS_PER_REV, watchdog_ms=200) as rig:
            yield rig, port


@pytest.fixture(scope="module")
def sine_run(built):
    with _rig() as (rig, port):
        recording = rig.run(SINE)
        device = rig.device
    return device, recording


def _fit_output_error(counts: np.ndarray, duty: np.ndarray, h: float, counts_per_rev: float):
    """Exact ZOH output-error fit of a, b (and initial speed, count offset) on the counts."""
    scale = counts_per_rev / (2 * math.pi)

    def model(p):
        a, b, w0, offset = p
        e = math.exp(-a * h)
        gain_w, gain_wu = (1 - e) / a, b / a * (h - (1 - e) / a)
        w, angle = w0, 0.0
        out = np.empty(len(duty))
        for k, u in enumerate(duty):
            out[k] = angle
            angle, w = angle + gain_w * w + gain_wu * u, e * w + b / a * (1 - e) * u
        return out * scale + counts[0] + offset

    fit = least_squares(lambda p: model(p) - counts, [0.8 * A, 0.8 * B, 0.0, 0.0], x_scale=[A, B, 1, 1])
    return fit.x[0], fit.x[1]


# ------------------------------------------------------------------ HELLO and BOOT
def test_hello_ack_reports_protocol_version_clock_and_power_on_reset(sine_run):
    device, _ = sine_run
    assert device.version == P.PROTOCOL_VERSION
    assert device.firmware_version == 0x0502   # 5.2 (major << 8 | minor)
    assert device.counts_per_rev == 0          # config.h leaves ENCODER_COUNTS_PER_REV unset
    assert device.f_cpu_hz == 16_000_000
    assert device.max_payload == P.MAX_PAYLOAD
    assert device.board == "uno"
    assert device.reset_cause & 1, "the harness starts the AVR from power-on (MCUSR.PORF)"


def test_boot_frame_comes_first_with_the_reset_cause(built):
    with _open() as port:
        link = DeviceLink(port)
        boot = link.wait_for(P.Boot, timeout=2.0)
        hello = link.hello()
    assert boot is not None and boot.version == P.PROTOCOL_VERSION
    assert link.received[0][1] == boot and link.received[0][0] == 0, "BOOT is the first frame after reset"
    assert boot.reset_cause == hello.reset_cause == 1


# ------------------------------------------------------------------ the sine run
def test_sine_run_has_no_drops_and_its_duty_equals_expand(sine_run):
    _, rec = sine_run
    n = SINE.n_samples
    meta = rec.metadata
    assert meta["complete"] == "true" and meta["device_end_reason"] == "0"
    assert meta["device_samples_dropped"] == "0" and meta["host_link_frames_lost"] == "0"
    assert meta["device_tick_overruns"] == "0" and meta["device_rx_errors"] == "0"
    assert meta["device_encoder_errors"] == "0"
    np.testing.assert_array_equal(rec.seq, np.arange(n))
    np.testing.assert_array_equal(rec.duty, P.expand(P.wave_for(SINE), n, SINE.duty_limit))
    np.testing.assert_array_equal(rec.duty, SINE.duty())
    # The Timer 1 clock is exact and each tick's snapshot comes at the same instant after its
    # compare (to 3 cycles), so only micros()'s 4 us steps are left: one interval is off by at
    # most 4 us (firmware 5.1, whose snapshot waited for the interrupts running: 12 us).
    assert np.all(np.abs(np.diff(rec.time) - SINE.sample_period) <= 4e-6 + 1e-9)


def test_sine_run_identifies_the_harness_motor_within_one_percent(sine_run):
    _, rec = sine_run
    counts = rec.counts.astype(float)
    h = SINE.sample_period
    if "oe" in identify.available_methods():
        est = identify.fit(rec, method="oe", input_delay=P.DEVICE_INPUT_DELAY)
        a, b = est.a, est.b
    else:
        a, b = _fit_output_error(counts[1:], rec.duty[:-1], h, COUNTS_PER_REV)
    # Truth is the harness's a, b; the device applies each duty one tick after its sample
    # (recorded as input_delay_samples).  Left over: count quantisation; the bound asserted is 1 %.
    assert rec.metadata["input_delay_samples"] == str(P.DEVICE_INPUT_DELAY)
    assert a == pytest.approx(A, rel=0.01)
    assert b == pytest.approx(B, rel=0.01)


def test_every_waveform_kind_matches_the_host_bit_for_bit(built):
    experiments = [
        Experiment(Multisine((5.0, 40.0, 150.0, 700.0), (300, 250, 200, 150), (0.3, 1.0, 2.0, 3.0), offset=-20),
                   sample_period=0.001, duration=0.3, duty_limit=200),      # 4 components, clamped
        Experiment(Chirp(2.0, 900.0, 255, offset=10), sample_period=0.001, duration=0.3),
        Experiment(PRBS(180, -160, order=7, hold=3, seed=5), sample_period=0.001, duration=0.3),
        Experiment(Step(-90, 0.1, 60), sample_period=0.001, duration=0.3),
        Experiment(Constant(-1023), sample_period=0.001, duration=0.1, duty_limit=37),
        Experiment(OddMultisine(256, 127, 15, 4321, offset=5), sample_period=0.002, duration=0.6),  # 43 of 64 odd lines
        Experiment(OddMultisine(64, 31, 40, 0, 0), sample_period=0.001, duration=0.2),   # Schroeder, none left out
        Experiment(OddMultisine(65536, 41, 30, 9, 4), sample_period=0.001, duration=0.2, duty_limit=90),
    ]
    with _rig() as (rig, _):
        for experiment in experiments:
            rec = rig.run(experiment)   # SerialRig also checks each duty against expand() on arrival
            np.testing.assert_array_equal(rec.duty, experiment.duty(), err_msg=experiment.excitation.describe())
            assert rec.metadata["host_duty_mismatches"] == "0"
            assert rec.metadata["device_tick_overruns"] == "0", experiment.excitation.describe()


# ------------------------------------------------------------------ STOP and watchdog
STEADY = P.Config(2000, 1000, 255, 4, 0)   # 2 s at 500 Hz, host-silence watchdog off
STEADY_SPEED = B / A * 150                 # rad/s under duty 150


def _settle_then_stop(port) -> float:
    # 0.3 s of emulated time, 7.5 time constants (1/a = 40 ms): duty 0 leaves < 0.1 % of the
    # speed; a duty still applied would leave all of it.
    port.wait(0.3)
    port.close()
    return port.avr_simulation.stop()["speed_rad_s"]


class _HostGivesUp(Exception):
    pass


def test_stop_mid_run_stops_the_motor(built):
    def give_up(sample):
        if sample.seq == 200:
            raise _HostGivesUp   # SerialRig sends STOP when a run is left early

    with _rig() as (rig, port):
        with pytest.raises(_HostGivesUp):
            rig.run(Experiment(Constant(150), sample_period=0.002, duration=2.0), on_sample=give_up)
        speed = _settle_then_stop(port)
    # Running at ~18 rad/s when stopped.
    assert abs(speed) < 1e-2 * STEADY_SPEED


def test_commands_are_refused_while_running_and_stop_ends_the_run(built):
    with _open() as port:
        link = DeviceLink(port)
        link.hello()
        busy_seqs = []

        def meddle_then_stop(link, sample):
            if sample.seq == 50:
                busy_seqs.extend(link.send(m) for m in (P.Hello(), STEADY, P.WaveConstant(0), P.Start()))
            if sample.seq == 200:
                link.send(P.Stop())

        run = link.run(STEADY, P.WaveConstant(150), on_sample=meddle_then_stop)
    naks = [m for m in run.others if isinstance(m, P.Nak)]
    assert [(n.refused_type, n.refused_frame_seq, n.reason) for n in naks] == [
        (t, frame_seq, P.NakReason.BUSY) for t, frame_seq in zip((P.MsgType.HELLO, P.MsgType.CONFIG, P.MsgType.WAVE,
                                                       P.MsgType.START), busy_seqs)]
    assert {s.duty for s in run.samples} == {150}, "the running experiment was not touched"
    assert run.end is not None and run.end.reason == P.EndReason.STOPPED_BY_HOST
    assert 200 < len(run.samples) < STEADY.n_samples
    assert run.end.samples_sent == len(run.samples)
    assert any(isinstance(m, P.Ack) and m.acked_type == P.MsgType.STOP for m in run.others)
    moved = run.samples[-1].counts - run.samples[-101].counts   # over the last 0.2 s
    assert moved > 0.5 * STEADY_SPEED * 0.2 * COUNTS_PER_REV / (2 * math.pi)


#: Samples the firmware queues before sending (config.h SAMPLE_QUEUE_LEN).
SAMPLE_QUEUE_LEN = 40


class _HostLink:
    """The port as SerialRig sees it, with a switch that stops the host's frames arriving.

    ``latest`` is the last sample index the host has handled (set by the test's callback);
    ``latest_at_last_write`` its value when the last frame that reached the device was
    written, and ``sent_at_last_write`` how many frames had left the device by then (read by
    the host, or waiting in the port): counted on the wire, so both hold however slow the host.
    """

    def __init__(self, port):
        self._port = port
        self._lock = threading.Lock()     # a write (heartbeat thread) sees a read as done or not begun
        self.silent = False
        self.latest = -1
        self.latest_at_last_write = -1
        self.frames_read = 0
        self.sent_at_last_write = 0

    def read(self, size=1):
        with self._lock:
            data = self._port.read(size)
            self.frames_read += data.count(0)      # every frame ends with one 0x00
            return data

    def handled(self, seq: int, *, go_silent: bool) -> None:
        """The host handled sample ``seq``; from now on nothing reaches the device if ``go_silent``."""
        with self._lock:      # a heartbeat is written entirely before this, or not at all
            self.latest = seq
            self.silent = self.silent or go_silent

    def write(self, data):
        with self._lock:
            if self.silent:
                return len(data)
            self.latest_at_last_write = self.latest
            waiting = self._port.in_waiting
            self.sent_at_last_write = self.frames_read + -(-waiting // 21) + 1   # a SAMPLE is 21 bytes
            return self._port.write(data)

    def __getattr__(self, name):
        return getattr(self._port, name)


def test_host_silence_watchdog_stops_the_motor_and_reports_fault_then_end(built):
    # SerialRig sends HEARTBEATs from a thread, so a slow host does not trip the watchdog; a
    # host that dies or loses its transmit line does: from sample 50 nothing reaches the device.
    with _open() as port:
        link = _HostLink(port)

        def go_silent(sample):
            link.handled(sample.seq, go_silent=sample.seq == 50)

        with SerialRig(link, 250000, counts_per_rev=COUNTS_PER_REV, watchdog_ms=200) as rig:
            with pytest.raises(DeviceFaultError, match="HOST_SILENCE") as info:
                rig.run(Experiment(Constant(150), sample_period=0.002, duration=2.0), on_sample=go_silent)
        speed = _settle_then_stop(port)
    meta = info.value.recording.metadata
    assert meta["device_end_reason"] == str(int(P.EndReason.HOST_SILENCE))
    assert meta["device_fault_code"] == str(int(P.FaultCode.HOST_SILENCE))
    # The device trips 200 ms (100 samples) after the last frame reached it.  When that frame
    # left, the host had handled sample `seen`, so the device was at `seen` or later (lower
    # bound); and the device was at most at the frames that had left it plus its queue of
    # SAMPLE_QUEUE_LEN (upper bound), whatever the host's lag: both are counted on the wire,
    # not on a clock.  The 5 samples of slack cover the emulator reading its input once per
    # main-loop pass and the off-by-one of "after".
    seen, sent = link.latest_at_last_write, link.sent_at_last_write
    assert seen <= 50
    assert seen + 99 <= int(meta["device_fault_index"]) <= sent + SAMPLE_QUEUE_LEN + 100 + 5
    assert int(meta["samples_received"]) == int(meta["device_fault_index"])
    assert abs(speed) < 1e-2 * STEADY_SPEED


def test_a_hung_loop_is_reset_by_the_avr_watchdog_and_the_harness_keeps_running(built):
    with _rig() as (rig, port):
        sim = port.avr_simulation

        def hang_at_100(sample):
            if sample.seq == 100:
                sim.hang_firmware()   # loop() stops; interrupts (and the sample clock) go on

        with pytest.raises(DeviceFaultError, match="reset during the run") as info:
            rig.run(Experiment(Constant(150), sample_period=0.002, duration=4.0), on_sample=hang_at_100)
        assert "0x08" in str(info.value), "BOOT reports the watchdog reset (MCUSR.WDRF)"
        assert int(info.value.recording.metadata["samples_received"]) >= 100
        speed = _settle_then_stop(port)
    assert sim.stats["resets"] >= 1, "the harness re-registered its motor after the reset"
    assert abs(speed) < 1e-2 * STEADY_SPEED, "the reset left the PWM pin floating: pulled down, off"


# ------------------------------------------------------------------ corrupted frames
def test_corrupted_frames_are_refused_and_counted_and_the_link_recovers(built):
    with _open() as port:
        link = DeviceLink(port)
        link.hello()
        frame = bytearray(P.encode_message(P.Hello(), 7))
        frame[2] ^= 0x10                                  # CRC no longer matches
        link.send_raw(bytes(frame))
        assert link.wait_for((P.HelloAck, P.Nak), timeout=0.3) is None, "a corrupted frame has no reply"
        assert isinstance(link.hello(), P.HelloAck)     # the link recovered

        injected = []

        def corrupt_twice(link, sample):
            if sample.seq in (50, 100) and sample.seq not in injected:
                injected.append(sample.seq)
                if sample.seq == 50:
                    bad = bytearray(P.encode_message(P.Heartbeat(), link.frame_seq))
                    bad[1] ^= 0xFF
                    link.send_raw(bytes(bad))             # bad CRC
                else:
                    link.send_raw(b"\x55" * 100 + b"\x00")  # overlong: discarded, counted once

        run = link.run(P.Config(2000, 250, 255, 4, 500), P.WaveConstant(50), on_sample=corrupt_twice)
    assert run.end is not None and run.end.reason == P.EndReason.COMPLETE
    assert run.end.rx_errors == 2
    assert len(run.samples) == 250


def test_unknown_type_and_wrong_length_are_naked(built):
    with _open() as port:
        link = DeviceLink(port)
        link.hello()
        frame_seq = link.frame_seq
        link.send_raw(P.encode_frame(0x3F, frame_seq, b""))
        link.frame_seq += 1
        nak = link.wait_for(P.Nak, timeout=1.0)
        assert nak == P.Nak(0x3F, frame_seq, P.NakReason.UNKNOWN_TYPE)
        frame_seq = link.frame_seq
        link.send_raw(P.encode_frame(P.MsgType.CONFIG, frame_seq, b"\x00" * 12))
        link.frame_seq += 1
        nak = link.wait_for(P.Nak, timeout=1.0)
        assert nak == P.Nak(P.MsgType.CONFIG, frame_seq, P.NakReason.BAD_LENGTH)
        frame_seq = link.frame_seq
        link.send_raw(P.encode_frame(P.MsgType.WAVE, frame_seq, b"\x09\x00\x00"))   # unknown kind
        link.frame_seq += 1
        nak = link.wait_for(P.Nak, timeout=1.0)
        assert nak == P.Nak(P.MsgType.WAVE, frame_seq, P.NakReason.BAD_VALUE)
        assert link.command(P.Config(50, 10, 255, 4, 0)) == P.Nak(P.MsgType.CONFIG, link.frame_seq - 1,
                                                                  P.NakReason.BAD_VALUE)
        assert link.command(P.Start()) == P.Nak(P.MsgType.START, link.frame_seq - 1, P.NakReason.NOT_CONFIGURED)


# ------------------------------------------------------------------ overload
def test_overload_shows_up_as_counted_drops_never_silent_ones(built):
    # 2000 samples/s x 21 bytes = 42 000 B/s on a 25 000 B/s line (250 000 baud, 8N1).
    # SerialRig refuses such a rate up front, so the device is driven frame by frame.
    n = 1000
    with _open() as port:
        link = DeviceLink(port)
        link.hello()
        run = link.run(P.Config(500, n, 255, 4, 500), P.WaveConstant(0))
    end = run.end
    assert end is not None and end.reason == P.EndReason.COMPLETE
    assert end.samples_dropped > 0
    assert all(np.diff(run.frame_seqs) % 256 == 1), "the link itself lost nothing"
    assert end.samples_sent == len(run.samples)
    assert len(run.samples) + end.samples_dropped == n
    indices = np.array([s.seq for s in run.samples])
    assert np.all(np.diff(indices) > 0)
    gaps = int(np.sum(np.diff(indices) - 1)) + indices[0] + (n - 1 - indices[-1])
    assert gaps == end.samples_dropped, "every dropped sample is a gap in the indices"
    assert [f.code for f in run.faults] == [P.FaultCode.QUEUE_OVERFLOW]
    first_gap = next(k for k, i in enumerate(indices) if i != k)
    assert run.faults[0].seq == first_gap


def test_serial_rig_refuses_a_rate_the_line_cannot_carry_before_starting(built):
    # The host's side of the same overload: SerialRig says so up front; the device never runs.
    with _rig() as (rig, _):
        with pytest.raises(ValueError, match="sample_period 0.0005 s needs 420000 baud"):
            rig.run(Experiment(Constant(0), sample_period=0.0005, duration=0.5))
        rec = rig.run(Experiment(Constant(0), sample_period=0.002, duration=0.2))   # still usable
    assert rec.metadata["device_samples_dropped"] == "0" and len(rec.seq) == 100


# ------------------------------------------------------------------ encoder
@pytest.mark.parametrize("decoding", [4, 2, 1], ids=["x4", "x2", "x1"])
def test_encoder_counts_exactly_below_the_ceiling(built, decoding):
    rate = -40_000.0   # 4x counts/s, backwards; the measured x4 ceiling is 90-100 k counts/s
    with _open(encoder_rate=rate) as port:
        link = DeviceLink(port)
        link.hello()
        run = link.run(P.Config(2000, 200, 255, decoding, 500), P.WaveConstant(0))
    assert run.end is not None and run.end.encoder_errors == 0
    counts = np.array([s.counts for s in run.samples])
    t = np.array([s.time_us for s in run.samples]) * 1e-6
    expected = rate * decoding / 4 * (t[-1] - t[0])
    # Exact up to the quantisation of both ends (1 count) and the snapshot jitter (<= 24 us).
    assert abs((counts[-1] - counts[0]) - expected) <= 1 + abs(rate) * decoding / 4 * 24e-6
    assert not any(s.flags & P.SampleFlag.ENCODER_ERROR for s in run.samples)


def test_encoder_beyond_the_ceiling_reports_errors(built):
    # 120 k counts/s x4 is past the ceiling (90-100 k): edges are missed, and END says so.
    with _open(encoder_rate=120_000) as port:
        link = DeviceLink(port)
        link.hello(timeout=5.0)
        run = link.run(P.Config(2000, 200, 255, 4, 500), P.WaveConstant(0))
    assert run.end is not None and run.end.encoder_errors > 0
    assert any(s.flags & P.SampleFlag.ENCODER_ERROR for s in run.samples)


# ------------------------------------------------------------------ firmware vs pure-Python device
def test_emulated_firmware_and_pure_python_device_agree_to_one_count(sine_run):
    _, avr = sine_run
    with SerialRig(f"fake://?a={A}&b={B}&counts_per_rev={COUNTS_PER_REV}&speed=0", 250000,
                   counts_per_rev=COUNTS_PER_REV) as rig:
        fake = rig.run(SINE)
    np.testing.assert_array_equal(avr.duty, fake.duty)
    # Both floor the same exact trajectory: the firmware reads the count and writes the duty a
    # cycle apart, at an instant that moves by up to 3 cycles from tick to tick, and the harness
    # applies the duty and moves the encoder's pins to the cycle, so the counts differ by at
    # most one, where the shaft is within a few thousandths of a count of a boundary (measured:
    # 3-10 of 600-3000 samples).
    assert np.max(np.abs(avr.counts - fake.counts)) <= 1
    assert np.max(np.abs(fake.counts)) > 1000, "the motor really turned"


# ------------------------------------------------------------------ the IN1/IN2 H-bridge build
def test_in1_in2_driver_build_turns_the_motor_both_ways(built):
    experiment = Experiment(Constant(-150), sample_period=0.002, duration=0.4)
    with _open(driver="in1-in2") as port:
        with SerialRig(port, 250000, counts_per_rev=COUNTS_PER_REV) as rig:
            rec = rig.run(experiment)
    # From rest under duty -150, applied from the second tick on (the device's one-sample delay):
    # speed -18 (1 - exp(-25 t)) rad/s; exact solution at 0.4 s.
    t = rec.time[-1] - rec.time[0] - experiment.sample_period
    angle = -STEADY_SPEED * (t - (1 - math.exp(-A * t)) / A)
    expected = angle * COUNTS_PER_REV / (2 * math.pi)
    assert rec.counts[-1] - rec.counts[0] == pytest.approx(expected, abs=2)


def test_harness_coulomb_friction_matches_the_pure_python_device(built):
    # Friction 40 rad/s^2 holds the motor while |b u| <= 40 (|duty| <= 13); a +-60 PRBS
    # reverses it 20 times, so sticking and zero crossings matter. fake:// integrates them
    # event by event, the harness per 1 us step: the counts still agree to one.
    experiment = Experiment(PRBS(60, -60, order=7, hold=25), sample_period=0.002, duration=1.0)
    with _rig(friction=40) as (rig, _):
        avr = rig.run(experiment)
    with SerialRig(f"fake://?a={A}&b={B}&counts_per_rev={COUNTS_PER_REV}&speed=0&friction=40", 250000,
                   counts_per_rev=COUNTS_PER_REV) as rig:
        fake = rig.run(experiment)
    assert np.max(np.abs(avr.counts - fake.counts)) <= 1
    assert np.ptp(fake.counts) > 1000
