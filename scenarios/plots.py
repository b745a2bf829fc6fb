"""All plotting (matplotlib, Agg backend, imported only here)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from motorsim.recording import Recording

__all__ = ["plot_run", "plot_overlay", "plot_validation"]


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
