"""SelectionReport: the default's record of its choice, typed, and its JSON object read back unchanged."""
from __future__ import annotations

import json
import math

import pytest

from identify import CandidateReport, Estimate, SelectionReport, fit
from identify.estimate import json_ready
from motorsim import Experiment, Motor, Multisine, SimRig
from motorsim.checks import ParameterError, ParameterTypeError

#: A ``selection`` object as the default wrote it before it was typed (a failed candidate's numbers null).
WRITTEN = {
    "criterion": "simplest candidate within the noise of the best (batch-means test)", "level": 0.001,
    "chosen": {"structure": "bias", "input_delay": 2, "method": "oe", "a": 20.000031061640886,
               "b": 3.9999991176712393, "residual_sum": 2.327185320902483e-05, "statistic": 0.0,
               "within_noise": True},
    "best": {"structure": "bias", "input_delay": 2, "method": "oe", "a": 20.000031061640886,
             "b": 3.9999991176712393, "residual_sum": 2.327185320902483e-05, "statistic": 0.0,
             "within_noise": True},
    "runner_up": {"structure": "second-order", "input_delay": 1, "method": "oe-electrical", "a": 19.998192146838985,
                  "b": 4.0047035144261445, "residual_sum": 2.334515302208404e-05, "statistic": 3.1081246007005796,
                  "within_noise": True},
    "clear": True, "doubt": "", "notes": ["delays 5-10 not fitted"],
    "candidates": [
        {"structure": "bias", "input_delay": 2, "method": "oe", "a": 20.000031061640886, "b": 3.9999991176712393,
         "residual_sum": 2.327185320902483e-05, "statistic": 0.0, "within_noise": True},
        {"structure": "second-order", "input_delay": 1, "method": "oe-electrical", "a": 19.998192146838985,
         "b": 4.0047035144261445, "residual_sum": 2.334515302208404e-05, "statistic": 3.1081246007005796,
         "within_noise": True},
        {"structure": "friction", "input_delay": 0, "method": "oe-friction", "a": None, "b": None,
         "residual_sum": None, "statistic": None, "within_noise": False, "note": "did not converge"}]}


def _document(selection) -> str:
    est = Estimate(method="oe", a=20.0, b=4.0, n_samples=100, sample_period=0.005, residual_rms=0.01,
                   fit_percent=99.0, extra={"bias": 5.0}, param_names=("a", "b", "bias"), structure="bias")
    doc = json.loads(est.to_json())
    doc["selection"] = selection
    return json.dumps(doc)


def test_a_written_selection_reads_as_a_report_and_writes_back_byte_for_byte():
    text = _document(WRITTEN)
    est = Estimate.from_json(text)
    report = est.selection
    assert isinstance(report, SelectionReport)
    assert report.chosen.label == "bias, delay 2" and report.chosen.method == "oe" and report.clear
    assert report.runner_up is not None and report.runner_up.structure == "second-order"
    failed = report.candidates[2]
    assert failed.note == "did not converge" and math.isnan(failed.a) and math.isnan(failed.statistic)
    assert json.loads(est.to_json())["selection"] == WRITTEN
    assert Estimate.from_json(est.to_json()).to_json() == est.to_json()


def test_a_fit_carries_the_report_of_what_it_compared():
    rec = SimRig(Motor(25.0, 3.0, input_delay=1)).run(
        Experiment(Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3)), 0.005, 4.0))
    est = fit(rec)
    report = est.selection
    assert isinstance(report, SelectionReport) and all(isinstance(c, CandidateReport) for c in report.candidates)
    assert (report.chosen.structure, report.chosen.input_delay) == (est.structure, est.input_delay)
    assert report.chosen in report.candidates and report.best in report.candidates
    assert report.best.residual_sum == min(c.residual_sum for c in report.candidates if math.isfinite(c.residual_sum))
    # the JSON object and the report hold the same record
    assert json.loads(est.to_json())["selection"] == json_ready(report.to_dict())
    assert SelectionReport.from_dict(json.loads(est.to_json())["selection"]) == SelectionReport.from_dict(
        json_ready(report.to_dict()))


def test_a_mapping_given_to_estimate_is_read_as_a_report():
    est = Estimate.from_json(_document(WRITTEN))
    again = Estimate(method="oe", a=20.0, b=4.0, n_samples=100, sample_period=0.005, residual_rms=0.01,
                     fit_percent=99.0, selection=WRITTEN)
    assert again.selection == est.selection


@pytest.mark.parametrize("change, field, error", [
    (lambda s: s.pop("chosen"), "'selection' must have 'chosen'", ParameterError),
    (lambda s: s.update(clear="yes"), "'selection.clear' must be true or false", ParameterTypeError),
    (lambda s: s["candidates"][1].update(input_delay=-1), r"'selection.candidates\[1\].input_delay' must be >= 0",
     ParameterError),
    (lambda s: s["best"].update(a="25"), "'selection.best.a' must be a number or null", ParameterTypeError),
    (lambda s: s["runner_up"].update(within_noise=1), "'selection.runner_up.within_noise' must be true or false",
     ParameterTypeError),
    (lambda s: s.update(notes=[1]), "'selection.notes' must be a list of strings", ParameterTypeError),
], ids=["missing", "clear", "delay", "number", "flag", "notes"])
def test_a_wrong_selection_field_is_named(change, field, error):
    selection = json.loads(json.dumps(WRITTEN))
    change(selection)
    with pytest.raises(error, match=field):
        Estimate.from_json(_document(selection))
