"""A port on an emulated device that runs in simulated time, in lock-step with the host.

``fake://`` and ``avr-sim://`` run their device in simulated time by default: the device's
clock moves only while the host reads (:meth:`LockstepPort.read`), by at most the read's
timeout, and stops at the end of the first frame the device sends.  What the host writes
reaches the device at the simulated instant it was written.  A run therefore gives the same
recording whatever the machine's load: a slow host, or a slow emulator, only makes it take
longer on the wall clock.  ``speed`` paces the simulated clock against the wall clock
(1: no faster than real time, as a board; 0: as fast as the machine goes).

A host that keeps time itself reads the port's :meth:`~LockstepPort.clock` (``SerialRig`` and
``DeviceLink`` do): its timeouts, HEARTBEATs and deadlines then count simulated seconds, so
the device's host-silence watchdog sees the host exactly as a board would see a host that
keeps up.  The real-time mode of both schemes (``realtime=1``) keeps the device on the wall
clock instead (``hardware/ports.py``).
"""
from __future__ import annotations

import math
import threading
import time

import serial

from motorsim.checks import check_real

__all__ = ["LockstepPort", "POLL_QUANTUM"]

#: Simulated seconds a read with a zero timeout lets pass (so that polling still moves time).
POLL_QUANTUM = 0.001


class LockstepPort:
    """A pyserial-compatible port whose device runs in simulated time, advanced as it is read.

    Subclasses provide :meth:`_exchange`, which delivers the host's bytes (:meth:`_take_written`)
    to the device at the current simulated time, lets the device run to ``until`` (or to the end
    of its first frame), appends what the device sent to ``self._rx`` as it arrives (so that an
    exchange cut short by Ctrl-C loses nothing) and returns the simulated time reached.

    Parameters
    ----------
    name : str
        The port's name (its URL).
    timeout : float or None
        Read timeout in simulated seconds (``None``: a read waits for its bytes however long).
    speed : float
        Largest ratio of simulated to wall-clock time (0: no pacing).
    """

    def __init__(self, name: str, timeout: float | None, speed: float):
        if timeout is not None:
            check_real("timeout", timeout, nonnegative=True)
        self.name = name
        self.timeout = timeout
        self.speed = check_real("speed", speed, nonnegative=True)
        self.is_open = True
        self._now = 0.0
        self._rx = bytearray()
        self._tx = bytearray()
        self._wall0 = time.monotonic()
        self._lock = threading.RLock()

    # ------------------------------------------------------------ what a subclass provides
    def _exchange(self, until: float, stop_on_frame: bool) -> float:
        """Deliver what was written, run the device to ``until`` s; its bytes go to ``self._rx``; the time reached."""
        raise NotImplementedError

    def _take_written(self) -> bytes:
        """What the host wrote since the last exchange (taken: it is delivered now)."""
        data = bytes(self._tx)
        del self._tx[:len(data)]
        return data

    def _close(self) -> None:
        """Release the device (called once by :meth:`close`)."""

    # ------------------------------------------------------------ the port
    def clock(self) -> float:
        """The device's simulated time in s since the port opened; it moves only in :meth:`read` and :meth:`wait`."""
        return self._now

    @property
    def in_waiting(self) -> int:
        """Bytes the device has sent that were not read yet."""
        return len(self._rx)

    def write(self, data) -> int:
        """Queue ``data``; it reaches the device at the current simulated time, before time moves on."""
        self._check_open()
        with self._lock:
            self._tx += bytes(data)
        return len(data)

    def flush(self) -> None:
        """Deliver what was written now (simulated time does not move)."""
        self._check_open()
        with self._lock:
            if self._tx:
                self._advance(self._now, stop_on_frame=False)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes: what has arrived, or what the device sends within ``timeout`` simulated s."""
        self._check_open()
        with self._lock:
            timeout = math.inf if self.timeout is None else max(self.timeout, POLL_QUANTUM)
            deadline = self._now + timeout
            while len(self._rx) < size and self._now < deadline:
                self._advance(deadline, stop_on_frame=True)
            out = bytes(self._rx[:size])
            del self._rx[:size]
            return out

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` of simulated time pass (``time.sleep`` on a real port); output is kept for reading."""
        check_real("seconds", seconds, nonnegative=True)
        self._check_open()
        with self._lock:
            until = self._now + seconds
            while self._now < until:
                self._advance(until, stop_on_frame=False)

    def reset_input_buffer(self) -> None:
        """Discard what arrived and was not read."""
        with self._lock:
            self._rx.clear()

    def reset_output_buffer(self) -> None:
        """Discard what was written and not delivered yet."""
        with self._lock:
            self._tx.clear()

    def close(self) -> None:
        """Close the port and release the device; idempotent."""
        with self._lock:
            if self.is_open:
                self.is_open = False
                self._close()

    def __enter__(self) -> "LockstepPort":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ internals
    def _check_open(self) -> None:
        if not self.is_open:
            raise serial.PortNotOpenError()

    def _advance(self, until: float, *, stop_on_frame: bool) -> None:
        had = len(self._rx)
        now = self._exchange(until, stop_on_frame)
        if now < self._now or (now == self._now and len(self._rx) == had and until > self._now):
            raise serial.SerialException(f"the emulated device on {self.name} did not advance "
                                         f"(simulated time {now!r} s, asked for {until!r} s)")
        self._now = now
        if self.speed > 0:
            ahead = self._now / self.speed - (time.monotonic() - self._wall0)
            if ahead > 0:
                time.sleep(ahead)
