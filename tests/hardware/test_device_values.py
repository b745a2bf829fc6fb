"""What a device says is data: a wrapping encoder counter, a fault code this version does not know, a board
name holding control characters.  Each ends in a right recording that says what happened, or a typed error.

The device is a script of the frames a device sends (the host's frame_seq 0 HELLO, 1 CONFIG, 2 WAVE, 3 START).
"""
from __future__ import annotations

import time

import numpy as np
import pytest

from hardware import protocol as P
from hardware.errors import RigCheckError
from hardware.serial_rig import SerialRig
from motorsim import Experiment, Motor, SimRig, Sine, read_recording, write_recording

EXPERIMENT = Experiment(Sine(25.0), 0.005, 0.3)     # 60 samples
CLEAN = SimRig(Motor(25.0, 3.0)).run(EXPERIMENT)


class _Port:
    """Replays the bytes of a script in 64-byte reads; then reads time out (b""), as pyserial's do."""

    name = "scripted"
    in_waiting = 0

    def __init__(self, data: bytes):
        self._data, self._pos = data, 0

    def read(self, size=1):
        if self._pos >= len(self._data):
            time.sleep(0.002)
            return b""
        out = self._data[self._pos:self._pos + 64]
        self._pos += 64
        return out

    def write(self, data):
        return len(data)


def _stream(counts, *, board="script", fault=None) -> bytes:
    msgs = [P.Boot(P.PROTOCOL_VERSION, 1), P.HelloAck(P.PROTOCOL_VERSION, 0x0100, 16_000_000, 1, 60, board),
            P.Ack(P.MsgType.CONFIG, 1), P.Ack(P.MsgType.WAVE, 2), P.Ack(P.MsgType.START, 3)]
    msgs += [P.Sample(k, 1000 + 5000 * k, int(c), int(u), 0) for k, (c, u) in enumerate(zip(counts, CLEAN.duty))]
    if fault is not None:
        msgs.append(P.Fault(fault, 30))
    msgs.append(P.End(0, len(CLEAN), 0, 0, 0, 0))
    return b"".join(P.encode_message(m, i & 0xFF) for i, m in enumerate(msgs))


def _int32(x):
    return (np.asarray(x, dtype=np.int64) + 2**31) % 2**32 - 2**31


def test_an_int32_counter_wrapping_mid_run_is_unwrapped_and_said():
    # the device's absolute count starts 100 counts below int32's top and runs on through it
    start = 2**31 - 1 - 100 - int(CLEAN.counts[:30].max())
    true = CLEAN.counts + start
    wire = _int32(true)
    wraps = int((np.abs(np.diff(wire)) > 2**31).sum())
    assert wraps >= 1                                 # the wire really wraps (the sine goes through and back)
    with pytest.warns(UserWarning, match=rf"32-bit encoder counter wrapped {wraps} time"):
        rec = SerialRig(_Port(_stream(wire)), timeout=0.05).run(EXPERIMENT)
    assert np.array_equal(rec.counts, true)           # before: a jump of -2**32 counts, a negative b
    assert rec.metadata["counter_wraps"] == str(wraps)


def test_an_unknown_fault_code_is_refused_naming_it_and_the_samples_kept():
    with pytest.raises(RigCheckError, match=r"FAULT code 77 \(not a fault code this version of motorid knows: "
                                            r"1 HOST_SILENCE") as err:
        SerialRig(_Port(_stream(CLEAN.counts, fault=77)), timeout=0.05).run(EXPERIMENT)
    # before: the run was returned complete, the fault only in the metadata
    assert err.value.recording is not None and len(err.value.recording) == len(CLEAN)


def test_a_known_fault_that_lets_the_run_complete_keeps_the_run():
    rec = SerialRig(_Port(_stream(CLEAN.counts, fault=int(P.FaultCode.QUEUE_OVERFLOW))), timeout=0.05).run(EXPERIMENT)
    assert rec.metadata["device_fault_code"] == str(int(P.FaultCode.QUEUE_OVERFLOW)) and len(rec) == len(CLEAN)


@pytest.mark.parametrize("board", ["ab\rcd", "ab\x00cd", "a\nb", "\x1b[2Jx"])
def test_a_board_name_with_control_characters_gives_a_recording_that_reads_back(board, tmp_path):
    rec = SerialRig(_Port(_stream(CLEAN.counts, board=board)), timeout=0.05).run(EXPERIMENT)
    path = write_recording(rec, tmp_path / "run.csv")
    back = read_recording(path)                       # before: "no header row" or a cut line, the file lost
    assert np.array_equal(back.counts, CLEAN.counts)
    assert "\\" in back.metadata["board"] and not any(c in back.metadata["board"] for c in "\r\n\x00\x1b")
