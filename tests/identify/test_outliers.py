"""One corrupted sample is found, named by its row, and never fitted silently."""
import numpy as np
import pytest

from identify import fit
from identify.checks.outliers import residual_outliers
from identify.errors import CorruptedSamplesError
from motorsim import Encoder, Experiment, Motor, Recording, SimRig, Sine


@pytest.fixture(scope="module")
def rec():
    return SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(5)).run(
        Experiment(Sine(20.0), 0.005, 10.0))


def _with(rec, counts=None, time=None):
    return Recording(time=rec.time if time is None else time, duty=rec.duty, sample_period=rec.sample_period,
                     counts=rec.counts if counts is None else counts, counts_per_rev=rec.counts_per_rev)


@pytest.mark.parametrize("bit", [20, 40, 62])
def test_a_flipped_high_bit_in_counts_is_implausible_at_its_row(rec, bit):
    counts = rec.counts.copy()
    counts[1000] ^= 1 << bit
    bad = _with(rec, counts=counts).implausible_samples()
    assert [s.row for s in bad] == [1000] and "99th-percentile speed" in bad[0].reason


def test_a_last_timestamp_of_1e9_is_implausible(rec):
    time = rec.time.copy()
    time[-1] = 1e9
    assert [s.row for s in _with(rec, time=time).implausible_samples()] == [len(rec) - 1]


def test_a_clean_recording_has_no_implausible_row_nor_outlier(rec):
    assert rec.implausible_samples() == []
    for method in ("oe", "zoh-ls", "iv"):
        assert residual_outliers(fit(rec, method=method), rec) == [], method


def test_a_small_flip_is_a_residual_outlier_and_dropping_it_restores_the_fit(rec):
    counts = rec.counts.copy()
    counts[1000] ^= 1 << 12                   # 4096 counts: below the implausibility limit
    bad = _with(rec, counts=counts)
    assert bad.implausible_samples() == []
    est = fit(bad, method="oe", outliers="keep")
    assert residual_outliers(est, bad) == [1000]
    with pytest.raises(CorruptedSamplesError, match="seq 1000"):      # identify.fit refuses it by default
        fit(bad, method="oe")
    clean = fit(bad.drop_rows([1000]), method="oe")
    truth = fit(rec, method="oe")
    # the dropped row costs little information: within 3 standard errors of the clean fit
    for name in ("a", "b"):
        assert abs(getattr(clean, name) - getattr(truth, name)) < 3 * truth.stderr()[name], name


def test_dropped_rows_become_gaps(rec):
    out = rec.drop_rows([10, 11, 500])
    assert len(out) == len(rec) - 3 and out.has_gaps
    assert 10 not in out.seq and 500 not in out.seq and len(out.segments()) == 3


def _speed_only(rec):
    speed = rec.measured_speed()
    speed[0] = speed[1]                       # the first difference is undefined
    return Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, speed=speed)


@pytest.mark.parametrize("case", ["separable", "bias", "gaps and pooled", "speed only"])
def test_the_fits_own_speed_residuals_are_model_outputs(rec, case):
    # reference: identify.checks.validation.model_output simulates the estimate again on each recording;
    # the residuals the oe fit keeps must be the same numbers (1e-9 of the speed scale: two
    # orders of rounding through the fit's least squares), nan at the same rows
    from identify.checks.validation import model_output
    options = {"fit_bias": True} if case == "bias" else {}
    if case == "gaps and pooled":
        recs = [rec.drop_rows([100, 101, 1500]), rec.slice(0, 900)]
    elif case == "speed only":
        recs = [_speed_only(rec)]
    else:
        recs = [rec]
    est = fit(recs, method="oe", **options)
    assert est.speed_residuals is not None and len(est.speed_residuals) == len(recs)
    scale = float(np.nanmax(np.abs(recs[0].measured_speed())))
    for r, kept in zip(recs, est.speed_residuals):
        measured, simulated = model_output(est, r)
        want = measured - simulated
        np.testing.assert_array_equal(np.isnan(kept), np.isnan(want))
        np.testing.assert_allclose(kept[~np.isnan(want)], want[~np.isnan(want)], rtol=0, atol=1e-9 * scale)


def test_outliers_from_the_kept_residuals_equal_those_from_a_new_simulation(rec):
    counts = rec.counts.copy()
    counts[1000] ^= 1 << 12
    bad = _with(rec, counts=counts)
    est = fit(bad, method="oe", outliers="keep")
    assert residual_outliers(est, bad, est.speed_residuals[0]) == residual_outliers(est, bad) == [1000]
    assert est.speed_residuals is not None and type(est).from_json(est.to_json()).speed_residuals is None


def test_a_residual_of_the_wrong_length_is_refused(rec):
    from motorsim.checks import ParameterError
    est = fit(rec, method="oe")
    with pytest.raises(ParameterError, match="residual must have one value per row"):
        residual_outliers(est, rec, np.zeros(10))


# --- a coarse encoder's count is its rounding, not a corrupted sample ----------------------------------

def _coarse(counts_per_rev: int, speed_column: bool = False) -> Recording:
    """Steps of a slow motor on a coarse encoder at 1 ms: the differenced speed is 0 most rows and one count's
    speed (2 pi / counts_per_rev / 1 ms) where a count arrives."""
    exp = Experiment(Sine(3.0, amplitude=120), 0.001, 6.0)
    rec = SimRig(Motor(20.0, 1.0), Encoder(counts_per_rev=counts_per_rev, angle_noise=1e-4),
                 rng=np.random.default_rng(3)).run(exp)
    if not speed_column:
        return rec
    speed = np.round(rec.measured_speed(), 2)
    speed[0] = 0.0
    return Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, speed=speed)


@pytest.mark.parametrize("counts_per_rev, speed_column", [(12, False), (12, True)])
def test_a_coarse_encoders_counts_are_no_outliers(counts_per_rev, speed_column, monkeypatch):
    import identify.checks.outliers as outliers
    rec = _coarse(counts_per_rev, speed_column)
    est = fit(rec, method="oe")
    step = 2 * np.pi / counts_per_rev / 0.001
    assert np.allclose(outliers.rounding_step(rec)[1:], step, rtol=1e-3)     # the count found, from the column too
    assert residual_outliers(est, rec) == []
    monkeypatch.setattr(outliers, "ROUNDING_FACTOR", 0.0)       # the rule without it names the counts: can fail
    assert len(residual_outliers(est, rec)) > 0


def test_a_glitch_of_many_counts_on_a_coarse_encoder_is_still_found():
    rec = _coarse(48)
    counts = rec.counts.copy()
    counts[3000] += 5                                  # five counts off and back: beyond any rounding
    bad = Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, counts=counts,
                    counts_per_rev=rec.counts_per_rev)
    assert 3000 in residual_outliers(fit(bad, method="oe", outliers="keep"), bad)
