"""motorid frequency: the table, the models against the data's bound, the distortion, the Bode plot."""
import json

import numpy as np
import pytest

from identify.checks.design import design_multisine
from identify.frequency.frequency_estimate import frequency_response
from motorid.cli import main
from motorsim import Encoder, Experiment, Motor, SimRig, read_recording


def _simulate(tmp_path, name, *extra):
    path = tmp_path / name
    assert main(["simulate", "--a", "25", "--b", "3", "--angle-noise", "0.001", "--duration", "15.36",
                 "--out", str(path), *extra]) == 0
    return path


def test_frequency_of_two_realisations_with_friction_names_the_distortion(tmp_path, capsys):
    runs = [_simulate(tmp_path, f"ms{s}.csv", "--excitation", f"odd-multisine:512,63,20,{s}", "--friction", "40",
                      "--seed", str(s)) for s in (1, 2)]
    assert main(["identify", str(runs[0]), "--method", "oe", "--save", str(tmp_path / "oe.json")]) == 0
    capsys.readouterr()
    plot = tmp_path / "bode.png"
    assert main(["frequency", *map(str, runs), "--model", str(tmp_path / "oe.json"), "--plot", str(plot),
                 "--json"]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    assert doc["frequency_response"]["method"] == "bla"
    assert not doc["distortion"]["linear"] and "oe-friction" in doc["distortion"]["summary"]
    assert doc["models"][0]["name"] == "oe"
    assert "odd-order distortion above the noise" in err and "gain dB" in err
    assert plot.stat().st_size > 10_000


def test_frequency_of_the_articles_sines_matches_the_truth(tmp_path, capsys):
    runs = [_simulate(tmp_path, f"s{w}.csv", "--sine", f"{w},200,0.3") for w in (10, 20, 30, 40)]
    capsys.readouterr()
    assert main(["frequency", *map(str, runs), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["frequency_response"]["method"] == "sines" and len(doc["frequency_response"]["omega"]) == 4
    assert doc["distortion"] is None
    frf = frequency_response([read_recording(p) for p in runs])
    assert np.all(frf.covers(frf.model_response(25.0, 3.0)))


def test_a_model_of_another_sample_period_is_refused(tmp_path, capsys):
    run = _simulate(tmp_path, "p.csv", "--prbs", "200,-200,10")
    other = _simulate(tmp_path, "q.csv", "--prbs", "200,-200,10", "--sample-period", "0.01")
    assert main(["identify", str(other), "--save", str(tmp_path / "m.json")]) == 0
    assert main(["frequency", str(run), "--model", str(tmp_path / "m.json")]) == 2
    assert "sample period" in capsys.readouterr().err


def test_identify_report_has_a_bode_panel(tmp_path):
    run = _simulate(tmp_path, "p.csv", "--prbs", "200,-200,10")
    assert main(["identify", str(run), "--report", str(tmp_path / "r.png")]) == 0
    assert (tmp_path / "r.png").stat().st_size > 10_000


def test_design_recommends_a_multisine_that_reaches_its_predicted_precision(tmp_path, capsys):
    assert main(["design", "--a", "25", "--b", "3", "--sample-period", "0.005", "--counts-per-rev", "16667",
                 "--angle-noise", "0.001", "--no-plots", "--out", str(tmp_path)]) == 0
    assert "--excitation odd-multisine:" in capsys.readouterr().out
    d = design_multisine(25.0, 3.0, 0.005, angle_noise=1e-3)
    errors = []
    for seed in range(5):
        rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(seed))
        frf = frequency_response(rig.run(Experiment(d.excitation, 0.005, d.duration)))
        errors.append(np.abs(frf.response / frf.model_response(25.0, 3.0) - 1))
    worst_rms = np.sqrt(np.mean(np.square(errors), axis=0)).max()
    assert worst_rms == pytest.approx(d.line_stderr, rel=0.5)


def test_bench_frequency_prints_the_ratio(capsys):
    assert main(["bench", "frequency", "--samples", "20000", "--segment", "512", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    assert "ratio" in out and "largest relative difference" in out


def test_the_header_names_the_input_unit_not_duty(capsys):
    data = "tests/data/undcmotor/DCmotor_prbs_open_exp.csv"
    assert main(["frequency", data, "--time", "t:s", "--input", "u:V", "--speed", "y:deg/s"]) == 0
    out = capsys.readouterr().out
    assert "frequency response input (V) -> speed" in out and "duty" not in out


def test_a_step_is_refused_by_frequency_and_has_no_bode_panel_in_the_report(tmp_path, capsys):
    run = _simulate(tmp_path, "step.csv", "--excitation", "step:150,1.0")
    assert main(["frequency", str(run)]) == 2
    assert "the input is not stationary" in capsys.readouterr().err
    report = tmp_path / "report.png"
    assert main(["identify", str(run), "--method", "oe", "--report", str(report)]) == 0
    assert "(no Bode panel: the input is not stationary" in capsys.readouterr().out and report.exists()
