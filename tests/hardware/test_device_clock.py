"""A device's clock is data too: its u32 microseconds wrap forward every 71.6 minutes, and a sample whose time
does not advance contradicts the order of the samples.

Before: a step back of 2 ms was unwrapped as a wrap, 4295 s later, and the recording written was refused by
its own reader ("time step 4294.97 s is 8.59e+05 sample periods"); a clock that stopped gave "time must be
strictly increasing ... at sample 31" with nothing of the device in it.
"""
from __future__ import annotations

import numpy as np
import pytest

from hardware import protocol as P
from hardware.errors import RigCheckError
from hardware.serial_rig import SerialRig
from tests.hardware.test_device_values import CLEAN, EXPERIMENT, _Port


def _stream(time_us) -> bytes:
    msgs = [P.Boot(P.PROTOCOL_VERSION, 1), P.HelloAck(P.PROTOCOL_VERSION, 0x0100, 16_000_000, 1, 60, "script"),
            P.Ack(P.MsgType.CONFIG, 1), P.Ack(P.MsgType.WAVE, 2), P.Ack(P.MsgType.START, 3)]
    msgs += [P.Sample(k, int(t) % 2**32, int(c), int(u), 0)
             for k, (t, c, u) in enumerate(zip(time_us, CLEAN.counts, CLEAN.duty))]
    msgs.append(P.End(0, len(CLEAN), 0, 0, 0, 0))
    return b"".join(P.encode_message(m, i & 0xFF) for i, m in enumerate(msgs))


def test_the_devices_clock_wrapping_mid_run_is_read_forward():
    start = 2**32 - 5000 * 20                            # wraps at sample 20
    rec = SerialRig(_Port(_stream(start + 5000 * np.arange(len(CLEAN)))), timeout=0.05).run(EXPERIMENT)
    np.testing.assert_allclose(np.diff(rec.time), 0.005, rtol=1e-9)
    assert np.array_equal(rec.counts, CLEAN.counts)


@pytest.mark.parametrize("shift, first, n_out", [
    (lambda k: np.where(k == 30, -7000, 0), "sample 30 at 144000 us after sample 29 at 146000 us", 1),   # back 2 ms
    (lambda k: np.where(k > 30, 5000 * (30 - k), 0), "sample 31 at 151000 us after sample 30 at 151000 us", 29),
])
def test_a_sample_whose_device_time_does_not_advance_is_kept_out_and_said(shift, first, n_out):
    k = np.arange(len(CLEAN))
    with pytest.raises(RigCheckError) as caught:
        SerialRig(_Port(_stream(1000 + 5000 * k + shift(k))), timeout=0.05).run(EXPERIMENT)
    text = str(caught.value)
    assert f"{n_out} samples carry a device time that does not advance (first: {first})" in text
    assert "link sequence" not in text                  # not also called lost on the link
    rec = caught.value.recording                        # what arrived in order is kept, its clock increasing
    assert len(rec) == len(CLEAN) - n_out and np.all(np.diff(rec.time) > 0)
