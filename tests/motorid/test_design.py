"""Experiment design: the recommendation minimises the Cramér-Rao criterion it reports."""
import json

import numpy as np
import pytest

from identify.checks.design import design_sine, predicted_stderr
from identify.checks.uncertainty import cramer_rao_bound
from motorid.cli import main
from motorsim import Motor, Sine, simulate


@pytest.fixture(scope="module")
def design():
    return design_sine(25.0, 3.0, 0.005, counts_per_rev=1024, angle_noise=1e-3, duration=4.0, n_frequencies=16)


def _finite_difference_stderr(a, b, duty, dt, variance, h=1e-6):
    """sqrt(diag(sigma^2 (J^T J)^-1)) for (a, b), J by central differences of the simulated angle
    with respect to (a, b, initial speed) and a column of ones for the angle offset."""
    t = np.arange(len(duty)) * dt

    def angle(a_, b_, w0):
        return simulate(Motor(a_, b_), duty, t, initial_speed=w0).angle
    columns = [(angle(a * (1 + h), b, 0.0) - angle(a * (1 - h), b, 0.0)) / (2 * a * h),
               (angle(a, b * (1 + h), 0.0) - angle(a, b * (1 - h), 0.0)) / (2 * b * h),
               (angle(a, b, h) - angle(a, b, -h)) / (2 * h), np.ones(len(t))]
    J = np.column_stack(columns)
    cov = variance * np.linalg.inv(J.T @ J)
    return np.sqrt(np.diag(cov)[:2])


def test_prediction_is_the_bound_of_the_bench_sine():
    p = predicted_stderr(25.0, 3.0, 20.0, 150, 0.005, 2.0, counts_per_rev=1024, angle_noise=1e-3)
    duty = Sine(20.0, 150).duty(400, 0.005)
    ref = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=1024, angle_noise=1e-3).stderr()
    assert (p.stderr_a, p.stderr_b) == (ref["a"], ref["b"])
    # independently: finite-difference Fisher information of the angle, noise = Gaussian + quantisation
    variance = 1e-3 ** 2 + (2 * np.pi / 1024) ** 2 / 12
    fd = _finite_difference_stderr(25.0, 3.0, duty.astype(float), 0.005, variance)
    np.testing.assert_allclose([p.stderr_a, p.stderr_b], fd, rtol=1e-5)   # central differences, h = 1e-6


def _criterion_from_the_bound(frequency, amplitude):
    """(se_a/a)^2 + (se_b/b)^2 straight from cramer_rao_bound of the bench's integer sine (not design_sine)."""
    n = int(round(4.0 / 0.005))
    duty = Sine(frequency, amplitude).duty(n, 0.005)
    se = cramer_rao_bound(25.0, 3.0, duty, 0.005, counts_per_rev=1024, angle_noise=1e-3).stderr()
    return (se["a"] / 25.0) ** 2 + (se["b"] / 3.0) ** 2


def test_recommendation_beats_every_scanned_sine_and_the_articles(design):
    best = design.best.criterion
    assert all(best <= p.criterion for p in (*design.scan, *design.amplitudes, *design.article))
    # independently of the scan: the criterion recomputed from the bound at the recommendation
    # equals the one reported, and sines between the scanned ones (5 % either side) are no better
    # than the recommendation by more than the scan's resolution allows (2 %)
    f, amp = design.best.frequency, design.best.amplitude
    assert _criterion_from_the_bound(f, amp) == pytest.approx(best, rel=1e-9)
    for factor in (0.95, 1.05):
        if 2 * 2 * np.pi / 4.0 <= f * factor <= 0.8 * np.pi / 0.005:
            assert _criterion_from_the_bound(f * factor, amp) >= best * 0.98
    freqs = [p.frequency for p in design.scan]
    assert freqs == sorted(freqs)
    assert freqs[0] == pytest.approx(2 * 2 * np.pi / 4.0) and freqs[-1] == pytest.approx(0.8 * np.pi / 0.005)
    assert [p.frequency for p in design.article] == [10.0, 20.0, 30.0, 40.0]


def test_largest_amplitude_wins_because_the_bound_scales_as_one_over_amplitude(design):
    # Fixed noise, linear model: the standard errors scale as 1/A (to the integer rounding
    # of the duty, well under 1 % at these amplitudes).
    by_amp = {p.amplitude: p for p in design.amplitudes}
    assert design.best.amplitude == 255 == max(by_amp)
    lo, hi = by_amp[min(by_amp)], by_amp[255]
    assert lo.stderr_a / hi.stderr_a == pytest.approx(255 / lo.amplitude, rel=0.01)


@pytest.mark.parametrize("kwargs, match", [
    ({"sample_period": 0.0}, "sample_period"), ({"a": -1.0}, "a must be > 0"), ({"b": 0.0}, "b must be nonzero"),
    ({"duration": 0.05}, "duration"), ({"duty_limit": 300}, "duty_limit"), ({"angle_noise": -1.0}, "angle_noise"),
], ids=["sample-period", "a", "b", "duration", "duty-limit", "noise"])
def test_bad_input_names_the_parameter(kwargs, match):
    args = dict(a=25.0, b=3.0, sample_period=0.005)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        design_sine(**args)


def test_cli_design_prints_the_comparison_and_writes_json_and_png(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["design", "--a", "25", "--b", "3", "--sample-period", "0.005", "--counts-per-rev", "1024",
                 "--angle-noise", "1e-3", "--duration", "4", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "recommended:" in text and "200 sin(40 t)" in text
    data = json.loads((out / "design.json").read_text(encoding="utf-8"))
    assert data["best"]["amplitude"] == 255
    assert (out / "design.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["design", "--a", "25", "--b", "3", "--sample-period", "-1", "--counts-per-rev", "1024"]) == 2
    assert "sample_period" in capsys.readouterr().err
