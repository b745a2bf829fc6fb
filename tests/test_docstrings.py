"""Docstrings: every public callable documents each of its parameters (as python-control's test
suite insists), and every ``Examples`` section of every module runs as a doctest.
"""
import doctest
import importlib
import inspect
from pathlib import Path

import pytest

PACKAGES = ["motorsim", "identify", "scenarios", "hardware", "motorid"]
ROOT = Path(__file__).resolve().parent.parent


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


def _modules() -> list[str]:
    """Every module of the five packages, found on disk (``__init__`` as the package name)."""
    names = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


@pytest.mark.parametrize("module_name", _modules())
def test_examples_in_docstrings_run(module_name, tmp_path, monkeypatch):
    """Every ``>>>`` example of every module runs and prints what it shows (in a scratch folder)."""
    module = importlib.import_module(module_name)
    monkeypatch.chdir(tmp_path)                      # examples may write files
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    report: list[str] = []
    failed = sum(runner.run(test, out=report.append).failed for test in finder.find(module, module_name))
    assert failed == 0, "".join(report)
