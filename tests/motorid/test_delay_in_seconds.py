"""A saved model's input delay is a time: control design, live and identify --validate at another sample period."""
import json

import pytest

from motorid.cli import main
from motorsim import read_recording


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same motor, 20 ms of input delay, run at 5 ms and at 1 ms; the model saved from the 5 ms run."""
    folder = tmp_path_factory.mktemp("delay")
    at_5ms, at_1ms, model = folder / "d5.csv", folder / "d1.csv", folder / "d5.json"
    for path, period, delay in ((at_5ms, "0.005", "4"), (at_1ms, "0.001", "20")):
        assert main(["simulate", "--a", "25", "--b", "3", "--input-delay", delay, "--sample-period", period,
                     "--duration", "4", "--out", str(path)]) == 0
    assert main(["identify", str(at_5ms), "--method", "oe", "--input-delay", "4", "--save", str(model)]) == 0
    return at_5ms, at_1ms, model


def test_control_design_at_another_sample_period_keeps_the_delay_in_seconds(runs, capsys):
    model = runs[2]
    fast = ["control", "design", "--model", str(model), "--controller", "pi", "--time-constant", "0.01",
            "--min-phase-margin", "0", "--counts-per-rev", "16667"]
    assert main([*fast, "--sample-period", "0.001"]) == 0
    out = capsys.readouterr().out
    # 4 samples of 1 ms called this loop stable with 31.5 deg of phase margin; at the real 20 ms it is not
    assert "input delay 20 (0.02 s), dt = 0.001 s" in out and "(UNSTABLE)" in out
    assert main([*fast, "--sample-period", "0.005"]) == 0
    assert "input delay 4 (0.02 s), dt = 0.005 s" in capsys.readouterr().out
    assert main([*fast, "--sample-period", "0.003"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("motorid: error: input_delay 4 samples at 0.005 s (0.02 s) is 6.66667 samples at 0.003 s, not a "
                   "whole number: choose a sample period that divides 0.02 s (e.g. 0.005 s)")


def test_live_designs_a_saved_model_at_its_own_sample_period_with_the_delay_in_seconds(runs, tmp_path, capsys):
    out = tmp_path / "live.csv"
    assert main(["live", "--port", "fake://?a=25&b=3&input_delay=20", "--model", str(runs[2]), "--controller", "pi",
                 "--sample-period", "0.001", "--duration", "0.3", "--quiet", "--out", str(out)]) == 0
    meta = read_recording(out).metadata
    assert meta["model_sample_period"] == "0.001" and meta["model_input_delay"] == "20"


def test_identify_validates_a_model_on_a_run_at_another_sample_period(runs, capsys):
    at_5ms, at_1ms, _ = runs
    fits = []
    for training, delay in ((at_5ms, "4"), (at_1ms, "20")):
        assert main(["identify", str(training), "--method", "oe", "--input-delay", delay, "--validate", str(at_1ms),
                     "--json"]) == 0
        fits.append(json.loads(capsys.readouterr().out)["validation_fit_percent"])
    # the 5 ms model is the same motor: it explains the 1 ms run as well as a model fitted on it (to 0.05
    # points, the encoder's rounding); counted as 4 samples of 1 ms it scored 84 %
    assert fits[0] == pytest.approx(fits[1], abs=0.05) and fits[0] > 98
