"""Measure the firmware under emulation: size, sample rates per baud rate, encoder ceiling, controllers, speed.

Run from the repository root (it builds what it needs)::

    motorid bench firmware                  # everything, ~3 min
    motorid bench firmware --only encoder   # (or python -m motorid.bench.firmware)
    motorid bench firmware --only control   # each controller's cost per sample, highest rate

Prints Markdown tables (the figures in ``hardware/firmware/README.md`` come from here).
Every figure is measured under simavr, which is cycle-counted but not cycle-exact for every
peripheral; treat the encoder ceiling as a guide for the real board, not a guarantee.
"""
from __future__ import annotations

import argparse
import re
import subprocess
from typing import Sequence
from urllib.parse import urlencode

import numpy as np

from hardware import protocol as P
from hardware.sim.device_link import DeviceLink
from hardware.sim.launcher import build, open_avr_sim

__all__ = ["firmware_size", "link_capacity", "encoder_ceiling", "controller_cost", "emulation_speed",
           "bench_firmware"]

_FLASH, _RAM = 32768, 2048


def firmware_size() -> dict[str, int]:
    """Flash and RAM bytes of the default build (``avr-size``)."""
    elf, _ = build()
    out = subprocess.run(["avr-size", "-C", "--mcu=atmega328p", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    sizes = {}
    for key, label in (("flash", "Program"), ("ram", "Data")):
        found = re.search(label + r":\s+(\d+)", out)
        if found is None:
            raise RuntimeError(f"avr-size output must have a {label!r} line, got {out!r}")
        sizes[key] = int(found.group(1))
    return sizes


def _run(query: dict, config: P.Config, wave, baudrate: int = 250000):
    with open_avr_sim("avr-sim://?" + urlencode(query), baudrate, 0.02) as port:
        link = DeviceLink(port)
        link.hello(timeout=5.0)
        result = link.run(config, wave, timeout=60.0)
    return result, port.avr_simulation.stats


def link_capacity(baudrates=(115200, 250000, 500000), rates=(250, 500, 1000, 2000),
                  duration: float = 1.0) -> list[dict]:
    """Samples dropped at each baud rate and sample rate (one sine run each).

    Parameters
    ----------
    baudrates : sequence of int
        Firmware builds to try.
    rates : sequence of int
        Sample rates in Hz.
    duration : float
        Seconds per run.
    """
    rows = []
    for baud in baudrates:
        build(baud)
        for rate in rates:
            period_us = round(1e6 / rate)
            n = int(duration * rate)
            inc = round(20.0 * period_us * 1e-6 / (2 * np.pi) * 2**32) % 2**32
            run, _ = _run({"a": 25, "b": 3}, P.Config(period_us, n, 255, 4, 500),
                          P.WaveMultisine(0, ((100, 0, inc),)), baud)
            rows.append({"baudrate": baud, "rate_hz": rate, "samples": n,
                         "dropped": run.end.samples_dropped, "late": run.end.tick_overruns,
                         "load": rate * 21 * 10 / baud})
    return rows


def _encoder_ok(rate: float, decoding: int, duration: float = 1.0) -> tuple[bool, int, float]:
    n = int(duration * 500)
    run, _ = _run({"encoder_rate": rate}, P.Config(2000, n, 255, decoding, 500), P.WaveConstant(0))
    counts = np.array([s.counts for s in run.samples], dtype=float)
    t = np.array([s.time_us for s in run.samples], dtype=float) * 1e-6
    expected = rate * decoding / 4 * (t[-1] - t[0])
    deficit = expected - (counts[-1] - counts[0])
    ok = run.end.encoder_errors == 0 and abs(deficit) <= 1 + abs(rate) * decoding / 4 * 24e-6
    return ok, run.end.encoder_errors, deficit


def encoder_ceiling(decodings=(4, 2, 1), start: float = 40_000, step: float = 10_000,
                    stop: float = 300_000) -> list[dict]:
    """Highest 4x edge rate (counts/s) counted exactly with no error, per decoding (500 Hz run).

    Parameters
    ----------
    decodings : sequence of {1, 2, 4}
        Quadrature decodings to measure.
    start, step, stop : float
        Edge rates tried, in x4 counts/s: ``start, start + step, ...`` up to ``stop`` or the
        first failure.
    """
    rows = []
    for decoding in decodings:
        best, first_bad = None, None
        rate = start
        while rate <= stop:
            try:
                ok, errors, deficit = _encoder_ok(rate, decoding)
            except (TimeoutError, RuntimeError):      # the CPU is starved: no reply at all
                ok, errors, deficit = False, -1, float("nan")
            if not ok:
                first_bad = f"{rate} counts/s: {errors} illegal transitions, {float(deficit):g} counts short"
                break
            best = rate
            rate += step
        rows.append({"decoding": decoding, "ceiling_4x_counts_s": best,
                     "ceiling_decoded_counts_s": best * decoding / 4 if best else None,
                     "first_failure": first_bad})
    return rows


def _overruns(link: DeviceLink, period_us: int, controller: str | None, duration: float) -> int:
    """Late ticks of one run at ``period_us`` (open loop: a sine WAVE; else the controller on a sine)."""
    from motorsim.control import ClosedLoopExperiment, PlantModel, design_controller, parse_reference
    n = max(50, int(duration * 1e6 / period_us))
    inc = round(20.0 * period_us * 1e-6 / (2 * np.pi) * 2**32) % 2**32
    wave = P.WaveMultisine(0, ((100, 0, inc),))
    setup: list = []
    if controller is not None:
        model = PlantModel(25.0, 3.0, period_us * 1e-6, 16667)
        spec = "sine:5,1" if controller.endswith("position") else "sine:20,8"
        settings = {"feedforward": True} if controller == "pi+feedforward" else {}
        c = design_controller(controller.split("+")[0], model, **settings)
        exp = ClosedLoopExperiment(c, parse_reference(spec), n * period_us * 1e-6)
        setup = [P.control_for(exp), P.reference_for(exp)]
    run = link.run(P.Config(period_us, n, 255, 4, 500), wave, setup=setup, timeout=60.0)
    if run.end is None:
        raise RuntimeError(f"no END at {period_us} µs ({controller or 'open loop'})")
    return run.end.tick_overruns


def controller_cost(controllers=("mpc", "pi", "pi+feedforward", "position", "feedforward", "lqr", "lqr-integral",
                                 "lqr-position"), duration: float = 0.2, baudrate: int = 500000) -> list[dict]:
    """The shortest sample period (µs, to 1 µs) with zero late ticks, open loop and per controller.

    In closed loop the sample interrupt runs the controller's step instead of the WAVE's
    (a one-component sine), so the difference between a controller's shortest period and the
    open loop's is the step's cost per sample beyond the sine's, with everything else the
    interrupts and the line do at that rate (samples beyond the line's capacity are dropped
    and counted; late ticks are what is measured).

    Parameters
    ----------
    controllers : sequence of str
        ``mpc``, ``pi``, ``pi+feedforward``, ``position``, ``feedforward``, ``lqr``, ``lqr-integral``,
        ``lqr-position``.
    duration : float
        Emulated seconds per trial run.
    baudrate : int
        Firmware build and line rate.
    """
    build(baudrate)
    periods: list[tuple[str, int]] = []
    with open_avr_sim("avr-sim://?" + urlencode({"a": 25, "b": 3, "speed": 0}), baudrate, 0.02) as port:
        link = DeviceLink(port)
        link.hello(timeout=5.0)
        for controller in (None, *controllers):
            lo, hi = 99, 2000       # lo fails (below the 100 µs minimum), hi holds
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if _overruns(link, mid, controller, duration) == 0:
                    hi = mid
                else:
                    lo = mid
            periods.append((controller or "open loop (sine WAVE)", hi))
    base = periods[0][1]
    return [{"controller": name, "period_us": p, "rate_hz": 1e6 / p, "cost_us": p - base,
             "cost_cycles": 16 * (p - base)} for name, p in periods]


def emulation_speed(duration: float = 2.0) -> list[dict]:
    """Emulated seconds per wall second, running free (speed=0), during a 500 Hz sine run.

    Parameters
    ----------
    duration : float
        Seconds of emulated run per case.
    """
    rows = []
    for label, query in (("500 Hz sine, motor at ~25 k counts/s", {"a": 25, "b": 3, "speed": 0}),
                         ("500 Hz, encoder at 60 k counts/s", {"encoder_rate": 60000, "speed": 0})):
        inc = round(20.0 * 0.002 / (2 * np.pi) * 2**32) % 2**32
        _, stats = _run(query, P.Config(2000, int(duration * 500), 255, 4, 500),
                        P.WaveMultisine(0, ((100, 0, inc),)))
        rows.append({"case": label, "ratio": stats["ratio"]})
    return rows


def _table(header: list[str], rows, cells, last: bool = False) -> None:
    """A Markdown table, each row printed as it is measured (``cells`` turns a row into its cells)."""
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for r in rows:
        print("| " + " | ".join(str(c) for c in cells(r)) + " |", flush=True)
    if not last:
        print()


def bench_firmware(argv: Sequence[str] | None = None) -> int:
    """Print the tables; ``argv`` as for the command line (default ``sys.argv[1:]``); returns 0.

    Parameters
    ----------
    argv : list of str, optional
        ``--only size|link|encoder|control|speed`` (repeatable).
    """
    parser = argparse.ArgumentParser(prog="motorid bench firmware", description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=["size", "link", "encoder", "control", "speed"], action="append",
                        help="measure only this (repeatable; default all)")
    args = parser.parse_args(None if argv is None else list(argv))
    only = set(args.only or ["size", "link", "encoder", "control", "speed"])
    if "size" in only:
        s = firmware_size()
        print(f"flash {s['flash']} B ({100 * s['flash'] / _FLASH:.1f} % of {_FLASH}), "
              f"RAM {s['ram']} B ({100 * s['ram'] / _RAM:.1f} % of {_RAM})\n")
    if "link" in only:
        _table(["baud", "rate (Hz)", "samples", "dropped", "late ticks", "line load"], link_capacity(),
               lambda r: [r["baudrate"], r["rate_hz"], r["samples"], r["dropped"], r["late"],
                          f"{100 * r['load']:.0f} %"])
    if "encoder" in only:
        _table(["decoding", "ceiling (4x counts/s)", "decoded counts/s", "first failure"], encoder_ceiling(),
               lambda r: [f"x{r['decoding']}", r["ceiling_4x_counts_s"], r["ceiling_decoded_counts_s"],
                          r["first_failure"]])
    if "control" in only:
        _table(["controller", "shortest period without late ticks (µs)", "highest rate (Hz)",
                "step's cost per sample (µs, cycles at 16 MHz)"], controller_cost(),
               lambda r: [r["controller"], r["period_us"], f"{r['rate_hz']:.0f}",
                          f"{r['cost_us']} µs, {r['cost_cycles']} cycles"])
    if "speed" in only:
        _table(["case", "emulated s per wall s"], emulation_speed(), lambda r: [r["case"], f"{r['ratio']:.2f}"],
               last=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(bench_firmware())
