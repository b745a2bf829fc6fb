"""The figures, checked through the returned matplotlib Figure: labels with units, legends, lines."""
import dataclasses

import numpy as np
import pytest

from identify import fit, validate
from identify.fits.recursive import RunningEstimator
from motorid import plots
from motorsim.excitation import Sine
from motorsim.plant import Motor
from motorsim.rig import Experiment, SimRig


@pytest.fixture(scope="module")
def runs():
    """Two sine runs (10 and 40 rad/s, 4 s) with their euler-ls and oe fits."""
    recs = [SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(w, 200), 0.005, 4.0)) for w in (10.0, 40.0)]
    fits = [{m: fit(r, method=m) for m in ("euler-ls", "oe")} for r in recs]
    return recs, fits


def _texts(legend):
    return [t.get_text() for t in legend.get_texts()]


def test_plot_functions_return_the_figure_and_write_only_when_given_a_path(tmp_path, runs, monkeypatch):
    monkeypatch.chdir(tmp_path)
    recs, _ = runs
    fig = plots.plot_run(recs[0])
    assert fig.axes and list(tmp_path.iterdir()) == []
    plots.plot_run(recs[0], tmp_path / "run.png")
    assert (tmp_path / "run.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_overlay_draws_measured_and_each_method_on_panels_named_by_their_sine(runs):
    recs, fits = runs
    fig = plots.plot_overlay(recs, fits, labels=["eta_1 = 200 sin(10 t)", "eta_4 = 200 sin(40 t)"], window=0.5)
    panels = fig.axes
    assert [ax.get_title(loc="left") for ax in panels] == ["eta_1 = 200 sin(10 t)", "eta_4 = 200 sin(40 t)"]
    for ax, rec, est in zip(panels, recs, fits):
        assert len(ax.get_lines()) == 3
        texts = _texts(ax.get_legend())
        assert texts[0] == "measured ω"
        assert texts[1].startswith("euler-ls: a=") and texts[2].startswith("oe: a=")
        assert f"fit {est['oe'].fit_percent:.1f} %" in texts[2]
        assert ax.get_ylabel() == "ω [rad/s]"
        assert ax.get_xlim()[1] == pytest.approx(rec.time[0] + 0.5)
    assert panels[-1].get_xlabel().startswith("time [s]")


def test_a_dense_run_is_drawn_as_an_envelope_above_a_window_of_samples(runs):
    recs, _ = runs
    dense = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(40.0, 200), 0.005, 10.0))   # 64 periods
    fig = plots.plot_run(dense, title="Figure 4", window=0.5)
    top, bottom = fig.axes[:2]                      # then their twins, the speed axes
    assert "envelope" in top.get_title()
    assert len(top.get_lines()) == 2 and len(top.get_lines()[0].get_xdata()) < 100   # max and min per slice
    assert bottom.get_xlabel() == "time [s]" and bottom.get_ylabel() == "input η [duty]"
    assert fig.axes[2].get_ylabel() == fig.axes[3].get_ylabel() == "ω [rad/s]"
    assert max(bottom.get_lines()[0].get_xdata()) <= 0.5
    sparse = plots.plot_run(recs[0], window=0.5)    # 10 rad/s for 4 s: 6 periods, drawn sample by sample
    assert "envelope" not in sparse.axes[0].get_title()
    assert len(sparse.axes[0].get_lines()[0].get_xdata()) == len(recs[0])


def _heat_rows():
    rows = []
    for method, scale in (("euler-ls", 10.0), ("oe", 0.001)):
        for f in (5.0, 40.0):
            for noise in (0.0, 1e-3):
                rows.append({"method": method, "frequency": f, "angle_noise": noise,
                             "bias_a_pct": scale * f * (1 + 1e3 * noise)})
    rows[0]["bias_a_pct"] = float("nan")
    return rows


def test_heatmap_text_contrasts_with_its_cell_and_axes_carry_units():
    fig = plots.plot_sweep_heatmap(_heat_rows(), "frequency", "angle_noise", value_label="|bias of a| [%]")
    euler, oe, bar = fig.axes
    assert euler.get_xlabel() == "sine frequency ω [rad/s]" and euler.get_ylabel() == "angle_noise [rad]"
    assert bar.get_ylabel() == "|bias of a| [%]"
    colors = {t.get_text(): t.get_color() for ax in (euler, oe) for t in ax.texts}
    assert colors["fail"] == "k"
    assert colors["8e+02"] == "k"           # the largest value: yellow end of viridis
    assert colors["0.005"] == "w"           # the smallest: dark purple


def test_bias_plot_legend_sits_outside_the_panels_one_entry_per_series():
    rows = [{"method": m, "friction": fr, "dead_zone": dz, "true_a": 25.0, "true_b": 3.0,
             "bias_a_pct": fr - dz, "bias_b_pct": 1.0, "std_a": 0.1, "std_b": 0.01}
            for m in ("euler-ls", "oe") for fr in (0.0, 10.0) for dz in (0.0, 5.0, 15.0)]
    fig = plots.plot_sweep_frequency(rows, others=["dead_zone"], x="friction")
    assert all(ax.get_legend() is None for ax in fig.axes)
    assert len(fig.legends) == 1
    assert _texts(fig.legends[0]) == ["dead_zone=0", "dead_zone=5", "dead_zone=15"]
    assert all(len(ax.get_lines()) == 1 + 3 for ax in fig.axes)      # the zero line and three series
    assert fig.axes[-1].get_xlabel() == "friction [rad/s^2]"


def test_validation_report_has_the_residual_series_labelled_correlations_and_a_legend_off_the_data(runs):
    recs, fits = runs
    est = fits[0]["oe"]
    report = validate(est, recs[0])
    fig = plots.plot_validation(report, est)
    speed, residual, auto, cross = fig.axes
    np.testing.assert_array_equal(residual.get_lines()[0].get_ydata(),
                                  report.measured_speed - report.simulated_speed)
    assert residual.get_ylabel().endswith("[rad/s]") and residual.get_xlabel() == "time [s]"
    assert auto.get_ylabel() and cross.get_ylabel() and "[samples]" in auto.get_xlabel()
    assert _texts(speed.get_legend())[0] == "measured ω"
    fig.canvas.draw()
    legend_box = speed.get_legend().get_window_extent()
    assert legend_box.y0 >= speed.get_window_extent().y1 - 1        # above the panel, not on the data


def test_live_plot_titles_in_words_and_shows_the_final_fit(tmp_path, runs):
    recs, _ = runs
    rec = recs[0]
    exp = Experiment(Sine(10.0, 200), 0.005, 4.0)
    live = plots.LivePlot(exp, counts_per_rev=rec.counts_per_rev, fallback_path=tmp_path / "live.png", interval=0)
    running = RunningEstimator(rec.sample_period, rec.counts_per_rev)
    assert live.ax.get_title().startswith("Live run: waiting")

    class Sample:
        def __init__(self, seq, time_s, duty, counts):
            self.seq, self.time_s, self.duty, self.counts = seq, time_s, duty, counts

    for i in range(len(rec)):
        running.add(i, rec.time[i], rec.duty[i], rec.counts[i])
        live.add(Sample(i, rec.time[i], rec.duty[i], rec.counts[i]), running)
    live.close()
    assert live.ax.get_title().startswith("Live run, estimate so far from")
    est = fit(rec, method="oe")
    live.show_fit(rec, est)
    assert live.ax.get_title().startswith(f"Finished: oe fit a = {est.a:.4g} 1/s")
    assert len(live.ax2.get_lines()) == 2            # measured and model speed
    assert _texts(live.ax.get_legend())[-1] == f"model (oe), fit {est.fit_percent:.1f} %"
    assert (tmp_path / "live.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_design_figure_draws_both_errors_and_one_mark_per_frequency(tmp_path):
    f = np.geomspace(1, 100, 20)
    fig = plots.plot_design(f, 1 / f, 2 / f, marks=[(10.0, "recommended"), (20.0, "article 20")])
    (ax,) = fig.axes
    assert ax.get_xlabel() == "sine frequency ω [rad/s]" and ax.get_ylabel().endswith("[% of value]")
    assert _texts(ax.get_legend()) == ["a", "b"]
    assert len(ax.get_lines()) == 2 + 2                           # a, b and the two marks
    assert [t.get_text() for t in ax.texts] == ["recommended", "article 20"]


def test_a_recording_in_volts_is_drawn_in_volts():
    rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 1.0))
    rec = dataclasses.replace(rec, metadata={**rec.metadata, "input_unit": "V"})
    fig = plots.plot_run(rec)
    assert fig.axes[0].get_ylabel() == "input η [V]"


def test_closed_loop_figure_shows_each_design_tracking_error():
    from motorid.commands.control import compare_designs
    from motorsim.control import parse_reference
    truth = Motor(25.0, 3.0)
    rows = compare_designs(SimRig(truth), [("truth", truth), ("slow", Motor(20.0, 2.7))], "mpc",
                           parse_reference("sine:30,10"), 0.5, 0.005, 16667, duty_weight=1e-4)
    fig = plots.plot_tracking(rows)
    # each design's error in a panel of its own (on one shared panel the truth's line hid under another's)
    error_axes = [ax for ax in fig.axes if "error" in ax.get_ylabel()]
    assert [ax.get_ylabel().split("\n")[0] for ax in error_axes] == ["truth", "slow"]
    for ax, row in zip(error_axes, rows):
        (line, _zero) = ax.get_lines()
        np.testing.assert_array_equal(line.get_ydata(), row.recording.measured_speed() - row.recording.reference)
    assert error_axes[0].get_ylim() == error_axes[1].get_ylim()   # one shared scale
    assert fig.axes[-1].get_ylabel() == "input [duty]"


def test_the_report_draws_tests_apart_not_a_line_across_the_pause_between_them():
    import warnings

    from tests.real_like import sysid_tests
    (_, t1, u1, w1), (_, t2, u2, w2), *_ = sysid_tests(seed=1)
    from motorsim import Recording
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)          # the non-uniform clock, said
        rec = Recording.from_columns(time=np.r_[t1, t2], duty=np.r_[u1, u2], speed=np.r_[w1, w2], input_unit="V")
        est = fit(rec, method="oe", input_delay=0)
        report = validate(est, rec)
    fig = plots.plot_validation(report, est)
    speed = fig.axes[0]
    x = speed.get_lines()[0].get_xdata()
    gap = np.flatnonzero(np.isnan(x))
    assert len(gap) == 1                                      # one break, in the pause (3 s), and only there
    assert x[gap[0] - 1] == pytest.approx(t1[-1]) and x[gap[0] + 1] == pytest.approx(t2[0])
