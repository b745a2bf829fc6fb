"""The firmware's sources against the host's: the sine table, the pin map, the launcher's URL."""
from __future__ import annotations

import re

import numpy as np
import pytest

from hardware.sim import launcher
from motorsim.excitation import PRBS_MASKS, sine_table

FIRMWARE = launcher.REPO_ROOT / "hardware" / "firmware"
SKETCH = FIRMWARE / "motorid_bench" / "motorid_bench.ino"


def _c_array(text: str, name: str) -> list[int]:
    body = re.search(name + r"\[[^\]]*\]\s*PROGMEM\s*=\s*\{([^}]*)\}", text).group(1)
    return [int(x, 0) for x in re.findall(r"-?(?:0x[0-9A-Fa-f]+|\d+)", body)]


def test_firmware_sine_table_equals_the_hosts():
    from hardware.firmware.gen_sine_table import HEADER_PATH, render_sine_table

    header = HEADER_PATH.read_text()
    assert header == render_sine_table(), "regenerate with python hardware/firmware/gen_sine_table.py"
    np.testing.assert_array_equal(_c_array(header, "SINE_TABLE"), sine_table())


def test_firmware_prbs_masks_equal_the_hosts():
    masks = _c_array(SKETCH.read_text(), "PRBS_MASK")
    assert masks[:2] == [0, 0]
    assert {order: masks[order] for order in range(2, 17)} == PRBS_MASKS


def test_harness_pins_match_the_firmware_defaults():
    config = (FIRMWARE / "motorid_bench" / "config.h").read_text()
    harness = (launcher.REPO_ROOT / "hardware" / "sim" / "motorid_avr_sim.c").read_text()
    pins = dict(re.findall(r"#define (PIN_\w+) (\d+)", config))
    assert pins == {"PIN_PWM": "11", "PIN_DIR": "8", "PIN_IN1": "8", "PIN_IN2": "9",
                    "PIN_ENC_A": "2", "PIN_ENC_B": "3"}
    # The harness reads OCR2A (pin 11 = PB3), DIR/IN1 on PB0, IN2 on PB1, drives PD2/PD3.
    for line in ("#define PWM_BIT 3", "#define DIR_BIT 0", "#define IN2_BIT 1",
                 "#define ENC_A_PIN 2", "#define ENC_B_PIN 3"):
        assert line in harness


def test_avr_sim_url_reads_the_motor_and_rejects_unknown_keys():
    opts = launcher.parse_avr_sim_url("avr-sim://?a=30&b=2.5&friction=0.4&counts_per_rev=2000&speed=0")
    assert (opts.a, opts.b, opts.friction, opts.counts_per_rev, opts.speed) == (30, 2.5, 0.4, 2000, 0)
    assert launcher.parse_avr_sim_url("avr-sim://") == launcher.HarnessOptions()
    with pytest.raises(ValueError, match="'ppr'"):
        launcher.parse_avr_sim_url("avr-sim://?ppr=100")
    with pytest.raises(ValueError, match="a must be > 0"):
        launcher.parse_avr_sim_url("avr-sim://?a=-1")
    with pytest.raises(ValueError, match="key b must be a number"):
        launcher.parse_avr_sim_url("avr-sim://?b=fast")
    with pytest.raises(ValueError, match="avr-sim://"):
        launcher.parse_avr_sim_url("fake://?a=1")
    assert isinstance(opts.counts_per_rev, int) and "--counts-per-rev" in opts.argv()
    assert opts.argv()[opts.argv().index("--counts-per-rev") + 1] == "2000"


def test_firmware_builds_exist_per_baud_rate_only_for_rates_the_uno_can_make():
    assert launcher.firmware_elf(250000).parent.name == "build"
    assert launcher.firmware_elf(115200).parent.name == "baud115200"
    assert launcher.firmware_elf(500000, "in1-in2").parent.name == "baud500000-in1-in2"
    with pytest.raises(ValueError, match="baudrate must be one of"):
        launcher.firmware_elf(300000)
