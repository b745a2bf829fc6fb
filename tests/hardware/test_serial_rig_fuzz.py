"""Fuzzing SerialRig end to end: whatever bytes the device sends, the host returns true rows or a typed error."""
from __future__ import annotations

import time

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware import protocol as P
from hardware.errors import ProtocolError, RigError
from hardware.serial_rig import SerialRig
from motorsim import Experiment, Motor, SimRig, Sine

EXPERIMENT = Experiment(Sine(25.0), 0.005, 0.3)     # 60 samples
CLEAN = SimRig(Motor(25.0, 3.0)).run(EXPERIMENT)


def _device_stream() -> bytes:
    """What a correct device sends to a host whose frames have frame_seq 0 (HELLO), 1 (CONFIG), 2 (WAVE), 3 (START)."""
    msgs = [P.Boot(P.PROTOCOL_VERSION, 1), P.HelloAck(P.PROTOCOL_VERSION, 0x0100, 16_000_000, 1, 60, "script"),
            P.Ack(P.MsgType.CONFIG, 1),
            P.Ack(P.MsgType.WAVE, 2), P.Ack(P.MsgType.START, 3)]
    msgs += [P.Sample(k, (1000 + 5000 * k) & 0xFFFFFFFF, int(c), int(u), 0)
             for k, (c, u) in enumerate(zip(CLEAN.counts, CLEAN.duty))]
    msgs.append(P.End(0, len(CLEAN), 0, 0, 0, 0))
    return b"".join(P.encode_message(m, i & 0xFF) for i, m in enumerate(msgs))


STREAM = _device_stream()


class _ScriptedPort:
    """Replays bytes in given read sizes; when they run out, reads time out (return b"") like pyserial."""

    name = "scripted"
    in_waiting = 0

    def __init__(self, data: bytes, sizes: list[int]):
        self._data, self._sizes, self._pos, self._i = data, sizes, 0, 0
        self.written = bytearray()

    def read(self, size=1):
        if self._pos >= len(self._data):
            time.sleep(0.002)
            return b""
        n = self._sizes[self._i % len(self._sizes)]
        self._i += 1
        out = self._data[self._pos:self._pos + n]
        self._pos += n
        return out

    def write(self, data):
        self.written += data
        return len(data)


def _mutate(data: bytes, edits) -> bytes:
    buf = bytearray(data)
    for kind, where, value in edits:
        i = where % (len(buf) + 1)
        if kind == "set" and i < len(buf):
            buf[i] = value
        elif kind == "insert":
            buf[i:i] = bytes([value])
        elif kind == "delete" and i < len(buf):
            del buf[i]
    return bytes(buf)


_edits = st.lists(st.tuples(st.sampled_from(["set", "insert", "delete"]), st.integers(0, 10_000),
                            st.integers(0, 255)), max_size=12)


def _check_rows(rec):
    if rec is None:
        return
    k = rec.seq
    assert np.array_equal(rec.duty, CLEAN.duty[k]) and np.array_equal(rec.counts, CLEAN.counts[k])


def test_the_unmutated_script_is_a_clean_run():
    port = _ScriptedPort(STREAM, [64])
    rec = SerialRig(port, timeout=0.05).run(EXPERIMENT)
    assert len(rec) == len(CLEAN) and not rec.has_gaps
    _check_rows(rec)


@settings(max_examples=80, deadline=None)
@given(_edits, st.lists(st.integers(1, 80), min_size=1, max_size=8))
def test_fuzz_any_corruption_gives_true_rows_or_a_typed_error(edits, sizes):
    port = _ScriptedPort(_mutate(STREAM, edits), sizes)
    rig = SerialRig(port, timeout=0.05, hello_timeout=0.1, command_timeout=0.03)
    completed = False
    try:
        rec = rig.run(EXPERIMENT)
        completed = True
    except (RigError, ProtocolError) as exc:     # the only errors allowed
        _check_rows(getattr(exc, "recording", None))
    else:
        _check_rows(rec)
        assert rec.metadata["complete"] == "true"
    sent = [m for _, m in P.FrameReader().feed(bytes(port.written))]
    assert sent[0] == P.Hello(P.PROTOCOL_VERSION)
    # once START has gone out, a run that did not complete ends with the host sending STOP
    if P.Start() in sent and not completed:
        assert sent[-1] == P.Stop()
