"""Hostile cases of the fourth round: refusals name the file the data came from; one rule per boundary.

Each case ran as a user would run it (``motorid.cli.main`` or the Python API); each failed before
the change it tests (a message naming ``recordings[0]`` instead of the file, a traceback, a wrong
number with exit 0) and now ends in a right answer or one ``motorid: error:`` line naming the
file or parameter, the rule and the value.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from motorid.cli import main
from motorsim import Experiment, Motor, SimRig, Sine, read_recording, write_recording
from tests.recording_files import rewrite_column


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A plain run (counts) and one with a speed column too, written as files."""
    folder = tmp_path_factory.mktemp("runs")
    exp = Experiment(Sine(10.0, 200), 0.005, 4.0)
    write_recording(SimRig(Motor(25.0, 3.0)).run(exp), folder / "r.csv")
    write_recording(SimRig(Motor(25.0, 3.0), record_speed=True).run(exp), folder / "s.csv")
    return folder


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("motorid: error:"), err
    return err[-1]


# --- every refusal of the data names the file they came from ------------------------------------------

_BAD = {
    "input-logged-late": ("r.csv", "duty", lambda cells: ["0", *cells[:-1]], "one sample before it"),
    "input-flat-while-speed-turns": ("r.csv", "duty", lambda cells: [str(max(-60, min(60, int(c)))) for c in cells],
                                     "stays at"),
    "speed-in-rpm": ("s.csv", "speed_rad_s",
                     lambda cells: [repr(float(c) * 60 / (2 * math.pi)) for c in cells], "9.55 x"),
    "encoder-stuck": ("r.csv", "counts", lambda cells: ["5"] * len(cells), "never changes (stuck at 5)"),
}


@pytest.mark.parametrize("method", ["auto", "oe", "zoh-ls", "euler-ls", "iv"])
@pytest.mark.parametrize("case", list(_BAD))
def test_a_refusal_of_the_data_names_the_file_on_every_method(runs, tmp_path, case, method, capsys):
    source, column, change, rule = _BAD[case]
    bad = rewrite_column(runs / source, tmp_path / f"{case}.csv", column, change)
    assert main(["identify", str(bad), "--method", method]) == 2
    line = _error(capsys)
    assert line.startswith(f"motorid: error: {bad}: ") and rule in line and "recordings[" not in line


def test_the_python_api_names_the_file_a_recording_was_read_from(runs, tmp_path):
    import identify
    from identify.errors import NotIdentifiableError
    bad = rewrite_column(runs / "r.csv", tmp_path / "late.csv", "duty", lambda cells: ["0", *cells[:-1]])
    rec = read_recording(bad)
    assert rec.path == str(bad) and rec.slice(0, 100).path == str(bad) and rec.drop_rows([3]).path == str(bad)
    with pytest.raises(NotIdentifiableError, match=rf"^{bad}: the output answers"):
        identify.fit(rec)
    # a recording built in memory is still named by its place in the list
    built = type(rec)(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, counts=rec.counts,
                      counts_per_rev=rec.counts_per_rev)
    with pytest.raises(NotIdentifiableError, match=r"^recordings\[1\]: the output answers"):
        identify.fit([read_recording(runs / "r.csv"), built])


def test_a_corrupted_row_found_by_the_python_api_names_the_file(runs, tmp_path):
    import identify
    from identify.errors import CorruptedSamplesError
    bad = rewrite_column(runs / "r.csv", tmp_path / "jump.csv", "counts",
                   lambda cells: [str(int(c) + (10**7 if k == 100 else 0)) for k, c in enumerate(cells)])
    with pytest.raises(CorruptedSamplesError, match=rf"^{bad}: implausible"):
        identify.fit(read_recording(bad, check_samples=False))


def test_an_imported_lab_file_is_named_in_the_refusal(runs, tmp_path, capsys):
    rec = read_recording(runs / "r.csv")
    lab = tmp_path / "lab.csv"
    late = np.r_[0.0, rec.duty[:-1]]
    rows = zip(rec.time, late, rec.counts)
    lab.write_text("t,u,c\n" + "".join(f"{float(t)!r},{int(u)},{int(c)}\n" for t, u, c in rows))
    assert main(["identify", str(lab), "--time", "t", "--input", "u:duty", "--counts", "c",
                 "--counts-per-rev", str(rec.counts_per_rev)]) == 2
    assert _error(capsys).startswith(f"motorid: error: {lab}: the output answers")


def test_the_path_is_never_written_back(runs, tmp_path):
    rec = read_recording(runs / "r.csv")
    write_recording(rec, tmp_path / "copy.csv")
    assert str(runs) not in (tmp_path / "copy.csv").read_text()
    assert read_recording(tmp_path / "copy.csv").path == str(tmp_path / "copy.csv")


# --- pathological numbers: one clear line, or the right answer ----------------------------------------

def test_a_sample_period_below_the_devices_microsecond_is_refused(capsys):
    assert main(["control", "design", "--controller", "pi", "--a", "25", "--b", "3", "--sample-period", "1e-320"]) == 2
    line = _error(capsys)
    assert "--sample-period" in line and "1e-06" in line and "1e-320" in line


def test_a_duration_of_no_countable_samples_is_refused(tmp_path, capsys):
    from motorsim.checks import ParameterError
    from motorsim.rig import MAX_SAMPLES
    with pytest.raises(ParameterError, match="duration must be under"):
        Experiment(Sine(10.0, 200), 0.001, 1e308)
    assert MAX_SAMPLES * 0.001 > 3600 * 24 * 7           # a week at 1 kHz is still a run
    with pytest.raises(SystemExit) as stop:             # refused where the flag is parsed: past any bench
        main(["live", "--port", "fake://?a=25&b=3", "--duration", "1e308", "--quiet", "--out", str(tmp_path / "o.csv")])
    assert stop.value.code == 2
    assert "duration must be within" in capsys.readouterr().err and not (tmp_path / "o.csv").exists()
    assert main(["live", "--port", "fake://?a=25&b=3", "--duration", "1e11", "--quiet",
                 "--out", str(tmp_path / "o.csv")]) == 2
    assert "duration" in _error(capsys) and not (tmp_path / "o.csv").exists()


def test_a_phase_of_many_turns_is_the_phase_within_one_turn():
    dt, n = 0.005, 400
    far = Sine(10.0, 200, 1e308).duty(n, dt, 255)
    near = Sine(10.0, 200, math.fmod(1e308, 2 * math.pi)).duty(n, dt, 255)
    assert np.array_equal(far, near) and np.any(far != 0)
    assert np.array_equal(Sine(10.0, 200, 0.3).duty(n, dt, 255), Sine(10.0, 200, 0.3 + 0.0).duty(n, dt, 255))


@pytest.mark.parametrize("call, match", [
    (lambda: __import__("identify").fit(None), "recordings must be a Recording or a sequence of them, got NoneType"),
    (lambda: __import__("identify").fit("r.csv"), "got the path 'r.csv'"),
    (lambda: __import__("motorsim").simulate(Motor(25.0, 3.0), ["a", "b"], [0.0, 0.1]),
     r"duty must be an array of real numbers, got \['a', 'b'\]"),
], ids=["fit-none", "fit-a-path", "simulate-strings"])
def test_the_python_api_names_a_wrong_argument(call, match):
    from motorsim.checks import ParameterTypeError
    with pytest.raises(ParameterTypeError, match=match):
        call()


# --- a flag that would have no effect is refused ---------------------------------------------------------

@pytest.fixture(scope="module")
def model_path(runs):
    path = runs / "m.json"
    assert main(["identify", str(runs / "r.csv"), "--method", "oe", "--save", str(path)]) == 0
    return path


@pytest.mark.parametrize("argv, flags", [
    (["identify", "{r}", "--counts-per-rev", "1000"], ["--counts-per-rev"]),
    (["identify", "{r}", "--input-limit", "100"], ["--input-limit"]),
    (["frequency", "{r}", "--method", "sines", "--segment", "100"], ["segment", "'sines'"]),
    (["control", "design", "--controller", "pi", "--a", "25", "--b", "3", "--repetitions", "10"], ["--repetitions"]),
    (["control", "design", "--controller", "pi", "--a", "25", "--b", "3", "--seed", "3"], ["--seed"]),
    (["control", "design", "--controller", "pi", "--model", "{m}", "--a", "30"], ["--model", "--a"]),
    (["demo", "--out", "{o}", "--no-plots", "--no-control", "--duration", "1", "--reference", "step:10"],
     ["--reference", "--no-control"]),
    (["demo", "--out", "{o}", "--no-plots", "--no-control", "--duration", "1", "--duty-weight", "0.1"],
     ["--duty-weight", "--no-control"]),
], ids=["identify-counts-per-rev-on-v1", "identify-input-limit-on-v1", "frequency-segment-not-welch",
        "control-repetitions-nothing-drawn", "control-seed-nothing-drawn", "control-model-and-a",
        "demo-reference-no-control", "demo-duty-weight-no-control"])
def test_a_flag_without_effect_is_refused(runs, model_path, tmp_path, argv, flags, capsys):
    argv = [a.format(r=runs / "r.csv", m=model_path, o=tmp_path / "o") for a in argv]
    assert main(argv) == 2
    line = _error(capsys)
    assert all(flag in line for flag in flags), line
    assert not (tmp_path / "o").exists()


def test_the_draw_flags_still_work_with_a_covariance(model_path, capsys):
    assert main(["control", "design", "--controller", "pi", "--model", str(model_path), "--seed", "3",
                 "--repetitions", "20"]) == 0
    assert "--seed 3" in capsys.readouterr().out


# --- a unit a column's name states and a flag contradicts -------------------------------------------------

@pytest.mark.parametrize("header, flags, said", [
    ("t_ms,u,y", ["--time", "t_ms:s", "--input", "u:duty", "--angle", "y"], ("'t_ms' is in ms", "gives s")),
    ("t,u_pct,y", ["--time", "t", "--input", "u_pct:duty", "--angle", "y"], ("'u_pct' is in %", "gives duty")),
    ("t,u,y_deg", ["--time", "t", "--input", "u:duty", "--angle", "y_deg:rad"], ("'y_deg' is in deg", "gives rad")),
], ids=["time", "input", "angle"])
def test_a_unit_the_column_name_states_may_not_be_contradicted(runs, tmp_path, header, flags, said, capsys):
    rec = read_recording(runs / "r.csv")
    angle = rec.counts * 2 * math.pi / rec.counts_per_rev
    lab = tmp_path / "lab.csv"
    lab.write_text(header + "\n" + "".join(f"{float(t)!r},{int(u)},{float(y)!r}\n"
                                           for t, u, y in zip(rec.time, rec.duty, angle)))
    assert main(["identify", str(lab), *flags]) == 2
    line = _error(capsys)
    assert all(s in line for s in said), line


def test_design_refuses_an_angle_noise_whose_variance_is_no_float(tmp_path, capsys):
    assert main(["design", "--a", "25", "--b", "3", "--sample-period", "0.005", "--counts-per-rev", "16667",
                 "--angle-noise", "1e308", "--out", str(tmp_path / "d"), "--no-plots"]) == 2
    line = _error(capsys)
    assert "angle-noise" in line and "1e+15" in line and "1e+308" in line     # the bound of every number flag


def test_an_output_name_ending_in_a_separator_is_refused_not_written_as_a_file(runs, tmp_path, capsys):
    # "m.json/" names a folder; Path() would drop the slash and write the file m.json
    target = tmp_path / "m.json"
    assert main(["identify", str(runs / "r.csv"), "--method", "oe", "--save", f"{target}/"]) == 2
    assert "names a folder" in _error(capsys)
    assert not target.exists()
