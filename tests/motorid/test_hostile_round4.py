"""Hostile cases of the fourth round: refusals name the file the data came from; one rule per boundary.

Each case ran as a user would run it (``motorid.cli.main`` or the Python API); each failed before
the change it tests (a message naming ``recordings[0]`` instead of the file, a traceback, a wrong
number with exit 0) and now ends in a right answer or one ``motorid: error:`` line naming the
file or parameter, the rule and the value.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from motorid.cli import main
from motorsim import Experiment, Motor, SimRig, Sine, read_recording, write_recording


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


def _rewrite(path: Path, out: Path, column: str, change) -> Path:
    """``path`` with ``change(cells)`` applied to ``column`` (its cells as text), written to ``out``."""
    lines = path.read_text().splitlines()
    header = [k for k, line in enumerate(lines) if line.startswith("seq")][0]
    k = lines[header].split(",").index(column)
    rows = [line.split(",") for line in lines[header + 1:]]
    for row, value in zip(rows, change([row[k] for row in rows])):
        row[k] = value
    out.write_text("\n".join(lines[:header + 1] + [",".join(row) for row in rows]) + "\n")
    return out


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
    bad = _rewrite(runs / source, tmp_path / f"{case}.csv", column, change)
    assert main(["identify", str(bad), "--method", method]) == 2
    line = _error(capsys)
    assert line.startswith(f"motorid: error: {bad}: ") and rule in line and "recordings[" not in line


def test_the_python_api_names_the_file_a_recording_was_read_from(runs, tmp_path):
    import identify
    from identify.errors import NotIdentifiableError
    bad = _rewrite(runs / "r.csv", tmp_path / "late.csv", "duty", lambda cells: ["0", *cells[:-1]])
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
    bad = _rewrite(runs / "r.csv", tmp_path / "jump.csv", "counts",
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
