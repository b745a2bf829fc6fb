"""Shared fixtures of the identify tests: the independent reference integrators."""
import importlib.util
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def reference():
    """The module ``reference_data.py`` beside this file (loaded by path)."""
    path = Path(__file__).with_name("reference_data.py")
    spec = importlib.util.spec_from_file_location("identify_reference_data", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
