"""Hostile cases of the third round: no data lost, no hang, no confident wrong answer, one clear line.

Each case ran as a user would run it, through ``motorid.cli.main``; each failed before the
change it tests (a file replaced, a traceback, a silently wrong number) and now ends in a
right answer or one ``motorid: error:`` line naming the parameter, the rule and the value.
"""
from __future__ import annotations

import math
import os
import stat

import pytest

from motorid.cli import main
from motorsim import Experiment, Motor, SimRig, Sine, write_recording
from tests.recording_files import rewrite_column


@pytest.fixture(scope="module")
def rec_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "r.csv"
    write_recording(SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 4.0)), path)
    return path


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("motorid: error:"), err
    return err[-1]


# --- data lost: every output waits for the whole command to succeed ---------------------------------

def test_a_failed_validation_leaves_the_saved_model_unchanged(rec_path, tmp_path, capsys):
    model, bad = tmp_path / "m.json", tmp_path / "bad.csv"
    model.write_text('{"old": 1}\n')
    bad.write_text("x,y\n1,2\n")
    assert main(["identify", str(rec_path), "--save", str(model), "--validate", str(bad)]) == 2
    assert model.read_text() == '{"old": 1}\n'
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]      # no temporary file left either


def test_two_outputs_of_one_command_may_not_name_one_file(rec_path, tmp_path, capsys):
    out = tmp_path / "out.png"
    assert main(["identify", str(rec_path), "--save", str(out), "--report", str(out)]) == 2
    assert "--save" in _error(capsys) and not out.exists()


def test_a_sweep_never_overwrites_its_own_scenario_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    scenario = 'name = "tiny"\nrepetitions = 1\nmethods = ["zoh-ls"]\n[bench]\nduration = 0.5\n' \
               '[grid]\n"excitation.frequency" = [10]\n'
    (tmp_path / "summary.json").write_text(scenario)
    assert main(["sweep", "summary.json", "--out", ".", "--quiet", "--no-plots"]) == 2
    assert "summary.json" in _error(capsys)
    assert (tmp_path / "summary.json").read_text() == scenario


def test_an_output_named_as_an_input_is_refused_even_when_it_is_written_late(tmp_path):
    from motorsim.files import OutputFileError, deferred_outputs, write_atomically
    scenario = tmp_path / "summary.json"
    scenario.write_text("x")
    with pytest.raises(OutputFileError, match="input of this command"), deferred_outputs([scenario]):
        write_atomically(tmp_path / "." / "summary.json", "y")
    assert scenario.read_text() == "x"


def test_demo_refuses_a_link_planted_at_its_table(tmp_path, capsys):
    target = tmp_path / "elsewhere.txt"
    target.write_text("precious")
    out = tmp_path / "o"
    out.mkdir()
    (out / "table.json").symlink_to(target)
    assert main(["demo", "--out", str(out), "--no-plots", "--no-control", "--duration", "1",
                 "--frequencies", "10", "--methods", "euler-ls"]) == 2
    assert "table.json" in _error(capsys) and target.read_text() == "precious"


def test_a_replaced_file_keeps_its_permission_bits(rec_path, tmp_path, capsys):
    model = tmp_path / "m.json"
    model.write_text("{}")
    model.chmod(0o600)
    assert main(["identify", str(rec_path), "--save", str(model)]) == 0
    assert stat.S_IMODE(model.stat().st_mode) == 0o600 and "motorid estimate" in model.read_text()


def test_the_live_figure_is_replaced_never_written_through_a_link(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    target = tmp_path / "elsewhere.png"
    target.write_bytes(b"precious")
    out = tmp_path / "r.csv"
    (tmp_path / "r.csv.live.png").symlink_to(target)
    assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet", "--plot",
                 "--out", str(out)]) == 2
    assert "symbolic link" in _error(capsys) and target.read_bytes() == b"precious"
    os.unlink(tmp_path / "r.csv.live.png")
    assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet", "--plot",
                 "--out", str(out)]) == 0
    assert (tmp_path / "r.csv.live.png").read_bytes()[:4] == b"\x89PNG"


def test_live_plot_onto_a_fifo_is_refused_before_the_run(tmp_path, capsys):
    os.mkfifo(tmp_path / "r.csv.live.png")
    assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet", "--plot",
                 "--out", str(tmp_path / "r.csv")]) == 2
    assert "FIFO" in _error(capsys) and not (tmp_path / "r.csv").exists()


def test_a_failed_live_run_with_overwrite_keeps_the_complete_recording(tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet",
                 "--out", str(out)]) == 0
    before = out.read_bytes()
    assert main(["live", "--port", "fake://?speed=0&disconnect_at=50", "--duration", "1", "--quiet",
                 "--out", str(out), "--overwrite"]) == 2
    line = _error(capsys)
    assert out.read_bytes() == before and "unchanged" in line
    partial = tmp_path / "r.csv.partial"
    assert "complete: false" in partial.read_text() and str(partial) in line


def test_a_partial_file_being_written_is_not_called_an_earlier_run(tmp_path, capsys):
    from motorsim.files import OutputFileError
    from motorsim.writing import RecordingWriter
    with RecordingWriter(tmp_path / "r.csv", 0.005, 1000):
        with pytest.raises(OutputFileError, match="being written by another run"):
            RecordingWriter(tmp_path / "r.csv", 0.005, 1000)


def test_a_default_live_name_taken_meanwhile_moves_on(tmp_path, monkeypatch, capsys):
    import motorid.commands.live as live
    from motorsim.writing import RecordingWriter
    monkeypatch.chdir(tmp_path)
    taken = live.default_out_path()
    names = iter([taken])
    real = live.default_out_path
    monkeypatch.setattr(live, "default_out_path", lambda now=None: next(names, None) or real(now))
    with RecordingWriter(taken, 0.005, 1000):       # the other run, still in its handshake when the name was chosen
        assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "recording to" in err and taken not in err.split("recording to", 1)[1].split()[0]


# --- hangs: inputs that are not regular files ------------------------------------------------------

def test_bench_parse_refuses_a_fifo_instead_of_waiting_for_a_writer(tmp_path, capsys):
    os.mkfifo(tmp_path / "fifo")
    assert main(["bench", "parse", "--file", str(tmp_path / "fifo"), "--repeats", "1"]) == 2
    assert "FIFO" in _error(capsys)


def test_bench_parse_names_a_file_that_is_not_a_recording(tmp_path, capsys):
    pytest.importorskip("pandas")
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n1,2\n")
    assert main(["bench", "parse", "--file", str(bad), "--repeats", "1"]) == 2
    assert "--file" in (line := _error(capsys)) and "time_s" in line


def test_a_benchmark_reads_back_its_scratch_recording(capsys):
    # a benchmark declares no outputs: its scratch files are moved into place at once, for its readers
    pytest.importorskip("pandas")
    assert main(["bench", "parse", "--rows", "2000", "--repeats", "1"]) in (0, 1)    # 1: a speed goal missed
    assert ", 2000 rows" in capsys.readouterr().out


# --- benchmark flags: each count and list checked where it is parsed -------------------------------

@pytest.mark.parametrize("argv, flag", [
    (["parse", "--repeats", "0"], "--repeats"),
    (["parse", "--rows", "0"], "--rows"),
    (["simulate", "--samples", "0"], "--samples"),
    (["accuracy", "--sample-periods", "0"], "--sample-periods"),
    (["accuracy", "--poles", "-4"], "--poles"),
    (["accuracy", "--poles", "4,,25"], "--poles"),
    (["frequency", "--segment", "1"], "--segment"),
], ids=["parse-repeats-0", "parse-rows-0", "simulate-samples-0", "accuracy-sample-periods-0", "accuracy-poles-neg",
        "accuracy-poles-empty-item", "frequency-segment-1"])
def test_benchmark_flags_are_checked_where_they_are_parsed(argv, flag, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["bench", *argv])
    assert exit_.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"argument {flag}: must be" in line and repr(argv[-1]) in line


# --- silently accepted: each now refused naming the flag, the rule and the value -------------------

@pytest.fixture(scope="module")
def lab_path(rec_path, tmp_path_factory):
    from motorsim import read_recording
    rec = read_recording(rec_path)
    path = tmp_path_factory.mktemp("lab") / "lab.csv"
    angle = rec.counts * 2 * 3.141592653589793 / rec.counts_per_rev
    rows = (f"{float(t)!r},{int(u)},{float(y)!r}\n" for t, u, y in zip(rec.time, rec.duty, angle))
    path.write_text("t,u,y\n" + "".join(rows))
    return path


@pytest.mark.parametrize("flags, roles", [
    (["import", "--time", "t", "--input", "y:duty", "--speed", "y:rad/s"], ("input", "speed")),
    (["import", "--time", "t", "--input", "u:duty", "--speed", "t:rad/s"], ("time", "speed")),
    (["import", "--time", "t", "--input", "u:duty", "--speed", "y:rad/s", "--angle", "2:rad"], ("speed", "angle")),
    (["identify", "--time", "t", "--input", "u:duty", "--speed", "y:rad/s", "--angle", "y:rad"], ("speed", "angle")),
], ids=["input-and-speed", "time-and-speed", "speed-and-angle-by-index", "identify-speed-and-angle"])
def test_one_column_in_two_roles_is_refused(lab_path, tmp_path, flags, roles, capsys):
    out = ["--out", str(tmp_path / "x.csv")] if flags[0] == "import" else []
    assert main([flags[0], str(lab_path), *flags[1:], *out]) == 2
    line = _error(capsys)
    assert all(f"--{role}" in line for role in roles) and "one role" in line and "problems" not in line


@pytest.fixture(scope="module")
def model_text(rec_path, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.json"
    assert main(["identify", str(rec_path), "--method", "oe", "--save", str(path)]) == 0
    return path.read_text()


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace('"a":', '"a": 30, "a":', 1), "'a' twice"),
    (lambda t: t.replace('"covariance": [', '"covariance": [[1e400, 0], [0, 1]], "x": [', 1), "1e400"),
    (lambda t: t.replace('"input": "duty"', '"input": ""', 1), "units.input"),
], ids=["duplicate-key", "covariance-1e400", "empty-input-unit"])
def test_a_model_file_that_does_not_say_one_thing_is_refused(model_text, tmp_path, edit, match, capsys):
    text = edit(model_text)
    assert text != model_text
    path = tmp_path / "bad.json"
    path.write_text(text)
    assert main(["control", "design", "--model", str(path), "--controller", "pi"]) == 2
    assert match in _error(capsys)


def test_fix_bias_holds_the_bias_at_zero_in_the_default_fit_too(rec_path):
    from identify import fit
    from motorsim import read_recording
    rec = read_recording(rec_path)
    structures = {c.structure for c in fit(rec, fix_bias=True).selection.candidates}
    assert "bias" in {c.structure for c in fit(rec).selection.candidates} and "bias" not in structures


@pytest.mark.parametrize("argv, match", [
    (["simulate", "--a", "25", "--b", "3", "--controller", "pi", "--reference", "sine:10,10@"], "OFFSET, got none"),
    (["demo", "--frequencies", ""], "--frequencies"),
    (["demo", "--frequencies", "10,,20"], "--frequencies"),
], ids=["reference-empty-offset", "demo-no-frequency", "demo-empty-frequency"])
def test_an_empty_item_is_refused_not_skipped(argv, match, tmp_path, capsys):
    out = ["--out", str(tmp_path / ("o.csv" if argv[0] == "simulate" else "o"))]
    assert main([*argv, *out]) == 2
    assert match in _error(capsys) and not (tmp_path / "o.csv").exists() and not (tmp_path / "o").exists()


# --- tracebacks and misleading messages: one range check where each number enters -------------------

@pytest.mark.parametrize("extra, names", [
    (["--a", "25", "--b", "1e-308"], ("b", "1e-308")),
    (["--a", "25", "--b", "3", "--reference", "step:1,1e308"], ("at_time", "1e+308")),
    (["--a", "25", "--b", "3", "--duration", "0.001"], ("--duration", "0.001")),
    (["--a", "25", "--b", "3", "--sample-period", "1e6", "--duration", "1e7"], ("--sample-period", "1000000.0")),
], ids=["b-1e-308", "step-at-1e308", "duration-0.001", "sample-period-1e6"])
@pytest.mark.parametrize("controller", ["mpc", "pi", "lqr-position"])
def test_control_design_numbers_are_range_checked(extra, names, controller, capsys):
    assert main(["control", "design", "--controller", controller, *extra]) == 2
    line = _error(capsys)
    assert all(n in line for n in names), line


def test_a_model_with_a_1e308_is_refused_and_its_feedforward_never_infinite(model_text, tmp_path, capsys):
    import json

    from identify.estimate import Estimate
    from identify.feedforward import feedforward_constants
    doc = json.loads(model_text)
    path = tmp_path / "big.json"
    path.write_text(json.dumps({**doc, "a": 1e308}))
    assert main(["control", "design", "--model", str(path), "--controller", "feedforward"]) == 2
    assert "a must be finite and within" in _error(capsys)
    ff = feedforward_constants(Estimate.from_json(path.read_text()))
    low, high = ff.confidence_interval()["kv"]
    assert all(math.isfinite(x) for x in (ff.kv, low, high)) and low < ff.kv < high and "inf" not in ff.describe()


def test_an_input_in_tiny_units_is_refused_by_its_scale(rec_path, tmp_path, capsys):
    lines = rec_path.read_text().splitlines()
    header = [k for k, line in enumerate(lines) if line.startswith("seq")][0]
    rows = [line.split(",") for line in lines[header + 1:]]
    body = [",".join([r[0], r[1], repr(float(r[2]) * 1e-300), *r[3:]]) for r in rows]
    tiny = tmp_path / "tiny.csv"
    tiny.write_text("\n".join(lines[:header + 1] + body) + "\n")
    assert main(["identify", str(tiny)]) == 2
    assert "input's largest magnitude must be in" in _error(capsys)


def test_frequency_on_a_constant_input_says_so(tmp_path, capsys):
    from motorsim import Constant
    path = tmp_path / "c.csv"
    write_recording(SimRig(Motor(25.0, 3.0)).run(Experiment(Constant(100), 0.005, 2.0)), path)
    assert main(["frequency", str(path)]) == 2
    assert "the input does not change" in _error(capsys)


def test_validate_refuses_a_model_with_a_nan(rec_path):
    import dataclasses

    from identify import fit, validate
    from motorsim import read_recording
    rec = read_recording(rec_path)
    est = fit(rec, method="zoh-ls")
    with pytest.raises(ValueError, match="estimate.a must be finite, got nan"):
        validate(dataclasses.replace(est, a=math.nan), rec)


def test_a_scenario_nested_too_deep_is_one_line(tmp_path, capsys):
    path = tmp_path / "deep.toml"
    path.write_text('name = "x"\nv = ' + "[" * 5000 + "]" * 5000 + "\n")
    assert main(["sweep", str(path), "--quiet", "--out", str(tmp_path / "o")]) == 2
    assert "nested too deep" in _error(capsys)


def test_dask_names_an_address_that_is_none_without_contacting_anything(capsys):
    pytest.importorskip("dask.distributed")
    assert main(["sweep", "article", "--quiet", "--dask", "not-an-address"]) == 2
    line = _error(capsys)
    assert "HOST:PORT" in line and "'not-an-address'" in line and "protocol" not in line


# --- confident wrong answers: what the data contradict is refused, naming the contradiction --------

@pytest.mark.parametrize("method", ["auto", "oe"])
def test_an_input_logged_one_sample_late_is_refused(rec_path, tmp_path, method, capsys):
    late = rewrite_column(rec_path, tmp_path / "late.csv", "duty", lambda cells: ["0", *cells[:-1]])
    assert main(["identify", str(late), "--method", method]) == 2
    assert "answers its recorded input one sample before it" in _error(capsys)


def test_a_true_input_delay_is_still_found(tmp_path, capsys):
    from identify import fit
    rec = SimRig(Motor(25.0, 3.0, input_delay=1)).run(Experiment(Sine(10.0, 200), 0.005, 4.0))
    est = fit(rec)
    assert est.input_delay == 1 and est.a == pytest.approx(25.0, rel=1e-3)


@pytest.fixture(scope="module")
def speed_rec_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("speed") / "s.csv"
    write_recording(SimRig(Motor(25.0, 3.0), record_speed=True).run(Experiment(Sine(10.0, 200), 0.005, 4.0)), path)
    return path


@pytest.mark.parametrize("edit, factor", [
    (lambda p, out: out.write_text(p.read_text().replace("# counts_per_rev: 16667", "# counts_per_rev: 4167")),
     "0.25 x"),
    (lambda p, out: rewrite_column(p, out, "speed_rad_s", lambda cells: [repr(float(c) * 60 / (2 * math.pi))
                                                                   for c in cells]), "9.55 x"),
], ids=["counts-per-rev-4x-off", "speed-in-rpm"])
def test_a_speed_column_contradicting_the_counts_is_refused(speed_rec_path, tmp_path, edit, factor, capsys):
    assert main(["identify", str(speed_rec_path)]) == 0
    capsys.readouterr()
    bad = tmp_path / "bad.csv"
    edit(speed_rec_path, bad)
    assert main(["identify", str(bad)]) == 2
    line = _error(capsys)
    assert "speed_rad_s" in line and "counts" in line and factor in line


def test_a_logged_input_flat_while_the_speed_turns_is_refused(rec_path, tmp_path, capsys):
    flat = rewrite_column(rec_path, tmp_path / "flat.csv", "duty",
                    lambda cells: [str(max(-60, min(60, int(c)))) for c in cells])
    assert main(["identify", str(flat)]) == 2
    line = _error(capsys)
    assert "stays at 60 duty" in line or "stays at -60 duty" in line
    assert "rises" in line and "falls" in line


def test_a_time_unit_in_the_header_is_refused_not_ignored(rec_path, tmp_path, capsys):
    lines = rec_path.read_text().splitlines()
    text = "\n".join([lines[0], "# time_unit: ms", *lines[1:]]) + "\n"
    path = tmp_path / "ms.csv"
    path.write_text(text)
    assert main(["identify", str(path)]) == 2
    assert "time_unit must be 's'" in _error(capsys)


@pytest.mark.parametrize("noise", [0.0, 2e-3], ids=["clean", "angle-noise-2mrad"])
def test_the_late_input_check_refuses_a_late_log_and_passes_the_same_run_logged_right(noise):
    # measured: the residual shrinks 15 % with the input one sample earlier under 2 mrad of noise, tenfold clean
    import numpy as np

    from identify.checks.causality import check_input_leads
    from identify.errors import NotIdentifiableError
    from motorsim import Encoder
    from motorsim.recording import Recording
    rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=noise), rng=np.random.default_rng(1))
    rec = rig.run(Experiment(Sine(10.0, 200), 0.005, 10.0))
    late = Recording(time=rec.time, duty=np.r_[0.0, rec.duty[:-1]], sample_period=rec.sample_period,
                     counts=rec.counts, counts_per_rev=rec.counts_per_rev)
    check_input_leads([rec])
    with pytest.raises(NotIdentifiableError, match="one sample before it"):
        check_input_leads([late])
