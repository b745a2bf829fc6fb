"""Samples at the input limit are counted, said, and kept in the fit, where the linear model still holds."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from identify import fit
from identify.data import saturation_note
from motorsim import Encoder, Experiment, Motor, SimRig, Sine


def _clipped_run(noise: float = 0.0):
    rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=noise), rng=np.random.default_rng(3))
    return rig.run(Experiment(Sine(10.0, 300), 0.005, 10.0))          # asks for 300, the bench clamps at 255


def test_the_note_counts_the_saturated_samples_and_the_fit_keeps_them_and_stays_exact():
    rec = _clipped_run()
    n = rec.saturated_samples()
    runs = rec.saturated_runs()
    assert n == sum(length for _, length in runs) > 0
    assert all(abs(rec.duty[k]) == 255 for first, length in runs for k in range(first, first + length))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        est = fit(rec)
    note = next(note for note in est.notes if "input limit" in note)
    assert note.startswith(f"{n} of the {len(rec)} samples") and f"in {len(runs)} run(s): kept in the fit" in note
    assert est.n_samples == len(rec)
    assert est.a == pytest.approx(25.0, rel=1e-4) and est.b == pytest.approx(3.0, rel=1e-4)


def test_keeping_the_saturated_samples_narrows_the_intervals_that_leaving_them_out_would_widen():
    rec = _clipped_run(noise=1e-3)
    rows = [k for first, length in rec.saturated_runs() for k in range(first, first + length)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        kept, left_out = fit(rec, method="oe"), fit(rec.drop_rows(rows), method="oe")
    for name, truth in (("a", 25.0), ("b", 3.0)):
        low, high = kept.confidence_interval(0.95)[name]
        assert low <= truth <= high
        out_low, out_high = left_out.confidence_interval(0.95)[name]
        assert high - low < out_high - out_low


def test_a_controller_at_its_limit_for_a_few_samples_is_not_noted_but_an_input_limit_in_volts_is():
    rec = _clipped_run()
    few = rec.saturated_runs()[0]
    duty = np.clip(rec.duty, -254, 254)
    duty[few[0]:few[0] + few[1]] = 255
    closed = dataclasses.replace(rec, duty=duty, reference=np.zeros(len(rec)))
    assert closed.saturated_samples() == few[1] and saturation_note([closed]) is None
    volts = dataclasses.replace(rec, duty=rec.duty / 255 * 12, metadata={**rec.metadata, "input_unit": "V",
                                                                         "input_limit": "12"})
    assert saturation_note([volts]).startswith(f"{rec.saturated_samples()} of the")
    assert "+-12 V" in saturation_note([volts])
