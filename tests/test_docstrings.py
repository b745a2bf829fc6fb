"""Every public callable documents each of its parameters (as python-control's test suite insists)."""
import importlib
import inspect

import pytest

PACKAGES = ["motorsim", "identify", "scenarios", "hardware"]


def _public_callables():
    seen = set()
    for pkg in PACKAGES:
        mod = importlib.import_module(pkg)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if (inspect.isfunction(obj) or inspect.isclass(obj)) and id(obj) not in seen:
                seen.add(id(obj))
                yield f"{pkg}.{name}", obj


def _undocumented(obj):
    target = obj.__init__ if inspect.isclass(obj) and "__init__" in vars(obj) else obj
    try:
        params = inspect.signature(target).parameters
    except (TypeError, ValueError):
        return []
    doc = (inspect.getdoc(obj) or "") + (inspect.getdoc(target) or "" if target is not obj else "")
    return [p for p in params if p not in ("self", "cls") and not p.startswith("_")
            and params[p].kind not in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
            and p not in doc]


@pytest.mark.parametrize("name, obj", list(_public_callables()), ids=lambda x: x if isinstance(x, str) else "")
def test_public_parameters_are_documented(name, obj):
    assert not _undocumented(obj), f"{name} does not document {_undocumented(obj)}"
