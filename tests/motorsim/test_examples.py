"""The Examples sections of motorsim's docstrings run and print what they say."""
import doctest
import importlib

import pytest

MODULES = ["motorsim.checks", "motorsim.knobs", "motorsim.excitation", "motorsim.plant", "motorsim.recording",
           "motorsim.rig", "motorsim.sensors"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
