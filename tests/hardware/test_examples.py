"""The Examples sections of hardware's docstrings run and print what they say (``fake://``, no board)."""
import doctest
import importlib

import pytest

MODULES = ["hardware.protocol", "hardware.serial_rig", "hardware.ports", "hardware.fake_device",
           "hardware.sim.launcher"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
