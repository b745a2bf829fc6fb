"""``motorid live --until PCT`` on the emulated Arduino: rounds until the intervals are as tight as asked."""
from __future__ import annotations

import json
import math

import pytest

from identify.estimate import Estimate
from motorid.cli import main
from motorsim import read_recording


def _until(tmp_path, url, *extra):
    out = tmp_path / "until.csv"
    return main(["live", "--port", url, "--out", str(out), "--quiet", *extra]), out


def test_until_on_fake_stops_within_target_with_intervals_holding_the_built_motor(tmp_path, capsys):
    # a slow motor, a = 2 1/s, where fixed sines do worst; fake:// is an exact ZOH with the device's
    # one-sample delay and a 16667-count encoder (measured: 2 rounds, 1 s, a ±0.23 %, b ±0.07 %)
    model = tmp_path / "model.json"
    status, out = _until(tmp_path, "fake://?a=2&b=0.3&speed=0", "--until", "1", "--json", "--save", str(model))
    assert status == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["reached"] and result["stop"] == "target" and result["clear"]
    rounds = result["rounds"]
    assert rounds[0]["phase"] == "ranging" and result["breakaway_duty"] is not None
    last = rounds[-1]
    assert max(last["reach_pct"].values()) <= 1.0
    est = result["estimate"]
    assert est["a_ci95"][0] <= 2.0 <= est["a_ci95"][1]
    assert est["b_ci95"][0] <= 0.3 <= est["b_ci95"][1]
    # the answer's intervals are the round's, widened to those with a lag left free (the stop asked both within)
    for k in ("a", "b"):
        lo, hi = est[f"{k}_ci95"]
        reach = 100 * max(est[k] - lo, hi - est[k]) / abs(est[k])
        assert reach == pytest.approx(max(last["reach_pct"][k], last["lag_free_reach_pct"][k]), rel=1e-9)
        assert lo <= last["intervals"][k][0] and last["intervals"][k][1] <= hi
    # every run in the one recording, each its own segment; the model file as identify --save writes it
    rec = read_recording(out)
    assert rec.metadata["runs"] == str(len(rounds)) and len(rec.segments()) == len(rounds)
    assert rec.metadata["until_stop"] == "target"
    assert sum(r["duration_s"] for r in rounds) == pytest.approx(result["motor_time_s"], rel=1e-12)
    saved = Estimate.from_json(model.read_text())
    assert saved.a == pytest.approx(est["a"], rel=1e-12)


def test_until_out_of_budget_stops_at_it_and_says_which_parameter_is_short(tmp_path, capsys):
    status, out = _until(tmp_path, "fake://?a=25&b=3&speed=0&angle_noise=0.05", "--until", "0.01", "--max-time", "2")
    assert status == 3
    text = capsys.readouterr()
    assert "stopped short: the time budget of 2 s is spent" in text.out
    assert "short: a ±" in text.out and "NOT a clear choice" not in text.out.split("until")[0]
    assert read_recording(out).metadata["until_stop"] == "budget"


def test_until_with_a_guess_opens_with_a_sine_for_it(tmp_path, capsys):
    status, _ = _until(tmp_path, "fake://?a=25&b=3&speed=0", "--until", "1", "--a", "20", "--b", "2", "--json")
    assert status == 0
    rounds = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["rounds"]
    assert rounds[0]["phase"] == "opening" and rounds[0]["excitation"].startswith("sine:")


@pytest.mark.parametrize("flags, message", [
    (["--until", "0"], "--until must be a percentage in (0, 100), got 0.0"),
    (["--until", "100"], "--until must be a percentage in (0, 100), got 100.0"),
    (["--until", "nan"], "--until must be a finite number"),
    (["--until", "1", "--max-time", "-1"], "--max-time must be a finite number of s > 0, got -1.0"),
    (["--until", "1", "--max-time", "inf"], "--max-time must be a finite number"),
    (["--until", "1", "--max-speed", "0"], "--max-speed must be a finite number of rad/s > 0, got 0.0"),
    (["--until", "1", "--max-travel", "-2"], "--max-travel must be a finite number of rad > 0, got -2.0"),
    (["--max-time", "5"], "--max-time applies only with --until PCT"),
    (["--until", "1", "--sine", "10,200"], "--until chooses the excitation round by round: leave out --sine"),
    (["--until", "1", "--a", "25"], "--until's guess needs both --a and --b"),
    (["--until", "1", "--a", "-3", "--b", "2"], "--a must be a finite pole > 0 in 1/s, got -3.0"),
])
def test_a_bad_target_or_budget_is_refused_before_the_port_opens(tmp_path, capsys, flags, message):
    # the port does not exist: the flags are refused first
    status = main(["live", "--port", "/dev/motorid-no-such-port", "--out", str(tmp_path / "x.csv"), *flags])
    assert status == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_until_plot_draws_the_rounds(tmp_path, capsys):
    status, out = _until(tmp_path, "fake://?a=25&b=3&speed=0", "--until", "2", "--plot")
    assert status == 0
    png = tmp_path / "until.csv.until.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert math.isfinite(len(png.read_bytes()))


def test_a_fault_mid_run_keeps_the_samples_that_arrived(tmp_path, capsys):
    # the device disconnects at its 50th sample of the first (ranging) run: nothing is lost
    status, out = _until(tmp_path, "fake://?a=2&b=0.3&speed=0&disconnect_at=50", "--until", "1")
    assert status == 2
    err = capsys.readouterr().err
    assert f"in {out} (complete: false)" in err
    rec = read_recording(out)
    assert rec.metadata["complete"] == "false" and 40 <= len(rec) < 100
