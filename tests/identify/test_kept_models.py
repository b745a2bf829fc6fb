"""The model an ``oe`` fit keeps for the checks that follow it (identify.checks.validation.keep_models)."""
import dataclasses
import gc

import numpy as np

from identify import fit
from identify.checks import validation
from motorsim import Encoder, Experiment, Motor, Multisine, SimRig


def _recording(seed=0, seconds=6.0):
    rig = SimRig(Motor(25.0, 3.0), Encoder(2000, angle_noise=1e-4), rng=np.random.default_rng(seed))
    rec = rig.run(Experiment(Multisine((5.0, 17.0, 41.0), (60, 60, 50), (0, 1, 2)), 0.005, seconds))
    return rec.drop_rows(range(400, 420))     # a gap: two segments


def _simulated(est, rec):
    """The model as the checks computed it before any was kept."""
    kept = dict(validation._kept_models)
    validation._kept_models.clear()
    validation._made_models.clear()
    try:
        return validation._models(est, rec)
    finally:
        validation._kept_models.update(kept)


def test_the_kept_model_is_the_simulated_one_to_rounding():
    rec = _recording()
    est = fit(rec, "oe")
    kept = validation._models(est, rec)
    assert rec in validation._kept_models and len(kept) == 2
    again = _simulated(est, rec)
    for (seg, model), (seg2, model2) in zip(kept, again):
        assert (seg.start, seg.kind, seg.recording, len(seg.time)) == (seg2.start, seg2.kind, seg2.recording,
                                                                       len(seg2.time))
        np.testing.assert_array_equal(seg.output, seg2.output)
        # the same least squares solved two ways: rounding of angles of a few hundred rad, 1e-9 relative
        np.testing.assert_allclose(model, model2, rtol=1e-9, atol=1e-9 * np.max(np.abs(model2)))
        assert not model.flags.writeable


def test_other_values_another_recording_or_a_later_fit_simulate_again():
    rec, other = _recording(0), _recording(1)
    est = fit(rec, "oe")
    moved = dataclasses.replace(est, a=est.a * 1.01)
    for e, r in ((moved, rec), (est, other)):
        got = validation._models(e, r)
        for (_, model), (_, model2) in zip(got, _simulated(e, r)):
            np.testing.assert_array_equal(model, model2)
    fit(other, "oe")                                 # keeps its own, forgetting the first fit's
    assert rec not in validation._kept_models and other in validation._kept_models


def test_a_fit_whose_model_is_not_the_checks_one_keeps_none():
    # with a bias the fit solves the initial states with everything else (no separable solution): its angle
    # carries no fitted offset, so it is not the model the checks compute
    rec = _recording(4)
    validation._kept_models.clear()
    est = fit(rec, "oe", fit_bias=True)
    assert est.structure == "bias" and not validation._kept_models


def test_a_kept_model_goes_with_its_recording():
    rec = _recording(2)
    fit(rec, "oe")
    assert len(validation._kept_models) == 1
    del rec
    gc.collect()
    assert len(validation._kept_models) == 0


def test_the_default_answers_as_with_the_model_simulated(monkeypatch):
    rec = _recording(3, seconds=40.0)       # 8000 rows: the part checks run
    kept = fit(rec)
    monkeypatch.setattr("identify.fits.output_error.keep_models", lambda *args: None)
    validation._kept_models.clear()
    validation._made_models.clear()
    simulated = fit(rec)
    assert not validation._kept_models
    assert (kept.a, kept.b, kept.structure) == (simulated.a, simulated.b, simulated.structure)
    assert kept.selection.checks and [c.agree for c in kept.selection.checks] == [
        c.agree for c in simulated.selection.checks]
    # the part checks' p-values from the two models: the same to the models' rounding
    np.testing.assert_allclose([c.p_value for c in kept.selection.checks],
                               [c.p_value for c in simulated.selection.checks], rtol=1e-6)


def test_a_model_no_fit_kept_is_simulated_once_for_the_checks(monkeypatch):
    # a friction model's fit keeps none: its part checks simulate it, and the outlier check after them takes that
    rig = SimRig(Motor(25.0, 3.0, friction=40.0), Encoder(16667, angle_noise=1e-4), rng=np.random.default_rng(5))
    rec = rig.run(Experiment(Multisine((5.0, 17.0, 41.0), (60, 60, 50), (0, 1, 2)), 0.005, 40.0))
    made = []
    simulate = validation._segment_model
    monkeypatch.setattr(validation, "_segment_model", lambda est, seg: made.append(est.structure) or simulate(est, seg))
    est = fit(rec)
    assert est.structure == "friction" and est.selection.checks
    assert made == ["friction"]                     # one segment, simulated once
    (seg, model), = validation._models(est, rec)
    assert not model.flags.writeable and made == ["friction"]
    # and it is the model simulated afresh, to the last bit
    (_, again), = _simulated(est, rec)
    np.testing.assert_array_equal(model, again)
    # other values: simulated again, and the first let go
    moved = dataclasses.replace(est, a=est.a * 1.01)
    validation._models(moved, rec)
    assert made == ["friction", "friction", "friction"] and validation._made_models[rec][0][1] != \
        validation._model_key(est, 0)[1]
