"""Files as other tools write them: a European spreadsheet's export, a "Unicode text" export, a LabVIEW
measurement file, an Arduino serial monitor's log; each read to the recording the plain CSV gives.

Before, each was refused with a misleading line: ``column 't' must hold a finite number, got '0,005000'``,
``not a UTF-8 text file (invalid start byte at byte 0)``, ``column 'LabVIEW Measurement' must hold a finite
number, got 'Writer_Version'``, ``column '12:00:00.000 -> 0' must hold a finite number``, ``line 2: 3 cells
where the header has 1``.
"""
from __future__ import annotations

import numpy as np
import pytest

from motorid.cli import main
from motorsim import Motor
from motorsim.columns import import_recording
from motorsim.plant import simulate

_T = np.arange(400) * 0.005
_U = np.repeat(np.random.default_rng(0).integers(-200, 200, 8), 50).astype(float)
_W = simulate(Motor(25.0, 3.0), _U, _T).speed
_ROWS = list(zip(_T, _U, _W))


def _plain(tmp_path):
    path = tmp_path / "plain.csv"
    path.write_text("t,u,w\n" + "".join(f"{a:.6f},{b:g},{c:.6f}\n" for a, b, c in _ROWS))
    return import_recording(path, time="t:s", input="u:duty", speed="w:rad/s")


def _excel_european(path):
    text = "\ufefft;u;w\r\n" + "".join(f"{a:.6f};{b:g};{c:.6f}\r\n".replace(".", ",") for a, b, c in _ROWS)
    path.write_text(text, encoding="utf-8", newline="")


def _unicode_text(path):
    path.write_bytes(("\ufefft\tu\tw\r\n" + "".join(f"{a:.6f}\t{b:g}\t{c:.6f}\r\n" for a, b, c in _ROWS))
                     .encode("utf-16-le"))


def _labview(path):
    header = ("LabVIEW Measurement\t\nWriter_Version\t2\nReader_Version\t2\nSeparator\tTab\nDecimal_Separator\t.\n"
              "***End_of_Header***\t\n\nChannels\t2\t\nSamples\t400\t400\t\nX_Dimension\tTime\tTime\t\n"
              "Delta_X\t0.005\t0.005\t\n***End_of_Header***\t\t\t\nt\tu\tw\tComment\n")
    path.write_text(header + "".join(f"{a:.6f}\t{b:g}\t{c:.6f}\n" for a, b, c in _ROWS))


def _serial_monitor(path):
    path.write_text("".join(f"10:15:{a % 60:06.3f} -> {a:.6f},{b:g},{c:.6f}\n" for a, b, c in _ROWS))


def _with_preamble(path):
    path.write_text("Starting...\nMotor test v1\n" + "".join(f"{a:.6f},{b:g},{c:.6f}\n" for a, b, c in _ROWS))


@pytest.mark.parametrize("write, names", [(_excel_european, ("t", "u", "w")), (_unicode_text, ("t", "u", "w")),
                                          (_labview, ("t", "u", "w")), (_serial_monitor, ("0", "1", "2")),
                                          (_with_preamble, ("0", "1", "2"))],
                         ids=["excel-semicolon-decimal-comma", "utf16-unicode-text", "labview-lvm",
                              "arduino-serial-monitor", "preamble-lines"])
def test_a_file_as_its_tool_writes_it_reads_as_the_plain_csv(tmp_path, write, names):
    path = tmp_path / "file.txt"
    write(path)
    rec = import_recording(path, time=f"{names[0]}:s", input=f"{names[1]}:duty", speed=f"{names[2]}:rad/s")
    plain = _plain(tmp_path)
    np.testing.assert_array_equal(rec.time, plain.time)
    np.testing.assert_array_equal(rec.duty, plain.duty)
    np.testing.assert_array_equal(rec.speed, plain.speed)


def test_a_comma_inside_a_european_number_row_is_not_taken_for_thousands(tmp_path, capsys):
    # '1.234,5' (a thousands point) is no number motorid guesses at: refused naming the cell
    path = tmp_path / "thousands.csv"
    path.write_text("t;u;w\n0,000;1.234,5;0,1\n0,005;1.234,5;0,2\n")
    assert main(["identify", str(path), "--time", "t:s", "--input", "u:duty", "--speed", "w:rad/s"]) == 2
    err = capsys.readouterr().err
    assert "column 'u' must hold a finite number, got '1.234,5'" in err and err.count("\n") == 1


def test_two_rows_are_too_short_not_a_constant_input(tmp_path, capsys):
    path = tmp_path / "two.csv"
    path.write_text("t,u,w\n0,100,0\n0.005,100,1.5\n")
    assert main(["identify", str(path), "--time", "t:s", "--input", "u:duty", "--speed", "w:rad/s"]) == 2
    assert "recording is too short: 2 samples" in capsys.readouterr().err


def test_a_ros2_bag_identifies_and_saves_its_model(tmp_path, capsys):
    # before: the fit printed, then 'motorid: error: run: Is a directory' (the model's data_files hashed the bag
    # folder as a file) and no model was saved
    from tests.motorsim.test_robot_logs import _write_bag
    bag = tmp_path / "run"
    _write_bag(bag)
    model = tmp_path / "model.json"
    assert main(["identify", str(bag), "--time", "time_s", "--input", "/motor_cmd:V", "--speed",
                 "/joint_states/wheel/velocity", "--save", str(model)]) == 0, capsys.readouterr().err
    import json
    files = json.loads(model.read_text())["data_files"]
    assert [f["path"] for f in files] == [str(bag)] and len(files[0]["sha256"]) == 64
    before = files[0]["sha256"]
    (bag / "metadata.yaml").write_text((bag / "metadata.yaml").read_text() + "\n")
    from identify.model_file import file_sha256
    assert file_sha256(bag) != before           # the digest covers the bag's files


@pytest.mark.parametrize("share", [0.5, 0.31])
def test_a_wpilog_cut_while_written_is_answered_from_its_whole_records(tmp_path, capsys, share):
    # before: the reader took the cut record's bytes for one more value at the last one's time:
    # 'element 2156, column 'time_s' (time): time must be strictly increasing, got 14.775814 after 14.775814'
    pytest.importorskip("wpiutil", reason="robotpy-wpiutil (the wpilib extra) is not installed")
    from tests.real_like import FLY_A, write_sysid_wpilog
    whole = write_sysid_wpilog(tmp_path / "whole.wpilog").read_bytes()
    path = tmp_path / "cut.wpilog"
    path.write_bytes(whole[:int(len(whole) * share) + 3])
    status = main(["identify", str(path), "--time", "time_s", "--input", "voltage-drive", "--speed",
                   "velocity-drive", "--json"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert "the log ends inside a record" in captured.err
    import json
    doc = json.loads(captured.out)
    assert doc["a_ci95"][0] <= FLY_A <= doc["a_ci95"][1]


def test_a_sysid_wpilog_is_answered_by_the_command_with_no_flags(tmp_path, capsys):
    # before: 'line 1: contains a NUL byte (at byte 6): binary data or a corrupted file, not a recording: ... is
    # not a motorid recording'; SysId's entries say which is the voltage and which the velocity, with units
    pytest.importorskip("wpiutil", reason="robotpy-wpiutil (the wpilib extra) is not installed")
    import json
    import warnings

    from tests.real_like import write_sysid_wpilog
    path = write_sysid_wpilog(tmp_path / "sysid.wpilog")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        assert main(["identify", str(path), "--json"]) == 0
        plain = capsys.readouterr()
        assert main(["identify", str(path), "--time", "time_s", "--input", "voltage-drive", "--speed",
                     "velocity-drive", "--json"]) == 0
    flagged = json.loads(capsys.readouterr().out)
    assert "read as SysId's log of motor 'drive'" in plain.err
    assert json.loads(plain.out)["a"] == flagged["a"] and json.loads(plain.out)["b"] == flagged["b"]


def test_a_ros2_bag_with_no_flags_is_refused_naming_its_columns(tmp_path, capsys):
    from tests.motorsim.test_robot_logs import _write_bag
    bag = tmp_path / "run"
    _write_bag(bag)
    assert main(["identify", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "is a robot log, not a motorid recording: name its columns with --time time_s" in err
    assert "/joint_states/wheel/velocity" in err and "/motor_cmd" in err and err.count("\n") == 1


def _v1(tmp_path, capsys, edit) -> str:
    good = tmp_path / "good.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "1", "--out", str(good)]) == 0
    path = tmp_path / "edited.csv"
    path.write_text(edit(good.read_text()), encoding="utf-8")
    capsys.readouterr()
    assert main(["identify", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def test_a_recording_stating_an_impossible_encoder_is_refused(tmp_path, capsys):
    # before: counts_per_rev 99999999999999999999 was read, every speed 1e-16 of the truth: b = 5.0e-16, 'a clear
    # choice', exit 0
    err = _v1(tmp_path, capsys, lambda s: s.replace("counts_per_rev: 16667", "counts_per_rev: 99999999999999999999"))
    assert "counts_per_rev must be in 1...4294967296, got 99999999999999999999" in err


@pytest.mark.parametrize("rows", [1, 2])
def test_a_recording_of_one_or_two_rows_is_too_short(tmp_path, capsys, rows):
    # before: 'input is zero throughout' (1 row), 'the encoder count never changes (stuck at 0)' (2 rows)
    def cut(text):
        head, body = text.split("seq,time_s,duty,counts\n")
        return head + "seq,time_s,duty,counts\n" + "".join(body.splitlines(keepends=True)[:rows])
    assert f"recording is too short: {rows} samples" in _v1(tmp_path, capsys, cut)


def test_a_recording_saved_with_a_bom_is_told_so_not_called_a_foreign_file(tmp_path, capsys):
    err = _v1(tmp_path, capsys, lambda s: "\ufeff" + s)
    assert "byte-order mark (BOM)" in err and "is not a motorid recording" not in err
