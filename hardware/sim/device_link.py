"""Drive a bench device frame by frame, below ``SerialRig`` (tests and benchmarks).

The byte-level tests (corrupted frames, overload, the encoder ceiling) need to send exactly
the frames they want and see every frame that comes back, which ``SerialRig`` rightly hides.
"""
from __future__ import annotations

import dataclasses
import time

import serial

from hardware import protocol as P

__all__ = ["DeviceLink", "RunResult"]


@dataclasses.dataclass
class RunResult:
    """Every frame of one run, split by kind.

    Attributes
    ----------
    samples : list of Sample
        SAMPLE frames in arrival order.
    faults : list of Fault
        FAULT frames.
    end : End or None
        The END frame (None if the run timed out).
    others : list
        Every other message (ACK, NAK, ...).
    frame_seqs : list of int
        Link frame counter of every frame received, in order.
    """

    samples: list
    faults: list
    end: "P.End | None"
    others: list
    frame_seqs: list


class DeviceLink:
    """Send messages to a device on an open port and collect what it sends back.

    Parameters
    ----------
    port : serial.Serial
        An open port (``timeout`` short, e.g. 0.02 s: reads poll).  When it keeps simulated time
        (a ``clock()``, :mod:`hardware.lockstep`), every timeout and heartbeat here counts the
        device's simulated seconds; else wall-clock seconds.
    """

    def __init__(self, port: serial.Serial):
        self.port = port
        clock = getattr(port, "clock", None)
        self.clock = clock if callable(clock) else time.monotonic
        self.reader = P.FrameReader()
        self.frame_seq = 0
        self.received: list = []   # (frame_seq, message) in arrival order

    def send(self, msg) -> int:
        """Send ``msg`` with the next frame_seq; returns that number."""
        frame_seq = self.frame_seq
        self.port.write(P.encode_message(msg, frame_seq))
        self.frame_seq = (frame_seq + 1) & 0xFF
        return frame_seq

    def send_raw(self, data: bytes) -> None:
        """Write ``data`` as is (a corrupted frame, a lone delimiter, ...)."""
        self.port.write(data)

    def poll(self) -> list:
        """Read what is waiting and return the new ``(frame_seq, message)`` pairs."""
        new = self.reader.feed(self.port.read(max(1, self.port.in_waiting)))
        self.received += new
        return new

    def wait_for(self, kind, timeout: float = 3.0, heartbeat: float | None = None):
        """The first new message of type ``kind`` within ``timeout`` s (the port's time), else None.

        Sends a HEARTBEAT every ``heartbeat`` s meanwhile (None: none).
        """
        deadline = self.clock() + timeout
        last_beat = 0.0
        while self.clock() < deadline:
            if heartbeat and self.clock() - last_beat > heartbeat:
                self.send(P.Heartbeat())
                last_beat = self.clock()
            for _, msg in self.poll():
                if isinstance(msg, kind):
                    return msg
        return None

    def hello(self, timeout: float = 3.0):
        """HELLO every 0.2 s until HELLO_ACK (as a host does), for at most ``timeout`` s.

        Every HELLO sent is answered: the answers to the extra ones are awaited (0.5 s at most)
        and consumed here, so that none is mistaken later for the answer to something else.
        """
        deadline = self.clock() + timeout
        sent = 0
        while self.clock() < deadline:
            self.send(P.Hello())
            sent += 1
            ack = self.wait_for(P.HelloAck, timeout=0.2)
            if ack is not None:
                for _ in range(sent - 1):
                    self.wait_for(P.HelloAck, timeout=0.5)
                return ack
        raise TimeoutError("no HELLO_ACK")

    def command(self, msg, timeout: float = 2.0):
        """Send ``msg`` and return its ACK or NAK (within ``timeout`` s, else TimeoutError)."""
        frame_seq = self.send(msg)
        deadline = self.clock() + timeout
        while self.clock() < deadline:
            for _, reply in self.poll():
                if isinstance(reply, (P.Ack, P.Nak)) and reply[1] == frame_seq:
                    return reply
        raise TimeoutError(f"no ACK/NAK for {msg!r}")

    def run(self, config, wave, *, timeout: float = 20.0, heartbeat: float | None = 0.05,
            on_sample=None, setup=()) -> RunResult:
        """CONFIG, WAVE, the ``setup`` messages, START, then collect until END.

        Parameters
        ----------
        config : Config
            The CONFIG message.
        wave : Wave
            The WAVE message.
        setup : sequence of messages
            Sent (and acknowledged) after the WAVE: CONTROL and REFERENCE for a closed loop.
        timeout : float
            Seconds (the port's time) to wait for END.
        heartbeat : float or None
            Seconds between HEARTBEATs (None sends none, to test the device's watchdog).
        on_sample : callable, optional
            ``on_sample(link, sample)`` for each SAMPLE as it arrives (e.g. to send STOP).
        """
        start = len(self.received)
        for msg in (config, wave, *setup, P.Start()):
            reply = self.command(msg)
            if not isinstance(reply, P.Ack):
                raise RuntimeError(f"{msg!r} refused: {reply!r}")
        deadline = self.clock() + timeout
        last_beat = self.clock()
        end = None
        while end is None and self.clock() < deadline:
            if heartbeat and self.clock() - last_beat > heartbeat:
                self.send(P.Heartbeat())
                last_beat = self.clock()
            for _, msg in self.poll():
                if isinstance(msg, P.End):
                    end = msg
                elif isinstance(msg, P.Sample) and on_sample is not None:
                    on_sample(self, msg)
        got = self.received[start:]
        return RunResult(samples=[m for _, m in got if isinstance(m, P.Sample)],
                         faults=[m for _, m in got if isinstance(m, P.Fault)], end=end,
                         others=[m for _, m in got if not isinstance(m, (P.Sample, P.Fault, P.End))],
                         frame_seqs=[s for s, _ in got])
