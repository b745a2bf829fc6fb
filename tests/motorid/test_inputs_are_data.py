"""Hostile inputs of the fourth round: what a file holds is data, never instructions to the terminal or the machine.

Each case ran as a user would run it (``motorid.cli.main`` or the ``motorid`` command); each failed before the
change it tests (text reaching the terminal raw, a traceback, a file of the machine read, memory without bound,
a wrong number with exit 0) and now ends in a right answer or one ``motorid: error:`` line naming the parameter,
the rule and the value.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from motorid.cli import main
from motorsim import Experiment, Motor, SimRig, Sine, write_recording

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rec_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "r.csv"
    write_recording(SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 4.0)), path)
    return path


@pytest.fixture(scope="module")
def model_doc(rec_path, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.json"
    assert main(["identify", str(rec_path), "--save", str(path)]) == 0
    return json.loads(path.read_text())


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("motorid: error:"), err
    return err[-1]


def _raw_controls(text: str) -> set[str]:
    return {c for c in text if (ord(c) < 32 and c not in "\n\t") or 0x7f <= ord(c) <= 0x9f
            or 0xd800 <= ord(c) <= 0xdfff}


# --- control characters from a file never reach the terminal raw ---------------------------------------

@pytest.mark.parametrize("where, text", [
    ("units.input", "\x1b]0;owned\x07\x1b[2Jduty"),          # retitles and clears a terminal
    ("units.input", "duty\nmotorid: error: forged"),         # forges a line
    ("units.speed", "rad/s\udc80"),                         # a lone surrogate: an encoding error when printed
    ("input_unit", "du\ud800ty"),
    ("notes", "fit \r overwritten"),
])
def test_a_model_whose_text_holds_control_characters_is_refused_in_one_printable_line(model_doc, tmp_path, where,
                                                                                    text, capsys):
    doc = json.loads(json.dumps(model_doc))
    if where.startswith("units."):
        doc["units"][where.split(".")[1]] = text
    elif where == "notes":
        doc["notes"] = [*doc.get("notes", []), text]
    else:
        doc[where] = text
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    assert main(["control", "design", "--model", str(path), "--controller", "pi"]) == 2
    out, err = capsys.readouterr()
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"motorid: error: --model {path}: not a saved model: an estimate's text must be printable")
    assert not _raw_controls(out + err) and "forged" not in out


def test_a_recordings_metadata_with_an_escape_sequence_is_printed_escaped(rec_path, tmp_path, capsys):
    text = rec_path.read_text().replace("# sample_period:", "# input_unit: \x1b[2J\x1b]0;owned\x07duty\n"
                                        "# sample_period:", 1)
    path = tmp_path / "esc.csv"
    path.write_text(text)
    main(["identify", str(path)])
    out, err = capsys.readouterr()
    assert "\\x1b[2J" in out + err                 # said, made visible
    assert not _raw_controls(out + err)            # before: the terminal was cleared and retitled


def test_a_column_name_with_an_escape_sequence_is_printed_escaped(tmp_path, capsys):
    path = tmp_path / "lab.csv"
    path.write_text("t,u\x1b[2J,y\n0,1,0\n0.01,1,0.1\n0.02,1,0.2\n")
    assert main(["import", str(path), "--time", "t", "--input", "nothing:duty", "--speed", "y:rad/s",
                 "--out", str(tmp_path / "o.csv")]) == 2
    line = _error(capsys)
    assert "u\\x1b[2J" in line and "\x1b" not in line


def test_a_warning_holding_a_newline_stays_one_line(capsys):
    import warnings

    from motorid.cli import _show_warning
    _show_warning(warnings.WarningMessage("one\nmotorid: error: forged", UserWarning, "f", 1).message,
                  UserWarning, "f", 1)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("motorid: warning: one motorid: error: forged")


# --- a locale without UTF-8 -------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["design", "--a", "25", "--b", "3", "--sample-period", "0.005",
                                   "--counts-per-rev", "1000", "--no-plots", "--out", "{tmp}/d"],
                                  ["control", "design", "--a", "25", "--b", "3", "--controller", "pi"]])
def test_commands_print_under_an_ascii_locale(argv, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONIOENCODING", "PYTHONUTF8", "LANG", "LC_CTYPE")}
    env.update(LC_ALL="C", PYTHONUTF8="0", PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "motorid", *[a.format(tmp=tmp_path) for a in argv]],
                          capture_output=True, env=env, timeout=600)
    # before: "internal error: UnicodeEncodeError: 'ascii' codec can't encode character '\xe9'", exit 1
    assert done.returncode == 0, done.stderr.decode("ascii", "replace")
    assert done.stdout.isascii() and done.stderr.isascii() and b"Error" not in done.stderr
