"""The bench firmware, compiled for the Uno and run byte for byte under simavr (``avr-sim://``).

Each test starts the harness (``hardware/sim/motorid_avr_sim.c``) with a motor, opens its
pseudo-terminal and talks protocol v1 to the real firmware. Emulated time is capped at wall
time, so every run costs its duration in wall time: the runs are short (0.5-3 s).
"""
from __future__ import annotations

import math
import time
from urllib.parse import urlencode

import numpy as np
import pytest
from scipy.optimize import least_squares

import identify
from hardware.sim.device_link import DeviceLink
from hardware import protocol as P
from hardware.sim.launcher import build, open_avr_sim
from motorsim import Constant, Experiment, Recording, Sine

A, B, COUNTS_PER_REV = 25.0, 3.0, 16667
# 20 rad/s, amplitude 100: the speed swings +-9.4 rad/s (25 k counts/s, well under the
# encoder ceiling) and one frequency with the start-up transient identifies both a and b.
SINE = Experiment(Sine(20.0, 100), sample_period=0.002, duration=3.0)


def _open(baudrate: int = 250000, **query):
    query = {"a": A, "b": B, "counts_per_rev": COUNTS_PER_REV, **query}
    return open_avr_sim("avr-sim://?" + urlencode(query), baudrate, 0.02)


@pytest.fixture(scope="module")
def built():
    """Firmware and harness built once (``make firmware avr-sim``; installs packages if missing)."""
    return build()


@pytest.fixture(scope="module")
def sine_run(built):
    with _open() as port:
        link = DeviceLink(port)
        boot = link.wait_for(P.Boot, timeout=2.0)
        hello = link.hello()
        result = link.run(P.config_for(SINE, watchdog_ms=500), P.wave_for(SINE))
    return boot, hello, result, port.avr_simulation.stats


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
def test_boot_and_hello_report_protocol_version_clock_and_power_on_reset(sine_run):
    boot, hello, _, _ = sine_run
    assert boot is not None and boot.version == P.PROTOCOL_VERSION
    assert hello.version == P.PROTOCOL_VERSION
    assert hello.firmware_version == 0x0100   # 1.0 (major << 8 | minor)
    assert hello.f_cpu_hz == 16_000_000
    assert hello.max_payload == P.MAX_PAYLOAD
    assert hello.board == "uno"
    assert hello.reset_cause & 1, "the harness starts the AVR from power-on (MCUSR.PORF)"
    assert boot.reset_cause == hello.reset_cause


# ------------------------------------------------------------------ the sine run
def test_sine_run_has_no_drops_and_its_duty_equals_expand(sine_run):
    _, _, run, _ = sine_run
    n = SINE.n_samples
    assert run.end is not None and run.end.reason == P.EndReason.COMPLETE
    assert run.end.samples_dropped == 0 and run.end.tick_overruns == 0 and run.end.rx_errors == 0
    assert run.end.samples_sent == n == len(run.samples)
    assert [s.index for s in run.samples] == list(range(n))
    assert all(np.diff(run.seqs) % 256 == 1), "no frame lost on the link"
    duty = np.array([s.duty for s in run.samples])
    np.testing.assert_array_equal(duty, P.expand(P.wave_for(SINE), n, SINE.duty_limit))
    np.testing.assert_array_equal(duty, SINE.duty())
    # The Timer 1 clock is exact; micros() has 4 us steps and the snapshot waits for any
    # interrupt already running (UART, encoder: under 10 us each), hence +-16 us.
    period = np.diff(np.array([s.time_us for s in run.samples], dtype=np.int64)) % 2**32
    assert np.all(np.abs(period - 2000) <= 16)
    assert run.end.encoder_errors == 0


def test_sine_run_identifies_the_harness_motor_within_one_percent(sine_run):
    _, _, run, _ = sine_run
    counts = np.array([s.counts for s in run.samples], dtype=float)
    duty = np.array([s.duty for s in run.samples], dtype=float)
    h = SINE.sample_period
    if "oe" in identify.available_methods():
        rec = Recording(time=np.arange(len(counts)) * h, duty=duty, sample_period=h,
                        counts=counts.astype(np.int64), counts_per_rev=COUNTS_PER_REV)
        est = identify.fit(rec, method="oe")
        a, b = est.a, est.b
    else:
        a, b = _fit_output_error(counts, duty, h, COUNTS_PER_REV)
    # Truth is the harness's a, b. Left over: the few us between the count snapshot and the
    # duty write, and count quantisation; measured 0.05 %, the issue asks for 1 %.
    assert a == pytest.approx(A, rel=0.01)
    assert b == pytest.approx(B, rel=0.01)


# ------------------------------------------------------------------ STOP and watchdog
STEADY = P.Config(2000, 1000, 255, 4, 0)   # 2 s at 500 Hz, host-silence watchdog off
STEADY_SPEED = B / A * 150                 # rad/s under duty 150


def _settle_then_stop(port) -> float:
    time.sleep(0.5)   # >= 0.35 s emulated (emulation runs at 0.7-1x wall time): 9 time constants
    port.close()
    return port.avr_simulation.stop()["speed_rad_s"]


def test_stop_mid_run_ends_the_run_and_stops_the_motor(built):
    with _open() as port:
        link = DeviceLink(port)
        link.hello()

        def stop_after_200(link, sample):
            if sample.index == 200:
                link.send(P.Stop())

        run = link.run(STEADY, P.WaveConstant(150), on_sample=stop_after_200)
        speed = _settle_then_stop(port)
    assert run.end is not None and run.end.reason == P.EndReason.STOPPED_BY_HOST
    assert 200 < len(run.samples) < STEADY.n_samples
    assert run.end.samples_sent == len(run.samples)
    assert any(isinstance(m, P.Ack) and m.acked_type == P.MsgType.STOP for m in run.others)
    # Running at ~18 rad/s when stopped; after 9 time constants at duty 0 it is at rest.
    assert run.samples[-1].counts - run.samples[-101].counts > 0.5 * STEADY_SPEED * 0.2 * COUNTS_PER_REV / (2 * math.pi)
    assert abs(speed) < 1e-3 * STEADY_SPEED


def test_host_silence_watchdog_stops_the_motor_and_reports_fault_then_end(built):
    with _open() as port:
        link = DeviceLink(port)
        link.hello()
        run = link.run(STEADY._replace(watchdog_ms=200), P.WaveConstant(150), heartbeat=None)
        speed = _settle_then_stop(port)
    assert run.end is not None and run.end.reason == P.EndReason.HOST_SILENCE
    assert [f.code for f in run.faults] == [P.FaultCode.HOST_SILENCE]
    # 200 ms after START at 2 ms per sample: index 100, give or take the millis() step and
    # the loop() pass that notices it.
    assert 98 <= run.faults[0].index <= 104
    assert len(run.samples) == run.end.samples_sent == run.faults[0].index
    assert abs(speed) < 1e-3 * STEADY_SPEED


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
            if sample.index in (50, 100) and sample.index not in injected:
                injected.append(sample.index)
                if sample.index == 50:
                    bad = bytearray(P.encode_message(P.Heartbeat(), link.seq))
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
        seq = link.seq
        link.send_raw(P.encode_frame(0x3F, seq, b""))
        link.seq += 1
        nak = link.wait_for(P.Nak, timeout=1.0)
        assert nak == P.Nak(0x3F, seq, P.NakReason.UNKNOWN_TYPE)
        seq = link.seq
        link.send_raw(P.encode_frame(P.MsgType.CONFIG, seq, b"\x00" * 12))
        link.seq += 1
        nak = link.wait_for(P.Nak, timeout=1.0)
        assert nak == P.Nak(P.MsgType.CONFIG, seq, P.NakReason.BAD_LENGTH)
        assert link.command(P.Config(50, 10, 255, 4, 0)) == P.Nak(P.MsgType.CONFIG, link.seq - 1, P.NakReason.BAD_VALUE)
        assert link.command(P.Start()) == P.Nak(P.MsgType.START, link.seq - 1, P.NakReason.NOT_CONFIGURED)


# ------------------------------------------------------------------ overload
def test_overload_shows_up_as_counted_drops_never_silent_ones(built):
    # 2000 samples/s x 21 bytes = 42 000 B/s on a 25 000 B/s line (250 000 baud, 8N1).
    n = 1000
    with _open() as port:
        link = DeviceLink(port)
        link.hello()
        run = link.run(P.Config(500, n, 255, 4, 500), P.WaveConstant(0))
    end = run.end
    assert end is not None and end.reason == P.EndReason.COMPLETE
    assert end.samples_dropped > 0
    assert all(np.diff(run.seqs) % 256 == 1), "the link itself lost nothing"
    assert end.samples_sent == len(run.samples)
    assert len(run.samples) + end.samples_dropped == n
    indices = np.array([s.index for s in run.samples])
    assert np.all(np.diff(indices) > 0)
    assert int(np.sum(np.diff(indices) - 1)) + indices[0] + (n - 1 - indices[-1]) == end.samples_dropped
    assert [f.code for f in run.faults] == [P.FaultCode.QUEUE_OVERFLOW]
    first_gap = next(k for k, i in enumerate(indices) if i != k)
    assert run.faults[0].index == first_gap


# ------------------------------------------------------------------ encoder
@pytest.mark.parametrize("decoding", [4, 2, 1], ids=["x4", "x2", "x1"])
def test_encoder_counts_exactly_below_the_ceiling(built, decoding):
    rate = -40_000.0   # 4x counts/s, backwards; the measured x4 ceiling is 80 k counts/s
    with _open(encoder_rate=rate) as port:
        link = DeviceLink(port)
        link.hello()
        run = link.run(P.Config(2000, 200, 255, decoding, 500), P.WaveConstant(0))
    assert run.end is not None and run.end.encoder_errors == 0
    counts = np.array([s.counts for s in run.samples])
    t = np.array([s.time_us for s in run.samples]) * 1e-6
    expected = rate * decoding / 4 * (t[-1] - t[0])
    # Exact up to the quantisation of both ends (1 count) and the +-16 us snapshot jitter.
    assert abs((counts[-1] - counts[0]) - expected) <= 1 + abs(rate) * decoding / 4 * 32e-6
    assert not any(s.flags & P.SampleFlag.ENCODER_ERROR for s in run.samples)


def test_encoder_beyond_the_ceiling_reports_errors(built):
    # 120 k counts/s x4 is past the ceiling: edges are missed, and END says so.
    with _open(encoder_rate=120_000) as port:
        link = DeviceLink(port)
        link.hello(timeout=5.0)
        run = link.run(P.Config(2000, 200, 255, 4, 500), P.WaveConstant(0))
    assert run.end is not None and run.end.encoder_errors > 0
    assert any(s.flags & P.SampleFlag.ENCODER_ERROR for s in run.samples)
