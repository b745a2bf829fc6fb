"""Hostile flags and recordings on the command line: one line, status 2, nothing silently believed."""
from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from motorid.cli import main


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "r.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "5", "--out", str(path)]) == 0
    return path


def _error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return err


def _system_exit(capsys, argv) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("argv, said", [
    (["control", "design", "--a", "25", "--b", "0", "--controller", "pi"], "b must be nonzero"),
    (["control", "design", "--a", "25", "--b", "3", "--controller", "mpc", "--reference", "step:1e308"],
     "reference"),
    (["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--sample-period", "1e-9"],
     "--sample-period"),
    (["live", "--port", "fake://?a=25&b=3&speed=0", "--sample-period", "1e-6", "--duration", "1", "--quiet"],
     "sample_period"),
    (["live", "--port", "fake://?a=25&b=3&speed=0", "--watchdog-ms", "-5", "--duration", "1", "--quiet"],
     "watchdog_ms"),
    (["live", "--port", "", "--duration", "1", "--quiet"], "port"),
    (["simulate", "--a", "25", "--b", "3", "--sine", "", "--out", "x.csv"], "--sine"),
    (["simulate", "--a", "25", "--b", "3", "--step", "", "--out", "x.csv"], "--step"),
    (["simulate", "--a", "25", "--b", "3", "--excitation", "", "--out", "x.csv"], "--excitation"),
], ids=["b=0", "step 1e308", "sample period 1e-9", "live 1 MHz", "negative watchdog", "empty port",
        "empty sine", "empty step", "empty excitation"])
def test_a_hostile_flag_is_one_line_with_status_2(tmp_path, capsys, monkeypatch, argv, said):
    monkeypatch.chdir(tmp_path)
    err = _error(capsys, argv)
    assert said in err
    assert not (tmp_path / "x.csv").exists()


def test_b_zero_in_a_saved_model_is_a_user_error(tmp_path, capsys):
    from identify.estimate import Estimate
    model = tmp_path / "m.json"
    import json
    doc = json.loads(Estimate(method="oe", a=25.0, b=3.0, n_samples=10, sample_period=0.005, residual_rms=0.0,
                              fit_percent=99.0).to_json())
    model.write_text(json.dumps({**doc, "b": 0.0}))
    assert "b must be nonzero" in _error(capsys, ["control", "design", "--controller", "pi", "--model", str(model)])


@pytest.mark.parametrize("argv, said", [
    (["simulate", "--a", "25", "--b", "3", "--seed", "-1", "--out", "x.csv"], "--seed must be an integer >= 0"),
    (["simulate", "--a", "25", "--b", "3", "--duration", "inf", "--out", "x.csv"], "duration must be a finite"),
    (["simulate", "--a", "٢٥", "--b", "3", "--out", "x.csv"], "a must be a number"),
], ids=["seed -1", "infinite duration", "Arabic-Indic digits"])
def test_a_malformed_number_is_named_as_such(tmp_path, capsys, monkeypatch, argv, said):
    monkeypatch.chdir(tmp_path)
    assert said in _system_exit(capsys, argv)


def _edit(recording: Path, tmp_path: Path, row: int, column: int, value: str, name: str = "edited.csv") -> Path:
    lines = recording.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("seq"))
    cells = lines[header + 1 + row].split(",")
    cells[column] = value
    lines[header + 1 + row] = ",".join(cells)
    out = tmp_path / name
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.mark.parametrize("value", ["100", "-200", "300", "1e6"])
def test_one_corrupted_duty_cell_is_refused_and_dropped_with_drop_outliers(recording, tmp_path, capsys, value):
    path = _edit(recording, tmp_path, 400, 2, value)
    err = _error(capsys, ["identify", str(path)])
    assert "seq 400" in err and "duty" in err
    assert main(["identify", str(path), "--drop-outliers", "--json"]) == 0
    import json
    out = json.loads(capsys.readouterr().out)
    assert out["dropped_samples"] == {str(path): [400]}
    assert out["a"] == pytest.approx(25.0, rel=1e-3)


def test_a_non_ascii_digit_in_a_recording_is_refused_at_its_line(recording, tmp_path, capsys):
    path = _edit(recording, tmp_path, 10, 3, "١٢")
    assert "ASCII" in _error(capsys, ["identify", str(path)])


@pytest.mark.parametrize("lines", [["# counts_per_rev: 1000"], ["# ppr: 1000"], ["# sample_period: 0.005"],
                                   ["# dt: 0.004"]],
                         ids=["counts_per_rev twice", "ppr alias", "sample_period twice", "dt alias"])
def test_a_metadata_key_given_twice_or_by_alias_is_refused(recording, tmp_path, capsys, lines):
    text = recording.read_text().splitlines()
    path = tmp_path / "twice.csv"
    path.write_text("\n".join([text[0], *lines, *text[1:]]) + "\n")
    assert "given" in _error(capsys, ["identify", str(path)])


def test_a_duty_clipped_at_its_limit_is_reported_with_its_samples(tmp_path, capsys):
    path = tmp_path / "sat.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--sine", "10,300", "--out", str(path)]) == 0
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("always")           # as on the command line: shown, not raised
        assert main(["identify", str(path)]) == 0
    err = capsys.readouterr().err
    assert "clipped at its limit" in err and "samples" in err


@pytest.mark.parametrize("method", [[], ["--method", "oe"]], ids=["default", "oe"])
def test_the_json_counts_the_samples_at_the_limit_and_says_they_stay_in_the_fit(tmp_path, capsys, method):
    import json

    from motorsim.reading import read_recording
    path = tmp_path / "sat.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--sine", "10,300", "--out", str(path)]) == 0
    n = read_recording(path).saturated_samples()
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert main(["identify", str(path), "--json", *method]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert n > 0 and out["saturated_samples"] == {str(path): n}
    assert out["n_samples"] == 2000 and out["a"] == pytest.approx(25.0, rel=1e-3)
    assert "stay in the fit" in captured.err
    if not method:
        assert any(note.startswith(f"{n} of the 2000 samples") and "kept in the fit" in note for note in out["notes"])


@pytest.mark.parametrize("delay", ["500", "2000"])
def test_an_input_delay_the_file_cannot_hold_is_refused_by_name(recording, capsys, delay):
    err = _error(capsys, ["identify", str(recording), "--input-delay", delay])
    assert f"input_delay {delay}" in err and "too short" not in err


def test_a_time_base_scaled_by_1e_300_is_refused(recording, tmp_path, capsys):
    lines = recording.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("seq"))
    out = [line for line in lines[:header] if not line.startswith(("# sample_period", "# dt"))] + [lines[header]]
    for line in lines[header + 1:]:
        c = line.split(",")
        c[1] = repr(float(c[1]) * 1e-300)
        out.append(",".join(c))
    path = tmp_path / "tiny.csv"
    path.write_text("\n".join(out) + "\n")
    assert "sample_period" in _error(capsys, ["identify", str(path)])


@pytest.fixture(scope="module")
def encoder_run():
    from motorsim import Experiment, Motor, SimRig, Sine
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 5.0))
    return rec, rec.counts - rec.counts[0]


def _lab_file(tmp_path: Path, encoder_run, per_rev: float) -> Path:
    rec, counts = encoder_run
    path = tmp_path / "lab.csv"
    path.write_text("t,u,theta\n" + "".join(f"{float(t)!r},{int(u)},{float(a)!r}\n" for t, u, a in
                                             zip(rec.time, rec.duty, counts * per_rev / 16667)))
    return path


def test_an_angle_column_in_degrees_read_as_radians_is_refused_naming_the_column_and_the_flag(
        tmp_path, capsys, encoder_run):
    path = _lab_file(tmp_path, encoder_run, 360.0)
    err = _error(capsys, ["identify", str(path), "--time", "t", "--input", "u:duty", "--angle", "theta"])
    assert "the angle column 'theta', read as rad" in err and "16667 per 360" in err
    assert "give --angle theta:deg" in err and len(err.strip().splitlines()) == 1
    assert main(["identify", str(path), "--time", "t", "--input", "u:duty", "--angle", "theta:deg", "--json"]) == 0
    import json
    out = json.loads(capsys.readouterr().out)
    assert out["b"] == pytest.approx(3.0, rel=1e-3)


def test_an_angle_stated_in_radians_that_reads_as_degrees_is_fitted_with_a_note(tmp_path, capsys, encoder_run):
    path = _lab_file(tmp_path, encoder_run, 360.0)
    assert main(["identify", str(path), "--time", "t", "--input", "u:duty", "--angle", "theta:rad"]) == 0
    assert "stated in rad: it moves only in exact steps" in capsys.readouterr().err


def test_an_angle_in_radians_is_neither_refused_nor_doubted(tmp_path, capsys, encoder_run):
    import math
    path = _lab_file(tmp_path, encoder_run, 2 * math.pi)
    assert main(["identify", str(path), "--time", "t:s", "--input", "u:duty", "--angle", "theta", "--json"]) == 0
    captured = capsys.readouterr()
    # no doubt about the column's unit (the part checks' "angle torque" line names the angle as a torque's)
    assert "column theta" not in captured.err and "degrees" not in captured.err
    import json
    assert json.loads(captured.out)["b"] == pytest.approx(3.0, rel=1e-3)


def test_a_recordings_angle_rad_column_in_degrees_is_said(tmp_path, capsys, encoder_run):
    import dataclasses

    from motorsim.writing import write_recording
    rec, counts = encoder_run
    path = write_recording(dataclasses.replace(rec, counts=None, angle=counts * 360 / 16667), tmp_path / "r.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("always")           # as on the command line: shown, not raised
        assert main(["identify", str(path)]) == 0
    assert "column angle_rad: it moves only in exact steps" in capsys.readouterr().err


# --- the simulated bench's numbers: a range each, said in its help, refused in one line before anything runs ------

@pytest.mark.parametrize("extra, said", [
    (["--a", "4.3e9"], ("--a times --sample-period", "1e-09...700", "4300000000.0", "a h = 2.15e+07")),
    (["--a", "1e-10"], ("--a times --sample-period", "1e-09...700", "1e-10", "a h = 5e-13")),
    (["--b", "4.3e11"], ("--b", "within 100000 rad/s", "430000000000.0", "4.39e+12 rad/s")),
    (["--b", "1e-300"], ("--b", "at least one count", "1e-300")),
    (["--bias=-1e9"], ("--bias", "within 100000 rad/s", "-1000000000.0", "4e+07 rad/s")),
    (["--friction", "1e9"], ("--friction", "at most a x 100000 rad/s", "1000000000.0")),
    (["--friction", "1", "--static-friction", "1e9"], ("--static-friction", "at most a x 100000", "1000000000.0")),
    (["--initial-speed=-2e5"], ("--initial-speed", "+-100000 rad/s", "-200000.0")),
    (["--angle-noise", "1e11"], ("--angle-noise", "at most 6.28319 rad", "100000000000.0")),
    (["--dead-zone", "300"], ("--dead-zone", "at most 255", "300.0")),
    (["--electrical-time-constant", "1e12"], ("--electrical-time-constant", "1e-06...700", "1000000000000.0")),
    (["--electrical-time-constant", "1e-300"], ("--electrical-time-constant", "1e-06...700", "1e-300")),
    (["--sample-period", "1e-300"], ("--sample-period", "1e-06...4294.97 s", "1e-300")),
    (["--duration", "1e12"], ("--duration", "under 2**32 samples", "1000000000000.0")),
], ids=["a-4.3e9", "a-h-1e-12", "b-huge", "b-tiny", "bias", "friction", "static-friction", "initial-speed",
        "angle-noise", "dead-zone", "lag-long", "lag-short", "sample-period", "duration"])
def test_simulate_refuses_a_bench_number_past_its_range_naming_flag_rule_and_value(tmp_path, capsys, extra, said):
    # before: each wrote a recording (a pole of 4.3e9 1/s at 5 ms moved no count; b = 4.3e11 turned the shaft at
    # 4e12 rad/s), or named no flag (a sample period of 1e-300 s and a run of 1e12 s: "would need 2.2e+288 PiB")
    out = tmp_path / "r.csv"
    err = _error(capsys, ["simulate", "--a", "25", "--b", "3", *extra, "--out", str(out)])
    line = err.strip().splitlines()[-1]
    assert line.startswith("motorid: error: ") and all(s in line for s in said), line
    assert not out.exists()


@pytest.mark.parametrize("extra", [["--controller", "pi"], ["--sine", "10,100"]], ids=["closed loop", "open loop"])
def test_the_range_holds_in_closed_loop_and_for_the_demo(tmp_path, capsys, extra):
    err = _error(capsys, ["simulate", "--a", "4.3e9", "--b", "3", *extra, "--out", str(tmp_path / "r.csv")])
    assert "--a times --sample-period" in err
    err = _error(capsys, ["demo", "--b", "4.3e11", "--out", str(tmp_path / "demo"), "--no-plots", "--no-control"])
    assert "--b must keep the top speed of the run" in err and not (tmp_path / "demo").exists()


@pytest.mark.parametrize("extra", [
    ["--a", "140000"], ["--a", "2.1e-7"], ["--a", "2.1e-7", "--b", "390"], ["--b", "1960"], ["--bias=-2.5e6"],
    ["--electrical-time-constant", "7.2e-6"], ["--angle-noise", "6.28"], ["--dead-zone", "255"],
    ["--initial-speed", "1e5"],
], ids=["a h 700", "a h 1e-9", "a h 1e-9 near the top speed", "top speed 1e5", "bias at the top speed",
        "lag h/700", "noise of a turn", "dead zone 255", "initial speed 1e5"])
def test_simulate_takes_a_bench_number_at_the_edge_of_its_range(tmp_path, extra):
    out = tmp_path / "r.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "1", *extra, "--out", str(out)]) == 0
    assert out.exists()


def test_simulate_help_says_each_bench_range(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for rule in ("a x --sample-period within 1e-09...700",
                 "abs(b) x the duty limit x (1 - exp(-a T)) / a at most 100000 rad/s",
                 "--sample-period / it within 1e-06...700", "at most 6.28319 rad (one turn)", "1e-06...4294.97 s",
                 "2 samples to 2**32 samples", "abs(initial speed) at most 100000 rad/s"):
        assert rule in text, rule
