"""identify/ is read from its folders: the estimators (fits/), the default's selection (default/), uncertainty and
checks (checks/), the frequency view (frequency/); every module importable by its earlier name too, as the same
module object."""
from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import identify

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("old, new", sorted(identify.MOVED_MODULES.items()))
def test_a_moved_module_is_imported_by_its_earlier_name_as_itself(old, new):
    moved = importlib.import_module(f"identify.{new}")
    assert importlib.import_module(f"identify.{old}") is moved
    assert not (ROOT / "identify" / f"{old}.py").exists()
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
