"""``motorid frequency --structure``: a structure fitted to the response; the report's Bode panel draws the
estimate's full model."""
import json

import numpy as np
import pytest

from identify import structures
from identify.frequency.frequency_estimate import frequency_response
from motorid import plots
from motorid.cli import main
from motorsim import read_recording

TAU = 0.004


@pytest.fixture(scope="module")
def lag_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("lag") / "ms.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--electrical-time-constant", str(TAU), "--sample-period",
                 "0.001", "--odd-multisine", "512,127,15,3", "--duration", "3.072", "--angle-noise", "2e-3",
                 "--seed", "3", "--out", str(path)]) == 0
    return path


def test_frequency_structure_fits_and_overlays_the_second_order_model(lag_run, capsys):
    capsys.readouterr()
    assert main(["frequency", str(lag_run), "--structure", "second-order", "--input-delay", "0", "--json"]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    fit = doc["fit"]
    assert fit["structure"] == "second-order" and fit["method"] == "frequency"
    tau, se = fit["electrical_time_constant"], fit["electrical_time_constant_stderr"]
    assert abs(tau - TAU) < 4 * se and abs(fit["a"] - 25.0) < 4 * fit["a_stderr"]   # calibrated: identify's tests
    assert doc["models"][-1]["name"] == "second-order"
    assert "fit second-order: a = " in err and "electrical_time_constant = " in err and " s; standardised" in err


def test_frequency_input_delay_needs_a_structure(lag_run, capsys):
    assert main(["frequency", str(lag_run), "--input-delay", "1"]) == 2
    assert "--input-delay 1 applies to the --structure fit" in capsys.readouterr().err


def test_the_reports_bode_panel_draws_the_second_order_model(lag_run, tmp_path, monkeypatch, capsys):
    drawn = []
    original = plots.bode_axes

    def spy(gain_ax, phase_ax, frf, models=(), **kw):
        drawn.append((frf, list(models)))
        return original(gain_ax, phase_ax, frf, models, **kw)
    monkeypatch.setattr(plots, "bode_axes", spy)
    save = tmp_path / "m.json"
    assert main(["identify", str(lag_run), "--method", "oe-electrical", "--save", str(save),
                 "--report", str(tmp_path / "r.png")]) == 0
    (frf, (model,)), = drawn
    from identify import Estimate
    est = Estimate.from_json(save.read_text())
    full = structures()["second-order"].frequency_response(est.values(), frf.sample_period, frf.omega,
                                                          output=frf.output, input_delay=est.input_delay)
    assert np.array_equal(model.response, full)
    first = frf.model_response(est.a, est.b, est.input_delay)
    assert np.max(np.abs(full - first) / np.abs(first)) > 0.5            # what the panel drew before
    assert frf.omega.tolist() == frequency_response(read_recording(lag_run)).omega.tolist()
