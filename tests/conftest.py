"""Markers set in one place: ``slow`` and ``firmware`` by test id.

``make test-fast`` runs ``pytest -m "not slow and not firmware"``.  A test is ``slow`` when it
takes over about 1.5 s on its own (``pytest --durations=40``); it is listed in :data:`SLOW`
with what makes it slow.  Tests that start the AVR emulator are ``firmware``: the module
``tests/hardware/test_firmware_emulation.py`` marks itself; :data:`FIRMWARE` lists those
elsewhere.  A test may also carry ``@pytest.mark.slow`` itself; the lists here keep the test
files untouched.

An entry names ``path::function`` (every parametrisation of it).  An entry whose function
no longer exists in its file stops the collection, so a renamed test cannot silently leave
the fast subset slower.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: test id -> why it is slow (seconds measured alone on a 2-core machine)
SLOW = {
    "tests/scenarios/test_sweep.py::test_same_csv_from_one_worker_two_processes_and_dask":
        "12 s: starts worker processes and a local Dask cluster",
    "tests/scenarios/test_sweep.py::test_cli_sweep_lists_runs_and_plots": "1.5 s: a sweep with its figures",
    "tests/scenarios/test_demo.py::test_demo_table_matches_direct_fits_of_its_recordings":
        "4.5 s: the whole demo, oe-friction included",
    "tests/scenarios/test_demo.py::test_demo_writes_the_figures": "1.5 s: the demo's figures",
    "tests/identify/test_output_error.py::test_unstable_data_is_refused_with_theta1":
        "4.5 s: a long reference integration",
    "tests/motorsim/test_plant.py::test_nonuniform_time_equals_matrix_exponential_per_interval":
        "2.9 s: one matrix exponential per interval",
    "tests/hardware/test_serial_rig_fuzz.py::test_fuzz_any_corruption_gives_true_rows_or_a_typed_error":
        "2.3 s: 80 hypothesis examples",
}

#: test id -> which part of the emulator it needs (outside tests/hardware/test_firmware_emulation.py)
FIRMWARE = {
    "tests/scenarios/test_live.py::test_live_on_the_emulated_firmware_recovers_a_and_b_within_one_percent":
        "motorid live on avr-sim://",
}


def _check_entries(entries: dict[str, str], marker: str) -> None:
    """Stop the run when an entry names a file or a test function that does not exist."""
    for test_id in entries:
        path, _, function = test_id.partition("::")
        file = ROOT / path
        text = file.read_text(encoding="utf-8") if file.is_file() else ""
        if not re.search(rf"^\s*(async\s+)?def {re.escape(function)}\(", text, re.MULTILINE):
            raise pytest.UsageError(f"tests/conftest.py: {marker} entry {test_id!r} names no test function; "
                                    "update the list after renaming or moving a test")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Add the ``slow`` and ``firmware`` markers to the tests listed above."""
    _check_entries(SLOW, "slow")
    _check_entries(FIRMWARE, "firmware")
    for item in items:
        path = Path(str(item.path)).resolve().relative_to(ROOT).as_posix()
        test_id = f"{path}::{item.originalname}" if isinstance(item, pytest.Function) else item.nodeid
        if test_id in SLOW:
            item.add_marker(pytest.mark.slow)
        if test_id in FIRMWARE:
            item.add_marker(pytest.mark.firmware)
