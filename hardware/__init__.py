"""hardware: the real bench (serial protocol, SerialRig, emulated device, firmware)."""
