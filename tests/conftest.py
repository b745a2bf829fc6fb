"""Markers set in one place (``slow`` and ``firmware``, by test id), and the ``motorid`` parsers.

``make test-fast`` runs ``pytest -m "not slow and not firmware"``.  Tests marked ``realtime``
run an emulated rig against the wall clock, which a loaded machine can fail by design: they
are skipped unless pytest is given ``--realtime`` (``make test-realtime``).  A test is ``slow`` when it
takes over about 1.5 s on its own (``pytest --durations=40``); it is listed in :data:`SLOW`
with what makes it slow.  Tests that start the AVR emulator are ``firmware``, listed in
:data:`FIRMWARE`.  A test may also carry the marker itself (a module ``pytestmark``); the
lists here keep the test files untouched.

An entry names ``path::function`` (every parametrisation of it) or a whole ``path``.  An
entry whose file or function no longer exists stops the collection, so a renamed test cannot
silently leave the fast subset slower.
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent

#: test id -> why it is slow (seconds measured alone on a 2-core machine)
SLOW = {
    "tests/identify/test_drive_limit.py::test_the_default_leaves_the_clipped_driver_unclear_and_the_rule_would_make_it_clear":
        "2.3 s: a 2000-sample plant integrated by RK4 in Python, the default and the drive limit's fits",
    "tests/identify/test_current_limit.py::test_the_default_chooses_it_where_the_gain_is_lower_at_high_drive":
        "2.4 s: a 4000-sample plant integrated by RK4 in Python, the default and the current limit's fits",
    "tests/identify/test_current_limit.py::test_its_fit_of_the_bench_current_limit_holds_the_truth":
        "1.5 s: a 4000-sample plant integrated by RK4 in Python and the current limit's fit from six starts",
    "tests/identify/test_asymmetric_gain.py::test_the_default_chooses_it_on_a_driver_stronger_forward":
        "2.5 s: two 4000-sample plants integrated by RK4 in Python, each fitted by the default twice over",
    "tests/identify/test_selection.py::test_a_second_pole_and_a_static_level_stop_where_their_fits_have_worsened_far_beyond_the_best":
        "5 s: two selections on a 3000-sample delayed run, the second scanning every delay",
    "tests/identify/test_selection.py::test_a_choice_at_the_top_of_the_range_leaves_the_higher_ranks_to_the_wider_one":
        "5 s: two defaults on a 3000-sample run whose delay widens the range",
    "tests/motorsim/test_robustness.py::test_robust_design_measured_rms_stays_within_its_predicted_worst_case":
        "4 s: nine candidate designs judged on 60 drawn plants, then four SimRig runs",
    "tests/motorid/test_article_figures.py": "6 s: the whole demo, its closed loop included, once for the module",
    "tests/scenarios/test_sweep.py::test_same_csv_from_one_worker_two_processes_and_dask":
        "12 s: starts worker processes and a local Dask cluster",
    "tests/scenarios/test_sweep.py::test_cli_sweep_lists_runs_and_plots": "1.5 s: a sweep with its figures",
    "tests/motorid/test_demo.py::test_demo_table_matches_direct_fits_of_its_recordings":
        "4.5 s: the whole demo, oe-friction included",
    "tests/motorid/test_demo.py::test_demo_writes_the_figures": "1.5 s: the demo's figures",
    "tests/identify/test_output_error.py::test_unstable_data_is_refused_with_theta1":
        "4.5 s: a long reference integration",
    "tests/motorsim/test_plant.py::test_nonuniform_time_equals_matrix_exponential_per_interval":
        "2.9 s: one matrix exponential per interval",
    "tests/hardware/test_serial_rig_fuzz.py::test_fuzz_any_corruption_gives_true_rows_or_a_typed_error":
        "2.3 s: 80 hypothesis examples",
    "tests/identify/test_second_order.py::test_a_delay_past_ten_samples_is_searched_and_found":
        "1.7-3 s each: the default's selection run again over 20 and 40 delays",
    "tests/identify/test_second_order.py::test_a_twenty_sample_delay_on_a_prbs_is_found":
        "3.3 s: the selection over 40 delays",
    "tests/identify/test_selection.py::test_a_position_loop_with_friction_and_a_fed_back_load_is_never_a_narrow_wrong_answer":
        "3-6 s: a closed loop simulated sample by sample, then the whole selection",
}

#: test id or module -> what it runs under the emulator
FIRMWARE = {
    "tests/hardware/test_firmware_emulation.py": "the firmware ELF under simavr, frame by frame",
    "tests/hardware/test_firmware_closed_loop.py": "the firmware's controllers under simavr",
    "tests/hardware/test_harness_lifetime.py::test_the_harness_itself_ends_when_its_parent_is_killed":
        "the real harness, its parent killed",
    "tests/hardware/test_harness_lifetime.py::test_kill_9_of_motorid_live_on_avr_sim_leaves_no_emulator":
        "motorid live on avr-sim://, killed by SIGKILL",
    "tests/motorid/test_live.py::test_live_on_the_emulated_firmware_holds_a_and_b_in_its_intervals":
        "motorid live on avr-sim://",
}


def _check_entries(entries: dict[str, str], marker: str) -> None:
    """Stop the run when an entry names a file or a test function that does not exist."""
    for test_id in entries:
        path, _, function = test_id.partition("::")
        file = ROOT / path
        text = file.read_text(encoding="utf-8") if file.is_file() else ""
        if not function and text:
            continue
        if not re.search(rf"^\s*(async\s+)?def {re.escape(function)}\(", text, re.MULTILINE):
            raise pytest.UsageError(f"tests/conftest.py: {marker} entry {test_id!r} names no test file or function; "
                                    "update the list after renaming or moving a test")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--realtime", action="store_true", default=False,
                     help="also run the tests marked realtime (emulated rigs on the wall clock; "
                          "they need an idle machine)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Add the ``slow`` and ``firmware`` markers to the tests listed above; skip ``realtime`` without ``--realtime``."""
    _check_entries(SLOW, "slow")
    _check_entries(FIRMWARE, "firmware")
    for item in items:
        path = Path(str(item.path)).resolve().relative_to(ROOT).as_posix()
        test_id = f"{path}::{item.originalname}" if isinstance(item, pytest.Function) else item.nodeid
        if test_id in SLOW or path in SLOW:
            item.add_marker(pytest.mark.slow)
        if test_id in FIRMWARE or path in FIRMWARE:
            item.add_marker(pytest.mark.firmware)
        if item.get_closest_marker("realtime") and not config.getoption("--realtime"):
            item.add_marker(pytest.mark.skip(reason="runs against the wall clock: pytest --realtime "
                                                    "(make test-realtime) on an idle machine"))


class _ParserFound(BaseException):   # not an Exception: main() turns those into exit statuses
    """Carries the parser whose ``parse_known_args`` was called first."""


def _subcommands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) not in seen:          # an alias maps to the same parser
                    seen.add(id(sub))
                    yield from _subcommands(sub, path + (name,))


def _parser_of(main, argv: list[str], known: list[argparse.ArgumentParser]) -> argparse.ArgumentParser | None:
    """The first parser that ``main(argv)`` asks to parse whose ``prog`` is not one of ``known``'s, or None.

    ``main`` may build its parsers anew on each call, so they are told apart by ``prog``.
    """
    progs = {parser.prog for parser in known}
    original = argparse.ArgumentParser.parse_known_args

    def catch(self, args=None, namespace=None):
        if self.prog in progs:
            return original(self, args, namespace)
        raise _ParserFound(self)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(argparse.ArgumentParser, "parse_known_args", catch)
        try:
            main(argv)
        except _ParserFound as found:
            return found.args[0]
        except SystemExit:
            return None
    return None


def _dispatched_names(parser: argparse.ArgumentParser) -> list[str]:
    """Choices of a positional that hands the rest of the line (``REMAINDER``) to its own parser."""
    positionals = [a for a in parser._actions if not a.option_strings]
    if not any(a.nargs == argparse.REMAINDER for a in positionals):
        return []
    return [str(c) for a in positionals if a.choices and a.nargs != argparse.REMAINDER for c in a.choices]


@pytest.fixture(scope="session")
def motorid_commands() -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every parser of the ``motorid`` console script by command path (``()``, ``("bench", "sweep")``).

    The entry point is read from pyproject.toml and each parser caught when ``main`` parses its
    arguments (``--help``), so the tests do not depend on how the CLI builds its parsers: the
    sub-parsers, and the parsers of commands such as ``bench NAME`` that parse their own flags.
    """
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]
    module_name, _, attr = scripts["motorid"].partition(":")
    main = getattr(importlib.import_module(module_name), attr)
    top = _parser_of(main, ["--help"], [])
    assert top is not None, f"{scripts['motorid']} parsed no arguments"
    commands = dict(_subcommands(top))
    for path, parser in list(commands.items()):
        for name in _dispatched_names(parser):
            inner = _parser_of(main, [*path, name, "--help"], list(commands.values()))
            if inner is not None:
                commands.update(_subcommands(inner, path + (name,)))
    return commands


@pytest.fixture(params=["python", "numba"])
def kernel_path(request, monkeypatch):
    """Run simulate's friction loop in Python (never compile) or by numba (compile at once)."""
    from motorsim import compiled
    if request.param == "numba":
        if compiled.compiled_kernel() is None:
            pytest.skip("numba is not installed or MOTORID_NUMBA=0")
        monkeypatch.setattr(compiled, "COMPILE_AFTER", 0)
    else:
        monkeypatch.setattr(compiled, "COMPILE_AFTER", 10 ** 18)
    return request.param
