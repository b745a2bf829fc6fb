"""One lazy-import mechanism: names loaded on first use, moved names that warn, registries by text."""
import sys
import types
import warnings

import pytest

import motorsim.control
from motorsim.checks import ParameterError
from motorsim.lazy import lazy_attributes, load


@pytest.fixture
def scratch_module():
    module = types.ModuleType("scratch_lazy")
    sys.modules[module.__name__] = module
    yield module
    del sys.modules[module.__name__]


def test_an_exported_name_is_loaded_once_and_kept(scratch_module):
    scratch_module.__getattr__, scratch_module.__dir__ = lazy_attributes(scratch_module.__name__,
                                                                         exports={"sqrt": "math"})
    import math
    assert "sqrt" not in vars(scratch_module) and "sqrt" in dir(scratch_module)
    assert scratch_module.sqrt is math.sqrt
    assert vars(scratch_module)["sqrt"] is math.sqrt      # cached: the next use does not ask again


def test_a_moved_name_warns_with_its_new_place_and_an_unknown_one_is_an_attribute_error(scratch_module):
    scratch_module.__getattr__, _ = lazy_attributes(scratch_module.__name__, moved={"check_int": "motorsim.checks"},
                                                    hint=" (see {name})")
    from motorsim.checks import check_int
    with pytest.warns(DeprecationWarning, match=r"scratch_lazy.check_int moved to motorsim.checks.check_int "
                                                r"\(see check_int\)"):
        assert scratch_module.check_int is check_int
    with pytest.raises(AttributeError, match="scratch_lazy.*no attribute 'nothing'"):
        _ = scratch_module.nothing


def test_load_resolves_relative_targets_and_names_a_malformed_one():
    from motorsim.checks import check_real
    assert load(".checks:check_real", "motorsim") is check_real
    with pytest.raises(ParameterError, match="target must be 'module:name', got 'motorsim.checks'"):
        load("motorsim.checks")


def test_the_control_package_re_exports_each_public_name_from_its_own_module():
    for name in motorsim.control.__all__:
        obj = getattr(motorsim.control, name)
        owner = getattr(obj, "__module__", None)
        if owner is not None and not isinstance(obj, (int, float, dict)):
            assert owner.startswith("motorsim.control.") and name in sys.modules[owner].__all__, name


def test_the_fixed_point_names_moved_out_of_control_still_warn():
    from motorsim import fixed_point
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DeprecationWarning, match="motorsim.fixed_point.GAIN_ORDER"):
            _ = motorsim.control.GAIN_ORDER
    with pytest.warns(DeprecationWarning):
        assert motorsim.control.gains_from_wire is fixed_point.gains_from_wire
