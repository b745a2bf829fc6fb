"""The one output rule, per command: regular files only, never an input, the extension written is the one named."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from motorid.cli import main

COLUMNS = ["--time", "time_s", "--input", "duty", "--counts", "counts", "--counts-per-rev", "16667"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "r.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--out", str(path)]) == 0
    return path


@pytest.fixture
def rec(recording, tmp_path) -> Path:
    copy = tmp_path / "r.csv"
    copy.write_bytes(recording.read_bytes())
    return copy


def _refused(capsys, argv, flag: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = next(x for x in err.splitlines() if x.startswith("motorid: error:"))
    assert flag in line, line
    return line


def test_import_never_overwrites_its_own_input(rec, capsys):
    before = rec.read_bytes()
    line = _refused(capsys, ["import", str(rec), *COLUMNS, "--out", str(rec)], "--out")
    assert "input" in line
    assert rec.read_bytes() == before


def test_identify_save_never_replaces_a_recording_it_reads(rec, capsys):
    before = rec.read_bytes()
    _refused(capsys, ["identify", str(rec), "--save", str(rec)], "--save")
    assert rec.read_bytes() == before


def test_identify_save_never_replaces_the_validation_file_through_another_name(rec, tmp_path, capsys):
    other = tmp_path / "v.csv"
    os.link(rec, other)
    _refused(capsys, ["identify", str(rec), "--validate", str(rec), "--save", str(other)], "--save")


def test_simulate_never_overwrites_its_model(tmp_path, capsys):
    model = tmp_path / "m.json"
    from identify.estimate import Estimate
    model.write_text(Estimate(method="oe", a=25.0, b=3.0, n_samples=10, sample_period=0.005, residual_rms=0.0,
                              fit_percent=99.0).to_json())
    before = model.read_bytes()
    _refused(capsys, ["simulate", "--a", "25", "--b", "3", "--controller", "pi", "--model", str(model),
                      "--out", str(model)], "--out")
    assert model.read_bytes() == before


def test_a_report_through_a_symbolic_link_is_refused_and_the_target_kept(rec, tmp_path, capsys):
    victim = tmp_path / "victim.png"
    victim.write_bytes(b"precious")
    (tmp_path / "link.png").symlink_to(victim)
    _refused(capsys, ["identify", str(rec), "--report", str(tmp_path / "link.png")], "--report")
    assert victim.read_bytes() == b"precious"


@pytest.mark.parametrize("argv", [["simulate", "--a", "25", "--b", "3", "--out"],
                                  ["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--plot"]],
                         ids=["simulate --out", "control --plot"])
def test_every_file_output_refuses_a_symbolic_link(tmp_path, capsys, argv):
    victim = tmp_path / "victim.png"
    victim.write_bytes(b"precious")
    (tmp_path / "link.png").symlink_to(victim)
    _refused(capsys, [*argv, str(tmp_path / "link.png")], argv[-1])
    assert victim.read_bytes() == b"precious"


def test_a_report_to_a_device_is_refused_not_renamed(rec, capsys):
    existed = Path("/dev/full.png").exists()
    line = _refused(capsys, ["identify", str(rec), "--report", "/dev/full"], "--report")
    assert "/dev/full" in line
    assert existed or not Path("/dev/full.png").exists()


def test_a_device_with_a_figure_extension_is_refused_as_a_device(tmp_path, capsys):
    fifo = tmp_path / "plot.png"
    os.mkfifo(fifo)
    line = _refused(capsys, ["control", "design", "--a", "25", "--b", "3", "--controller", "pi",
                             "--plot", str(fifo)], "--plot")
    assert "FIFO" in line


@pytest.mark.parametrize("name", ["myreport", "fit.jpeg2", "fit.csv"])
def test_a_figure_without_a_known_extension_is_refused_before_any_work(rec, tmp_path, capsys, name):
    line = _refused(capsys, ["identify", str(rec), "--report", str(tmp_path / name)], "--report")
    assert ".png" in line
    assert list(tmp_path.iterdir()) == [rec]


@pytest.mark.parametrize("suffix", [".png", ".svg", ".pdf"])
def test_the_figure_written_is_exactly_the_path_reported(rec, tmp_path, capsys, suffix):
    out = tmp_path / f"fit{suffix}"
    assert main(["identify", str(rec), "--report", str(out)]) == 0
    assert f"report      {out}" in capsys.readouterr().out
    assert out.is_file() and sorted(p.name for p in tmp_path.iterdir()) == sorted(["r.csv", out.name])


def test_frequency_plot_follows_the_rule(rec, tmp_path, capsys):
    _refused(capsys, ["frequency", str(rec), "--plot", str(tmp_path / "bode")], "--plot")
    _refused(capsys, ["frequency", str(rec), "--plot", str(rec)], "--plot")


@pytest.mark.parametrize("command", ["design", "sweep", "demo"])
def test_a_folder_output_that_is_a_file_is_refused_naming_the_flag(tmp_path, capsys, command):
    target = tmp_path / "file"
    target.write_text("keep")
    argv = {"design": ["design", "--a", "25", "--b", "3", "--sample-period", "0.005", "--counts-per-rev", "1000"],
            "sweep": ["sweep", "article"], "demo": ["demo"]}[command]
    _refused(capsys, [*argv, "--out", str(target)], "--out")
    assert target.read_text() == "keep"


def test_every_command_with_a_file_output_is_in_the_table():
    from motorid.cli import build_parser
    from motorid.outputs import FILE_OUTPUTS
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():
        dests = {a.dest for a in p._actions if a.metavar and str(a.metavar).startswith(("FILE", "MODEL"))
                 and a.option_strings and a.dest not in ("model", "validate")}
        assert dests <= set(FILE_OUTPUTS.get(name, {})), (name, dests)
