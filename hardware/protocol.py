"""The bench wire protocol (version: PROTOCOL_VERSION): pure encode/decode, COBS, CRC, and the device's duty arithmetic.

This module is the executable form of ``hardware/PROTOCOL.md`` (read that first):
bytes in, values out, no I/O and no clock.  A frame on the wire is
``COBS(type u8 | frame_seq u8 | payload | crc u16) 0x00``, little-endian, with
CRC-16/CCITT-FALSE over ``type|frame_seq|payload``; ``frame_seq`` is the sender's
link frame counter (a sample's index is ``Sample.seq``, as in a recording).

Messages are small immutable named tuples (one class per type, fixed fields):
they are created at up to 2 000 per second per direction and decoded at well
over 100 000 per second by :class:`FrameReader`, which is why they are not
frozen dataclasses (whose ``__init__`` costs several times more).

:func:`expand` reproduces the firmware's duty sequence from a decoded WAVE
(integers only); :func:`wave_for` and :func:`config_for` build the WAVE and
CONFIG that make a device run a :class:`~motorsim.rig.Experiment`, and
``expand(wave_for(e), e.n_samples, e.duty_limit) == e.duty()``.  In closed loop
(version 2) :func:`control_for` and :func:`reference_for` build the CONTROL and
REFERENCE of a :class:`~motorsim.control.ClosedLoopExperiment`; the device then runs
the controller's integer step, :class:`motorsim.fixed_point.ControlLoop`, on its counts.

One concept, the wire protocol, in one module although it is long: the messages, their
framing and the duty and reference arithmetic are specified together in ``PROTOCOL.md``,
change together with its version, and are tested against each other.
"""
from __future__ import annotations

import binascii
import enum
import struct
from typing import Any, NamedTuple, Union

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int
from motorsim.control import ClosedLoopExperiment
from motorsim.excitation import (
    MAX_AMPLITUDE,
    MAX_COMPONENTS,
    PRBS,
    PRBS_MASKS,
    Chirp,
    Constant,
    Multisine,
    OddMultisine,
    Step,
    chirp_duty,
    multisine_duty,
    prbs_bits,
)
from motorsim.fixed_point import MAX_REFERENCE, ReferenceWords, gains_from_wire
from motorsim.rig import Experiment

from .errors import FrameError, ProtocolError, ProtocolVersionError

__all__ = [
    "PROTOCOL_VERSION", "DEVICE_INPUT_DELAY", "MAX_PAYLOAD", "MAX_ENCODED", "MsgType", "NakReason", "EndReason",
    "FaultCode",
    "WaveKind", "SampleFlag", "Hello", "Config", "Start", "Stop", "Heartbeat", "HelloAck", "Ack", "Nak",
    "Sample", "End", "Fault", "Boot", "WaveConstant", "WaveStep", "WaveMultisine", "WaveChirp",
    "WavePrbs", "WaveOddMultisine", "Message", "Wave", "crc16", "cobs_encode", "cobs_decode", "encode_frame",
    "decode_frame", "encode_message", "decode_message", "FrameReader", "expand", "wave_for",
    "config_for", "check_version", "msg_type_of", "wave_range_problems", "FrameSplitter", "FrameError",
    "Control", "ControllerKind", "ReferenceKind", "ReferenceWords", "control_for", "reference_for",
    "control_problems", "reference_problems", "controller_name", "MAX_GAINS",
    "ProtocolError", "ProtocolVersionError",
]

#: Version of this protocol; the host refuses a device that reports another.
PROTOCOL_VERSION = 6
#: Samples between a SAMPLE's duty and the tick that applies it: the device latches the duty it
#: computes at tick k (from the waveform, or from the counts read at k) and applies it exactly at
#: tick k + 1, in open and closed loop.  Recordings say so (``input_delay_samples``).
DEVICE_INPUT_DELAY = 1
#: Longest payload of any frame, bytes.
MAX_PAYLOAD = 60
#: Longest encoded frame (without its delimiter) a receiver accepts, bytes.
MAX_ENCODED = 66
_MIN_BODY = 4


class MsgType(enum.IntEnum):
    """Frame types: host to device 0x01-0x3F, device to host 0x80-0xBF."""

    HELLO = 0x01
    CONFIG = 0x02
    WAVE = 0x03
    START = 0x04
    STOP = 0x05
    HEARTBEAT = 0x06
    CONTROL = 0x07
    REFERENCE = 0x08
    HELLO_ACK = 0x81
    ACK = 0x82
    NAK = 0x83
    SAMPLE = 0x84
    END = 0x85
    FAULT = 0x86
    BOOT = 0x87


class NakReason(enum.IntEnum):
    """Why the device refused a command (NAK ``reason``)."""

    BUSY = 1
    BAD_LENGTH = 2
    BAD_VALUE = 3
    NOT_CONFIGURED = 4
    UNKNOWN_TYPE = 5


class EndReason(enum.IntEnum):
    """Why a run ended (END ``reason``)."""

    COMPLETE = 0
    STOPPED_BY_HOST = 1
    HOST_SILENCE = 2
    DEVICE_FAULT = 3


class FaultCode(enum.IntEnum):
    """FAULT ``code``."""

    HOST_SILENCE = 1
    QUEUE_OVERFLOW = 2
    ENCODER_ERROR_RATE = 3


class WaveKind(enum.IntEnum):
    """WAVE ``kind``."""

    CONSTANT = 0
    STEP = 1
    MULTISINE = 2
    CHIRP = 3
    PRBS = 4
    ODD_MULTISINE = 5


class ControllerKind(enum.IntEnum):
    """CONTROL ``controller``: 0 runs the WAVE (open loop), the others a controller of :mod:`motorsim.control`."""

    NONE = 0
    MPC = 1
    PI = 2
    POSITION = 3
    FEEDFORWARD = 4
    LQR = 5
    LQR_POSITION = 6
    LQR_INTEGRAL = 7


class ReferenceKind(enum.IntEnum):
    """REFERENCE ``kind``."""

    CONSTANT = 0
    STEP = 1
    MULTISINE = 2
    TRAPEZOID = 3


#: Most gains in one CONTROL (its payload: 3 + 4 n bytes).
MAX_GAINS = 14
_KIND_NAMES = {ControllerKind.MPC: "mpc", ControllerKind.PI: "pi", ControllerKind.POSITION: "position",
               ControllerKind.FEEDFORWARD: "feedforward", ControllerKind.LQR: "lqr",
               ControllerKind.LQR_POSITION: "lqr-position", ControllerKind.LQR_INTEGRAL: "lqr-integral"}
_REFERENCE_NAMES = {ReferenceKind.CONSTANT: "constant", ReferenceKind.STEP: "step",
                    ReferenceKind.MULTISINE: "multisine", ReferenceKind.TRAPEZOID: "trapezoid"}


class SampleFlag(enum.IntFlag):
    """SAMPLE ``flags`` bits."""

    ENCODER_ERROR = 1
    TICK_LATE = 2


# ---------------------------------------------------------------- messages
class Hello(NamedTuple):
    """HELLO (0x01): the host's protocol version."""

    version: int = PROTOCOL_VERSION


class Config(NamedTuple):
    """CONFIG (0x02): sample period in µs, samples, duty clamp, quadrature decoding (1, 2, 4),
    watchdog in ms (0 off)."""

    sample_period_us: int
    n_samples: int
    duty_limit: int
    decoding: int
    watchdog_ms: int


class Start(NamedTuple):
    """START (0x04)."""


class Stop(NamedTuple):
    """STOP (0x05)."""


class Heartbeat(NamedTuple):
    """HEARTBEAT (0x06): refreshes the device's host-silence watchdog; never answered."""


class HelloAck(NamedTuple):
    """HELLO_ACK (0x81): the device's protocol and firmware versions, clock (Hz), MCUSR at boot,
    max payload, board name, encoder counts per revolution (0: not known to the device)."""

    version: int
    firmware_version: int
    f_cpu_hz: int
    reset_cause: int
    max_payload: int
    board: str
    counts_per_rev: int = 0


class Control(NamedTuple):
    """CONTROL (0x07): a :class:`ControllerKind`, the reference preview in samples, the Q16 gains
    in the order of :data:`motorsim.fixed_point.GAIN_ORDER`."""

    controller: int
    preview: int
    gains: tuple


class Ack(NamedTuple):
    """ACK (0x82): the type and frame_seq of the accepted frame."""

    acked_type: int
    acked_frame_seq: int


class Nak(NamedTuple):
    """NAK (0x83): the type and frame_seq of the refused frame and a :class:`NakReason`."""

    refused_type: int
    refused_frame_seq: int
    reason: int


class Sample(NamedTuple):
    """SAMPLE (0x84): sample index ``seq``, device time in µs (wrapping u32), absolute encoder count, duty,
    flags."""

    seq: int
    time_us: int
    counts: int
    duty: int
    flags: int


class End(NamedTuple):
    """END (0x85): an :class:`EndReason` and the device's counters for the run."""

    reason: int
    samples_sent: int
    samples_dropped: int
    encoder_errors: int
    rx_errors: int
    tick_overruns: int


class Fault(NamedTuple):
    """FAULT (0x86): a :class:`FaultCode` and the sample index ``seq`` at which it happened."""

    code: int
    seq: int


class Boot(NamedTuple):
    """BOOT (0x87): sent once after every reset."""

    version: int
    reset_cause: int


class WaveConstant(NamedTuple):
    """WAVE kind 0: duty ``level``."""

    level: int


class WaveStep(NamedTuple):
    """WAVE kind 1: ``before`` for k < ``step_index``, else ``after``."""

    before: int
    after: int
    step_index: int


class WaveMultisine(NamedTuple):
    """WAVE kind 2: ``offset`` and 1-4 components ``(amplitude, phase0, phase_inc)``."""

    offset: int
    components: tuple


class WaveChirp(NamedTuple):
    """WAVE kind 3: ``offset``, ``amplitude``, start phase, start phase step, step change per sample."""

    offset: int
    amplitude: int
    phase0: int
    inc0: int
    inc_step: int


class WavePrbs(NamedTuple):
    """WAVE kind 4: Galois LFSR of ``order`` from ``seed``, each bit held ``hold`` samples.

    Fields in the order of :class:`motorsim.excitation.PRBS` (``high, low, order, hold, seed``);
    on the wire they go as ``low, high, order, seed, hold`` (PROTOCOL.md).
    """

    high: int
    low: int
    order: int
    hold: int
    seed: int


class WaveOddMultisine(NamedTuple):
    """WAVE kind 5: the odd random-phase multisine of :class:`motorsim.excitation.OddMultisine`.

    The device derives its lines and phases from these fields (PROTOCOL.md, "Waveforms");
    the period is ``2**period_log2`` samples.
    """

    offset: int
    amplitude: int
    period_log2: int
    max_harmonic: int
    seed: int
    group: int

    def excitation(self) -> OddMultisine:
        """The excitation these fields describe (ValueError when a field is out of range)."""
        if not 4 <= self.period_log2 <= 16:
            raise ParameterError(f"period_log2 must be in 4...16, got {self.period_log2!r}")
        return OddMultisine(1 << self.period_log2, self.max_harmonic, self.amplitude, self.seed, self.group,
                            offset=self.offset)


Wave = Union[WaveConstant, WaveStep, WaveMultisine, WaveChirp, WavePrbs, WaveOddMultisine]
_WAVE_TYPES = (WaveConstant, WaveStep, WaveMultisine, WaveChirp, WavePrbs, WaveOddMultisine)
Message = Union[Hello, Config, Start, Stop, Heartbeat, HelloAck, Ack, Nak, Sample, End, Fault, Boot, Wave, Control,
                ReferenceWords]

# type -> (class, struct) for the fixed-length messages
_FIXED: dict[int, tuple[Any, struct.Struct]] = {
    MsgType.HELLO: (Hello, struct.Struct("<B")),
    MsgType.CONFIG: (Config, struct.Struct("<IIhBH")),
    MsgType.START: (Start, struct.Struct("<")),
    MsgType.STOP: (Stop, struct.Struct("<")),
    MsgType.HEARTBEAT: (Heartbeat, struct.Struct("<")),
    MsgType.HELLO_ACK: (HelloAck, struct.Struct("<BHIBB8sI")),
    MsgType.ACK: (Ack, struct.Struct("<BB")),
    MsgType.NAK: (Nak, struct.Struct("<BBB")),
    MsgType.SAMPLE: (Sample, struct.Struct("<IIihB")),
    MsgType.END: (End, struct.Struct("<BIIIHH")),
    MsgType.FAULT: (Fault, struct.Struct("<BI")),
    MsgType.BOOT: (Boot, struct.Struct("<BB")),
}
_TYPE_OF = {cls: t for t, (cls, _) in _FIXED.items()}
_WAVE_KIND = {WaveConstant: WaveKind.CONSTANT, WaveStep: WaveKind.STEP, WaveMultisine: WaveKind.MULTISINE,
              WaveChirp: WaveKind.CHIRP, WavePrbs: WaveKind.PRBS, WaveOddMultisine: WaveKind.ODD_MULTISINE}
_WAVE_FIXED: dict[int, tuple[Any, struct.Struct]] = {
    WaveKind.CONSTANT: (WaveConstant, struct.Struct("<h")),
    WaveKind.STEP: (WaveStep, struct.Struct("<hhI")),
    WaveKind.CHIRP: (WaveChirp, struct.Struct("<hhIIi")),
    WaveKind.PRBS: (WavePrbs, struct.Struct("<hhBHH")),
    WaveKind.ODD_MULTISINE: (WaveOddMultisine, struct.Struct("<hhBBHB")),
}
#: Wire position of each WavePrbs field (the wire order is low, high, order, seed, hold).
_PRBS_WIRE = (1, 0, 2, 4, 3)
_MS_HEAD = struct.Struct("<hB")
_MS_COMPONENT = struct.Struct("<hII")
_CONTROL_HEAD = struct.Struct("<BBB")
_REFERENCE_FIXED: dict[int, struct.Struct] = {
    ReferenceKind.CONSTANT: struct.Struct("<i"),
    ReferenceKind.STEP: struct.Struct("<iiI"),
    ReferenceKind.TRAPEZOID: struct.Struct("<iIII"),
}
_REF_MS_HEAD = struct.Struct("<iB")
_REF_MS_COMPONENT = struct.Struct("<iII")
_SAMPLE_STRUCT = _FIXED[MsgType.SAMPLE][1]
_SAMPLE_BODY = 2 + _SAMPLE_STRUCT.size + 2


# ---------------------------------------------------------------- CRC and COBS
def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, no final xor) of ``data``."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing (Cheshire & Baker 1999): ``data`` with no 0x00 left in it.

    The delimiter is not appended.
    """
    out = bytearray()
    segments = bytes(data).split(b"\x00")
    last = len(segments) - 1
    for s, segment in enumerate(segments):
        full = False
        while len(segment) >= 254:
            out.append(0xFF)
            out += segment[:254]
            segment = segment[254:]
            full = True
        if s == last and full and not segment:
            break   # a final 0xFF block needs no closing code
        out.append(len(segment) + 1)
        out += segment
    return bytes(out)


def cobs_decode(encoded: bytes) -> bytes:
    """Inverse of :func:`cobs_encode` (no delimiter).

    Raises
    ------
    FrameError
        A 0x00 inside ``encoded``, or a block that runs past its end.
    """
    if b"\x00" in encoded:
        raise FrameError("COBS data must not contain 0x00")
    out = bytearray()
    i, n = 0, len(encoded)
    while i < n:
        code = encoded[i]
        j = i + code
        if j > n:
            raise FrameError(f"COBS block at byte {i} (code {code}) runs past the end of the {n}-byte frame")
        out += encoded[i + 1:j]
        if code != 0xFF and j < n:
            out.append(0)
        i = j
    return bytes(out)


# ---------------------------------------------------------------- frames and messages
def encode_frame(msg_type: int, frame_seq: int, payload: bytes = b"") -> bytes:
    """One frame as sent on the wire: ``COBS(type | frame_seq | payload | crc) 0x00``.

    Raises
    ------
    ValueError
        ``msg_type`` or ``frame_seq`` outside 0...255, or ``payload`` longer than :data:`MAX_PAYLOAD`.
    """
    if not 0 <= msg_type <= 255:
        raise ParameterError(f"msg_type must be in 0...255, got {msg_type!r}")
    if not 0 <= frame_seq <= 255:
        raise ParameterError(f"frame_seq must be in 0...255, got {frame_seq!r}")
    if len(payload) > MAX_PAYLOAD:
        raise ParameterError(f"payload must be at most {MAX_PAYLOAD} bytes, got {len(payload)}")
    body = bytes((msg_type, frame_seq)) + bytes(payload)
    return cobs_encode(body + crc16(body).to_bytes(2, "little")) + b"\x00"


def decode_frame(encoded: bytes) -> tuple[int, int, bytes]:
    """``(type, frame_seq, payload)`` of one encoded frame (without its 0x00), CRC checked.

    Raises
    ------
    FrameError
        Too long, bad COBS, body shorter than 4 bytes, or CRC mismatch.
    """
    if len(encoded) > MAX_ENCODED:
        raise FrameError(f"encoded frame must be at most {MAX_ENCODED} bytes, got {len(encoded)}")
    body = cobs_decode(encoded)
    if len(body) < _MIN_BODY:
        raise FrameError(f"frame body must be at least {_MIN_BODY} bytes, got {len(body)}")
    crc = body[-2] | (body[-1] << 8)
    if binascii.crc_hqx(body[:-2], 0xFFFF) != crc:
        raise FrameError(f"CRC mismatch: frame says {crc:#06x}, data gives {crc16(body[:-2]):#06x}")
    return body[0], body[1], body[2:-2]


def msg_type_of(msg: Message) -> MsgType:
    """The frame type that carries ``msg`` (WAVE for every ``Wave*`` message).

    Examples
    --------
    >>> msg_type_of(Hello()).name, msg_type_of(WaveConstant(5)).name
    ('HELLO', 'WAVE')
    """
    cls = type(msg)
    if cls in _WAVE_KIND:
        return MsgType.WAVE
    if cls is Control:
        return MsgType.CONTROL
    if cls is ReferenceWords:
        return MsgType.REFERENCE
    if cls not in _TYPE_OF:
        raise ParameterTypeError(f"msg must be a protocol message (Hello, Config, ..., WaveConstant, ...), "
                                 f"got {cls.__name__}")
    return MsgType(_TYPE_OF[cls])


def encode_message(msg: Message, frame_seq: int) -> bytes:
    """The wire bytes (COBS frame and delimiter) of ``msg`` with link frame counter ``frame_seq``."""
    t = msg_type_of(msg)
    if isinstance(msg, _WAVE_TYPES):
        return encode_frame(MsgType.WAVE, frame_seq, _wave_payload(msg))
    if isinstance(msg, Control):
        return encode_frame(t, frame_seq, _control_payload(msg))
    if isinstance(msg, ReferenceWords):
        return encode_frame(t, frame_seq, _reference_payload(msg))
    cls = type(msg)
    fields = tuple(msg)
    if isinstance(msg, HelloAck):
        board = msg.board.encode("ascii")
        if len(board) > 8:
            raise ParameterError(f"board must be at most 8 ASCII characters, got {msg.board!r}")
        fields = fields[:5] + (board.ljust(8, b"\x00"),) + fields[6:]
    try:
        payload = _FIXED[t][1].pack(*fields)
    except struct.error as exc:
        raise ParameterError(f"{cls.__name__} field out of range: {exc} (got {msg!r})") from None
    return encode_frame(t, frame_seq, payload)


def _wave_payload(wave: Wave) -> bytes:
    kind = _WAVE_KIND[type(wave)]
    try:
        if isinstance(wave, WaveMultisine):
            comps = tuple(wave.components)
            if not 1 <= len(comps) <= MAX_COMPONENTS:
                raise ParameterError(f"components must hold 1...{MAX_COMPONENTS} entries, got {len(comps)}")
            return (bytes((kind,)) + _MS_HEAD.pack(wave.offset, len(comps))
                    + b"".join(_MS_COMPONENT.pack(*c) for c in comps))
        fields = tuple(wave)
        if kind == WaveKind.PRBS:
            fields = tuple(fields[i] for i in _PRBS_WIRE)
        return bytes((kind,)) + _WAVE_FIXED[kind][1].pack(*fields)
    except struct.error as exc:
        raise ParameterError(f"{type(wave).__name__} field out of range: {exc} (got {wave!r})") from None


def _control_payload(msg: Control) -> bytes:
    gains = tuple(msg.gains)
    if len(gains) > MAX_GAINS:
        raise ParameterError(f"gains must hold at most {MAX_GAINS} entries, got {len(gains)}")
    try:
        return _CONTROL_HEAD.pack(msg.controller, msg.preview, len(gains)) + struct.pack(f"<{len(gains)}i", *gains)
    except struct.error as exc:
        raise ParameterError(f"Control field out of range: {exc} (got {msg!r})") from None


def _reference_payload(words: ReferenceWords) -> bytes:
    kinds = {name: kind for kind, name in _REFERENCE_NAMES.items()}
    if words.kind not in kinds:
        raise ParameterError(f"reference kind must be one of {', '.join(kinds)}, got {words.kind!r}")
    kind = kinds[words.kind]
    try:
        if kind == ReferenceKind.MULTISINE:
            comps = tuple(words.components)
            if not 1 <= len(comps) <= MAX_COMPONENTS:
                raise ParameterError(f"components must hold 1...{MAX_COMPONENTS} entries, got {len(comps)}")
            return (bytes((kind,)) + _REF_MS_HEAD.pack(words.level, len(comps))
                    + b"".join(_REF_MS_COMPONENT.pack(*c) for c in comps))
        fields = {ReferenceKind.CONSTANT: (words.level,), ReferenceKind.STEP: (words.before, words.level, words.start),
                  ReferenceKind.TRAPEZOID: (words.level, words.start, words.ramp, words.hold)}[kind]
        return bytes((kind,)) + _REFERENCE_FIXED[kind].pack(*fields)
    except struct.error as exc:
        raise ParameterError(f"REFERENCE field out of range: {exc} (got {words!r})") from None


def _decode_control(payload: bytes) -> Control:
    if len(payload) < _CONTROL_HEAD.size:
        raise FrameError(f"CONTROL payload must be 3 + 4 n bytes, got {len(payload)}")
    controller, preview, n = _CONTROL_HEAD.unpack_from(payload)
    if len(payload) != _CONTROL_HEAD.size + 4 * n:
        raise FrameError(f"CONTROL with n = {n} must be {_CONTROL_HEAD.size + 4 * n} bytes, got {len(payload)}")
    return Control(controller, preview, struct.unpack_from(f"<{n}i", payload, _CONTROL_HEAD.size))


def _decode_reference(payload: bytes) -> ReferenceWords:
    if not payload:
        raise FrameError("REFERENCE payload must hold at least the kind byte, got 0 bytes")
    kind, rest = payload[0], payload[1:]
    if kind == ReferenceKind.MULTISINE:
        n = rest[4] if len(rest) >= _REF_MS_HEAD.size else -1
        if not 1 <= n <= MAX_COMPONENTS or len(rest) != _REF_MS_HEAD.size + n * _REF_MS_COMPONENT.size:
            raise FrameError(f"REFERENCE multisine must be 5 + 12 n bytes after the kind with n in "
                             f"1...{MAX_COMPONENTS}, got {len(rest)} bytes")
        level, _ = _REF_MS_HEAD.unpack_from(rest)
        comps = tuple(_REF_MS_COMPONENT.unpack_from(rest, _REF_MS_HEAD.size + j * _REF_MS_COMPONENT.size)
                      for j in range(n))
        return ReferenceWords("multisine", level, components=comps)
    st = _REFERENCE_FIXED.get(kind)
    if st is None:
        raise FrameError(f"unknown REFERENCE kind {kind}")
    if len(rest) != st.size:
        raise FrameError(f"REFERENCE kind {kind} must have {st.size} bytes after the kind, got {len(rest)}")
    f = st.unpack(rest)
    if kind == ReferenceKind.CONSTANT:
        return ReferenceWords("constant", f[0])
    if kind == ReferenceKind.STEP:
        return ReferenceWords("step", f[1], f[0], f[2])
    return ReferenceWords("trapezoid", f[0], 0, f[1], f[2], f[3])


def decode_message(msg_type: int, payload: bytes) -> Message:
    """The message of a decoded frame.

    Raises
    ------
    FrameError
        Unknown type, or a payload length the type (or WAVE kind) does not allow.
    """
    entry = _FIXED.get(msg_type)
    if entry is None:
        if msg_type == MsgType.WAVE:
            return _decode_wave(payload)
        if msg_type == MsgType.CONTROL:
            return _decode_control(payload)
        if msg_type == MsgType.REFERENCE:
            return _decode_reference(payload)
        raise FrameError(f"unknown frame type {msg_type:#04x}")
    cls, st = entry
    if len(payload) != st.size:
        raise FrameError(f"{cls.__name__} payload must be {st.size} bytes, got {len(payload)}")
    fields = st.unpack(payload)
    if cls is HelloAck:
        fields = fields[:5] + (fields[5].rstrip(b"\x00").decode("ascii", "replace"),) + fields[6:]
    return cls._make(fields)


def _decode_wave(payload: bytes) -> Wave:
    if not payload:
        raise FrameError("WAVE payload must hold at least the kind byte, got 0 bytes")
    kind, rest = payload[0], payload[1:]
    if kind == WaveKind.MULTISINE:
        if len(rest) < _MS_HEAD.size:
            raise FrameError(f"WAVE multisine payload must be 3 + 10 n bytes after the kind, got {len(rest)}")
        offset, n = _MS_HEAD.unpack_from(rest)
        if not 1 <= n <= MAX_COMPONENTS:
            raise FrameError(f"WAVE multisine n must be in 1...{MAX_COMPONENTS}, got {n}")
        if len(rest) != _MS_HEAD.size + n * _MS_COMPONENT.size:
            raise FrameError(f"WAVE multisine with n = {n} must have {_MS_HEAD.size + n * _MS_COMPONENT.size} "
                             f"bytes after the kind, got {len(rest)}")
        comps = tuple(_MS_COMPONENT.unpack_from(rest, _MS_HEAD.size + j * _MS_COMPONENT.size) for j in range(n))
        return WaveMultisine(offset, comps)
    entry = _WAVE_FIXED.get(kind)
    if entry is None:
        raise FrameError(f"unknown WAVE kind {kind}")
    cls, st = entry
    if len(rest) != st.size:
        raise FrameError(f"WAVE {cls.__name__} must have {st.size} bytes after the kind, got {len(rest)}")
    fields = st.unpack(rest)
    if kind == WaveKind.PRBS:
        fields = tuple(fields[i] for i in _PRBS_WIRE)   # the permutation is its own inverse
    return cls._make(fields)


class FrameSplitter:
    """Cuts a byte stream at each 0x00 into encoded frames, with bounded memory.

    Bytes beyond :data:`MAX_ENCODED` without a delimiter are discarded up to the next
    0x00 (what a receiver does with an overlong frame, PROTOCOL.md "Framing").
    """

    __slots__ = ("_pending", "_discarding")

    def __init__(self) -> None:
        self._pending = b""
        self._discarding = False

    @property
    def pending_bytes(self) -> int:
        """Bytes held while waiting for their delimiter (at most :data:`MAX_ENCODED`)."""
        return len(self._pending)

    def split(self, data: bytes) -> tuple[list[bytes], bool]:
        """The encoded frames completed by ``data`` (empty ones included), and True when an
        overlong frame began to be discarded (one receive error)."""
        parts = (self._pending + bytes(data)).split(b"\x00")
        tail = parts.pop()
        if self._discarding and parts:
            parts[0] = b""   # the overlong frame ends at this delimiter
            self._discarding = False
        overflow = False
        if self._discarding:
            tail = b""
        elif len(tail) > MAX_ENCODED:
            self._discarding = overflow = True
            tail = b""
        self._pending = tail
        return parts, overflow


class FrameReader:
    """Incremental frame reader: feed it bytes as they arrive, get ``(frame_seq, message)`` pairs.

    Every invalid frame is dropped and counted in :attr:`rx_errors` (never raised),
    and the reader resynchronises at the next 0x00; zero-length frames are
    ignored.  Bytes beyond :data:`MAX_ENCODED` without a delimiter are discarded
    up to the next 0x00 and counted once.  Memory is bounded by ``MAX_ENCODED``
    plus one read.

    Attributes
    ----------
    rx_errors : int
        Invalid frames seen so far.
    last_error : str
        Description of the most recent invalid frame ("" if none).
    """

    __slots__ = ("_splitter", "rx_errors", "last_error")

    def __init__(self) -> None:
        self._splitter = FrameSplitter()
        self.rx_errors = 0
        self.last_error = ""

    @property
    def pending_bytes(self) -> int:
        """Bytes of an unfinished frame held until its delimiter arrives."""
        return self._splitter.pending_bytes

    def feed(self, data: bytes) -> list[tuple[int, Message]]:
        """Consume ``data`` (any length, any split) and return the complete valid frames in it."""
        parts, overflow = self._splitter.split(data)
        out: list[tuple[int, Message]] = []
        append = out.append
        sample_cls = Sample
        unpack = _SAMPLE_STRUCT.unpack_from
        crc = binascii.crc_hqx
        join = b"\x00".join
        for part in parts:
            n = len(part)
            if not n:
                continue
            try:
                if n > MAX_ENCODED:
                    raise FrameError(f"encoded frame must be at most {MAX_ENCODED} bytes, got {n}")
                # COBS, inlined: a frame this short has no 0xFF block (one would run past the
                # end), so every block but the last ends in a zero and the body is their join
                blocks = []
                i = 0
                while i < n:
                    j = i + part[i]
                    blocks.append(part[i + 1:j])
                    i = j
                if i != n:
                    raise FrameError(f"COBS block runs past the end of the {n}-byte frame")
                body = join(blocks)
                if len(body) < _MIN_BODY:
                    raise FrameError(f"frame body must be at least {_MIN_BODY} bytes, got {len(body)}")
                if crc(body[:-2], 0xFFFF) != body[-2] | (body[-1] << 8):
                    raise FrameError("CRC mismatch")
                if body[0] == 0x84 and len(body) == _SAMPLE_BODY:   # fast path for SAMPLE
                    append((body[1], sample_cls._make(unpack(body, 2))))
                else:
                    append((body[1], decode_message(body[0], body[2:-2])))
            except FrameError as exc:
                self.rx_errors += 1
                self.last_error = str(exc)
        if overflow:
            self.rx_errors += 1
            self.last_error = f"more than {MAX_ENCODED} bytes without a delimiter"
        return out


# ---------------------------------------------------------------- versions
def check_version(device_version: int, host_version: int = PROTOCOL_VERSION) -> None:
    """Raise :class:`ProtocolVersionError` naming both versions unless they are equal."""
    if device_version != host_version:
        raise ProtocolVersionError(f"device speaks protocol version {device_version}, this host speaks "
                                   f"version {host_version}; update the firmware or the host so they match")


# ---------------------------------------------------------------- the device's duty arithmetic
def expand(wave: Wave, n_samples: int, duty_limit: int) -> np.ndarray:
    """The duty sequence a device computes from ``wave`` for samples ``0 ... n_samples-1`` (int64).

    Integer arithmetic exactly as ``hardware/PROTOCOL.md`` ("Waveforms") specifies it,
    from the WAVE fields alone, then clamped to ``+-duty_limit``.

    Parameters
    ----------
    wave : WaveConstant, WaveStep, WaveMultisine, WaveChirp, WavePrbs or WaveOddMultisine
        Decoded WAVE parameters.
    n_samples : int
        Number of samples, >= 0.
    duty_limit : int
        Clamp, 0...255.
    """
    n = check_int("n_samples", n_samples, 0, allow_integral_float=False)
    duty_limit = check_int("duty_limit", duty_limit, 0, 255, allow_integral_float=False)
    if isinstance(wave, WaveConstant):
        raw = np.full(n, wave.level, dtype=np.int64)
    elif isinstance(wave, WaveStep):
        raw = np.where(np.arange(n) < wave.step_index, wave.before, wave.after).astype(np.int64)
    elif isinstance(wave, WaveMultisine):
        raw = multisine_duty(wave.components, wave.offset, n)
    elif isinstance(wave, WaveChirp):
        raw = chirp_duty(wave.offset, wave.amplitude, wave.phase0, wave.inc0, wave.inc_step, n)
    elif isinstance(wave, WaveOddMultisine):
        raw = multisine_duty(wave.excitation().components(), wave.offset, n)
    elif isinstance(wave, WavePrbs):
        if wave.order not in PRBS_MASKS:
            raise ParameterError(f"PRBS order must be in 2...16, got {wave.order!r}")
        if not 0 < wave.seed < (1 << wave.order):
            raise ParameterError(f"PRBS seed must be in 1...{(1 << wave.order) - 1}, got {wave.seed!r}")
        if wave.hold < 1:
            raise ParameterError(f"PRBS hold must be >= 1, got {wave.hold!r}")
        bits = prbs_bits(wave.order, wave.seed, -(-n // wave.hold))
        raw = np.where(np.repeat(bits, wave.hold)[:n] == 1, wave.high, wave.low).astype(np.int64)
    else:
        raise ParameterTypeError(f"wave must be a WAVE message (WaveConstant, ..., WaveOddMultisine), "
                                 f"got {type(wave).__name__}")
    return np.clip(raw, -duty_limit, duty_limit).astype(np.int64)


def wave_for(experiment: Experiment) -> Wave:
    """The WAVE that makes a device generate ``experiment``'s duty sequence.

    Raises
    ------
    ValueError
        The excitation is of a kind the protocol cannot carry.
    """
    if not isinstance(experiment, Experiment):
        raise ParameterTypeError(f"experiment must be an Experiment, got {type(experiment).__name__}")
    ex, dt, n = experiment.excitation, experiment.sample_period, experiment.n_samples
    if isinstance(ex, Constant):
        return WaveConstant(ex.level)
    if isinstance(ex, Step):
        return WaveStep(ex.before, ex.after, ex.step_index(dt))
    if isinstance(ex, Multisine):
        return WaveMultisine(ex.offset, tuple(ex.components(dt)))
    if isinstance(ex, Chirp):
        inc0, step = ex.words(n, dt)
        return WaveChirp(ex.offset, ex.amplitude, 0, inc0, step)
    if isinstance(ex, PRBS):
        return WavePrbs(ex.high, ex.low, ex.order, ex.hold, ex.seed)
    if isinstance(ex, OddMultisine):
        return WaveOddMultisine(ex.offset, ex.amplitude, ex.period.bit_length() - 1, ex.max_harmonic, ex.seed,
                                ex.group)
    raise ParameterError(f"excitation must be one the device can generate (constant, step, sine, multisine, "
                     f"chirp, prbs, odd-multisine), got {type(ex).__name__}")


def control_for(experiment: ClosedLoopExperiment) -> Control:
    """The CONTROL that makes a device run ``experiment``'s controller (its gains in wire order)."""
    if not isinstance(experiment, ClosedLoopExperiment):
        raise ParameterTypeError(f"experiment must be a ClosedLoopExperiment, got {type(experiment).__name__}")
    c = experiment.controller
    kinds = {name: kind for kind, name in _KIND_NAMES.items()}
    gains = c.gains()
    return Control(kinds[c.kind], c.preview, tuple(gains.values()))


def reference_for(experiment: ClosedLoopExperiment) -> ReferenceWords:
    """The REFERENCE of ``experiment``: its reference's integer words in the controller's unit."""
    if not isinstance(experiment, ClosedLoopExperiment):
        raise ParameterTypeError(f"experiment must be a ClosedLoopExperiment, got {type(experiment).__name__}")
    c = experiment.controller
    return experiment.reference.words(experiment.sample_period, c.reference_scale)


def control_problems(msg: Control) -> list[str]:
    """Problems a device would NAK with BAD_VALUE in a CONTROL (unknown controller, gain count, preview)."""
    if msg.controller == ControllerKind.NONE:
        return [] if not msg.gains else [f"controller 0 (none) takes no gains, got {len(msg.gains)}"]
    if msg.controller not in _KIND_NAMES:
        return [f"controller must be in 0...{max(_KIND_NAMES)}, got {msg.controller}"]
    bad = []
    try:
        gains_from_wire(_KIND_NAMES[ControllerKind(msg.controller)], msg.gains)
    except ValueError as exc:
        bad.append(str(exc))
    if msg.preview > MAX_GAINS:
        bad.append(f"preview must be <= {MAX_GAINS} samples, got {msg.preview}")
    return bad


def reference_problems(words: ReferenceWords) -> list[str]:
    """Problems a device would NAK with BAD_VALUE in a REFERENCE (values beyond +-65535, ramp 0)."""
    values = [words.level, words.before] + [c[0] for c in words.components]
    bad = [f"reference values must satisfy |x| <= {MAX_REFERENCE}, got {x}" for x in values if abs(x) > MAX_REFERENCE]
    if sum(abs(c[0]) for c in words.components) > MAX_REFERENCE:
        bad.append(f"reference amplitudes must sum to at most {MAX_REFERENCE}")
    if words.kind == "trapezoid" and words.ramp < 1:
        bad.append(f"ramp must be >= 1 sample, got {words.ramp}")
    return bad


def controller_name(kind: int) -> str:
    """The :data:`motorsim.control.CONTROLLERS` name of CONTROL ``controller`` ``kind`` (1...7)."""
    return _KIND_NAMES[ControllerKind(kind)]


def config_for(experiment: Experiment | ClosedLoopExperiment, *, decoding: int = 4,
               watchdog_ms: int = 500) -> Config:
    """The CONFIG of ``experiment`` (sample period rounded to whole µs, which must be exact to 1 ns).

    Parameters
    ----------
    experiment : Experiment
        What to run.
    decoding : {1, 2, 4}
        Quadrature decoding of the encoder.
    watchdog_ms : int
        Host-silence watchdog in ms; 0 disables it, else 50...60 000.
    """
    if not isinstance(experiment, (Experiment, ClosedLoopExperiment)):
        raise ParameterTypeError(f"experiment must be an Experiment, got {type(experiment).__name__}")
    period_us = round(experiment.sample_period * 1e6)
    if abs(period_us * 1e-6 - experiment.sample_period) > 1e-9 or not 100 <= period_us <= 1_000_000:
        raise ParameterError(f"sample_period must be a whole number of microseconds in 100...1 000 000 µs "
                         f"for the bench, got {experiment.sample_period!r} s")
    if decoding not in (1, 2, 4):
        raise ParameterError(f"decoding must be 1, 2 or 4, got {decoding!r}")
    if not (watchdog_ms == 0 or 50 <= watchdog_ms <= 60_000):
        raise ParameterError(f"watchdog_ms must be 0 (off) or in 50...60 000 ms, got {watchdog_ms!r}")
    if experiment.n_samples > 0xFFFFFFFF:
        raise ParameterError(f"duration gives {experiment.n_samples} samples, more than a u32 holds")
    return Config(period_us, experiment.n_samples, experiment.duty_limit, decoding, watchdog_ms)


def wave_range_problems(wave: Wave) -> list[str]:
    """Problems a device would NAK with BAD_VALUE (amplitudes beyond +-1023, bad PRBS fields).

    Returns
    -------
    list of str
        One message per problem; empty when the device accepts ``wave``.
    """
    bad: list[str] = []

    def amp(name: str, x: int) -> None:
        if abs(x) > MAX_AMPLITUDE:
            bad.append(f"{name} must satisfy |x| <= {MAX_AMPLITUDE}, got {x}")
    if isinstance(wave, WaveConstant):
        amp("level", wave.level)
    elif isinstance(wave, WaveStep):
        amp("before", wave.before)
        amp("after", wave.after)
    elif isinstance(wave, WaveMultisine):
        amp("offset", wave.offset)
        for a, _, _ in wave.components:
            amp("amplitude", a)
    elif isinstance(wave, WaveChirp):
        amp("offset", wave.offset)
        amp("amplitude", wave.amplitude)
    elif isinstance(wave, WavePrbs):
        amp("low", wave.low)
        amp("high", wave.high)
        if wave.order not in PRBS_MASKS:
            bad.append(f"order must be in 2...16, got {wave.order}")
        elif not 0 < wave.seed < (1 << wave.order):
            bad.append(f"seed must be in 1...2**order - 1, got {wave.seed}")
        if wave.hold < 1:
            bad.append(f"hold must be >= 1, got {wave.hold}")
    elif isinstance(wave, WaveOddMultisine):
        try:
            wave.excitation()
        except ValueError as exc:
            bad.append(str(exc))
    return bad

