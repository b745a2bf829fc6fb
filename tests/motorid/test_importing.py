"""``motorid import`` and ``motorid identify FILE --time ... --speed ...`` on the lab's own files."""
import json
import math
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from motorid.cli import main
from motorsim.reading import read_recording

DATA = Path(__file__).parents[1] / "data" / "undcmotor"
PRBS = str(DATA / "DCmotor_prbs_open_exp.csv")
STEP = str(DATA / "DCmotor_step_open_exp.csv")
COLUMNS = ["--time", "t:s", "--input", "u:V", "--speed", "y:deg/s"]


def test_import_writes_a_recording_in_si_units(tmp_path, capsys):
    out = tmp_path / "prbs.csv"
    assert main(["import", PRBS, *COLUMNS, "--out", str(out)]) == 0
    assert "wrote 4093 samples (sample period 0.02 s, input in V)" in capsys.readouterr().err
    rec = read_recording(out)
    t, u, y = np.loadtxt(PRBS, delimiter=",", skiprows=1, unpack=True)
    assert rec.sample_period == 0.02 and rec.input_unit == "V" and rec.metadata["source"] == Path(PRBS).name
    np.testing.assert_allclose(rec.time, t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec.duty, u, rtol=1e-12)
    np.testing.assert_allclose(rec.speed, np.deg2rad(y), rtol=1e-12)


def test_import_by_index_from_a_headerless_tsv(tmp_path):
    t, u, y = np.loadtxt(STEP, delimiter=",", skiprows=1, unpack=True)
    src = tmp_path / "step.tsv"
    np.savetxt(src, np.column_stack([t * 1e6, u, y / 360]), delimiter="\t")
    assert main(["import", str(src), "--time", "0:µs", "--input", "1:V", "--speed", "2:rev/s",
                 "--out", str(tmp_path / "step.csv")]) == 0
    rec = read_recording(tmp_path / "step.csv")
    np.testing.assert_allclose(rec.speed, np.deg2rad(y), rtol=1e-12)
    assert rec.sample_period == pytest.approx(0.02, rel=1e-12)


def test_import_refusal_names_the_file_and_rule(tmp_path, capsys):
    assert main(["import", PRBS, "--time", "t:s", "--input", "u:V", "--speed", "w:deg/s",
                 "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "DCmotor_prbs_open_exp.csv: no column named 'w' for the speed (columns: t, u, y" in err


def test_identify_needs_time_and_input_with_a_foreign_file(capsys):
    assert main(["identify", PRBS, "--speed", "y:deg/s"]) == 2
    assert "needs --time COL[:UNIT] and --input COL[:UNIT]" in capsys.readouterr().err


def test_readme_real_motor_figures_reproduce_end_to_end(tmp_path, capsys):
    """The README's UNDCMotor figures, by its documented commands, on the lab's files as they are.

    The fit is deterministic, so the tolerance is the README's rounding (half a unit of the last
    printed digit): 94.3 % fit, b/a = 157.6 (deg/s)/V, 95.1 % on the held-out step run, one
    sample of input delay.  Both routes (import then identify, and identify on the lab's
    file directly) give the same numbers.
    """
    shutil.copy(PRBS, tmp_path / "prbs_lab.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)   # the motor never reverses: c merges into d (said)
        assert main(["import", PRBS, *COLUMNS, "--out", str(tmp_path / "prbs.csv")]) == 0
        assert main(["import", STEP, *COLUMNS, "--out", str(tmp_path / "step.csv")]) == 0
        capsys.readouterr()
        assert main(["identify", str(tmp_path / "prbs.csv"), "--method", "oe-friction", "--input-delay", "auto",
                     "--validate", str(tmp_path / "step.csv"), "--json"]) == 0
        via_import = json.loads(capsys.readouterr().out)
        assert main(["identify", PRBS, *COLUMNS, "--method", "oe-friction", "--input-delay", "auto",
                     "--validate", STEP, "--json"]) == 0
        direct = json.loads(capsys.readouterr().out)
    for res in (via_import, direct):
        assert res["fit_percent"] == pytest.approx(94.3, abs=0.05)
        assert math.degrees(res["static_gain"]) == pytest.approx(157.6, abs=0.05)      # (deg/s)/V
        assert res["validation_fit_percent"] == pytest.approx(95.1, abs=0.05)
        assert res["input_delay"] == 1 and res["input_unit"] == "V"
    assert via_import["a"] == pytest.approx(direct["a"], rel=1e-9)


_UNIT_NAMED = "time_ms,u_pct,speed_rpm\n0,10,0\n10,10,100\n20,20,200\n30,20,250\n40,20,300\n"


@pytest.mark.parametrize("flags,column,unit", [
    (["--time", "time_ms", "--input", "u_pct:%", "--speed", "speed_rpm:rpm"], "time_ms", "ms"),
    (["--time", "time_ms:ms", "--input", "u_pct", "--speed", "speed_rpm:rpm"], "u_pct", "%"),
    (["--time", "time_ms:ms", "--input", "u_pct:%", "--speed", "speed_rpm"], "speed_rpm", "rpm"),
], ids=["time_ms", "u_pct", "speed_rpm"])
def test_a_column_named_with_a_unit_but_given_without_one_is_read_in_it_and_said(tmp_path, capsys, flags, column,
                                                                                  unit):
    src = tmp_path / "lab.csv"
    src.write_text(_UNIT_NAMED)
    assert main(["import", str(src), *flags, "--out", str(tmp_path / "rec.csv")]) == 0
    assert f"column {column!r} is read in {unit}, the unit its header states" in capsys.readouterr().err
    rec = read_recording(tmp_path / "rec.csv")
    assert rec.sample_period == 0.01 and rec.input_unit == "%" and rec.speed_unit == "rpm"
    assert rec.speed[1] == pytest.approx(100 * 2 * math.pi / 60, rel=1e-12)


def test_a_column_named_rpm_is_read_in_rpm_and_said(tmp_path, capsys):
    # a column named by its unit alone says it: 'rpm' was refused as unitless before
    src = tmp_path / "lab.csv"
    src.write_text("t_ms,pwm_pct,rpm\n0,10,0\n10,10,100\n20,20,200\n")
    assert main(["import", str(src), "--time", "t_ms:ms", "--input", "pwm_pct:%", "--speed", "rpm",
                 "--out", str(tmp_path / "rec.csv")]) == 0
    assert "the speed column 'rpm' is read in rpm, the unit its header states" in capsys.readouterr().err
    rec = read_recording(tmp_path / "rec.csv")
    assert rec.speed_unit == "rpm" and rec.speed[1] == pytest.approx(100 * 2 * math.pi / 60, rel=1e-12)


def test_the_unit_named_columns_import_with_their_units(tmp_path):
    src = tmp_path / "lab.csv"
    src.write_text(_UNIT_NAMED)
    assert main(["import", str(src), "--time", "time_ms:ms", "--input", "u_pct:%", "--speed", "speed_rpm:rpm",
                 "--out", str(tmp_path / "rec.csv")]) == 0
    rec = read_recording(tmp_path / "rec.csv")
    assert rec.sample_period == pytest.approx(0.01) and rec.input_unit == "%"


def test_identify_on_a_file_that_is_not_a_recording_names_the_column_flags_and_import(tmp_path, capsys):
    src = tmp_path / "lab.csv"
    src.write_text("t,u,y\n0,1,0\n0.01,1,1\n0.02,1,2\n")
    assert main(["identify", str(src)]) == 2
    err = capsys.readouterr().err
    for hint in ("--time", "--input", "--speed", "motorid import"):
        assert hint in err, hint


def _rpm_lab_file(tmp_path):
    """A lab's ``t_ms, pwm_pct, rpm`` file of the simulated motor a = 25 1/s, b = 3 (rad/s^2)/duty."""
    run = tmp_path / "sim.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "4", "--prbs", "200,-200,9,3", "--record-speed",
                 "--out", str(run)]) == 0
    rec = read_recording(run)
    lab = tmp_path / "lab.csv"
    rows = [f"{t * 1000:.3f},{u / 255 * 100:.9f},{w * 60 / (2 * math.pi):.9f}"
            for t, u, w in zip(rec.time, rec.duty, rec.speed)]
    lab.write_text("t_ms,pwm_pct,rpm\n" + "\n".join(rows) + "\n")
    return lab


def test_a_model_fitted_in_rpm_shows_and_saves_rpm_beside_si(tmp_path, capsys):
    from identify.estimate import Estimate
    lab, model = _rpm_lab_file(tmp_path), tmp_path / "model.json"
    capsys.readouterr()
    assert main(["identify", str(lab), "--time", "t_ms", "--input", "pwm_pct", "--speed", "rpm:rpm",
                 "--input-limit", "100", "--json", "--save", str(model)]) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    # truth: b/a = 3/25 (rad/s)/duty = 0.306 (rad/s)/% = 2.9221 rpm/%; the noise-free data give it to 1e-6
    truth = 3 / 25 * 255 / 100 * 60 / (2 * math.pi)
    assert doc["units"]["speed"] == "rpm" and doc["in_speed_unit"]["unit"] == "rpm"
    assert doc["in_speed_unit"]["static_gain"] == pytest.approx(truth, rel=1e-6)
    assert doc["static_gain"] == pytest.approx(truth * 2 * math.pi / 60, rel=1e-6)        # SI stays SI
    assert doc["in_speed_unit"]["top_speed"] == pytest.approx(100 * truth, rel=1e-6)
    assert "in rpm      b/a 2.92" in captured.err and "rpm/%" in captured.err
    saved = Estimate.from_json(model.read_text())
    assert saved.speed_unit == "rpm" and json.loads(model.read_text())["units"]["speed"] == "rpm"
