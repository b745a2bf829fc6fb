"""All plotting (matplotlib, Agg backend, imported only here)."""
from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

__all__ = ["plot_run", "plot_overlay", "plot_validation", "plot_sweep_frequency", "plot_sweep_heatmap",
           "plot_design", "plot_prediction", "plot_tracking", "LivePlot"]


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_run(recording: Recording, path, *, title: str = "") -> Path:
    """Duty and measured speed against time (the article's figures 1-4)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.6), constrained_layout=True)
    ax.step(recording.time, recording.duty, where="post", color="tab:blue", lw=0.8, label="duty η")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("duty η", color="tab:blue")
    ax2 = ax.twinx()
    ax2.plot(recording.time, recording.measured_speed(), color="tab:red", lw=0.8, label="ω")
    ax2.set_ylabel("ω [rad/s]", color="tab:red")
    ax.set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_overlay(recordings: Sequence[Recording], estimates: Sequence, path) -> Path:
    """Measured speed against each estimate's simulated speed, one panel per recording."""
    from identify.validation import simulated_speed
    plt = _pyplot()
    n = len(recordings)
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.2 * n), sharex=False, constrained_layout=True, squeeze=False)
    for ax, rec, est in zip(axes[:, 0], recordings, estimates):
        ax.plot(rec.time, rec.measured_speed(), color="0.3", lw=0.8, label="measured ω")
        if est is not None:
            sim = simulated_speed(est.a, est.b, rec, input_delay=int(est.extra.get("input_delay", 0)))
            ax.plot(rec.time, sim, color="tab:orange", lw=0.8, ls="--",
                    label=f"{est.method}: a={est.a:.3g}, b={est.b:.3g}, fit {est.fit_percent:.1f} %")
        ax.set_ylabel("ω [rad/s]")
        ax.legend(loc="upper right", fontsize=7)
        end = rec.time[0] + min(rec.time[-1] - rec.time[0], 2.0)
        ax.set_xlim(rec.time[0], end)
    axes[-1, 0].set_xlabel("time [s] (first 2 s)")
    fig.suptitle("measured vs model speed")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def _series_key(row: dict, others: Sequence[str]) -> str:
    return ", ".join(f"{c}={row[c]:g}" if isinstance(row[c], float) else f"{c}={row[c]}" for c in others)


def plot_sweep_frequency(rows: Sequence[dict], path, *, others: Sequence[str] = (), title: str = "",
                         x: str = "frequency") -> Path:
    """Bias (line) and spread (band, +-1 std) in % of the truth against sine frequency, per estimator.

    ``rows`` are sweep CSV rows (``scenarios.sweep.read_sweep_csv``); one line per value of the
    columns ``others`` (the other grid axes).  ``x`` is the column on the horizontal axis
    (default ``frequency``; logarithmic when its values span more than a factor of 30).
    Rows with no successful fit leave a gap.
    """
    plt = _pyplot()
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(2, len(methods), figsize=(4.2 * len(methods), 6), sharex=True,
                             constrained_layout=True, squeeze=False)
    for j, method in enumerate(methods):
        mine = [r for r in rows if r["method"] == method]
        series = dict.fromkeys(_series_key(r, others) for r in mine)
        for key in series:
            pts = sorted((r for r in mine if _series_key(r, others) == key), key=lambda r: r[x])
            f = np.array([r[x] for r in pts])
            for i, name in enumerate(("a", "b")):
                truth = np.array([r[f"true_{name}"] for r in pts])
                bias = np.array([r[f"bias_{name}_pct"] for r in pts])
                spread = 100 * np.array([r[f"std_{name}"] for r in pts]) / np.abs(truth)
                spread = np.nan_to_num(spread)
                line, = axes[i, j].plot(f, bias, marker="o", ms=3, lw=1, label=key or None)
                axes[i, j].fill_between(f, bias - spread, bias + spread, color=line.get_color(), alpha=0.2)
        for i, name in enumerate(("a", "b")):
            ax = axes[i, j]
            ax.axhline(0, color="0.5", lw=0.6)
            ax.set_ylabel(f"bias of {name} [%]  (band: ±1 std)")
            ax.set_title(f"{method}: {name}")
            ax.grid(alpha=0.3)
        axes[1, j].set_xlabel("sine frequency ω [rad/s]" if x == "frequency" else x)
        xs = [r[x] for r in mine if r[x] > 0]
        if xs and max(xs) > 30 * min(xs):
            for i in range(2):
                axes[i, j].set_xscale("log")
        if others:
            axes[0, j].legend(fontsize=6)
    fig.suptitle(title or f"bias and spread against {x}")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_sweep_heatmap(rows: Sequence[dict], x: str, y: str, path, *, value: str = "bias_a_pct",
                       title: str = "") -> Path:
    """|``value``| over the grid axes ``x`` and ``y`` (CSV columns), one panel per estimator.

    Cells without a successful fit are grey and marked "fail"; each cell shows its value.
    """
    plt = _pyplot()
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
    fig, axes = plt.subplots(1, len(methods), figsize=(4.6 * len(methods), 3.9), constrained_layout=True,
                             squeeze=False)
    for ax, m in zip(axes[0], methods):
        z = grids[m]
        ax.set_facecolor("0.8")
        im = ax.imshow(np.where(z > 0, z, np.nan), origin="lower", aspect="auto", cmap="viridis", norm=norm)
        for (i, k), v in np.ndenumerate(z):
            ax.text(k, i, "fail" if not np.isfinite(v) else f"{v:.2g}", ha="center", va="center", fontsize=6,
                    color="k" if not np.isfinite(v) else "w")
        ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs], rotation=45, fontsize=7)
        ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys], fontsize=7)
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(m)
    fig.colorbar(im, ax=axes[0, -1], label=f"|{value}|")
    fig.suptitle(title or f"|{value}| over {x} × {y}")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_design(frequencies, stderr_a, stderr_b, path, *, marks: Sequence[tuple[float, str]] = (),
                title: str = "") -> Path:
    """Predicted (Cramér-Rao) standard errors of a and b, in %, against sine frequency.

    ``marks`` are ``(frequency, label)`` pairs drawn as vertical lines (the recommendation,
    the article's frequencies).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_validation(report, estimate, path, *, title: str = "") -> Path:
    """Validation figure: measured vs model speed, residual autocorrelation and residual-input
    cross-correlation, each correlation with its 95 % band."""
    plt = _pyplot()
    fig = plt.figure(figsize=(9, 6.4), constrained_layout=True)
    grid = fig.add_gridspec(2, 2)
    ax = fig.add_subplot(grid[0, :])
    ax.plot(report.time, report.measured_speed, color="0.3", lw=0.8, label="measured ω")
    ax.plot(report.time, report.simulated_speed, color="tab:orange", lw=0.8, ls="--",
            label=f"{estimate.method}: a={estimate.a:.4g}, b={estimate.b:.4g}, fit {report.fit_percent:.1f} %")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("ω [rad/s]")
    ax.legend(loc="upper right", fontsize=7)
    ac = fig.add_subplot(grid[1, 0])
    ac.stem(report.lags[1:], report.autocorrelation[1:], basefmt=" ")
    ac.axhspan(-report.band, report.band, color="tab:blue", alpha=0.15, label="95 % band")
    ac.set_title(f"residual autocorrelation (Ljung–Box p = {report.whiteness_p:.2g})", fontsize=9)
    ac.set_xlabel("lag [samples]")
    ac.legend(fontsize=7)
    cc = fig.add_subplot(grid[1, 1])
    cc.stem(report.cross_lags, report.cross_correlation, basefmt=" ")
    cc.axhspan(-report.band, report.band, color="tab:blue", alpha=0.15)
    cc.set_title(f"residual–input cross-correlation (p = {report.independence_p:.2g})", fontsize=9)
    cc.set_xlabel("lag [samples]")
    fig.suptitle(title or "validation")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
class LivePlot:
    """Duty and speed of a bench run as the samples arrive, with the running estimate in the title.

    Opens a matplotlib window when a display is available; otherwise (a headless
    machine) it redraws ``fallback_path`` (PNG, Agg) instead.  Redraws at most every
    ``interval`` s so plotting never holds up the serial reader for long.
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
        self.fig, self.ax = plt.subplots(figsize=(8, 3.6), constrained_layout=True)
        self.ax2 = self.ax.twinx()
        (self._duty_line,) = self.ax.step([], [], where="post", color="tab:blue", lw=0.8)
        (self._speed_line,) = self.ax2.plot([], [], color="tab:red", lw=0.8)
        self.ax.set_xlim(0, experiment.duration)
        lim = max(experiment.duty_limit, 1)
        self.ax.set_ylim(-1.05 * lim, 1.05 * lim)
        self.ax.set_xlabel("time [s]")
        self.ax.set_ylabel("duty η", color="tab:blue")
        self.ax2.set_ylabel("ω [rad/s]", color="tab:red")

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

    def _draw(self) -> None:
        self._next = time.monotonic() + self._interval
        self._duty_line.set_data(self._t, self._u)
        self._speed_line.set_data(self._t, self._w)
        finite = [x for x in self._w if math.isfinite(x)]
        if finite:
            lo, hi = min(finite), max(finite)
            pad = 0.05 * (hi - lo) or 1.0
            self.ax2.set_ylim(lo - pad, hi + pad)
        e = self._running.estimate() if self._running is not None else None
        if e is not None and e.ready:
            self.ax.set_title(f"running {e.model}: a ≈ {e.a:.4g} 1/s, b ≈ {e.b:.4g}  ({e.n_rows} rows)")
        if self.window:
            self.fig.canvas.draw_idle()
            self._plt.pause(0.001)
        else:
            self.fig.savefig(self._path, dpi=100)

    def close(self) -> None:
        """Final redraw; the window stays open until the user closes it (non-blocking here)."""
        self._draw()
        if not self.window:
            self._plt.close(self.fig)


def plot_prediction(prediction, path, *, title: str = "") -> Path:
    """A controller's predicted output and duty against its reference (``Controller.predict``)."""
    plt = _pyplot()
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 4.8), sharex=True, constrained_layout=True)
    ax.plot(prediction.time, prediction.reference, color="0.3", lw=0.8, ls="--", label="reference")
    ax.plot(prediction.time, prediction.output, color="tab:red", lw=0.9,
            label=f"predicted (tracking RMS {prediction.tracking_rms:.3g})")
    ax.legend(loc="upper right", fontsize=8)
    ax2.plot(prediction.time, prediction.duty, color="tab:blue", lw=0.8)
    ax2.set_ylabel("duty")
    ax2.set_xlabel("time [s]")
    ax.set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_tracking(rows: Sequence, path, *, title: str = "", window: float = 0.6) -> Path:
    """Closed-loop runs against their reference: measured (solid) and predicted (dotted) output of each design.

    ``rows`` carry ``design``, ``recording`` and ``prediction`` (``scenarios.control.ClosedLoopRow``).
    """
    plt = _pyplot()
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 5.2), sharex=True, constrained_layout=True)
    first = rows[0].recording
    ax.plot(first.time, first.reference, color="0.2", lw=1.2, ls="--", label="reference")
    for row, color in zip(rows, ("tab:red", "tab:green", "tab:purple", "tab:orange")):
        rec = row.recording
        label = f"{row.design}: measured RMS {row.measured_rms:.3g} (predicted {row.prediction.tracking_rms:.3g})"
        ax.plot(rec.time, rec.measured_speed(), color=color, lw=0.9, label=label)
        ax.plot(row.prediction.time, row.prediction.output, color=color, lw=0.9, ls=":")
        ax2.step(rec.time, rec.duty, where="post", color=color, lw=0.7, label=row.design)
    ax.set_ylabel("ω [rad/s]")
    ax.legend(loc="upper right", fontsize=7)
    ax2.set_ylabel("duty")
    ax2.set_xlabel(f"time [s] (first {window:g} s)")
    ax2.set_xlim(first.time[0], first.time[0] + min(window, first.time[-1] - first.time[0]))
    ax.set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
