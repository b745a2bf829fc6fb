"""hardware: the real bench (serial protocol, SerialRig, emulated device, firmware).

``protocol`` is the executable form of ``hardware/PROTOCOL.md``; ``SerialRig``
runs an :class:`~motorsim.rig.Experiment` on a device over any pyserial port or
URL; ``fake_device`` is an emulated Arduino (``fake://?a=25&b=3``), run like ``avr-sim://`` in
simulated time, in lock-step with the host (``lockstep``).
"""
from .errors import (
                     DeviceFaultError,
                     DeviceRefusedError,
                     FrameError,
                     ProtocolError,
                     ProtocolVersionError,
                     RigCheckError,
                     RigDisconnectedError,
                     RigError,
                     RigTimeoutError,
)
from .fake_device import FakeDevice, FaultPlan
from .ports import open_port
from .protocol import PROTOCOL_VERSION, expand
from .serial_rig import RecordedSample, SerialRig

__all__ = ["SerialRig", "RecordedSample", "FakeDevice", "FaultPlan", "open_port", "PROTOCOL_VERSION", "expand",
           "ProtocolError", "FrameError", "ProtocolVersionError", "RigError", "RigTimeoutError",
           "RigDisconnectedError", "DeviceRefusedError", "DeviceFaultError", "RigCheckError"]
