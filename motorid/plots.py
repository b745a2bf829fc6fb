"""All plotting (matplotlib, imported only here).

Every ``plot_*`` function builds and returns a :class:`matplotlib.figure.Figure` made
without pyplot (no global state, no backend switch), so a notebook shows it inline;
it writes a PNG only when given ``path``.  :class:`LivePlot` alone uses pyplot, for
its window.
"""
from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from motorsim.recording import Recording

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plot_run", "plot_overlay", "plot_validation", "plot_sweep_frequency", "plot_sweep_heatmap",
           "plot_design", "plot_prediction", "plot_tracking", "plot_bode", "bode_axes", "axis_label", "LivePlot",
           "plot_until"]

#: Dots per inch of the PNGs.
DPI = 110

#: Units of the sweep CSV columns that are not bench knobs.
_COLUMN_LABELS = {"frequency": "sine frequency ω [rad/s]", "amplitude": "sine amplitude [duty]",
                  "true_a": "a [1/s]", "true_b": "b [(rad/s²)/duty]"}


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure
    return Figure(figsize=(width, height), layout="constrained")


def _finish(fig: Figure, path) -> Figure:
    """Write ``fig`` to ``path`` (if given) in the format its extension names, atomically.

    The figure is drawn into memory first, so a link, FIFO or device at ``path`` is never
    opened, and the file that appears is exactly ``path``: no extension is added.
    """
    if path is not None:
        import io

        from motorsim.files import FIGURE_SUFFIXES, OutputFileError, write_bytes_atomically
        suffix = Path(path).suffix.lower()
        if suffix not in FIGURE_SUFFIXES:
            raise OutputFileError(f"figure {path}: the extension names the format written; "
                                  f"give one of {', '.join(FIGURE_SUFFIXES)}")
        buffer = io.BytesIO()
        fig.savefig(buffer, format=suffix[1:], dpi=DPI)
        write_bytes_atomically(path, buffer.getvalue())
    return fig


def axis_label(column: str) -> str:
    """Axis label of a sweep CSV column, with its unit (``"friction"`` -> ``"friction [rad/s^2]"``)."""
    if column in _COLUMN_LABELS:
        return _COLUMN_LABELS[column]
    from motorsim.rig import bench_knobs
    for k in bench_knobs():
        if k.name == column:
            return f"{column} [{k.unit}]" if k.unit else column
    return column


def _envelope(t: np.ndarray, y: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin centres, minimum and maximum of ``y`` in ``bins`` equal slices of the samples."""
    edges = np.linspace(0, len(t), bins + 1).astype(int)
    centre, lo, hi = [], [], []
    for i, j in zip(edges[:-1], edges[1:]):
        seg = y[i:j][np.isfinite(y[i:j])]
        if j > i and len(seg):
            centre.append(t[(i + j - 1) // 2])
            lo.append(seg.min())
            hi.append(seg.max())
    return np.array(centre), np.array(lo), np.array(hi)


def _duty_speed_axes(ax, t, duty, speed, *, envelope: int = 0, input_unit: str = "duty") -> None:
    """Input (left axis, blue, in ``input_unit``) and speed (right axis, red), as lines, or as
    min-max envelopes over ``envelope`` slices of the samples when ``envelope`` > 0."""
    ax2 = ax.twinx()
    if envelope:
        for axis, y, color, label in ((ax, duty, "tab:blue", "duty η"), (ax2, speed, "tab:red", "ω")):
            c, lo, hi = _envelope(t, np.asarray(y, float), envelope)
            axis.plot(c, hi, color=color, lw=1.2, label=f"{label}: max and min per slice")
            axis.plot(c, lo, color=color, lw=1.2)
            axis.fill_between(c, lo, hi, color=color, alpha=0.08, lw=0)
    else:
        ax.step(t, duty, where="post", color="tab:blue", lw=0.8, label="duty η")
        ax2.plot(t, speed, color="tab:red", lw=0.8, label="ω")
    ax.set_ylabel(f"input η [{input_unit}]", color="tab:blue")
    ax2.set_ylabel("ω [rad/s]", color="tab:red")


def plot_run(recording: Recording, path=None, *, title: str = "", window: float = 1.0) -> Figure:
    """Duty and measured speed against time (the article's figures 1-4).

    Parameters
    ----------
    recording : Recording
    path : str or path-like, optional
        Where to write the PNG; nothing is written without it.
    title : str
    window : float
        Length in s of the lower panel, the start of the run drawn sample by sample.
        The upper panel shows the whole run, as a min-max envelope over slices of about
        three periods when the duty changes sign more than 60 times (30 periods of a
        sine: too dense to draw as lines).

    Returns
    -------
    matplotlib.figure.Figure
    """
    t, duty, speed = recording.time, recording.duty, recording.measured_speed()
    crossings = int(np.count_nonzero(np.diff(np.sign(duty)) != 0))
    fig = _figure(8, 5.6)
    top, bottom = fig.subplots(2, 1)
    dense = crossings > 60
    _duty_speed_axes(top, t, duty, speed, envelope=max(10, crossings // 6) if dense else 0,
                     input_unit=recording.input_unit)
    top.set_title(f"whole run ({t[-1] - t[0]:.3g} s)" + (", min–max envelope" if dense else ""),
                  fontsize=9)
    start = t[0]
    keep = t <= start + window
    _duty_speed_axes(bottom, t[keep], duty[keep], speed[keep], input_unit=recording.input_unit)
    bottom.set_title(f"first {window:g} s", fontsize=9)
    bottom.set_xlabel("time [s]")
    fig.suptitle(title or "duty and speed")
    return _finish(fig, path)


def plot_overlay(recordings: Sequence[Recording], estimates: Sequence[Mapping[str, Any]], path=None, *,
                 labels: Sequence[str] = (), window: float = 1.0) -> Figure:
    """Measured speed against each method's simulated speed, one panel per recording.

    Parameters
    ----------
    recordings : sequence of Recording
    estimates : sequence of mapping
        Per recording, ``{method: Estimate}`` (an estimate may be None: that method failed).
    path : str or path-like, optional
        Where to write the PNG; nothing is written without it.
    labels : sequence of str
        Panel titles (e.g. the input, ``"eta_1 = 200 sin(10 t)"``).
    window : float
        Seconds shown from the start of each recording.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from identify.checks.validation import simulated_speed
    n = len(recordings)
    fig = _figure(9.5, 2.3 * n + 0.4)
    axes = fig.subplots(n, 1, squeeze=False)[:, 0]
    colors = ("tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:cyan")
    for i, (ax, rec, fits) in enumerate(zip(axes, recordings, estimates)):
        keep = rec.time <= rec.time[0] + window
        ax.plot(rec.time[keep], rec.measured_speed()[keep], color="k", lw=1.6, alpha=0.55, label="measured ω")
        for color, (method, est) in zip(colors, fits.items()):
            if est is None:
                ax.plot([], [], color=color, lw=1, ls="--", label=f"{method}: failed")
                continue
            sim = simulated_speed(est.a, est.b, rec, input_delay=est.input_delay)
            ax.plot(rec.time[keep], sim[keep], color=color, lw=1, ls="--",
                    label=f"{method}: a={est.a:.3g} 1/s, b={est.b:.3g}, fit {est.fit_percent:.1f} %")
        ax.set_ylabel("ω [rad/s]")
        ax.set_title(labels[i] if i < len(labels) else f"recording {i + 1}", fontsize=9, loc="left")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
        ax.set_xlim(rec.time[0], rec.time[0] + window)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(f"time [s] (first {window:g} s)")
    fig.suptitle("measured speed and each model's simulated speed")
    return _finish(fig, path)


def _series_key(row: dict, others: Sequence[str]) -> str:
    return ", ".join(f"{c}={row[c]:g}" if isinstance(row[c], float) else f"{c}={row[c]}" for c in others)


def plot_sweep_frequency(rows: Sequence[dict], path=None, *, others: Sequence[str] = (), title: str = "",
                         x: str = "frequency") -> Figure:
    """Bias (line) and spread (band, +-1 std) in % of the truth against sine frequency, per estimator.

    ``rows`` are sweep CSV rows (``scenarios.sweep.read_sweep_csv``); one line per value of the
    columns ``others`` (the other grid axes), named in one legend right of the panels (colours
    repeat after ten series, with another line style).
    ``x`` is the column on the horizontal axis (default ``frequency``; logarithmic when its
    values span more than a factor of 30).  Rows with no successful fit leave a gap.  The
    PNG is written to ``path`` when given; the figure is returned.
    """
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig = _figure(4.2 * len(methods) + (3.2 if others else 0), 6)
    axes = fig.subplots(2, len(methods), sharex=True, squeeze=False)
    for j, method in enumerate(methods):
        mine = [r for r in rows if r["method"] == method]
        for k, key in enumerate(dict.fromkeys(_series_key(r, others) for r in mine)):
            pts = sorted((r for r in mine if _series_key(r, others) == key), key=lambda r: r[x])
            style = {"color": f"C{k % 10}", "ls": ("-", "--", ":", "-.")[k // 10 % 4]}
            f = np.array([r[x] for r in pts])
            for i, name in enumerate(("a", "b")):
                truth = np.array([r[f"true_{name}"] for r in pts])
                bias = np.array([r[f"bias_{name}_pct"] for r in pts])
                spread = np.nan_to_num(100 * np.array([r[f"std_{name}"] for r in pts]) / np.abs(truth))
                axes[i, j].plot(f, bias, marker="o", ms=3, lw=1, label=key or None, **style)
                axes[i, j].fill_between(f, bias - spread, bias + spread, color=style["color"], alpha=0.2)
        for i, name in enumerate(("a", "b")):
            ax = axes[i, j]
            ax.axhline(0, color="0.5", lw=0.6)
            ax.set_ylabel(f"bias of {name} [%]  (band: ±1 std)")
            ax.set_title(f"{method}: {name}")
            ax.grid(alpha=0.3)
        axes[1, j].set_xlabel(axis_label(x))
        xs = [r[x] for r in mine if r[x] > 0]
        if xs and max(xs) > 30 * min(xs):
            for i in range(2):
                axes[i, j].set_xscale("log")
    if others:
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside right upper", fontsize=7, title="other grid axes",
                   title_fontsize=8, frameon=False)
    fig.suptitle(title or f"bias and spread against {x}")
    return _finish(fig, path)


def _text_color(rgba) -> str:
    """Black on light cells, white on dark ones (relative luminance, ITU-R BT.709)."""
    r, g, b = rgba[:3]
    return "k" if 0.2126 * r + 0.7152 * g + 0.0722 * b > 0.5 else "w"


def plot_sweep_heatmap(rows: Sequence[dict], x: str, y: str, path=None, *, value: str = "bias_a_pct",
                       title: str = "", value_label: str = "") -> Figure:
    """The absolute ``value`` over the grid axes ``x`` and ``y`` (CSV columns), one panel per estimator.

    Cells without a successful fit are grey and marked "fail"; each cell shows its value in
    black or white, whichever reads better on the cell's colour.  The colour bar (logarithmic)
    is titled ``value_label`` (default: the absolute ``value``).  The PNG is written to ``path`` when
    given; the figure is returned.
    """
    from matplotlib.colors import LogNorm
    methods = list(dict.fromkeys(r["method"] for r in rows))
    xs = sorted({r[x] for r in rows})
    ys = sorted({r[y] for r in rows})
    grids = {}
    for m in methods:
        z = np.full((len(ys), len(xs)), np.nan)
        for r in rows:
            if r["method"] == m:
                z[ys.index(r[y]), xs.index(r[x])] = abs(r[value])
        grids[m] = z
    finite = np.concatenate([z[np.isfinite(z) & (z > 0)] for z in grids.values()])
    norm = LogNorm(vmin=finite.min(), vmax=finite.max()) if len(finite) else None
    fig = _figure(4.6 * len(methods) + 1.2, 4.2)
    axes = fig.subplots(1, len(methods), squeeze=False)[0]
    im = None
    for ax, m in zip(axes, methods):
        z = grids[m]
        ax.set_facecolor("0.8")
        im = ax.imshow(np.where(z > 0, z, np.nan), origin="lower", aspect="auto", cmap="viridis", norm=norm)
        for (i, k), v in np.ndenumerate(z):
            color = "k" if not np.isfinite(v) or v <= 0 else _text_color(im.cmap(im.norm(v)))
            ax.text(k, i, "fail" if not np.isfinite(v) else f"{v:.2g}", ha="center", va="center", fontsize=7,
                    color=color)
        ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs], rotation=45, fontsize=7)
        ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys], fontsize=7)
        ax.set_xlabel(axis_label(x))
        ax.set_ylabel(axis_label(y))
        ax.set_title(m)
    assert im is not None   # one panel per method, and rows are never empty here
    bar = fig.colorbar(im, ax=list(axes))
    bar.set_label(value_label or f"|{value}|")
    fig.suptitle(title or f"|{value}| over {x} × {y}")
    return _finish(fig, path)


def plot_design(frequencies, stderr_a, stderr_b, path=None, *, marks: Sequence[tuple[float, str]] = (),
                title: str = "") -> Figure:
    """Predicted (Cramér-Rao) standard errors of a and b, in %, against sine frequency.

    ``marks`` are ``(frequency, label)`` pairs drawn as vertical lines (the recommendation,
    the article's frequencies).  The PNG is written to ``path`` when given; the figure is
    returned.
    """
    fig = _figure(7, 4)
    ax = fig.subplots()
    ax.loglog(frequencies, stderr_a, label="a", color="tab:blue")
    ax.loglog(frequencies, stderr_b, label="b", color="tab:red")
    for f, label in marks:
        ax.axvline(f, color="0.4", lw=0.7, ls="--")
        ax.text(f, ax.get_ylim()[1], label, rotation=90, va="top", ha="right", fontsize=7)
    ax.set_xlabel("sine frequency ω [rad/s]")
    ax.set_ylabel("predicted standard error [% of value]")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    ax.set_title(title or "Cramér–Rao standard error against frequency")
    return _finish(fig, path)


def plot_until(result, path=None, *, title: str = "") -> Figure:
    """An ``--until`` run: each round's 95 % intervals of a and b (in % of the value) against motor time,
    the target, and the duty of every run one after the other.

    ``result`` is an :class:`identify.adaptive.UntilResult`.  The PNG is written to ``path`` when
    given; the figure is returned.
    """
    fig = _figure(7, 5)
    top, bottom = fig.subplots(2, 1, height_ratios=(3, 2))
    for name, color in (("a", "tab:blue"), ("b", "tab:red")):
        pts = [(r.motor_time, r.reach[name]) for r in result.rounds if math.isfinite(r.reach.get(name, math.inf))]
        if pts:
            t, reach = zip(*pts)
            top.semilogy(t, reach, "o-", color=color, label=f"{name}: 95 % interval, ± % of value")
    top.axhline(result.target, color="0.3", ls="--", lw=0.8, label=f"target ±{result.target:g} %")
    top.set_xlabel("motor time [s]")
    top.set_ylabel("interval [± %]")
    top.grid(alpha=0.3, which="both")
    top.legend(fontsize=8)
    verdict = "target reached" if result.reached else f"stopped: {result.stop}"
    top.set_title(title or f"identify until ±{result.target:g} %: {verdict} after {result.motor_time:.3g} s")
    rec = result.recording
    k = (rec.seq - rec.seq[0]) * rec.sample_period
    bottom.plot(k, rec.duty, lw=0.6, color="0.2")
    bottom.set_xlabel("time, runs one after the other [s]")
    bottom.set_ylabel("duty")
    bottom.grid(alpha=0.3)
    return _finish(fig, path)


#: An interval longer than this many median intervals is a gap a line is not drawn across (a pause between tests).
GAP_FACTOR = 1.5


def broken_at_gaps(t: np.ndarray, *series: np.ndarray) -> tuple[np.ndarray, ...]:
    """``t`` and ``series`` with a nan row inserted in every gap (an interval over :data:`GAP_FACTOR` median
    intervals), so that a line plot draws the runs apart instead of a straight line across the pause."""
    t = np.asarray(t, dtype=float)
    steps = np.diff(t)
    if len(steps) == 0:
        return (t, *(np.asarray(y, dtype=float) for y in series))
    gaps = np.flatnonzero(steps > GAP_FACTOR * np.median(steps)) + 1
    return (np.insert(t, gaps, np.nan), *(np.insert(np.asarray(y, dtype=float), gaps, np.nan) for y in series))


def plot_validation(report, estimate, path=None, *, title: str = "", frequency_response=None) -> Figure:
    """Validation figure: measured vs model speed, their difference against time, the residual
    autocorrelation and the residual-input cross-correlation, each correlation with its 95 % band,
    given ``frequency_response``, a Bode panel of the data with the model (:func:`bode_axes`), and, for
    the default's estimate, its part checks: ``a`` and ``b`` on each part of the recording (:func:`_part_axes`).

    ``report`` is an ``identify.checks.validation.ValidationReport`` of ``estimate``;
    ``frequency_response`` an ``identify.frequency.frequency_estimate.FrequencyResponse`` of the same
    recording.  The PNG is written to ``path`` when given; the figure is returned.
    """
    bode = frequency_response is not None
    checks = tuple(getattr(getattr(estimate, "selection", None), "checks", ()) or ())
    heights = [1.2, 0.8, 1.0] + ([1.1] if bode else []) + ([0.9] if checks else [])
    fig = _figure(9, 8.4 + (3.0 if bode else 0.0) + (2.4 if checks else 0.0))
    grid = fig.add_gridspec(len(heights), 2, height_ratios=heights)
    if checks:
        _part_axes(fig.add_subplot(grid[len(heights) - 1, 0]), fig.add_subplot(grid[len(heights) - 1, 1]),
                   estimate, checks)
    if bode:
        gain_ax, phase_ax = fig.add_subplot(grid[3, 0]), fig.add_subplot(grid[3, 1])
        bode_axes(gain_ax, phase_ax, frequency_response, [frequency_response.model_of(estimate)])
        gain_ax.set_xlabel("ω [rad/s]")
        gain_ax.set_title(f"frequency response ({frequency_response.method}) and {estimate.method}", fontsize=9)
        gain_ax.legend(loc="lower left", fontsize=6, frameon=False)
    from motorsim.units import SPEED_UNITS
    unit = getattr(estimate, "speed_unit", "rad/s")        # the unit the data came in; the fit is in rad/s
    per = 1.0 / SPEED_UNITS[unit]
    ax = fig.add_subplot(grid[0, :])
    t, measured, simulated = broken_at_gaps(report.time, report.measured_speed, report.simulated_speed)
    ax.plot(t, per * measured, color="0.3", lw=0.8, label="measured ω")
    ax.plot(t, per * simulated, color="tab:orange", lw=0.8, ls="--",
            label=f"{estimate.method}: a={estimate.a:.4g} 1/s, b={estimate.b:.4g} (rad/s²)/{estimate.input_unit}, "
                  f"fit {report.fit_percent:.1f} %")
    ax.set_ylabel(f"ω [{unit}]")
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, fontsize=7, frameon=False)
    res = fig.add_subplot(grid[1, :], sharex=ax)
    res.plot(t, per * (measured - simulated), color="tab:purple", lw=0.7)
    res.axhline(0, color="0.5", lw=0.6)
    res.set_xlabel("time [s]")
    res.set_ylabel(f"measured − model\nω [{unit}]")
    res.grid(alpha=0.3)
    ac = fig.add_subplot(grid[2, 0])
    ac.stem(report.lags[1:], report.autocorrelation[1:], basefmt=" ")
    ac.axhspan(-report.band, report.band, color="tab:blue", alpha=0.15, label="95 % band of white noise")
    ac.set_title(f"residual autocorrelation (Ljung–Box p = {report.whiteness_p:.2g})", fontsize=9)
    ac.set_xlabel("lag [samples]")
    ac.set_ylabel("autocorrelation of the residual")
    cc = fig.add_subplot(grid[2, 1])
    cc.stem(report.cross_lags, report.cross_correlation, basefmt=" ")
    cc.axhspan(-report.band, report.band, color="tab:blue", alpha=0.15)
    cc.set_title(f"residual–input cross-correlation (p = {report.independence_p:.2g})", fontsize=9)
    cc.set_xlabel("lag [samples] (input leads for positive lags)")
    cc.set_ylabel("cross-correlation residual–duty")
    fig.legend(*ac.get_legend_handles_labels(), loc="outside lower center", fontsize=7, frameon=False)
    fig.suptitle(title or "validation")
    return _finish(fig, path)


def _part_axes(a_ax, b_ax, estimate, checks) -> None:
    """The part checks (``identify.default.consistency``): each split's two parts' ``a`` and ``b`` with their 95 %
    intervals, against the answer's interval; a split whose parts differ is drawn in red."""
    ci = estimate.confidence_interval(0.95)
    for ax, name, unit in ((a_ax, "a", "1/s"), (b_ax, "b", f"(rad/s²)/{estimate.input_unit}")):
        ax.axhspan(*ci[name], color="tab:orange", alpha=0.2, lw=0, label="the answer's 95 % interval")
        ax.axhline(estimate.value(name), color="tab:orange", lw=0.8)
        ticks, labels = [], []
        for i, check in enumerate(checks):
            values = check.a if name == "a" else check.b
            intervals = check.a_interval if name == "a" else check.b_interval
            colour = "tab:green" if check.agree else "tab:red"
            for j in (0, 1):
                x = 3 * i + j
                low, high = intervals[j]
                ax.errorbar([x], [values[j]], yerr=[[values[j] - low], [high - values[j]]], fmt="o", ms=3,
                            color=colour, capsize=2, lw=0.9)
                ticks.append(x)
                labels.append(check.parts[j])
        ax.set_xticks(ticks, labels, rotation=40, ha="right", fontsize=6)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.set_title(f"{name} on parts of the recording (red: the parts differ)", fontsize=9)
        ax.grid(alpha=0.3, axis="y")


_MODEL_COLOURS = ("tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def bode_axes(gain_ax, phase_ax, frf, models: Sequence = (), *, level: float = 0.95, distortion=None) -> None:
    """Draw a frequency response with its bounds, models with their bands and their departures, on two axes.

    ``frf`` is an ``identify.frequency.frequency_estimate.FrequencyResponse``, ``models`` are its
    ``ModelResponse``s; ``distortion`` an optional ``BestLinearApproximation`` whose detection lines
    are drawn on the gain axis (odd and even distortion, and the noise).
    """
    w = frf.omega
    low, high = frf.gain_bounds_db(level)
    phase, half = frf.phase_deg(), frf.phase_bounds_deg(level)
    pct = f"{100 * level:g} %"
    gain_ax.fill_between(w, np.maximum(low, frf.gain_db().min() - 40), high, color="0.6", alpha=0.35, lw=0,
                         label=f"data, {pct} bound")
    gain_ax.plot(w, frf.gain_db(), ".", color="0.2", ms=3, label=f"data ({frf.method})")
    phase_ax.fill_between(w, phase - half, phase + half, color="0.6", alpha=0.35, lw=0)
    phase_ax.plot(w, phase, ".", color="0.2", ms=3)
    for colour, m in zip(_MODEL_COLOURS * 4, models):
        gm = 20 * np.log10(np.abs(m.response))
        r = m.radius(level) / np.abs(m.response)
        pm = np.degrees(np.unwrap(np.angle(m.response)))
        pm += 360.0 * np.round((phase[0] - pm[0]) / 360.0)
        gain_ax.plot(w, gm, color=colour, lw=1.2, label=m.name)
        gain_ax.fill_between(w, gm + 20 * np.log10(np.maximum(1 - r, 1e-3)), gm + 20 * np.log10(1 + r),
                             color=colour, alpha=0.25, lw=0)
        phase_ax.plot(w, pm, color=colour, lw=1.2)
        dp = np.degrees(np.arcsin(np.minimum(r, 1)))
        phase_ax.fill_between(w, pm - dp, pm + dp, color=colour, alpha=0.25, lw=0)
        out = ~frf.covers(m.response, level)
        if np.any(out):
            gain_ax.plot(w[out], gm[out], "x", color=colour, ms=5, label=f"{m.name} outside the data's bound")
    if distortion is not None:
        # powers relative to the mean linear output per line, drawn as gains: every excited line has the
        # same |U|, so output power / |U|^2 is a gain and the mean linear output sits at the mean |G|^2
        shift = 10 * np.log10(np.mean(np.abs(distortion.frequency_response.response) ** 2))
        for kind, marker in (("odd", "v"), ("even", "^")):
            sel = distortion.detection_kind == kind
            gain_ax.plot(distortion.detection_omega[sel], distortion.distortion_db()[sel] + shift, marker,
                         ms=3, color="tab:red" if kind == "odd" else "tab:blue", ls="none",
                         label=f"{kind}-order distortion")
        gain_ax.plot(distortion.detection_omega, distortion.noise_db() + shift, "_", color="0.4", ms=4,
                     ls="none", label="noise")
    gain_ax.set_xscale("log")
    gain_ax.set_ylabel(f"gain [dB re 1 (rad/s)/{frf.input_unit}]")
    gain_ax.grid(alpha=0.3, which="both")
    phase_ax.set_xscale("log")
    phase_ax.set_ylabel("phase [deg]")
    phase_ax.set_xlabel("ω [rad/s]")
    phase_ax.grid(alpha=0.3, which="both")


def plot_bode(frf, models: Sequence = (), path=None, *, title: str = "", level: float = 0.95,
              distortion=None) -> Figure:
    """Bode plot of a frequency response with its bounds and coherence, and models with their bands.

    ``frf``, ``models`` and ``distortion`` as :func:`bode_axes`.  A cross marks each frequency
    where a model leaves the data's bound.  The PNG is written to ``path`` when given.
    """
    fig = _figure(8, 8)
    grid = fig.add_gridspec(3, 1, height_ratios=(1.3, 1, 0.5))
    gain_ax = fig.add_subplot(grid[0])
    phase_ax = fig.add_subplot(grid[1], sharex=gain_ax)
    coh = fig.add_subplot(grid[2], sharex=gain_ax)
    bode_axes(gain_ax, phase_ax, frf, models, level=level, distortion=distortion)
    phase_ax.set_xlabel("")
    coh.plot(frf.omega, frf.coherence, ".", color="0.2", ms=3)
    coh.set_ylim(0, 1.05)
    coh.set_ylabel("coherence")
    coh.set_xlabel("ω [rad/s]" + (f"   (resolution {frf.resolution:.3g} rad/s)" if frf.resolution else ""))
    coh.grid(alpha=0.3, which="both")
    gain_ax.legend(loc="lower left", fontsize=7, frameon=False)
    fig.suptitle(title or "frequency response duty → speed")
    return _finish(fig, path)


class LivePlot:
    """Duty and speed of a bench run as the samples arrive, with the running estimate in the title.

    Opens a matplotlib window when a display is available; otherwise (a headless
    machine) it redraws ``fallback_path`` (PNG, Agg) instead.  Redraws at most every
    ``interval`` s so plotting never holds up the serial reader for long.  After the run,
    :meth:`show_fit` draws the fitted model's speed over the measured one.
    """

    def __init__(self, experiment, *, counts_per_rev: int, fallback_path, interval: float = 0.5):
        import matplotlib
        self._rad_per_count = 2 * math.pi / counts_per_rev
        self.window = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
                           or sys.platform in ("win32", "darwin"))
        if not self.window:
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        self._plt = plt
        self._path = Path(fallback_path)
        self._interval = float(interval) if self.window else max(float(interval), 1.0)   # PNGs are slow
        self._next = 0.0
        self._t: list[float] = []
        self._u: list[float] = []
        self._w: list[float] = []
        self._prev = None
        self._running = None
        if self.window:
            plt.ion()
        self.fig, self.ax = plt.subplots(figsize=(8, 3.8), constrained_layout=True)
        self.ax2 = self.ax.twinx()
        (self._duty_line,) = self.ax.step([], [], where="post", color="tab:blue", lw=0.8, label="duty η")
        (self._speed_line,) = self.ax2.plot([], [], color="tab:red", lw=0.8, label="measured ω")
        self.ax.set_xlim(0, experiment.duration)
        lim = max(experiment.duty_limit, 1)
        self.ax.set_ylim(-1.05 * lim, 1.05 * lim)
        self.ax.set_xlabel("time [s]")
        self.ax.set_ylabel("duty η [duty]", color="tab:blue")
        self.ax2.set_ylabel("ω [rad/s]", color="tab:red")
        self.ax.set_title("Live run: waiting for the motor's first samples", fontsize=10)

    def add(self, sample, running) -> None:
        """Add one sample (``seq, time_s, duty, counts``); ``running.estimate()`` is asked at redraws."""
        rad = self._rad_per_count
        w = math.nan
        if self._prev is not None and sample.seq == self._prev.seq + 1:
            w = (sample.counts - self._prev.counts) * rad / (sample.time_s - self._prev.time_s)
        self._prev = sample
        self._t.append(sample.time_s)
        self._u.append(sample.duty)
        self._w.append(w)
        self._running = running
        if time.monotonic() >= self._next:
            self._draw()

    def _rescale_speed(self, *series) -> None:
        finite = [x for s in series for x in s if math.isfinite(x)]
        if finite:
            lo, hi = min(finite), max(finite)
            pad = 0.05 * (hi - lo) or 1.0
            self.ax2.set_ylim(lo - pad, hi + pad)

    def _show(self) -> None:
        if self.window:
            self.fig.canvas.draw_idle()
            self._plt.pause(0.001)
        else:       # a figure watched during the run: each redraw replaces it at once, never written through a link
            import io

            from motorsim.files import write_bytes_atomically
            buffer = io.BytesIO()
            self.fig.savefig(buffer, format="png", dpi=100)
            write_bytes_atomically(self._path, buffer.getvalue(), at_once=True)

    def _draw(self) -> None:
        self._next = time.monotonic() + self._interval
        self._duty_line.set_data(self._t, self._u)
        self._speed_line.set_data(self._t, self._w)
        self._rescale_speed(self._w)
        e = self._running.estimate() if self._running is not None else None
        if e is not None and e.ready:
            self.ax.set_title(f"Live run, estimate so far from {e.n_rows} samples: "
                              f"a ≈ {e.a:.4g} 1/s, b ≈ {e.b:.4g} (rad/s²)/duty", fontsize=10)
        else:
            self.ax.set_title(f"Live run: {len(self._t)} samples received, too few to estimate yet",
                              fontsize=10)
        self._show()

    def show_fit(self, recording: Recording, estimate) -> None:
        """Draw ``estimate``'s simulated speed on ``recording`` over the measured speed, with the fit in the title."""
        from identify.checks.validation import simulated_speed
        sim = simulated_speed(estimate.a, estimate.b, recording,
                              input_delay=estimate.input_delay)
        self.ax2.plot(recording.time, sim, color="k", lw=0.9, ls="--",
                      label=f"model ({estimate.method}), fit {estimate.fit_percent:.1f} %")
        self._rescale_speed(self._w, sim)
        self.ax.set_title(f"Finished: {estimate.method} fit a = {estimate.a:.4g} 1/s, "
                          f"b = {estimate.b:.4g} (rad/s²)/duty, fit {estimate.fit_percent:.1f} %", fontsize=10)
        handles = [*self.ax.get_legend_handles_labels()[0], *self.ax2.get_legend_handles_labels()[0]]
        self.ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=7,
                       frameon=False)
        self._show()

    def close(self) -> None:
        """Final redraw; the window stays open until the user closes it (non-blocking here)."""
        self._draw()
        if not self.window:
            self._plt.close(self.fig)


def plot_prediction(prediction, path=None, *, title: str = "") -> Figure:
    """A controller's predicted output and duty against its reference (``Controller.predict``)."""
    fig = _figure(8, 4.8)
    ax, ax2 = fig.subplots(2, 1, sharex=True)
    ax.plot(prediction.time, prediction.reference, color="0.3", lw=0.8, ls="--", label="reference")
    ax.plot(prediction.time, prediction.output, color="tab:red", lw=0.9,
            label=f"predicted (tracking RMS {prediction.tracking_rms:.3g})")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_ylabel("output [rad/s, or rad for position]")
    ax2.plot(prediction.time, prediction.duty, color="tab:blue", lw=0.8)
    ax2.set_ylabel("duty")
    ax2.set_xlabel("time [s]")
    ax.set_title(title)
    return _finish(fig, path)


def plot_tracking(rows: Sequence, path=None, *, title: str = "", window: float = 0.6) -> Figure:
    """Closed-loop runs against their reference: output, tracking error and input of each design.

    The top panel draws the measured (solid) and predicted (dotted) output of each design over the
    reference; where good designs track alike those lines lie on top of each other, so each run's
    tracking error (measured minus reference) has a panel of its own below, on one shared scale,
    where no design's line can hide another's. ``rows`` carry ``design``, ``recording`` and
    ``prediction`` (``motorid.commands.control.ClosedLoopRow``).
    """
    fig = _figure(10.5, 5.6 + 1.1 * len(rows))
    axes = fig.subplots(2 + len(rows), 1, sharex=True, gridspec_kw={"height_ratios": [2, *[1] * len(rows), 1]})
    ax, errors, ax2 = axes[0], axes[1:-1], axes[-1]
    first = rows[0].recording
    ax.plot(first.time, first.reference, color="0.2", lw=1.2, ls="--", label="reference")
    for row, color, ax_err in zip(rows, ("tab:red", "tab:green", "tab:purple", "tab:orange"), errors):
        rec = row.recording
        label = f"{row.design}: measured RMS {row.measured_rms:.3g} (predicted {row.prediction.tracking_rms:.3g})"
        ax.plot(rec.time, rec.measured_speed(), color=color, lw=0.9, label=label)
        ax.plot(row.prediction.time, row.prediction.output, color=color, lw=0.9, ls=":")
        ax_err.plot(rec.time, rec.measured_speed() - rec.reference, color=color, lw=0.9)
        ax_err.axhline(0.0, color="0.5", lw=0.6)
        ax_err.set_ylabel(f"{row.design}\nerror [rad/s]", fontsize=8)
        ax2.step(rec.time, rec.duty, where="post", color=color, lw=0.7, label=row.design)
    for ax_err in errors[1:]:
        ax_err.sharey(errors[0])
    errors[0].set_title("tracking error of each design (measured − reference), one shared scale", fontsize=9)
    ax.set_ylabel("ω [rad/s]")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)   # outside: never over the data
    ax2.set_ylabel(f"input [{first.input_unit}]")
    ax2.set_xlabel(f"time [s] (first {window:g} s)")
    ax2.set_xlim(first.time[0], first.time[0] + min(window, first.time[-1] - first.time[0]))
    ax.set_title(title)
    return _finish(fig, path)
