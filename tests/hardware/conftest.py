"""What the tests of the emulated firmware share: the firmware and its harness, built once per module."""
import pytest

from hardware.sim.launcher import build, missing_tools


@pytest.fixture(scope="module")
def built():
    """Firmware and harness built once (``make firmware avr-sim``); skipped without the AVR toolchain."""
    missing = missing_tools()
    if missing:
        pytest.skip(f"the AVR toolchain is missing: {', '.join(missing)} (make firmware-deps installs it)")
    return build()
