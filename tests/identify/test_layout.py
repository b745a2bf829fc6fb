"""identify/ is read from its folders: the estimators (fits/), the default's selection (default/), uncertainty and
checks (checks/), the frequency view (frequency/); every module importable by its earlier name too, as the same
module object; no function over 80 lines, no module over 800 without its reason below."""
from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import identify

ROOT = Path(__file__).resolve().parents[2]
#: The modules over 800 lines, each with the reason it stays one module.
LONG_MODULES = {
    "identify/adaptive.py": "one experiment loop: its rounds, their design and the stopping rule share its state",
    "identify/default/selection.py": "the default's one decision top to bottom: delays, candidates, choice, doubt",
    "identify/fits/prediction_error.py": "one Kalman predictor: its pass and that pass differentiated, compiled "
                                         "together by numba from one scope, and the fit on them",
}


@pytest.mark.parametrize("old, new", sorted(identify.MOVED_MODULES.items()))
def test_a_moved_module_is_imported_by_its_earlier_name_as_itself(old, new):
    moved = importlib.import_module(f"identify.{new}")
    assert importlib.import_module(f"identify.{old}") is moved
    assert not (ROOT / "identify" / f"{old.replace('.', '/')}.py").exists()
    assert (ROOT / "identify" / f"{new.replace('.', '/')}.py").exists()


def test_a_name_patched_through_the_earlier_path_is_patched_where_it_is_used():
    from unittest import mock

    from identify.checks import validation
    with mock.patch("identify.validation.segment_fit_percent", lambda *args: 42.0):
        assert validation.segment_fit_percent([], []) == 42.0
    assert validation.segment_fit_percent is not None


def test_earlier_names_import_nothing_until_asked_for():
    code = ("import sys, identify\nprint(sorted(m for m in sys.modules if m.startswith('identify.')))\n"
            "from identify.selection import fit_selected\nprint('identify.default.selection' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.splitlines() == ["[]", "True"]


def _modules():
    return sorted(p for p in (ROOT / "identify").rglob("*.py") if "build" not in p.parts)


def test_no_function_is_over_80_lines():
    long = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 80:
                long.append(f"{path.relative_to(ROOT)}:{node.name} {node.end_lineno - node.lineno + 1}")
    assert not long, f"functions over 80 lines: {long}"


def test_no_module_is_over_800_lines_without_its_reason():
    long = {p.relative_to(ROOT).as_posix(): len(p.read_text(encoding="utf-8").splitlines()) for p in _modules()}
    long = {p: n for p, n in long.items() if n > 800}
    assert set(long) <= set(LONG_MODULES), f"modules over 800 lines with no reason given: {long}"


#: The folders the default is built on: none of their modules imports the default's selection (``default/``).
BELOW_THE_DEFAULT = ("fits", "checks", "frequency", "model_structures")


def _imported_modules(source: str, module: str) -> list[tuple[str, int]]:
    """The dotted names the module ``module`` (``identify.fits.output_error``; a package's ``__init__`` named
    as ``identify.fits.__init__``) imports in ``source``, relative imports made absolute, with their lines."""
    package = module.split(".")[:-1]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - (node.level - 1)] if node.level else []
            stem = ".".join(base + ([node.module] if node.module else []))
            found += [(f"{stem}.{alias.name}", node.lineno) for alias in node.names]
    return found


def _imports_of_the_default(path: Path) -> list[str]:
    module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    return [f"{path.relative_to(ROOT)}:{line} imports {name}"
            for name, line in _imported_modules(path.read_text(encoding="utf-8"), module)
            if name == "identify.default" or name.startswith("identify.default.")]


def test_the_estimators_and_the_checks_import_nothing_of_the_default():
    offenders = [found for folder in BELOW_THE_DEFAULT for path in sorted((ROOT / "identify" / folder).rglob("*.py"))
                 for found in _imports_of_the_default(path)]
    assert not offenders, "the default is built on these folders, not they on it:\n" + "\n".join(offenders)


def test_the_rule_resolves_relative_imports():
    source = ("from ..default.comparison import LEVEL\nfrom .sensitivity import zoh_response\n"
              "def f():\n    from ...identify import default\n    import identify.default.selection\n")
    assert _imported_modules(source, "identify.fits.output_error") == [
        ("identify.default.comparison.LEVEL", 1), ("identify.fits.sensitivity.zoh_response", 2),
        ("identify.default", 4), ("identify.default.selection", 5)]
    assert _imported_modules("from . import x\n", "identify.fits.__init__") == [("identify.fits.x", 1)]
