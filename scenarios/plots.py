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

__all__ = ["plot_run", "plot_overlay", "LivePlot"]


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
    ax2.plot(recording.time, recording.speed_rad_s(), color="tab:red", lw=0.8, label="ω")
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
        ax.plot(rec.time, rec.speed_rad_s(), color="0.3", lw=0.8, label="measured ω")
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
        self._t, self._u, self._w = [], [], []
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
