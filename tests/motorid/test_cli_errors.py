"""The CLI's error contract: user errors exit 2 with one line, bugs exit 1 and never pass as user errors.

The fuzz tests feed ``identify`` and ``sweep FILE.toml`` mutated valid files: every outcome is
a result (0) or a user error (2) with one ``motorid: error:`` line, never an internal error
or a traceback.
"""
import argparse

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import motorid.commands.identify as identification
from motorid.arguments import CommandError
from motorid.cli import main
from motorsim import Encoder, Experiment, Motor, SimRig, Sine, write_recording


def _raising(exc):
    def run(args: argparse.Namespace) -> int:
        raise exc
    return run


@pytest.mark.parametrize("exc", [ValueError("index out of range"), TypeError("unsupported operand"),
                                 KeyError("a"), ZeroDivisionError("division by zero")], ids=repr)
def test_a_bug_exits_1_with_one_line_asking_for_the_traceback(monkeypatch, capsys, exc):
    monkeypatch.setattr(identification, "run_identify", _raising(exc))
    assert main(["identify", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"motorid: internal error: {type(exc).__name__}")
    assert "--traceback" in err and "Traceback" not in err


def test_traceback_flag_shows_the_traceback(monkeypatch, capsys):
    monkeypatch.setattr(identification, "run_identify", _raising(ValueError("a bug")))
    assert main(["--traceback", "identify", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "ValueError: a bug" in err


@pytest.mark.parametrize("exc, text", [
    (CommandError("--out must be a folder"), "--out must be a folder"),
    (FileNotFoundError(2, "No such file or directory", "/no/such.csv"), "/no/such.csv: No such file or directory"),
    (PermissionError(13, "Permission denied", "/ro/run.csv"), "/ro/run.csv: Permission denied"),
], ids=["CommandError", "FileNotFoundError", "PermissionError"])
def test_a_user_error_exits_2_with_one_line(monkeypatch, capsys, exc, text):
    monkeypatch.setattr(identification, "run_identify", _raising(exc))
    assert main(["identify", "x.csv"]) == 2
    assert capsys.readouterr().err == f"motorid: error: {text}\n"


def test_bad_bench_flags_are_user_errors(tmp_path, capsys):
    assert main(["simulate", "--a", "25", "--b", "3", "--jitter", "1.5", "--out", str(tmp_path / "r.csv")]) == 2
    assert "jitter must be < 1" in capsys.readouterr().err


@pytest.fixture(scope="module")
def recording_bytes(tmp_path_factory):
    rec = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(2)).run(
        Experiment(Sine(20.0), 0.005, 0.6))
    return write_recording(rec, tmp_path_factory.mktemp("fuzz") / "r.csv").read_bytes()


def _mutate(data: bytes, edits) -> bytes:
    out = bytearray(data)
    for kind, where, value in edits:
        k = where % (len(out) + 1)
        if kind == "flip" and out:
            out[k % len(out)] ^= 1 << (value % 8)
        elif kind == "set" and out:
            out[k % len(out)] = value
        elif kind == "insert":
            out[k:k] = bytes([value])
        elif kind == "delete":
            del out[k:k + 1 + value % 40]
        elif kind == "truncate":
            del out[k:]
        elif kind == "duplicate":
            out[k:k] = out[k:k + 1 + value]
    return bytes(out)


#: Bytes that matter to CSV and TOML (NUL, newlines, quote, comma, '-', '.', digits, '=', '[', '_', 'e'),
#: the lead byte of a UTF-8 sequence and an invalid byte.
BYTES = [0, 10, 13, 34, 44, 45, 46, 48, 49, 57, 61, 91, 95, 101, 0xC3, 255]
EDITS = st.lists(st.tuples(st.sampled_from(["flip", "set", "insert", "delete", "truncate", "duplicate"]),
                           st.integers(0, 1 << 20), st.sampled_from(BYTES)), min_size=1, max_size=4)


def _assert_result_or_user_error(code, err):
    assert code in (0, 2), err
    assert "Traceback" not in err and "internal error" not in err
    if code == 2:
        assert err.startswith("motorid: error: ") and err.count("\n") == 1, err


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=EDITS)
def test_identify_on_a_mutated_recording_is_a_result_or_a_user_error(tmp_path, capsys, recording_bytes, edits):
    path = tmp_path / "mutated.csv"
    path.write_bytes(_mutate(recording_bytes, edits))
    code = main(["identify", "--method", "zoh-ls", str(path)])
    _assert_result_or_user_error(code, capsys.readouterr().err)


SCENARIO = b"""name = "fuzz"
seed = 1
repetitions = 2
methods = ["zoh-ls"]

[motor]
a = 25.0
b = 3.0

[bench]
sample_period = 0.005
counts_per_rev = 16667
duration = 0.5

[excitation]
frequency = 10.0
amplitude = 200

[grid]
"bench.angle_noise" = [0.0, 2e-4]
"""


#: Values a careless user might type, none of them a legitimately huge run.
HOSTILE_VALUES = ["-1", "0", "-0.0", "nan", "inf", "-inf", "3.5", "256", "-255", "1e-3", "\"x\"", "\"\"", "[]",
                  "[1, \"a\"]", "true", "{}", "{a = 1}", "\"../../x\"", "\"sine:10\"", "[0.0, -1.0]", "0x10"]


def _replace_values(data: bytes, choices) -> bytes:
    lines = data.decode().splitlines()
    for index, value in choices:
        assigned = [k for k, line in enumerate(lines) if " = " in line]
        k = assigned[index % len(assigned)]
        lines[k] = lines[k].partition(" = ")[0] + " = " + value
    return ("\n".join(lines) + "\n").encode()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=st.one_of(
    EDITS.map(lambda edits: ("bytes", edits)),
    st.lists(st.tuples(st.integers(0, 100), st.sampled_from(HOSTILE_VALUES)), min_size=1, max_size=3).map(
        lambda choices: ("values", choices))))
def test_sweep_on_a_mutated_scenario_is_a_result_or_a_user_error(tmp_path, capsys, edits):
    kind, changes = edits
    path = tmp_path / "s.toml"
    path.write_bytes(_mutate(SCENARIO, changes) if kind == "bytes" else _replace_values(SCENARIO, changes))
    code = main(["sweep", str(path), "--out", str(tmp_path / "out"), "--workers", "1", "--quiet", "--no-plots",
                 "--repetitions", "2"])
    _assert_result_or_user_error(code, capsys.readouterr().err)


@pytest.mark.parametrize("argv, text", [
    (["design", "--a", "25", "--b", "0", "--sample-period", "0.005", "--counts-per-rev", "1024"], "b must be nonzero"),
    (["design", "--a", "25", "--b", "3", "--sample-period", "0.005", "--counts-per-rev", "1024", "--duration", "0.05"],
     "duration must cover at least 20 samples"),
], ids=["b=0", "short"])
def test_rules_of_the_library_reached_from_flags_are_user_errors(tmp_path, capsys, argv, text):
    assert main([*argv, "--out", str(tmp_path / "d"), "--no-plots"]) == 2
    assert text in capsys.readouterr().err


def test_pooling_recordings_of_different_periods_is_a_user_error(tmp_path, capsys):
    files = [str(tmp_path / f"r{dt}.csv") for dt in ("0.005", "0.01")]
    for dt, f in zip(("0.005", "0.01"), files):
        assert main(["simulate", "--a", "25", "--b", "3", "--sample-period", dt, "--duration", "1", "--out", f]) == 0
    capsys.readouterr()
    assert main(["identify", *files]) == 2
    assert "must share one sample_period" in capsys.readouterr().err
