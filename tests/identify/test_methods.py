"""The estimator registry: every name resolves to its function, and only when first used."""
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

from identify import DEFAULT_METHOD, available_methods, check_options, fit, method_options, option_declarations
from identify.methods import method_function
from motorsim import Experiment, Motor, SimRig, Sine

ROOT = Path(__file__).resolve().parent.parent.parent


@pytest.mark.parametrize("method", available_methods())
def test_every_registered_name_resolves_to_an_estimator_of_this_package(method):
    function = method_function(method)
    assert callable(function) and function.__module__.startswith("identify.")
    assert next(iter(inspect.signature(function).parameters)) == "recordings"

#: Every method's options as its function took them before they were declared (its signature after the
#: recordings): the declaration accepts exactly these.
ACCEPTED = {
    "auto": ("input_delay", "structures", "fix_bias"),
    "euler-ls": (),
    "zoh-ls": (),
    "oe": ("input_delay", "fit_bias", "jac", "covariance"),
    "iv": ("input_delay", "iterations"),
    "oe-friction": ("input_delay", "fix_bias", "dead_zone", "static_friction"),
    "iv-reference": ("input_delay",),
    "oe-electrical": ("input_delay",),
    "oe-asymmetric": ("input_delay", "covariance"),
    "oe-drive-limit": ("input_delay", "covariance"),
    "oe-current-limit": ("input_delay", "covariance"),
    "pem-disturbance": ("input_delay", "friction", "disturbance_pole"),
}


def test_every_method_accepts_the_options_it_accepted():
    assert {m: method_options(m) for m in ACCEPTED} == ACCEPTED
    # every other is a structure's own estimator, listed from the structure registry: the generic fit's option
    from identify import structures
    own = {s.method for s in structures().values()}
    assert all(m in own and method_options(m) == ("input_delay",) for m in available_methods() if m not in ACCEPTED)


@pytest.mark.parametrize("method", [DEFAULT_METHOD, *available_methods()])
def test_each_declaration_is_its_functions_keywords_with_their_defaults(method):
    # the declaration is what fit and the command line check: it must be what the function takes
    params = list(inspect.signature(method_function(method)).parameters.values())[1:]
    declared = option_declarations(method)
    assert [(o.name, o.default) for o in declared] == [(p.name, p.default) for p in params]
    assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in params)
    assert all(o.kind and o.help and "\n" not in o.help for o in declared)


@pytest.mark.parametrize("method, option, message", [
    ("oe", "fix_bias", "method 'oe' has no option 'fix_bias': its options are input_delay, fit_bias, jac, covariance"),
    ("zoh-ls", "input_delay", "method 'zoh-ls' has no option 'input_delay': it takes no options"),
    ("auto", "fit_bias", "method 'auto' has no option 'fit_bias': its options are input_delay, structures, fix_bias"),
], ids=["oe", "none", "auto"])
def test_an_option_the_method_does_not_take_is_refused_naming_it(method, option, message):
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 1.0))
    with pytest.raises(TypeError, match=message):         # as Python's own for an unexpected keyword
        fit(rec, method, **{option: True})
    with pytest.raises(ValueError, match="method must be one of"):
        check_options("ols", {})
    check_options(method, {o: None for o in ACCEPTED[method]})       # every declared one passes


def test_an_unknown_name_is_refused_with_the_known_ones():
    with pytest.raises(ValueError, match=r"method must be one of \['auto', 'euler-ls'.*got 'ols'"):
        method_function("ols")


def test_listing_the_methods_imports_no_estimator():
    code = ("import sys\nfrom identify import available_methods, DEFAULT_METHOD\navailable_methods()\n"
            "print(','.join(m for m in ('identify.fits.output_error', 'identify.fits.friction', 'scipy.optimize')"
            " if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""
