"""``motorid live``: run an experiment on the bench, record it as it arrives, identify a and b.

The samples go three ways as they arrive: to a :class:`~motorsim.recording.RecordingWriter`
(so a fault or Ctrl-C leaves a valid recording marked ``complete: false``), to a
running RLS estimate (:mod:`identify.recursive`) shown in the progress line, and
to an optional live plot.  After the run the recording is identified with
``identify.fit`` (default: ``identify.DEFAULT_METHOD``).

``--port 'fake://?a=25&b=3'`` runs the emulated Arduino, so this works without a board.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

__all__ = ["add_live_arguments", "run_live"]


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    from identify import DEFAULT_METHOD, available_methods
    from motorsim.sensors import DEFAULT_COUNTS_PER_REV

    from .cli import add_experiment_arguments
    g = parser.add_argument_group("bench")
    g.add_argument("--port", required=True, metavar="PORT",
                   help="serial port or URL: /dev/ttyACM0, COM3, socket://host:port, 'fake://?a=25&b=3' "
                        "(the emulated Arduino), avr-sim://...")
    g.add_argument("--baud", type=int, default=250_000, metavar="B",
                   help="line rate (default 250000 for <= 500 Hz; 115200 is the safe choice at <= 250 Hz)")
    g.add_argument("--counts-per-rev", type=int, default=DEFAULT_COUNTS_PER_REV, metavar="N",
                   help=f"encoder counts per revolution after decoding (default {DEFAULT_COUNTS_PER_REV})")
    g.add_argument("--decoding", type=int, default=4, choices=(1, 2, 4), help="quadrature decoding (default 4)")
    g.add_argument("--watchdog-ms", type=int, default=500, metavar="MS",
                   help="device stops the motor after this much host silence (default 500; 0 off)")
    g.add_argument("--timeout", type=float, default=1.0, metavar="S",
                   help="give up after the device is silent this long during a run (default 1 s)")
    add_experiment_arguments(parser)
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="where to write the recording")
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=available_methods(),
                        help=f"estimator after the run (default {DEFAULT_METHOD})")
    parser.add_argument("--json", action="store_true", help="end the output with one JSON line")
    parser.add_argument("--plot", action="store_true",
                        help="show duty and speed live with the running estimate (matplotlib window; "
                             "without a display, FILE.csv.live.png is updated instead)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")


class _Progress:
    """The progress line on stderr, at most 4 times a second."""

    def __init__(self, n_samples: int, enabled: bool):
        self.n = n_samples
        self.enabled = enabled and n_samples > 0
        self._next = 0.0

    def show(self, k: int, running, force: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (now < self._next and not force):
            return
        self._next = now + 0.25
        estimate = running.estimate()
        est = (f"a ≈ {estimate.a:.4g} 1/s  b ≈ {estimate.b:.4g}  ({estimate.model}, {estimate.n_rows} rows)"
               if estimate.ready else "estimate: waiting for data")
        print(f"\r  {k + 1:>7}/{self.n} samples ({100 * (k + 1) / self.n:5.1f} %)  {est}   ",
              end="", file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.enabled:
            print(file=sys.stderr)


def run_live(args: argparse.Namespace) -> int:
    from hardware.errors import RigError
    from hardware.serial_rig import SerialRig
    from identify import fit
    from identify.recursive import RunningEstimator
    from motorsim.recording import RecordingWriter

    from .cli import CommandError, experiment_from_args, format_estimate
    experiment = experiment_from_args(args)
    running = RunningEstimator(experiment.sample_period, args.counts_per_rev)
    progress = _Progress(experiment.n_samples, not args.quiet)
    plot = None
    if args.plot:
        from .plots import LivePlot
        plot = LivePlot(experiment, counts_per_rev=args.counts_per_rev, fallback_path=f"{args.out}.live.png")
    writer = RecordingWriter(args.out, experiment.sample_period, args.counts_per_rev,
                             metadata={"source": "SerialRig", **experiment.metadata(), "port": args.port})

    def on_sample(s) -> None:
        writer.append(s.seq, s.time_s, s.duty, s.counts)
        running.add(s.seq, s.time_s, s.duty, s.counts)
        progress.show(s.seq, running)
        if plot is not None:
            plot.add(s, running)

    try:
        with SerialRig(args.port, args.baud, counts_per_rev=args.counts_per_rev, decoding=args.decoding,
                       watchdog_ms=args.watchdog_ms, timeout=args.timeout) as rig:
            recording = rig.run(experiment, on_sample=on_sample)
    except RigError as exc:
        progress.done()
        meta = exc.recording.metadata if exc.recording is not None else None
        path = writer.close(False, f"{type(exc).__name__}: {exc}", metadata=meta)
        kept = f"; the {writer.n_rows} samples received are in {path} (complete: false)" if path else ""
        raise CommandError(f"{exc}{kept}") from None
    except BaseException as exc:   # Ctrl-C, a protocol version mismatch, ...: keep what arrived
        progress.done()
        reason = "interrupted (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
        path = writer.close(False, reason)
        if path is not None:
            print(f"motorid: the {writer.n_rows} samples received are in {path} (complete: false)",
                  file=sys.stderr)
        raise
    finally:
        if plot is not None:
            plot.close()
    progress.show(experiment.n_samples - 1, running, force=True)
    progress.done()
    path = writer.close(True, metadata=recording.metadata)
    estimate = fit(recording, method=args.method)
    m = recording.metadata
    print(f"wrote {len(recording)} samples to {path}: {m['samples_received']} received of "
          f"{m['samples_expected']}, {m['host_link_frames_lost']} lost on the link, "
          f"{m['device_samples_dropped']} dropped by the device, {m['host_rx_errors']} bad frames")
    print(format_estimate(estimate))
    run_est = running.estimate()
    if run_est.ready:
        print(f"running     a {run_est.a:.6g} 1/s, b {run_est.b:.6g} ({run_est.model}, {run_est.n_rows} rows, "
              f"the estimate shown during the run)")
    if args.json:
        out = {**estimate.to_dict(), "running_estimate": run_est.to_dict(), "recording": str(path),
               "samples_received": len(recording), "samples_expected": experiment.n_samples,
               "link_frames_lost": int(m["host_link_frames_lost"]),
               "device_samples_dropped": int(m["device_samples_dropped"]),
               "host_rx_errors": int(m["host_rx_errors"])}
        print(json.dumps(out))
    return 0
