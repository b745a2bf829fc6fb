"""The estimator registry: every name resolves to its function, and only when first used."""
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

from identify import available_methods
from identify.methods import method_function, method_options

ROOT = Path(__file__).resolve().parent.parent.parent


@pytest.mark.parametrize("method", available_methods())
def test_every_registered_name_resolves_to_an_estimator_of_this_package(method):
    function = method_function(method)
    assert callable(function) and function.__module__.startswith("identify.")
    assert next(iter(inspect.signature(function).parameters)) == "recordings"
    assert method_options(method) == tuple(inspect.signature(function).parameters)[1:]


def test_an_unknown_name_is_refused_with_the_known_ones():
    with pytest.raises(ValueError, match=r"method must be one of \['auto', 'euler-ls'.*got 'ols'"):
        method_function("ols")


def test_listing_the_methods_imports_no_estimator():
    code = ("import sys\nfrom identify import available_methods, DEFAULT_METHOD\navailable_methods()\n"
            "print(','.join(m for m in ('identify.output_error', 'identify.friction', 'scipy.optimize')"
            " if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""
