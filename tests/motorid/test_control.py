"""motorid control design, motorid simulate --controller, and the demo's closed-loop part."""
import json
import math

import numpy as np
import pytest

from motorid.cli import main
from motorsim import read_recording
from motorsim.control import PlantModel, design_controller, tracking_error


def test_control_design_prints_the_fixed_point_gains_and_plots(tmp_path, capsys):
    png = tmp_path / "pred.png"
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--time-constant", "0.03",
                 "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    gains = design_controller("pi", PlantModel(25.0, 3.0, 0.005, 16667), time_constant=0.03).gains()
    assert f"kp = {gains['kp']}, ki = {gains['ki']}" in out and "(stable)" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("argv, message", [
    (["--controller", "mpc"], "give the model: --a and --b"),
    (["--a", "25", "--b", "3", "--controller", "position", "--duty-weight", "1"], "--duty-weight does not apply"),
    (["--a", "25", "--b", "3", "--controller", "mpc", "--reference", "sine:10"], "FREQ,AMP"),
    (["--a", "-1", "--b", "3", "--controller", "mpc"], "a must be"),
], ids=["no-model", "wrong-knob", "bad-reference", "bad-a"])
def test_control_design_errors_name_the_flag(argv, message, capsys):
    assert main(["control", "design", *argv]) == 2
    assert message in capsys.readouterr().err


def test_simulate_closed_loop_writes_reference_and_settings(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--controller", "mpc", "--duty-weight", "2e-4",
                 "--reference", "sine:10,10", "--duration", "2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    rec = read_recording(out)
    assert rec.reference is not None and rec.metadata["controller"] == "mpc"
    assert rec.metadata["controller_duty_weight"] == "0.0002"
    measured, predicted = (float(x) for x in text.split("measured ")[1].split(" rad/s")[0].split(", predicted "))
    assert measured == pytest.approx(predicted, rel=0.10)
    assert main(["simulate", "--a", "25", "--b", "3", "--sine", "10", "--controller", "pi", "--out", str(out)]) == 2
    assert "exclude each other" in capsys.readouterr().err


@pytest.mark.parametrize("kind, reference, unit", [("lqr", "sine:10,10", "rad/s"),
                                                   ("lqr-position", "trapezoid:3,0.3,0.5,0.1", "rad")])
def test_lqr_is_designed_simulated_and_predicted_from_the_command_line(kind, reference, unit, tmp_path, capsys):
    common = ["--a", "25", "--b", "3", "--input-delay", "1", "--controller", kind, "--reference", reference,
              "--duration", "1.5"]
    assert main(["control", "design", *common]) == 0
    text = capsys.readouterr().out
    gains = design_controller(kind, PlantModel(25.0, 3.0, 0.005, 16667, input_delay=1)).gains()
    assert "fixed-point gains (Q16): " + ", ".join(f"{k} = {v}" for k, v in gains.items()) in text
    assert "(stable)" in text and "margins at the point estimate: gain margin" in text
    out = tmp_path / "run.csv"
    assert main(["simulate", *common, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert read_recording(out).metadata["controller"] == kind
    measured, predicted = (float(x) for x in text.split("measured ")[1].split(f" {unit}")[0].split(", predicted "))
    assert measured == pytest.approx(predicted, rel=0.10)


def test_demo_closed_loop_part_follows_the_unchanged_open_loop_table(tmp_path, capsys):
    argv = ["demo", "--duration", "4", "--methods", "euler-ls,oe", "--no-plots"]
    assert main([*argv, "--no-control", "--out", str(tmp_path / "a")]) == 0
    open_loop = capsys.readouterr().out
    assert main([*argv, "--out", str(tmp_path / "b")]) == 0
    full = capsys.readouterr().out
    assert full.replace(str(tmp_path / "b"), str(tmp_path / "a")).startswith(open_loop)
    rows = {line.split()[0]: [float(x) for x in line.split()[1:]]
            for line in (tmp_path / "b" / "closed_loop.txt").read_text().splitlines()[2:]}
    assert set(rows) == {"truth", "euler-ls", "oe"}
    # oe's model is the truth to 1e-4: its prediction holds to the encoder's quantisation
    assert rows["oe"][4] == pytest.approx(1.0, abs=0.01)
    # the article's biased a and b mispredict their own loop by more than 5 %
    assert abs(rows["euler-ls"][4] - 1.0) > 0.05
    assert read_recording(tmp_path / "b" / "closed_loop_oe.csv").metadata["controller"] == "mpc"


def test_live_runs_a_controller_on_the_device_and_keeps_the_reference(tmp_path, capsys):
    out = tmp_path / "live.csv"
    assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--controller", "pi", "--a", "25", "--b", "3",
                 "--reference", "step:10,0.1", "--duration", "1", "--out", str(out), "--quiet"]) == 0
    rec = read_recording(out)
    assert rec.metadata["controller"] == "pi" and rec.metadata["host_duty_mismatches"] == "0"
    # the reference is quantised to 1/16 count per sample: 1 / (16 x 13.26) = 0.0047 rad/s
    assert rec.reference is not None and rec.reference[-1] == pytest.approx(10.0, abs=0.005)
    assert abs(rec.measured_speed()[-50:].mean() - 10.0) < 0.1   # PI: no steady error (encoder 0.075 rad/s)
    capsys.readouterr()
    assert main(["live", "--port", "fake://?speed=0", "--controller", "pi", "--duration", "1",
                 "--out", str(out), "--quiet"]) == 2
    assert "give the model the controller is designed from" in capsys.readouterr().err


def test_live_takes_counts_per_rev_from_the_device_and_refuses_a_contradiction(tmp_path, capsys):
    out = tmp_path / "live.csv"
    port = "fake://?a=25&b=3&speed=0&counts_per_rev=1200"
    assert main(["live", "--port", port, "--duration", "0.5", "--out", str(out), "--quiet"]) == 0
    assert read_recording(out).counts_per_rev == 1200
    capsys.readouterr()
    assert main(["live", "--port", port, "--counts-per-rev", "16667", "--duration", "0.5", "--out", str(out),
                 "--quiet"]) == 2
    assert "counts_per_rev 16667 was given but the device" in capsys.readouterr().err


def test_control_design_from_a_saved_model_matches_the_same_numbers_given_as_flags(tmp_path, capsys):
    # identify --save writes the model; control design --model must design exactly what --a/--b
    # with the saved values design (gains are integers, so equality is exact).
    run, model = tmp_path / "run.csv", tmp_path / "model.json"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "4", "--out", str(run)]) == 0
    assert main(["identify", str(run), "--input-delay", "0", "--save", str(model)]) == 0
    capsys.readouterr()
    saved = json.loads(model.read_text())
    assert main(["control", "design", "--model", str(model), "--controller", "pi"]) == 0
    from_file = capsys.readouterr().out
    assert main(["control", "design", "--a", repr(saved["a"]), "--b", repr(saved["b"]), "--controller", "pi"]) == 0
    from_flags = capsys.readouterr().out
    gains = [line for line in from_file.splitlines() if line.startswith("fixed-point gains")]
    assert gains and gains == [line for line in from_flags.splitlines() if line.startswith("fixed-point gains")]


@pytest.mark.filterwarnings("default::motorsim.control.DesignLimitWarning")
def test_control_design_lengthens_a_time_constant_the_delay_cannot_take_and_says_so(capsys):
    fast = ["control", "design", "--a", "25", "--b", "3", "--input-delay", "1", "--controller", "pi",
            "--time-constant", "0.01"]
    assert main(fast) == 0
    captured = capsys.readouterr()
    assert "motorid: warning: pi time_constant 0.01 s leaves a phase margin of 6.05 deg" in captured.err
    assert "designed with time_constant 0.026 s" in captured.err
    assert "controller: pi time_constant = 0.026," in captured.out
    assert "phase margin 60.1 deg" in captured.out
    assert main([*fast, "--min-phase-margin", "0"]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err and "phase margin 6.05 deg" in captured.out
    assert main([*fast, "--min-phase-margin", "200"]) == 2
    assert "min_phase_margin must be in 0...180 deg, got 200.0" in capsys.readouterr().err
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "mpc", "--min-phase-margin", "45"]) == 2
    assert "--min-phase-margin does not apply to --controller mpc" in capsys.readouterr().err


def test_lqr_integral_from_a_saved_model_leaves_no_steady_error_on_a_bench_the_model_does_not_know(tmp_path, capsys):
    run, model = tmp_path / "run.csv", tmp_path / "model.json"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--sine", "10,200,0", "--out", str(run)]) == 0
    assert main(["identify", str(run), "--method", "oe", "--save", str(model)]) == 0
    assert main(["control", "design", "--model", str(model), "--controller", "lqr-integral",
                 "--integral-weight", "50", "--repetitions", "5"]) == 0
    out = capsys.readouterr().out
    assert "controller: lqr-integral duty_weight = 0.001, integral_weight = 50.0" in out and ", ki = " in out
    steady = {}
    for kind in ("lqr", "lqr-integral"):      # the bench: b 20 % higher and a bias the model lacks
        rec = tmp_path / f"{kind}.csv"
        assert main(["simulate", "--a", "25", "--b", "3.6", "--bias", "-20", "--model", str(model), "--controller",
                     kind, "--reference", "constant:10", "--duration", "2", "--out", str(rec)]) == 0
        steady[kind] = float(np.mean(tracking_error(read_recording(rec))[-200:]))
    assert abs(steady["lqr-integral"]) < 0.01 and abs(steady["lqr"]) > 0.2      # measured: 0.0004 and 0.36 rad/s
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "lqr", "--integral-weight", "5"]) == 2
    assert "--integral-weight does not apply to --controller lqr" in capsys.readouterr().err


def test_control_design_refuses_a_file_that_is_not_a_saved_model(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert main(["control", "design", "--model", str(bad), "--controller", "pi"]) == 2
    assert "not a saved model" in capsys.readouterr().err


def test_control_design_prints_margins_and_the_robustness_of_a_saved_model(tmp_path, capsys):
    import numpy as np

    from identify import fit
    from motorid.cli import main
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rec = SimRig(Motor(25.0, 3.0, input_delay=1), Encoder(angle_noise=2e-3),
                 rng=np.random.default_rng(1)).run(Experiment(Sine(10.0), 0.005, 1.0))
    path = tmp_path / "model.json"
    path.write_text(fit(rec, method="oe", input_delay=1).to_json())
    fragile = ["--time-constant", "0.01", "--min-phase-margin", "0"]     # 6 degrees of phase margin with the delay
    assert main(["control", "design", "--model", str(path), "--controller", "pi", *fragile,
                 "--repetitions", "30"]) == 0
    out = capsys.readouterr().out
    assert "margins at the point estimate: gain margin" in out and "Monte Carlo: 30 plants" in out
    assert "warning:" in out and "badly damped" in out
    assert main(["control", "design", "--model", str(path), "--controller", "pi", *fragile,
                 "--repetitions", "30", "--robust"]) == 0
    out = capsys.readouterr().out
    assert "time_constant = 0.01," not in out and "warning:" not in out
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--robust"]) == 2
    assert "--robust needs the model's covariance" in capsys.readouterr().err


@pytest.fixture
def volt_model(tmp_path):
    """A model fitted to the UNDCMotor PRBS run, its input in V with a 12 V drive."""
    rec = tmp_path / "prbs.csv"
    assert main(["import", "tests/data/undcmotor/DCmotor_prbs_open_exp.csv", "--time", "t:s", "--input", "u:V",
                 "--speed", "y:deg/s", "--input-limit", "12", "--out", str(rec)]) == 0
    model = tmp_path / "model.json"
    assert main(["identify", str(rec), "--method", "oe", "--save", str(model)]) == 0
    return model


def test_a_volt_model_carries_its_unit_and_limit_into_the_saved_model(volt_model):
    doc = json.loads(volt_model.read_text())
    assert doc["units"]["input"] == "V" and doc["input_limit"] == 12


def test_control_design_speaks_the_model_unit_and_warns_beyond_its_limit(volt_model, capsys):
    capsys.readouterr()
    argv = ["control", "design", "--model", str(volt_model), "--controller", "pi", "--time-constant", "0.05",
            "--reference", "sine:10,50"]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert "(rad/s^2)/V" in out and "input limit +-12 V" in out and "(rad/s^2)/duty" not in out
    assert "more than the input limit +-12 V" in err
    assert main([*argv, "--input-limit", "100"]) == 0
    assert "input limit" not in capsys.readouterr().err


def test_feedforward_design_prints_no_empty_pole_list_as_stable(capsys):
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "feedforward"]) == 0
    out = capsys.readouterr().out
    assert "closed-loop poles:  (stable)" not in out and "closed-loop poles: none" in out


@pytest.mark.parametrize("command", [["simulate", "--a", "25", "--b", "3", "--out", "x.csv"],
                                     ["live", "--port", "fake://?a=25&b=3", "--out", "x.csv"]])
def test_a_rig_controller_refuses_a_model_not_in_duty(volt_model, capsys, tmp_path, command):
    argv = [*command, "--controller", "pi", "--model", str(volt_model), "--reference", "sine:10,10"]
    argv[argv.index("x.csv")] = str(tmp_path / "x.csv")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "its input is in V" in err and "duty" in err and not (tmp_path / "x.csv").exists()


def test_a_model_fitted_to_a_speed_column_assumes_no_encoder(volt_model, capsys):
    # the volt model was fitted to a tachometer's deg/s column: no encoder to assume, no firmware gains
    assert main(["control", "design", "--model", str(volt_model), "--controller", "pi"]) == 0
    captured = capsys.readouterr()
    assert "assuming" not in captured.err and "counts/rev" not in captured.out
    assert "speed sensor (the model was fitted to a speed column)" in captured.out
    assert main(["control", "design", "--model", str(volt_model), "--controller", "pi", "--counts-per-rev",
                 "1000"]) == 0
    captured = capsys.readouterr()
    assert "assuming" not in captured.err and "the rig's encoder 1000 counts/rev" in captured.out


@pytest.mark.parametrize("flags, named", [
    (["--reference", "step:5"], "--reference applies"),
    (["--model", "m.json"], "--model applies"),
    (["--time-constant", "0.1", "--duty-weight", "1e-3"], "--duty-weight, --time-constant apply"),
    (["--integral-weight", "50"], "--integral-weight applies"),
    (["--min-phase-margin", "45"], "--min-phase-margin applies"),
    (["--feedforward"], "--feedforward applies"),
    (["--derivative", "false"], "--derivative applies"),
], ids=["reference", "model", "tuning", "integral-weight", "min-phase-margin", "feedforward", "derivative"])
@pytest.mark.parametrize("command", [["simulate", "--a", "25", "--b", "3"], ["live", "--port", "fake://?a=25&b=3"]],
                         ids=["simulate", "live"])
def test_controller_flags_without_a_controller_are_refused_by_name(command, flags, named, tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main([*command, *flags, "--duration", "0.2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert named + " only with --controller" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("flags, named", [(["--a", "25", "--b", "3"], "--a, --b apply"),
                                          (["--friction", "0.5"], "--friction applies"),
                                          (["--bias", "1"], "--bias applies"),
                                          (["--input-delay", "1"], "--input-delay applies")],
                         ids=["a-b", "friction", "bias", "input-delay"])
def test_live_refuses_the_design_model_flags_without_a_controller(flags, named, tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["live", "--port", "fake://?a=25&b=3", *flags, "--duration", "0.2", "--out", str(out)]) == 2
    assert named + " only with --controller" in capsys.readouterr().err and not out.exists()


def test_simulate_keeps_its_bench_flags_and_the_default_reference_of_a_controller(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--friction", "0.5", "--input-delay", "1", "--duration", "0.2",
                 "--out", str(out)]) == 0
    assert main(["simulate", "--a", "25", "--b", "3", "--controller", "pi", "--duration", "0.2", "--out",
                 str(out)]) == 0
    assert read_recording(out).metadata["reference"] == "sine:10.0,10.0,0.0"


@pytest.fixture(scope="module")
def backwards_model(tmp_path_factory):
    """A motor wired backwards (b = -3), identified correctly and saved."""
    folder = tmp_path_factory.mktemp("backwards")
    run, model = folder / "run.csv", folder / "model.json"
    assert main(["simulate", "--a", "25", "--b", "-3", "--duration", "4", "--out", str(run)]) == 0
    assert main(["identify", str(run), "--method", "oe", "--input-delay", "0", "--save", str(model)]) == 0
    return model


@pytest.mark.parametrize("kind", ["pi", "lqr", "mpc"])
def test_control_design_of_a_motor_wired_backwards_ends_robustly(backwards_model, kind, capsys):
    assert main(["control", "design", "--model", str(backwards_model), "--controller", kind, "--robust",
                 "--repetitions", "20", "--counts-per-rev", "16667"]) == 0
    out = capsys.readouterr().out
    assert "b = -3" in out and "unstable 0 %" in out and "warning:" not in out


def test_control_design_says_when_the_uncertainty_does_not_know_the_motors_direction(backwards_model, tmp_path,
                                                                                     capsys):
    doc = json.loads(backwards_model.read_text())
    doc["b"], doc["covariance"] = 3.0, [[1.0, 0.0], [0.0, 96.0]]      # P(b <= 0) = 38 %
    wide = tmp_path / "wide.json"
    wide.write_text(json.dumps(doc))
    assert main(["control", "design", "--model", str(wide), "--controller", "pi", "--counts-per-rev", "16667"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if "smallest margins" in x)
    other = float(line.split("b of the other sign ")[1].split(" %")[0])
    unstable = float(line.split("unstable ")[1].split(" %")[0])
    # 100 draws of a 38 % share: 4 binomial standard deviations (4.9 points each) either side
    assert abs(other - 38) < 20 and unstable >= other
    assert "warning: " in out and "does not know which way the motor turns" in out


def test_a_model_fitted_to_counts_says_which_encoder_the_design_assumes(tmp_path, capsys):
    run, model = tmp_path / "run.csv", tmp_path / "model.json"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--out", str(run)]) == 0
    assert main(["identify", str(run), "--method", "oe", "--input-delay", "0", "--save", str(model)]) == 0
    capsys.readouterr()
    assert main(["control", "design", "--model", str(model), "--controller", "pi"]) == 0
    captured = capsys.readouterr()
    assert "assuming" not in captured.err and "the model's encoder 16667 counts/rev" in captured.out
    doc = json.loads(model.read_text())
    del doc["counts_per_rev"]                      # a model that does not say its encoder: the bench's, said
    model.write_text(json.dumps(doc))
    assert main(["control", "design", "--model", str(model), "--controller", "pi"]) == 0
    assert "assuming 16667 counts/rev (give --counts-per-rev N)" in capsys.readouterr().err


def test_the_default_reference_is_in_the_models_range_and_speed_unit(volt_model, capsys):
    # the model's data came in deg/s with a 12 V limit: top speed b/a x 12 V (1726 deg/s measured);
    # a third of it, to 2 significant figures, in deg/s, instead of a 10 rad/s sine that barely moves it
    assert main(["control", "design", "--model", str(volt_model), "--controller", "pi"]) == 0
    captured = capsys.readouterr()
    saved = json.loads(volt_model.read_text())
    top = math.degrees(saved["b"] / saved["a"] * 12)
    amplitude = float(f"{top / 3:.2g}")
    assert f"--reference sine:10,{amplitude:g}deg/s" in captured.err
    assert f"of sine:10,{amplitude:g}deg/s (sine:10.0,{math.radians(amplitude)!r},0.0 rad/s)" in captured.out


@pytest.mark.parametrize("spec,si", [("step:1500rpm", 1500 * 2 * math.pi / 60), ("step:2.5rev/s,0.5", 5 * math.pi),
                                     ("constant:90deg/s", math.pi / 2), ("step:7.5", 7.5)])
def test_a_reference_takes_units(spec, si, capsys):
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--reference", spec]) == 0
    out = capsys.readouterr().out
    kind = spec.split(":")[0]
    assert f"of {spec} ({kind}:{si!r}" in out or f"of {kind}:{si!r}" in out


def test_a_reference_in_the_wrong_kind_of_unit_is_refused(capsys):
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--reference",
                 "step:90deg"]) == 2
    assert "'90deg' is a position, but this controller tracks a speed" in capsys.readouterr().err


def test_a_model_in_percent_designs_within_its_full_scale_by_default(tmp_path, capsys):
    # before: no limit was assumed for %, the default reference sine:10,10 rad/s and a note; a slow motor's design
    # then asked for 115 % of the duty. A percentage's limit is its full scale: the reference is a third of the top
    # speed b/a x 100 %, and the design stays within it.
    from identify import Estimate
    est = Estimate(method="oe", a=2.0, b=0.05, n_samples=2000, sample_period=0.005, residual_rms=0.01,
                   fit_percent=99.0, covariance=np.diag([1e-4, 1e-8]), input_unit="%")
    model = tmp_path / "pct.json"
    model.write_text(est.to_json())
    assert main(["control", "design", "--model", str(model), "--controller", "pi"]) == 0
    captured = capsys.readouterr()
    assert "input limit +-100 %" in captured.out
    largest = float(captured.out.split("largest input ")[1].split(" %")[0])
    assert 0 < largest <= 100
    assert "more than the input limit" not in captured.err and "no input limit known" not in captured.err


def test_a_volt_model_without_a_limit_is_refused_naming_the_flag(tmp_path, capsys):
    # before: designed with a note only ('no input limit known for a model in V'), its reference sine:10,10
    # chosen blind; a volt model's limit is the drive's supply, which only the user knows
    from identify import Estimate
    est = Estimate(method="oe", a=12.0, b=200.0, n_samples=2000, sample_period=0.001, residual_rms=0.1,
                   fit_percent=99.0, covariance=np.diag([1e-4, 1e-2]), input_unit="V")
    model = tmp_path / "volts.json"
    model.write_text(est.to_json())
    argv = ["control", "design", "--model", str(model), "--controller", "pi"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("motorid: error: --input-limit must be given for a model in V") and err.count("\n") == 1
    assert main([*argv, "--input-limit", "12"]) == 0
    captured = capsys.readouterr()
    largest = float(captured.out.split("largest input ")[1].split(" V")[0])
    assert "input limit +-12 V" in captured.out and 0 < largest <= 12
    assert "more than the input limit" not in captured.err


@pytest.mark.parametrize("argv, unit, limit", [
    (["--a", "2", "--b", "0.05", "--controller", "position"], "duty", 255.0),
    (["--a", "2", "--b", "0.05", "--controller", "lqr-position"], "duty", 255.0)])
def test_a_default_design_is_slowed_until_it_stays_within_the_input_limit(capsys, argv, unit, limit):
    # before: a slow motor's position loop by default asked for 16 220 duty (lqr-position 313 % of a % model's
    # scale) with a warning only; the knob left to its default is stepped until the prediction fits the limit
    assert main(["control", "design", *argv]) == 0
    captured = capsys.readouterr()
    largest = float(captured.out.split("largest input ")[1].split(f" {unit}")[0])
    assert 0 < largest <= limit
    assert "slowed until the design stays within it" in captured.err
    assert "more than the input limit" not in captured.err
    knob = "--time-constant" if "position" == argv[-1] else "--duty-weight"
    default = {"--time-constant": "0.05", "--duty-weight": "1e-06"}[knob]
    assert main(["control", "design", *argv, knob, default]) == 0          # a knob given is kept, and warned of
    assert "more than the input limit" in capsys.readouterr().err
