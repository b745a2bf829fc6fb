"""hardware.protocol against published references (CRC catalogue, COBS paper examples) and its own spec."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware import protocol as P
from hardware.errors import FrameError, ProtocolError, ProtocolVersionError
from motorsim import PRBS, Chirp, Constant, Experiment, Multisine, OddMultisine, Sine, Step


# ------------------------------------------------------------------ CRC and COBS
def test_crc16_matches_the_ccitt_false_catalogue_check_value():
    # The CRC catalogue (reveng) lists CRC-16/CCITT-FALSE (a.k.a. CRC-16/IBM-3740): check = 0x29B1
    # for the ASCII bytes "123456789".
    assert P.crc16(b"123456789") == 0x29B1


_COBS_EXAMPLES = [  # Cheshire & Baker 1999 / Wikipedia "Consistent Overhead Byte Stuffing" examples
    (b"\x00", b"\x01\x01"),
    (b"\x00\x00", b"\x01\x01\x01"),
    (b"\x00\x11\x00", b"\x01\x02\x11\x01"),
    (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
    (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
    (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
    (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255))),
    (bytes(range(0, 255)), b"\x01\xff" + bytes(range(1, 255))),
    (bytes(range(1, 256)), b"\xff" + bytes(range(1, 255)) + b"\x02\xff"),
    (bytes(range(2, 256)) + b"\x00", b"\xff" + bytes(range(2, 256)) + b"\x01\x01"),
]


@pytest.mark.parametrize("raw, encoded", _COBS_EXAMPLES, ids=[f"ex{i}" for i in range(len(_COBS_EXAMPLES))])
def test_cobs_matches_the_published_examples(raw, encoded):
    assert P.cobs_encode(raw) == encoded
    assert P.cobs_decode(encoded) == raw


@settings(deadline=None)   # no per-example time limit: the shared machine stalls processes at times
@given(st.binary(max_size=600))
def test_cobs_round_trips_and_removes_every_zero(data):
    enc = P.cobs_encode(data)
    assert b"\x00" not in enc
    assert P.cobs_decode(enc) == data
    assert len(enc) <= len(data) + 1 + len(data) // 254


@pytest.mark.parametrize("bad", [b"\x05\x11\x22", b"\x02\x00", b"\xff\x01"], ids=["overrun", "zero", "short-ff"])
def test_cobs_decode_rejects_malformed_blocks(bad):
    with pytest.raises(FrameError):
        P.cobs_decode(bad)


# ------------------------------------------------------------------ frames and messages
_MESSAGES = [
    P.Hello(1), P.Config(5000, 2000, 255, 4, 500), P.Start(), P.Stop(), P.Heartbeat(),
    P.HelloAck(2, 0x0102, 16_000_000, 2, 60, "uno", 16667), P.Ack(0x02, 7), P.Nak(0x04, 9, P.NakReason.NOT_CONFIGURED),
    P.Sample(123456, 4_000_000_000, -2_000_000_000, -255, 3), P.End(0, 2000, 1, 2, 3, 4), P.Fault(1, 77),
    P.Boot(1, 1), P.WaveConstant(-100), P.WaveStep(0, 100, 200),
    P.WaveMultisine(5, ((200, 0, 34_359_738), (-50, 2**32 - 1, 1))), P.WaveChirp(0, 200, 5, 100_000, -3),
    P.WavePrbs(200, -200, 10, 3, 1), P.WaveOddMultisine(-5, 20, 10, 63, 65535, 3),
    P.Control(1, 1, (14642, -206745, 0, 0, -21450)), P.Control(2, 0, (1397, 198)),
    P.ReferenceWords("constant", -65535), P.ReferenceWords("step", 100, -5, 40),
    P.ReferenceWords("trapezoid", 400, 0, 10, 100, 50),
    P.ReferenceWords("multisine", 7, components=((4244, 0, 34_359_738), (-1000, 2**32 - 1, 1))),
]

_LENGTHS = {P.Hello: 1, P.Config: 13, P.Start: 0, P.Stop: 0, P.Heartbeat: 0, P.HelloAck: 21, P.Ack: 2,
            P.Nak: 3, P.Sample: 15, P.End: 17, P.Fault: 5, P.Boot: 2, P.WaveConstant: 3, P.WaveStep: 9,
            P.WaveChirp: 17, P.WavePrbs: 10, P.WaveOddMultisine: 10}


@pytest.mark.parametrize("msg", _MESSAGES, ids=[type(m).__name__ for m in _MESSAGES])
def test_every_message_round_trips_with_the_documented_length(msg):
    wire = P.encode_message(msg, 200)
    assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
    t, frame_seq, payload = P.decode_frame(wire[:-1])
    assert frame_seq == 200
    # PROTOCOL.md's table: payload lengths (WAVE: 1 kind byte + the kind's fields; multisine 3 + 10 n)
    expected = _LENGTHS.get(type(msg), 1 + 3 + 10 * len(getattr(msg, "components", ())))
    if isinstance(msg, P.Control):        # PROTOCOL.md: 3 + 4 n
        expected = 3 + 4 * len(msg.gains)
    elif isinstance(msg, P.ReferenceWords):   # kind byte + 4, 12, 16, or 5 + 12 n
        expected = 1 + {"constant": 4, "step": 12, "trapezoid": 16}.get(msg.kind, 5 + 12 * len(msg.components))
    assert len(payload) == expected
    assert P.decode_message(t, payload) == msg


def test_odd_multisine_fields_out_of_range_are_problems_a_device_would_nak():
    assert P.wave_range_problems(P.WaveOddMultisine(0, 20, 10, 63, 1, 3)) == []
    for bad, match in ((P.WaveOddMultisine(0, 20, 3, 31, 1, 3), "period_log2"),
                       (P.WaveOddMultisine(0, 20, 10, 62, 1, 3), "max_harmonic must be odd"),
                       (P.WaveOddMultisine(0, 0, 10, 63, 1, 3), "amplitude"),
                       (P.WaveOddMultisine(0, 20, 10, 63, 1, 1), "group"),
                       (P.WaveOddMultisine(2000, 20, 10, 63, 1, 3), "offset")):
        problems = P.wave_range_problems(bad)
        assert len(problems) == 1 and match in problems[0]


def test_wave_payload_spans_3_to_44_bytes():
    # kind byte + CONSTANT's level (3) up to kind + offset + n + 4 x 10 for a four-sine multisine (44)
    comps = ((1, 2, 3),) * 4
    lengths = [len(P.decode_frame(P.encode_message(w, 0)[:-1])[2])
               for w in (P.WaveConstant(1), P.WaveMultisine(0, comps))]
    assert lengths == [3, 44] and 44 <= P.MAX_PAYLOAD


def test_sample_frame_is_21_bytes_on_the_wire_as_documented():
    assert len(P.encode_message(P.Sample(1, 2, 3, 4, 0), 0)) == 21


def test_sample_payload_layout_is_little_endian_byte_for_byte():
    _, _, payload = P.decode_frame(P.encode_message(P.Sample(0x01020304, 0x0A0B0C0D, -2, -3, 1), 0)[:-1])
    assert payload == bytes([4, 3, 2, 1, 0x0D, 0x0C, 0x0B, 0x0A, 0xFE, 0xFF, 0xFF, 0xFF, 0xFD, 0xFF, 1])


def test_decode_frame_rejects_bad_crc_short_body_and_long_frames():
    good = P.encode_message(P.Ack(2, 3), 0)[:-1]
    body = bytearray(P.cobs_decode(good))
    body[2] ^= 0x10
    with pytest.raises(FrameError, match="CRC"):
        P.decode_frame(P.cobs_encode(bytes(body)))
    with pytest.raises(FrameError, match="at least 4"):
        P.decode_frame(P.cobs_encode(b"\x82\x00\x01"))
    with pytest.raises(FrameError, match="at most 66"):
        P.decode_frame(b"\x01" * 67)


@pytest.mark.parametrize("msg_type, payload, rule", [
    (0x84, bytes(14), "SAMPLE|Sample"), (0x7F, b"", "unknown frame type"),
    (0x03, b"\x09\x00", "unknown WAVE kind"), (0x03, b"\x02\x00\x00\x05", "n must be"),
    (0x03, b"\x02\x00\x00\x01" + bytes(9), "must have 13"), (0x03, b"", "kind byte")],
    ids=["short-sample", "unknown-type", "unknown-kind", "too-many-sines", "short-multisine", "empty-wave"])
def test_decode_message_rejects_wrong_lengths_and_types(msg_type, payload, rule):
    with pytest.raises(FrameError, match=rule):
        P.decode_message(msg_type, payload)


def test_encode_rejects_out_of_range_fields_naming_them():
    with pytest.raises(ValueError, match="frame_seq"):
        P.encode_frame(1, 256)
    with pytest.raises(ValueError, match="payload"):
        P.encode_frame(1, 0, bytes(61))
    with pytest.raises(ValueError, match="Sample"):
        P.encode_message(P.Sample(-1, 0, 0, 0, 0), 0)
    with pytest.raises(TypeError, match="protocol message"):
        P.encode_message((1, 2), 0)


def test_protocol_errors_subclass_value_error():
    assert issubclass(FrameError, ValueError) and issubclass(ProtocolVersionError, ProtocolError)


def test_version_mismatch_names_both_versions():
    P.check_version(P.PROTOCOL_VERSION)
    with pytest.raises(ProtocolVersionError, match=r"version 7.*version 6"):
        P.check_version(7)


# ------------------------------------------------------------------ every single-bit flip is detected
_sample_st = st.builds(P.Sample, st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1),
                       st.integers(-2**31, 2**31 - 1), st.integers(-255, 255), st.integers(0, 3))


@settings(max_examples=60, deadline=None)
@given(_sample_st, st.integers(0, 255))
def test_every_single_bit_flip_of_a_sample_frame_is_detected(sample, frame_seq):
    wire = P.encode_message(sample, frame_seq)
    after = P.encode_message(P.Ack(1, 2), (frame_seq + 1) % 256)
    for byte in range(len(wire) - 1):           # every bit of the encoded frame ...
        for bit in range(8):
            bad = bytearray(wire)
            bad[byte] ^= 1 << bit
            reader = P.FrameReader()
            got = reader.feed(b"\x00" + bytes(bad) + after)
            # ... is caught: the damaged frame yields nothing and is counted, the next frame survives
            assert got == [((frame_seq + 1) % 256, P.Ack(1, 2))], (byte, bit)
            assert reader.rx_errors >= 1


# ------------------------------------------------------------------ FrameReader
def _stream(n):
    msgs = [P.Sample(i, 1000 * i, -7 * i, i % 200 - 100, 0) for i in range(n)]
    return msgs, b"".join(P.encode_message(m, i % 256) for i, m in enumerate(msgs))


def test_reader_reassembles_frames_fed_one_byte_at_a_time():
    msgs, wire = _stream(50)
    reader, got = P.FrameReader(), []
    for i in range(len(wire)):
        got += reader.feed(wire[i:i + 1])
    assert [m for _, m in got] == msgs and [s for s, _ in got] == list(range(50))
    assert reader.rx_errors == 0


def test_reader_skips_garbage_before_and_between_frames_and_counts_it():
    msgs, _ = _stream(3)
    garbage = b"\x13\x37\xff\x42"
    wire = garbage + b"\x00" + b"".join(P.encode_message(m, i) + garbage + b"\x00" for i, m in enumerate(msgs))
    reader = P.FrameReader()
    assert [m for _, m in reader.feed(wire)] == msgs
    assert reader.rx_errors == 4       # one per garbage run (each ends at a delimiter)


def test_reader_ignores_empty_frames_silently():
    reader = P.FrameReader()
    assert reader.feed(b"\x00\x00\x00" + P.encode_message(P.Stop(), 5) + b"\x00") == [(5, P.Stop())]
    assert reader.rx_errors == 0


def test_reader_discards_an_overlong_run_up_to_the_next_delimiter_counting_one_error():
    reader = P.FrameReader()
    assert reader.feed(b"\x01" * 50) == []
    assert reader.feed(b"\x01" * 50) == [] and reader.rx_errors == 1
    assert reader.feed(b"\x01" * 500) == [] and reader.rx_errors == 1
    assert reader.feed(b"\x00" + P.encode_message(P.Start(), 1)) == [(1, P.Start())]
    assert reader.rx_errors == 1


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=120), st.sampled_from([b"\x00", b"\xff" * 70])), max_size=30),
       st.lists(st.integers(1, 64), min_size=1, max_size=10))
def test_fuzz_reader_never_raises_never_grows_and_recovers(chunks, sizes):
    # Arbitrary bytes in arbitrary splits: feed() returns only valid messages (never raises),
    # keeps at most MAX_ENCODED bytes pending, and a good frame after a delimiter always survives.
    reader = P.FrameReader()
    data = b"".join(chunks)
    i, j = 0, 0
    while i < len(data):
        n = sizes[j % len(sizes)]
        for frame_seq, msg in reader.feed(data[i:i + n]):
            assert 0 <= frame_seq <= 255 and type(msg).__module__ == P.__name__
        assert reader.pending_bytes <= P.MAX_ENCODED
        i, j = i + n, j + 1
    marker = P.End(0, 1, 2, 3, 4, 5)
    assert reader.feed(b"\x00" + P.encode_message(marker, 9)) == [(9, marker)]


def _reference_decode(part: bytes):
    try:
        t, frame_seq, payload = P.decode_frame(part)
        return [(frame_seq, P.decode_message(t, payload))]
    except FrameError:
        return []


def _edited_frame(sample, frame_seq, where, value):
    frame = bytearray(P.encode_message(sample, frame_seq)[:-1])
    if where is not None:
        frame[where % len(frame)] = value
    return bytes(frame)


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.binary(min_size=1, max_size=70).map(lambda b: b.replace(b"\x00", b"\x01")),
                 st.builds(_edited_frame, _sample_st, st.integers(0, 255), st.none() | st.integers(0, 19),
                           st.integers(1, 255))))
def test_reader_accepts_exactly_what_decode_frame_and_decode_message_accept(part):
    # The reader's inlined COBS fast path against the plain functions, on random and on valid frames.
    assert P.FrameReader().feed(part + b"\x00") == _reference_decode(part)


# ------------------------------------------------------------------ expand() is the device's arithmetic
_EXCITATIONS = [Constant(-120), Constant(400), Step(150, 0.3, -40), Sine(10.0), Sine(37.0, 300, 1.2, 20),
                Multisine((10.0, 20.0, 30.0, 40.0), (100, 60, -40, 30), (0.1, 0.2, 0.3, 0.4), 10),
                Chirp(1.0, 300.0, 250), Chirp(200.0, 2.0, 180, -15), PRBS(200, -200, 2, 1, 1),
                PRBS(120, -80, 7, 5, 33), PRBS(255, 0, 16, 0xACE1, 1),
                OddMultisine(1024, 63, 20, 5), OddMultisine(256, 127, 9, 0, 0, offset=-7),
                OddMultisine(65536, 127, 60, 65535, 16)]


@pytest.mark.parametrize("excitation", _EXCITATIONS, ids=[e.describe() for e in _EXCITATIONS])
@pytest.mark.parametrize("sample_period, duty_limit", [(0.005, 255), (0.001, 180)], ids=["5ms", "1ms-clamped"])
def test_expand_of_the_decoded_wave_reproduces_experiment_duty_exactly(excitation, sample_period, duty_limit):
    exp = Experiment(excitation, sample_period, 3.0, duty_limit)
    wave = P.wave_for(exp)
    (_, decoded), = P.FrameReader().feed(P.encode_message(wave, 0))   # through the wire format
    assert np.array_equal(P.expand(decoded, exp.n_samples, exp.duty_limit), exp.duty())


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0.5, 600.0), st.integers(-400, 400), st.floats(-7.0, 7.0)),
                min_size=1, max_size=4), st.integers(-300, 300), st.integers(0, 255))
def test_expand_matches_multisine_for_any_parameters(components, offset, limit):
    f, a, p = zip(*components)
    exp = Experiment(Multisine(f, a, p, offset), 0.005, 2.0, limit)
    assert np.array_equal(P.expand(P.wave_for(exp), exp.n_samples, limit), exp.duty())


def test_expand_sine_is_within_one_duty_unit_of_the_real_sine():
    # Independent reference: 200 sin(10 t + 0.3), rounded.  The Q15 table is within 4.8e-5 of
    # full scale, so the integer duty can only differ from the rounded real sine by one unit.
    dt, n = 0.005, 4000
    wave = P.WaveMultisine(0, ((200, round(0.3 / (2 * math.pi) * 2**32), round(10 * dt / (2 * math.pi) * 2**32)),))
    ref = np.round(200 * np.sin(10 * dt * np.arange(n) + 0.3))
    assert np.max(np.abs(P.expand(wave, n, 255) - ref)) <= 1


def test_expand_prbs_has_maximal_period_and_balance():
    # Defining property of a maximal-length LFSR of order m: period 2^m - 1 with 2^(m-1) ones.
    m = 9
    d = P.expand(P.WavePrbs(1, 0, m, 1, 1), 2 * (2**m - 1), 255)
    period = 2**m - 1
    assert np.array_equal(d[:period], d[period:]) and d[:period].sum() == 2 ** (m - 1)
    for shift in range(1, period):
        assert not np.array_equal(d[:period], np.roll(d[:period], shift))


def test_expand_rejects_bad_arguments_naming_them():
    with pytest.raises(ValueError, match="n_samples"):
        P.expand(P.WaveConstant(1), -1, 255)
    with pytest.raises(ValueError, match="duty_limit"):
        P.expand(P.WaveConstant(1), 10, 256)
    with pytest.raises(ValueError, match="seed"):
        P.expand(P.WavePrbs(1, 0, 3, 1, 8), 10, 255)
    with pytest.raises(TypeError, match="wave"):
        P.expand(P.Ack(1, 2), 10, 255)


def test_config_for_rounds_the_period_to_microseconds_and_checks_ranges():
    exp = Experiment(Sine(10.0), 0.002, 1.0, 200)
    assert P.config_for(exp, watchdog_ms=300) == P.Config(2000, 500, 200, 4, 300)
    with pytest.raises(ValueError, match="sample_period"):
        P.config_for(Experiment(Sine(10.0), 0.0050005, 1.0))
    with pytest.raises(ValueError, match="sample_period"):
        P.config_for(Experiment(Sine(1.0), 2.0, 10.0))
    with pytest.raises(ValueError, match="decoding"):
        P.config_for(exp, decoding=3)
    with pytest.raises(ValueError, match="watchdog_ms"):
        P.config_for(exp, watchdog_ms=10)
