"""The bench's exceptions; each subclasses the built-in a caller would expect.

``ProtocolError`` and its children are about bytes and messages (``ValueError``:
the data was wrong).  The ``Rig*`` errors are about the run: the device went
silent (``TimeoutError``), the port went away (``ConnectionError``), or the
device refused or contradicted the host (``RuntimeError``).  Every ``RigError``
carries the samples received before it happened as ``recording`` (a
:class:`~motorsim.recording.Recording`, or None when no sample had arrived), so
nothing received is lost with the exception.
"""
from __future__ import annotations

__all__ = ["ProtocolError", "FrameError", "ProtocolVersionError", "RigError", "RigTimeoutError",
           "RigDisconnectedError", "DeviceRefusedError", "DeviceFaultError", "RigCheckError"]


class ProtocolError(ValueError):
    """Bytes or a message that break ``hardware/PROTOCOL.md``."""


class FrameError(ProtocolError):
    """One frame that cannot be decoded: bad COBS, too short or long, bad CRC, unknown type, bad length."""


class ProtocolVersionError(ProtocolError):
    """The device speaks another protocol version than the host."""


class RigError(Exception):
    """Base of the run-time errors of a rig; ``recording`` holds what was received (or None)."""

    recording = None

    def with_recording(self, recording):
        """Attach the partial recording and return ``self`` (for ``raise err.with_recording(rec)``)."""
        self.recording = recording
        return self


class RigTimeoutError(RigError, TimeoutError):
    """The device did not answer, or went silent during a run."""


class RigDisconnectedError(RigError, ConnectionError):
    """The serial port disappeared or failed during I/O."""


class DeviceRefusedError(RigError, RuntimeError):
    """The device NAKed a command (the reason is named in the message)."""


class DeviceFaultError(RigError, RuntimeError):
    """The device stopped the run itself (host-silence watchdog or a device fault)."""


class RigCheckError(RigError, RuntimeError):
    """What the host received contradicts the device (END counters, duty sequence)."""
