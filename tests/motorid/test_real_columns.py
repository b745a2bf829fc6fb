"""Columns as real files bring them: a time in ms with no unit, a column named by its unit, a robot log
with several wrong names, a command logged just after the state it answers."""
from __future__ import annotations

import json

import numpy as np
import pytest

from motorid.cli import main
from motorsim import Motor
from motorsim.plant import simulate
from tests.real_like import LAB_A, LAB_B, write_lab_csv


def _steps() -> np.ndarray:
    u = np.zeros(3000)
    u[500:1500], u[1500:2500] = 6.0, 3.0
    return u


def test_a_time_in_ms_without_a_unit_is_refused_naming_the_column(tmp_path, capsys):
    # before: read as s, 'a 0.0119984 1/s ... sample period 2 s ... a clear choice' for a = 12
    path = write_lab_csv(tmp_path / "lab_millis.csv", _steps(), time_unit="ms", dt=2e-3)
    assert main(["identify", str(path), "--time", "time", "--input", "voltage:V", "--speed", "speed_rad_s"]) == 2
    err = capsys.readouterr().err
    assert "the time column 'time' has no unit" in err and "give --time time:UNIT" in err
    assert main(["identify", str(path), "--time", "time:ms", "--input", "voltage:V", "--speed", "speed_rad_s",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["sample_period"] == pytest.approx(2e-3)
    # the coarse encoder on a jittered clock: a within 5 % of 12 (its interval is the default's to judge)
    assert doc["a"] == pytest.approx(LAB_A, rel=0.05)


def test_a_time_in_seconds_without_a_unit_is_read_so_and_said(tmp_path, capsys):
    path = write_lab_csv(tmp_path / "lab.csv", _steps(), dt=2e-3)
    out = tmp_path / "rec.csv"
    assert main(["import", str(path), "--time", "time", "--input", "voltage:V", "--speed", "speed_rad_s",
                 "--out", str(out)]) == 0
    assert "the time column 'time' has no unit: read in s, as its intervals (median 0.002) leave no doubt" in \
        capsys.readouterr().err


def test_a_robot_log_names_every_wrong_column_at_once(tmp_path, capsys):
    pytest.importorskip("wpiutil", reason="robotpy-wpiutil (the wpilib extra) is not installed")
    from tests.real_like import write_sysid_wpilog
    path = write_sysid_wpilog(tmp_path / "sysid.wpilog", pause=0.5)
    assert main(["import", str(path), "--time", "time_s", "--input", "voltage-left", "--speed", "velocity-left",
                 "--out", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert "2 problems with the columns" in err
    assert "no column named 'voltage-left' for the input" in err and "no column named 'velocity-left'" in err


def _late_log(path, shift: int) -> None:
    """A chirp whose command is written ``shift`` rows after the state it answers."""
    t = np.arange(4000) * 1e-3
    u = np.round(6 + 3 * np.sin(2 * np.pi * (0.5 + 5 * t) * t), 3)
    w = simulate(Motor(LAB_A, LAB_B), u, t).speed + np.random.default_rng(2).normal(0, 0.05, len(t))
    logged = np.r_[np.full(shift, u[0]), u[:len(u) - shift]]
    path.write_text("t_s,volts,w_rad_s\n" + "\n".join(f"{a:.4f},{b:.3f},{c:.5f}" for a, b, c in zip(t, logged, w))
                    + "\n")


def test_input_shift_moves_a_command_logged_after_its_state(tmp_path, capsys):
    path = tmp_path / "late.csv"
    _late_log(path, 1)
    flags = ["--time", "t_s", "--input", "volts", "--speed", "w_rad_s"]
    assert main(["identify", str(path), *flags]) == 2
    assert "--input-shift 1" in capsys.readouterr().err
    assert main(["identify", str(path), *flags, "--input-shift", "1", "--method", "oe", "--input-delay", "0",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    # 0.05 rad/s of noise on 4000 samples: within 3 standard errors
    assert abs(doc["a"] - LAB_A) <= 3 * doc["a_stderr"] and abs(doc["b"] - LAB_B) <= 3 * doc["b_stderr"]
    out = tmp_path / "shifted.csv"
    assert main(["import", str(path), *flags, "--input-shift", "1", "--out", str(out)]) == 0
    assert "# input_shift_rows: 1" in out.read_text()


def test_input_shift_is_bounded(tmp_path, capsys):
    path = tmp_path / "late.csv"
    _late_log(path, 1)
    status = main(["identify", str(path), "--time", "t_s", "--input", "volts", "--speed", "w_rad_s",
                   "--input-shift", "100000"])
    assert status == 2
    assert "input shift must be a whole number of rows in -10000...10000, got 100000" in capsys.readouterr().err
