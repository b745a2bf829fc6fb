"""Files as they come: PlotJuggler's CSV export of topics logged at different times, a clock with random
intervals, and refusals of the data that name the file.

Before: PlotJuggler's export was refused naming its first empty cell; a file with random sample instants
stopped with ``time and sample_period disagree ... (median over 3 intervals)`` (a short run of its own
clock checked against the whole clock's median) and named no file; an input of 1e-300 was refused without
the file's name.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from motorid.cli import main
from motorsim import read_recording

_A, _B = 25.0, 3.0


def _motor(t_fine: np.ndarray, u_fine: np.ndarray) -> np.ndarray:
    """The exact response of b/(s + a) to ``u_fine`` held over each step of the fine grid ``t_fine``."""
    w = np.zeros(len(t_fine))
    for k in range(len(t_fine) - 1):
        e = np.exp(-_A * (t_fine[k + 1] - t_fine[k]))
        w[k + 1] = e * w[k] + _B / _A * (1 - e) * u_fine[k]
    return w


def _plotjuggler(path, *, seed=1, offset=0.0005, command_period=0.05, speed_period=0.01, duration=4.0):
    """A file written as PlotJuggler's CSV export writes two topics: ``__time`` in s (6 decimals), one column per
    series (9 decimals), a row per instant any series was logged, the other cells empty.  The command topic at
    20 Hz, ``offset`` after the state topic's instants (a node that answers the state it reads); the state's
    speed at 100 Hz with its receive times jittered by +-0.2 ms, and 0.02 rad/s of noise."""
    rng = np.random.default_rng(seed)
    fine = np.arange(int(duration / 0.0005)) * 0.0005
    ct = np.arange(0.0, duration, command_period) + offset
    levels = rng.choice([-150.0, -80.0, 80.0, 150.0], len(ct))
    held = np.searchsorted(ct, fine, side="right") - 1
    w = _motor(fine, np.where(held >= 0, levels[np.maximum(held, 0)], 0.0))
    st = np.arange(0.0, duration - 0.02, speed_period)
    st = np.maximum(st + rng.uniform(-2e-4, 2e-4, len(st)), 0.0)
    speed = np.interp(st, fine, w) + rng.normal(0.0, 0.02, len(st))
    rows: dict[float, list] = {}
    for t, c in zip(ct, levels):
        rows.setdefault(round(1.7e9 + t, 6), [None, None])[0] = c
    for t, s in zip(st, speed):
        rows.setdefault(round(1.7e9 + t, 6), [None, None])[1] = s
    with open(path, "w") as f:
        f.write("__time,/motor/cmd/data,/motor/state/velocity\n")
        for t in sorted(rows):
            c, s = rows[t]
            f.write(f"{t:.6f},{'' if c is None else f'{c:.9f}'},{'' if s is None else f'{s:.9f}'}\n")
    return path, int(np.count_nonzero(np.round(st, 6) >= round(ct[0], 6)))    # speed rows with a command by then


_FLAGS = ["--time", "__time:s", "--input", "/motor/cmd/data:duty", "--speed", "/motor/state/velocity:rad/s"]


@pytest.mark.parametrize("offset", [0.0005, 0.0052])
def test_plotjuggler_export_is_aligned_by_time_and_answered_right(tmp_path, offset, capsys):
    path, n_speed = _plotjuggler(tmp_path / "pj.csv", offset=offset)
    assert main(["identify", str(path), *_FLAGS, "--json"]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    # the 95 % intervals hold the motor the file was made from (the project's criterion for a right answer)
    assert doc["a_ci95"][0] <= _A <= doc["a_ci95"][1], doc["a_ci95"]
    assert doc["b_ci95"][0] <= _B <= doc["b_ci95"][1], doc["b_ci95"]
    assert doc["n_samples"] == n_speed                   # one sample per row of the speed topic, none made up
    assert f"read as {n_speed} samples at the rows holding the speed ('/motor/state/velocity')" in err
    assert "PlotJuggler" in err and "held from the last one logged" in err


def test_plotjuggler_import_holds_each_command_and_averages_where_one_came_within_a_sample(tmp_path, capsys):
    path = tmp_path / "pj.csv"
    path.write_text("__time,/cmd,/speed\n"
                    "0.000000,,0.0\n"              # no command yet: left out
                    "0.001000,10.0,\n"
                    "0.010000,,0.5\n"
                    "0.014000,30.0,\n"             # comes 40 % into the sample from 0.010 to 0.020
                    "0.020000,,1.0\n"
                    "0.030000,,1.5\n"
                    "0.040000,50.0,2.0\n")         # logged with the speed: drives the interval it starts
    out = tmp_path / "rec.csv"
    assert main(["import", str(path), "--time", "__time:s", "--input", "/cmd:duty", "--speed", "/speed:rad/s",
                 "--out", str(out)]) == 0
    rec = read_recording(out)
    np.testing.assert_allclose(rec.time, [0.01, 0.02, 0.03, 0.04])
    np.testing.assert_allclose(rec.duty, [0.4 * 10 + 0.6 * 30, 30, 30, 50], rtol=1e-12)
    np.testing.assert_allclose(rec.speed, [0.5, 1.0, 1.5, 2.0])
    err = capsys.readouterr().err
    assert "read as 4 samples" in err and "3 of 7 rows left out" in err and "1 before any input" in err


@pytest.mark.parametrize("text, said", [
    ("__time,/cmd,/speed\n0.0,1,0\n,2,0.1\n0.02,3,0.2\n", "line 3, column '__time' (time): the time cell is empty"),
    ("__time,/cmd,/speed\n0.0,,0\n0.01,,0.1\n0.02,,0.2\n", "the input column '/cmd' holds no value"),
    ("__time,/cmd,/speed\n0.0,1,\n0.01,2,\n0.02,3,0.2\n", "only 1 row(s) hold the speed"),
])
def test_an_export_with_nothing_to_align_is_refused_naming_the_file_and_column(tmp_path, text, said, capsys):
    path = tmp_path / "pj.csv"
    path.write_text(text)
    assert main(["identify", str(path), "--time", "__time:s", "--input", "/cmd:duty", "--speed",
                 "/speed:rad/s"]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"motorid: error: {path}") and said in line


def test_a_clock_with_random_instants_is_fitted_on_its_own_instants(tmp_path, capsys):
    # event-driven logging: 600 instants drawn at random over 3 s (a Poisson-like clock: intervals from 0 to
    # several times their median, its longer pauses cutting the run), the exact response at those instants
    rng = np.random.default_rng(1)
    t = np.unique(np.round(np.r_[0.0, np.sort(rng.uniform(0.0, 3.0, 600))], 6))
    u = np.where(np.sin(2 * np.pi * 1.3 * t) > 0, 150.0, -150.0)
    w = _motor(t, u) + rng.normal(0.0, 0.05, len(t))
    path = tmp_path / "random_clock.csv"
    path.write_text("t,u,w\n" + "".join(f"{a:.6f},{b:g},{c:.5f}\n" for a, b, c in zip(t, u, w)))
    assert main(["identify", str(path), "--time", "t:s", "--input", "u:duty", "--speed", "w:rad/s", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["a_ci95"][0] <= _A <= doc["a_ci95"][1] and doc["b_ci95"][0] <= _B <= doc["b_ci95"][1]


def test_a_run_of_a_jittered_clock_is_a_recording_as_the_whole_clock_is():
    from motorsim import Recording
    steps = np.full(400, 0.004)
    steps[10:13] = 0.0013                   # a burst of rows: its median interval a third of the whole clock's
    t = np.r_[0.0, np.cumsum(steps)]
    with pytest.warns(UserWarning, match="the time column is not uniform"):
        rec = Recording.from_columns(time=t, duty=np.sign(np.sin(9 * t)), speed=np.sin(t))
    part = rec.slice(10, 14)
    assert len(part) == 4 and part.sample_period == rec.sample_period and part.time[0] == rec.time[10]
    assert not part.time.flags.writeable and part.drop_rows([1]).time.tolist() == part.time[[0, 2, 3]].tolist()


@pytest.mark.parametrize("scale", ["1e-300", "1e-150"])
def test_an_input_no_drive_gives_is_refused_naming_the_file(tmp_path, scale, capsys):
    t = np.arange(400) * 0.01
    path = tmp_path / "scaled.csv"
    u = np.where((t * 3) % 2 < 1, 1.0, -1.0)
    path.write_text("t,u,w\n" + "".join(f"{a:.6f},{b * float(scale):.3e},{np.sin(a):.5f}\n" for a, b in zip(t, u)))
    assert main(["identify", str(path), "--time", "t:s", "--input", "u:duty", "--speed", "w:rad/s"]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"motorid: error: {path}: input's largest magnitude must be in 1e-100...1e+100 duty, "
                           f"got {float(scale):g}")
